"""`hypergs build-extension`: the Blender extension zip(s), built and validated with Blender's tool
(tools/build_extension.py, run from the source checkout)."""
from __future__ import annotations

from . import options
from .checkout import ROOT, run_tool


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("build-extension", help="build and validate the Blender extension zip(s)")
    p.add_argument("--output-dir", default=str(ROOT / "dist"), type=options.output_folder)
    p.add_argument("--split-platforms", action="store_true", help="one zip per platform")
    p.set_defaults(func=_build_command)


def _build_command(args) -> None:
    run_tool("build_extension.py", "--output-dir", args.output_dir, *(["--split-platforms"] if args.split_platforms else []))
