"""`hypergs bench splat`: the HyperGS engine's F12 in headless Blender (the bpy wheel), default 1920 x 1080
with 100k Gaussians per frame, through its two paths: the GPU splats (engine/splat.py, Blender's gpu module;
on a machine without a GPU, Mesa's software OpenGL) and the numpy path (what runs without a GPU context).
Also the viewport's cost per frame, what view_draw does on a new frame: the splat rows (numpy) and the
offscreen drawing (until the GPU has finished).

Each path runs in its own Blender session, a subprocess (bpy imports once per process): the numpy one with
EGL hidden (bench.blender.NO_EGL), as on a machine without Mesa's EGL. F12 times are wall seconds of
`bpy.ops.render.render()` (no file written), medians over `repeats` renders after a warm-up one; CPU seconds
are the session process's (Mesa's threads included), telling what a loaded machine takes from the wall time.
"""
from __future__ import annotations

import importlib
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from ..errors import HyperGSError
from .blender import NO_EGL, build_zip, in_gpu_context, install_extension, start_blender
from .common import machine_report
from .raster import realistic_params

CLIP_FRAMES = 3  # the renders cycle through the clip's frames


def bench_splat(width: int = 1920, height: int = 1080, gaussians: int = 100_000, repeats: int = 5) -> dict:
    report = {"machine": machine_report(), "width": width, "height": height, "gaussians": gaussians,
              "repeats": repeats}
    with tempfile.TemporaryDirectory(prefix="hypergs-bench-splat-") as tmp:
        tmp = Path(tmp)
        zip_path = build_zip(tmp / "dist")
        for path, env in (("gpu", {}), ("numpy", NO_EGL)):
            out = tmp / f"{path}.json"
            cmd = [sys.executable, "-m", __name__, str(zip_path), str(tmp / path), str(out),
                   str(width), str(height), str(gaussians), str(repeats)]
            proc = subprocess.run(cmd, env=dict(os.environ, **env), capture_output=True, text=True)
            if not out.is_file():
                raise HyperGSError(f"bench splat: the Blender session ({path}) died (rc {proc.returncode}):\n"
                                   f"{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
            report[path] = json.loads(out.read_text())
    if report["numpy"]["gpu_context"]:
        raise HyperGSError("bench splat: hiding EGL (bench.blender.NO_EGL) did not take the GPU context away")
    return report


def session(zip_path, work: Path, width: int, height: int, gaussians: int, repeats: int) -> dict:
    """One Blender session: a clip of `gaussians` per frame at width x height, F12 timed (and, where the
    engine has a GPU context, the viewport's drawing)."""
    from ..gaussians import GaussianVideo
    from ..io.npz import save_npz

    work.mkdir(parents=True, exist_ok=True)
    bpy = start_blender(work / "user")
    addon = install_extension(bpy, zip_path)
    engine = importlib.import_module(f"{addon.__name__}.engine")
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

    splat = importlib.import_module(f"{addon.__name__}.engine.splat")
    geometry = importlib.import_module(f"{addon.__name__}.engine.geometry")
    from ..splat import splat_rows

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


if __name__ == "__main__":
    zip_arg, work_arg, out_arg, *numbers = sys.argv[1:]
    w, h, n, r = (int(v) for v in numbers)
    Path(out_arg).write_text(json.dumps(session(zip_arg, Path(work_arg), w, h, n, r)))
    sys.stdout.flush()
    os._exit(0)  # skip bpy's slow teardown
