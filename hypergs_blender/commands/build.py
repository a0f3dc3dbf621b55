"""`hypergs build-extension`: the Blender extension zip(s), built and validated with Blender's tool."""
from __future__ import annotations

from . import options


def add_commands(subparsers) -> None:
    from ..bench.blender import ROOT
    p = subparsers.add_parser("build-extension", help="build and validate the Blender extension zip(s)")
    p.add_argument("--output-dir", default=str(ROOT / "dist"), type=options.output_folder)
    p.add_argument("--split-platforms", action="store_true", help="one zip per platform")
    p.set_defaults(func=_build_command)


def _build_command(args) -> None:
    from ..bench.blender import build
    for path in build(args.output_dir, args.split_platforms):
        print(path)
