"""The HyperGS engine's F12 in headless Blender (the bpy wheel), default 1920 x 1080
with 100k Gaussians per frame, through its two paths: the GPU splats (engine/splat.py, Blender's gpu module;
on a machine without a GPU, Mesa's software OpenGL) and the numpy path (what runs without a GPU context).
Also the viewport's cost per frame, what view_draw does on a new frame: the splat rows (numpy) and the
offscreen drawing (until the GPU has finished).

    python tools/bench_splat.py [--size 1920x1080] [--gaussians 100000] [--repeats 5] [--report REPORT.json]

(`hypergs bench splat` runs this script and prints the report.) Each path runs in its own Blender
session, a subprocess (bpy imports once per process): the numpy one with EGL hidden
(blender_headless.NO_EGL), as on a machine without Mesa's EGL. F12 times are wall seconds of
`bpy.ops.render.render()` (no file written), medians over `repeats` renders after a warm-up one; CPU seconds
are the session process's (Mesa's threads included), telling what a loaded machine takes from the wall time.
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from blender_headless import NO_EGL, addon_module, exit_session, in_gpu_context, install_extension, start_blender
from build_extension import BuildError, build_zip
from hypergs_blender.bench.common import machine_report
from hypergs_blender.bench.raster import realistic_params

CLIP_FRAMES = 3  # the renders cycle through the clip's frames


def bench_splat(width: int = 1920, height: int = 1080, gaussians: int = 100_000, repeats: int = 5) -> dict:
    report = {"machine": machine_report(), "width": width, "height": height, "gaussians": gaussians,
              "repeats": repeats}
    with tempfile.TemporaryDirectory(prefix="hypergs-bench-splat-") as tmp:
        tmp = Path(tmp)
        zip_path = build_zip(tmp / "dist")
        for path, env in (("gpu", {}), ("numpy", NO_EGL)):
            out = tmp / f"{path}.json"
            cmd = [sys.executable, __file__, "--session", str(zip_path), str(tmp / path), str(out),
                   str(width), str(height), str(gaussians), str(repeats)]
            proc = subprocess.run(cmd, env=dict(os.environ, **env), capture_output=True, text=True)
            if not out.is_file():
                raise RuntimeError(f"bench splat: the Blender session ({path}) died (rc {proc.returncode}):\n"
                                   f"{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
            report[path] = json.loads(out.read_text())
    if report["numpy"]["gpu_context"]:
        raise RuntimeError("bench splat: hiding EGL (blender_headless.NO_EGL) did not take the GPU context away")
    return report


def session(zip_path, work: Path, width: int, height: int, gaussians: int, repeats: int) -> dict:
    """One Blender session: a clip of `gaussians` per frame at width x height, F12 timed (and, where the
    engine has a GPU context, the viewport's drawing)."""
    from hypergs_blender.gaussians import GaussianVideo
    from hypergs_blender.io.npz import save_npz

    work.mkdir(parents=True, exist_ok=True)
    bpy = start_blender(work / "user")
    addon = install_extension(bpy, zip_path)
    engine = addon_module(addon, "engine")
    params, sigma = realistic_params(CLIP_FRAMES, gaussians, width, height)
    save_npz(GaussianVideo(params, width, height), work / "bench.npz")
    bpy.ops.hypergs.import_clip(filepath=str(work / "bench.npz"))
    scene = bpy.context.scene
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = width, height, 100

    def f12(i):
        scene.frame_set(scene.frame_start + i % CLIP_FRAMES)
        wall, cpu = time.perf_counter(), time.process_time()
        bpy.ops.render.render()
        return time.perf_counter() - wall, time.process_time() - cpu

    f12(0)  # warm-up: shader compilation, first allocations
    runs = [f12(i) for i in range(1, repeats + 1)]
    result = {"gpu_context": engine.HyperGSRenderEngine.bl_use_gpu_context, "sigma_px": round(sigma, 2),
              "f12_s": [round(w, 3) for w, _ in runs],
              "f12_median_s": round(statistics.median(w for w, _ in runs), 3),
              "f12_cpu_median_s": round(statistics.median(c for _, c in runs), 3)}
    if result["gpu_context"]:
        result["viewport"] = _viewport_times(bpy, addon, width, height, repeats)
    return result


def _viewport_times(bpy, addon, width: int, height: int, repeats: int) -> dict:
    """What view_draw does for a new frame of a width x height frame rect, inside a render with a GPU context
    (there is no window here): medians of the splat rows (numpy, from the evaluated clips) and of drawing
    them into a SplatImage until the GPU has finished (a one-pixel read waits for it)."""
    import gpu

    splat = addon_module(addon, "engine.splat")
    geometry = addon_module(addon, "engine.geometry")
    from hypergs_blender.splat import splat_rows

    def work(depsgraph) -> dict:
        image = splat.SplatImage(width, height)
        finish = gpu.types.GPUFrameBuffer(color_slots=image.texture)
        rows_s, draw_s = [], []
        for _ in range(repeats + 1):
            started = time.perf_counter()
            clips = [(p, cw, ch) for _, p, cw, ch in geometry.evaluated_clips(depsgraph)]
            rows = splat_rows(clips, width, height)
            drawn = time.perf_counter()
            image.draw(rows)
            with finish.bind():
                finish.read_color(0, 0, 1, 1, 4, 0, "FLOAT")
            rows_s.append(drawn - started)
            draw_s.append(time.perf_counter() - drawn)
        image.free()
        return dict(instances=len(rows), rows_median_s=round(statistics.median(rows_s[1:]), 4),
                    draw_median_s=round(statistics.median(draw_s[1:]), 4))

    return in_gpu_context(bpy, work)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Blender F12 s/frame, GPU splats vs numpy path, viewport draw time.")
    parser.add_argument("--size", default="1920x1080", help="render size WxH")
    parser.add_argument("--gaussians", type=int, default=100_000, help="Gaussians per frame")
    parser.add_argument("--repeats", type=int, default=5, help="timed renders per path (after a warm-up one)")
    parser.add_argument("--report", help="write the JSON report here (else print it)")
    parser.add_argument("--session", nargs=7, help=argparse.SUPPRESS)  # one Blender session (a subprocess)
    args = parser.parse_args(argv)
    if args.session:
        zip_arg, work_arg, out_arg, *numbers = args.session
        w, h, n, r = (int(v) for v in numbers)
        Path(out_arg).write_text(json.dumps(session(zip_arg, Path(work_arg), w, h, n, r)))
        exit_session()
    width, height = (int(v) for v in args.size.lower().split("x"))
    try:
        report = json.dumps(bench_splat(width, height, args.gaussians, args.repeats), indent=1)
    except (BuildError, RuntimeError, OSError) as e:
        print(f"error: {' '.join(str(e).split())}", file=sys.stderr)
        return 1
    if args.report:
        Path(args.report).write_text(report)
    else:
        print(report)
    return 0


if __name__ == "__main__":
    sys.exit(main())
