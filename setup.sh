#!/usr/bin/env bash
# One-time set-up on a fresh machine: a virtual environment in .venv with the pinned dependencies
# and this package installed in editable mode. Re-running it is cheap (pip skips what is installed).
set -euo pipefail
cd "$(dirname "$0")"
PY=${PYTHON:-python3.11}
[ -x .venv/bin/python ] || "$PY" -m venv .venv
.venv/bin/python -m pip install -q --upgrade pip
.venv/bin/python -m pip install -q -r requirements.txt
.venv/bin/python -m pip install -q --no-deps -e .
