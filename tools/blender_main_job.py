"""The main job, headless: build the extension, install it into a throw-away Blender user directory,
add the bundled sample video as a sequencer strip, convert it with `bpy.ops.hypergs.convert_strip()`,
render the Sequencer's output (the scene strip the conversion adds) with F12 to PNG and print its PSNR
against the source frames. With --transformer WEIGHTS (a folder as `hypergs export` writes it) the job
also converts a few frames of it with the HyperGS transformer (Model in the Convert dialog, its weights
set in the add-on's preferences), N Gaussians per tile on a patch grid, and renders one with F12.

    .venv/bin/python tools/blender_main_job.py [--video PATH] [--size WxH] [--frames 1,20,40]
                                               [--quality draft|standard|high] [--gaussians N]
                                               [--encoder floor|bundled]
                                               [--zip EXTENSION.zip] [--json FIGURES.json]
                                               [--transformer WEIGHTS [--transformer-gaussians N]
                                                [--transformer-grid CxR]]

Runs with the `bpy` wheel of the venv (no Blender install needed). PNGs go to runs/main_job/.
tools/blender_matrix.py runs it in every supported Blender.
"""
from __future__ import annotations

import argparse
import json
import math
import os
import platform
import shutil
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

from blender_headless import (ROOT, SAMPLE, add_movie_strip, addon_module, exit_session, install_extension,
                              read_png, render_png, set_strip_range, source_frames, start_blender)
from build_extension import build_zip
from hypergs_blender.encode import QUALITY
from hypergs_blender.metrics import psnr

# The encoder the main job uses unless --encoder says otherwise: the bundled network ("floor": the
# no-learning grid floor, for comparison).
DEFAULT_ENCODER = "bundled"
TRANSFORMER_FRAMES = 6  # converted with the transformer: a clip of 4 frames and one padded


def main_job(argv=None) -> int:
    parser = argparse.ArgumentParser(description="The main job: the bundled sample strip converted in Blender, "
                                                 "F12 of the Sequencer's output to PNG, PSNR.")
    parser.add_argument("--video", default=str(SAMPLE), help="video to convert (default: the bundled sample)")
    parser.add_argument("--size", help="render size WxH (default: the video's)")
    parser.add_argument("--frames", help="scene frames to render, comma-separated (default: 5 spread)")
    parser.add_argument("--quality", choices=tuple(QUALITY), default="standard",
                        help="the Convert dialog's Quality preset")
    parser.add_argument("--gaussians", type=int, default=0, help="Gaussians per frame instead of a preset")
    parser.add_argument("--cell", type=float, default=None, help="cell size in source pixels instead of a preset")
    parser.add_argument("--encoder", choices=("floor", "bundled"),
                        default=os.environ.get("HYPERGS_ENCODER", DEFAULT_ENCODER))
    parser.add_argument("--zip", help="install this extension zip instead of building one")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--out", default=str(ROOT / "runs" / "main_job"))
    parser.add_argument("--transformer", help="also convert a few frames with the transformer of this weights folder")
    parser.add_argument("--transformer-gaussians", type=int, default=64, help="its Gaussians per tile")
    parser.add_argument("--transformer-grid", default="2x1", help="its patch grid, COLSxROWS")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    video = Path(args.video).resolve()

    started = time.perf_counter()
    if args.zip:
        zip_path = Path(args.zip)
    else:
        zip_path = build_zip(out / "dist")  # its own folder: runs side by side do not build into one
        print(f"built and validated {zip_path.name} ({zip_path.stat().st_size / 1e6:.0f} MB) "
              f"in {time.perf_counter() - started:.1f} s")
    os.environ["HYPERGS_ENCODER"] = args.encoder
    user_dir = tempfile.mkdtemp(prefix="hypergs-blender-user-")
    report = dict(python=platform.python_version(), encoder=args.encoder)
    try:
        bpy = start_blender(user_dir)
        report["blender"] = bpy.app.version_string
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t = time.perf_counter()
            addon = install_extension(bpy, zip_path)
            report["install_s"] = time.perf_counter() - t
            print(f"installed into {user_dir} (Blender {bpy.app.version_string}, Python {report['python']}), "
                  f"encoder: {args.encoder}")
            _main_job_scene(bpy, addon, args, video, out, report)
            if args.transformer:
                _transformer_conversion(bpy, addon, args, video, out, report)
        here = str(Path(addon.__file__).parent)
        report["deprecations"] = sorted({f"{Path(w.filename).relative_to(here)}:{w.lineno}: {w.message}"
                                         for w in caught if issubclass(w.category, DeprecationWarning)
                                         and w.filename.startswith(here)})
        for line in report["deprecations"]:
            print("deprecated:", line)
    finally:
        shutil.rmtree(user_dir, ignore_errors=True)
        if args.json:
            Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


def _main_job_scene(bpy, addon, args, video: Path, out: Path, report: dict) -> None:
    """Convert the video's strip, then F12 of the Sequencer's output (the scene strip the conversion
    added plays the clip's scene, rendered by HyperGS) at spread frames, against the source."""
    compat = addon_module(addon, "com.compat")
    scene = bpy.context.scene
    from hypergs_blender.io.frames import probe
    info = probe(video)
    width, height = (map(int, args.size.lower().split("x")) if args.size else (info.width, info.height))
    scene.render.resolution_x, scene.render.resolution_y = width, height  # before the strip: it fits this
    scene.render.resolution_percentage = 100
    strip = add_movie_strip(bpy, scene, video, name=video.stem)
    scene.view_settings.view_transform = "Standard"  # as in a video editing file: output = the strips' sRGB
    first, end = compat.strip_range(strip)
    scene.frame_start, scene.frame_end = first, end - 1
    t = time.perf_counter()
    if args.gaussians or args.cell:
        options = dict(quality="CUSTOM", gaussian_count=args.gaussians or 0,
                       cell_size=args.cell or QUALITY["standard"]["cell"])
    else:
        options = dict(quality=args.quality.upper())
    bpy.ops.hypergs.convert_strip(**options)
    report["convert_s"] = convert_s = time.perf_counter() - t
    scene_strip = scene.sequence_editor.active_strip
    obj = next(o for o in scene_strip.scene.objects if o.hypergs.is_clip)
    s = obj.hypergs
    report.update(frames=s.num_frames, gaussians=s.gaussians_per_frame, encode_psnr=s.psnr,
                  scene_strip=dict(name=scene_strip.name, range=list(compat.strip_range(scene_strip)),
                                   channel=scene_strip.channel, movie_range=[first, end], movie_muted=strip.mute,
                                   engine=scene_strip.scene.render.engine))
    print(f"converted strip '{strip.name}': {s.num_frames} frames x {s.gaussians_per_frame} Gaussians "
          f"in {convert_s:.1f} s (encode-time PSNR {s.psnr:.2f} dB), played by the scene strip "
          f"'{scene_strip.name}' on channel {scene_strip.channel}")
    if args.frames:
        frames = [int(f) for f in args.frames.split(",")]
    else:
        frames = sorted(set(np.linspace(scene.frame_start, scene.frame_end, 5).round().astype(int).tolist()))
    offset = s.source_start - first  # source frame index = scene frame + offset
    truth = source_frames(video, [f + offset for f in frames], width, height)
    values, seconds = [], []
    print(f"F12 of the Sequencer at {width}x{height}:")
    for f in frames:
        png = out / f"frame_{f:04d}.png"
        seconds.append(render_png(bpy, scene, f, png))
        values.append(float(psnr(read_png(bpy, png), truth[f + offset])))
        shown = png.relative_to(ROOT) if png.is_relative_to(ROOT) else png
        print(f"  frame {f:4d}: PSNR {values[-1]:6.2f} dB  ({seconds[-1]:.2f} s)  {shown}")
    print(f"mean PSNR {np.mean(values):.2f} dB over {len(values)} frames")
    report.update(render_frames=frames, psnr=values, render_s=seconds, mean_psnr=float(np.mean(values)))
    # The clip exported to a .hgs file it is then linked to (the codec's bundled wheels at work): the
    # Sequencer's F12 shows it as before, up to the file's 8-bit quantization.
    clip_scene = scene_strip.scene
    with bpy.context.temp_override(scene=clip_scene, view_layer=clip_scene.view_layers[0], active_object=obj,
                                   object=obj):
        bpy.ops.hypergs.export_clip(filepath=str(out / "clip.hgs"), link=True)
    middle = frames[len(frames) // 2]
    png = out / f"linked_{middle:04d}.png"
    render_png(bpy, scene, middle, png)
    report.update(linked=obj.hypergs.linked, linked_psnr=float(psnr(read_png(bpy, png), truth[middle + offset])),
                  cached_psnr=values[len(frames) // 2])
    print(f"linked to {out / 'clip.hgs'}: frame {middle} PSNR {report['linked_psnr']:.2f} dB "
          f"(from its frame cache {report['cached_psnr']:.2f} dB)")


def _transformer_conversion(bpy, addon, args, video: Path, out: Path, report: dict) -> None:
    """A few frames of the video as a movie strip above the others, converted with Model: HyperGS
    Transformer (weights from the preferences), N per tile on the patch grid; F12 of one frame against
    the source. report["transformer"]: the Gaussians per frame against tiles x N (N rounded to a
    square: the tile's k x k lattice), both PSNRs."""
    compat = addon_module(addon, "com.compat")
    preferences = addon_module(addon, "ops.preferences")
    bpy.context.preferences.addons[preferences.ADDON].preferences.transformer_weights = str(Path(args.transformer))
    scene = bpy.context.scene
    editor = scene.sequence_editor
    channel = max(s.channel for s in compat.all_strips(editor)) + 1
    strip = add_movie_strip(bpy, scene, video, name=f"{video.stem}_transformer")
    strip.channel = channel
    first = compat.strip_range(strip)[0]
    set_strip_range(strip, first, first + TRANSFORMER_FRAMES)
    for s in compat.all_strips(editor):
        s.select = s == strip
    editor.active_strip = strip
    columns, rows = (int(v) for v in args.transformer_grid.lower().split("x"))
    t = time.perf_counter()
    bpy.ops.hypergs.convert_strip(model="TRANSFORMER", quality="CUSTOM", gaussian_count=args.transformer_gaussians,
                                  patch_grid=(columns, rows))
    convert_s = time.perf_counter() - t
    scene_strip = editor.active_strip
    obj = next(o for o in scene_strip.scene.objects if o.hypergs.is_clip)
    s = obj.hypergs
    frame = first + TRANSFORMER_FRAMES // 2
    png = out / f"transformer_{frame:04d}.png"
    render_png(bpy, scene, frame, png)
    offset = s.source_start - first
    truth = source_frames(video, [frame + offset], scene.render.resolution_x, scene.render.resolution_y)
    f12 = float(psnr(read_png(bpy, png), truth[frame + offset]))
    report["transformer"] = dict(frames=s.num_frames, gaussians=s.gaussians_per_frame,
                                 expected=columns * rows * round(math.sqrt(args.transformer_gaussians)) ** 2,
                                 encoder=s.encoder,  # expected: a k x k lattice per tile, k = round(sqrt(N))
                                 encode_psnr=s.psnr, psnr=f12, convert_s=convert_s, on_top=scene_strip.channel > channel)
    print(f"transformer: {s.num_frames} frames x {s.gaussians_per_frame} Gaussians ({columns}x{rows} tiles x "
          f"{args.transformer_gaussians}) with {s.encoder} in {convert_s:.1f} s (encode-time PSNR {s.psnr:.2f} dB); "
          f"F12 of frame {frame}: PSNR {f12:.2f} dB")


if __name__ == "__main__":
    exit_session(main_job())
