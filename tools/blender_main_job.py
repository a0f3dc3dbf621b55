"""The main job, headless: build the extension, install it into a throw-away Blender user directory,
add the bundled sample video as a sequencer strip, convert it with `bpy.ops.hypergs.convert_strip()`,
render frames with F12 to PNG and print their PSNR against the source frames.

    .venv/bin/python tools/blender_main_job.py [--video PATH] [--size WxH] [--frames 1,20,40]
                                               [--gaussians N | --cell C] [--encoder floor|bundled]

Runs with the `bpy` wheel of the venv (no Blender install needed). PNGs go to runs/main_job/.
The work is in hypergs_blender/bench/blender.py.
"""
import sys

from hypergs_blender.bench.blender import main_job

if __name__ == "__main__":
    sys.exit(main_job())
