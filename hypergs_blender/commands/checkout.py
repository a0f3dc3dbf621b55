"""The source checkout this package runs from (an editable install): the extension's manifest, tools/
and docs/ live beside hypergs_blender/. Commands that build the extension or drive Blender run the
scripts in tools/ in a fresh Python (`run_tool`): the core never imports them."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from ..errors import HyperGSError

ROOT = Path(__file__).resolve().parents[2]


def run_tool(script: str, *args) -> None:
    """Run tools/`script` with this Python and `args`; its stdout and stderr pass through as they come,
    but for a failed run's last stderr line (the tool's `error: ...`), raised as the HyperGSError."""
    path = ROOT / "tools" / script
    if not path.is_file():
        raise HyperGSError(f"{path} is missing: this command needs a source checkout of HyperGS")
    with subprocess.Popen([sys.executable, str(path), *map(str, args)], stderr=subprocess.PIPE, text=True) as proc:
        last = ""
        for line in proc.stderr:
            if last:
                sys.stderr.write(last)
            last = line
    if proc.returncode != 0:
        raise HyperGSError(last.strip().removeprefix("error: ") or f"tools/{script} failed "
                                                                   f"(exit status {proc.returncode})")
    sys.stderr.write(last)
