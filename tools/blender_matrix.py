"""The Blender matrix: build the extension zip, then install it and run the main job (convert the
sample strip, F12 of the Sequencer's output, PSNR) in bpy 4.2 LTS (Python 3.11), 5.0 (3.11) and
5.2 (3.13), each in its own venv under .blender-matrix/ (made once, reused).

    .venv/bin/python tools/blender_matrix.py [--versions 4.2,5.0,5.2] [--encoder bundled|floor]

`.ci/run` runs it after the tests. The work is in hypergs_blender/bench/matrix.py.
"""
import sys

from hypergs_blender.bench.matrix import main

if __name__ == "__main__":
    sys.exit(main())
