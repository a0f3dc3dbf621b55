"""F12 of a converted clip's own scene at a percentage of the clip's size, with the pixel filter
(`gaussians.PIXEL_VARIANCE`) and without it (the installed extension's constant set to 0 in the same session),
against the source resized to that size (swscale's AREA): the model card's session 32 table.

    .venv/bin/python tools/pixel_filter_f12.py runs/heldout720/Aqua.mp4 --quality high [--percent 50]

Runs with the `bpy` wheel of the venv: builds the extension, converts the video's strip with the Sequencer's
Convert, then renders the scene frames 13, 25 and 37 of the clip's scene at 100 % and at --percent. Prints one JSON line.
"""
from __future__ import annotations

import argparse
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np

from blender_headless import (add_movie_strip, addon_module, exit_session, install_extension, read_png, render_png,
                              source_frames, start_blender)
from build_extension import build_zip
from hypergs_blender.encode import QUALITY
from hypergs_blender.io.frames import probe
from hypergs_blender.metrics import psnr


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("video")
    parser.add_argument("--quality", choices=tuple(QUALITY), default="standard")
    parser.add_argument("--percent", type=int, default=50, help="the clip scene's resolution percentage")
    args = parser.parse_args()
    video = Path(args.video).resolve()
    work = Path(tempfile.mkdtemp(prefix="hypergs-pixel-filter-"))
    try:
        print(json.dumps(measure(args, video, work)), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    return 0


def measure(args, video: Path, work: Path) -> dict:
    zip_path = build_zip(work / "dist")
    bpy = start_blender(work / "user")
    addon = install_extension(bpy, zip_path)
    compat = addon_module(addon, "com.compat")
    gaussians = addon_module(addon, "hypergs_blender.gaussians")
    info = probe(video)
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = (
        info.width, info.height, 100)
    strip = add_movie_strip(bpy, scene, video, name=video.stem)
    first, end = compat.strip_range(strip)
    scene.frame_start, scene.frame_end = first, end - 1
    bpy.ops.hypergs.convert_strip(quality=args.quality.upper())
    clip_scene = scene.sequence_editor.active_strip.scene
    clip_scene.view_settings.view_transform = "Standard"  # output = the Gaussians' sRGB sums, as the source
    obj = next(o for o in clip_scene.objects if o.hypergs.is_clip)
    offset = obj.hypergs.source_start - first
    frames = [f for f in (first + 12, first + 24, first + 36) if f < end]
    filtered = gaussians.PIXEL_VARIANCE
    report = dict(video=video.name, quality=args.quality, frames=frames)
    for percent in (100, args.percent):
        clip_scene.render.resolution_percentage = percent
        width, height = info.width * percent // 100, info.height * percent // 100
        truth = source_frames(video, [f + offset for f in frames], width, height)
        for label, variance in (("filter", filtered), ("no filter", 0.0)):
            gaussians.PIXEL_VARIANCE = variance
            values = []
            for f in frames:
                png = work / f"frame_{f:04d}.png"
                with bpy.context.temp_override(scene=clip_scene, view_layer=clip_scene.view_layers[0]):
                    render_png(bpy, clip_scene, f, png)
                values.append(float(psnr(read_png(bpy, png), truth[f + offset])))
            report[f"{percent}% ({width}x{height}), {label}"] = round(float(np.mean(values)), 3)
        gaussians.PIXEL_VARIANCE = filtered
    return report


if __name__ == "__main__":
    exit_session(main())
