"""`hypergs` command line. Each module in COMMAND_MODULES adds its own subcommands with
`add_commands(subparsers)`; modules are imported only when the CLI starts."""
from __future__ import annotations

import argparse
import importlib
import sys

from ..errors import HyperGSError

COMMAND_MODULES = ["encode", "evaluate", "fit", "train", "data", "clips", "bench", "build"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="hypergs", description="HyperGS: videos to editable 2D Gaussians in one forward pass.")
    subparsers = parser.add_subparsers(dest="command", required=True)
    for name in COMMAND_MODULES:
        importlib.import_module(f"{__package__}.{name}").add_commands(subparsers)
    return parser


def main(argv=None) -> None:
    args = build_parser().parse_args(argv)
    try:
        args.func(args)
    except HyperGSError as e:
        print(f"hypergs: error: {e}", file=sys.stderr)
        sys.exit(2)
