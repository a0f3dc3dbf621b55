"""The main job, headless: build the extension, install it into a throw-away Blender user directory,
add the bundled sample video as a sequencer strip, convert it with `bpy.ops.hypergs.convert_strip()`,
render the Sequencer's output (the scene strip the conversion adds) with F12 to PNG and print its PSNR
against the source frames.

    .venv/bin/python tools/blender_main_job.py [--video PATH] [--size WxH] [--frames 1,20,40]
                                               [--quality draft|standard|high] [--gaussians N]
                                               [--encoder floor|bundled]
                                               [--zip EXTENSION.zip] [--json FIGURES.json]

Runs with the `bpy` wheel of the venv (no Blender install needed). PNGs go to runs/main_job/.
The work is in hypergs_blender/bench/blender.py.
"""
import os
import sys

from hypergs_blender.bench.blender import main_job

if __name__ == "__main__":
    code = main_job()
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(code)  # bpy 4.2 segfaults at a normal exit once a render engine is registered
