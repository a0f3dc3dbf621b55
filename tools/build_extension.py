"""Build the Blender extension zip(s) with Blender's own tool, and validate them with it.

    python tools/build_extension.py [--output-dir dist] [--split-platforms]

The same as `hypergs build-extension` (hypergs_blender/bench/blender.py does the work).
"""
import sys

from hypergs_blender.commands.cli import main

if __name__ == "__main__":
    main(["build-extension", *sys.argv[1:]])
