"""Long clips: the figures of issue 17, printed (1080p30 at the Standard quality, 30 -> 300 -> 1,800 frames).

Stages (each one process per clip length, so peak memory is that job's own):
  make     the test videos: 1080p30 camera pans over a procedural image (bench/scale.py), made once into
           --out (never the dev clips);
  cli      `hypergs encode VIDEO -o clip.hgs` at Standard: seconds per frame (wall and CPU), peak RSS;
  blender  File > Import of the video in headless Blender (the bpy wheel, the built extension) at Standard:
           conversion seconds per frame (wall and CPU) and the dialog's estimate for it, peak RSS of the
           session, the scene's frame rate and range after it, the cost of a frame change (scene.frame_set:
           playback of frames not decoded yet, playback again from the decoded-frame cache, random scrubbing,
           and after saving and reopening), the .blend's and the frame cache's size.

    .venv/bin/python tools/long_clips.py --frames 30,300 --stages make,cli,blender
    HYPERGS_ENCODER=floor .venv/bin/python tools/long_clips.py --stages blender ...  # the no-learning floor:
        fast, for what does not depend on the network (frame changes, .blend size, Blender's own memory)

The CLI runs the network on onnxruntime by default (--backend), as Blender does, so the two figures compare
the paths, not the backends. Time figures on a shared machine: repeat (--repeats) and take the minimum, and
read the CPU seconds beside the wall seconds; the report says the load average. Long runs belong in the
background, nice'd (`nohup nice -n 10 ... > log 2>&1 &`): 1,800 frames of 1080p through the network are
15+ CPU minutes per conversion.
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tools")]

WIDTH, HEIGHT, FPS = 1920, 1080, 30
STAGES = ("make", "cli", "blender")
SCENE_FPS = 24  # the scene's rate before the import (File > Import must make it the clip's)
PLAYBACK = 90  # frames played in order (each decoded from the cache: not in its LRU yet)
SCRUBS = 60  # random frame changes


def video_path(out: Path, frames: int) -> Path:
    return out / f"pan_{WIDTH}x{HEIGHT}_{FPS}fps_{frames}.mp4"


def make_video(out: Path, frames: int) -> Path:
    from hypergs_blender.bench.scale import make_pan_video
    path = video_path(out, frames)
    if not path.is_file():
        partial = path.with_name(".part_" + path.name)
        make_pan_video(partial, seconds=frames / FPS, width=WIDTH, height=HEIGHT, fps=FPS)
        os.replace(partial, path)
    return path


def measured(cmd: list[str], env: dict | None = None) -> dict:
    """Run `cmd`; its wall time, CPU time and peak RSS (MiB; os.wait4's rusage of the process and its
    children)."""
    started = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout, stderr = proc.communicate()
    seconds = time.perf_counter() - started
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)  # one child per tool process (see main)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed (exit {proc.returncode}):\n{stdout[-2000:]}\n{stderr[-3000:]}")
    return {"seconds": seconds, "cpu_seconds": usage.ru_utime + usage.ru_stime, "peak_rss_mib": usage.ru_maxrss / 1024,
            "stdout": stdout, "stderr": stderr}


def load() -> float:
    return os.getloadavg()[0]


def cli_stage(out: Path, frames: int, encoder: str, backend: str) -> dict:
    video = video_path(out, frames)
    clip = out / f"cli_{frames}.hgs"
    cmd = [sys.executable, "-m", "hypergs_blender", "encode", str(video), "-o", str(clip), "--quality", "standard"]
    cmd += ["--encoder", "floor"] if encoder == "floor" else ["--encoder", "network", "--backend", backend]
    run = measured(cmd)
    return {"frames": frames, "encoder": encoder if encoder == "floor" else f"network-{backend}",
            "s_per_frame": round(run["seconds"] / frames, 3), "cpu_s_per_frame": round(run["cpu_seconds"] / frames, 3),
            "peak_rss_mib": round(run["peak_rss_mib"]), "hgs_mb": round(clip.stat().st_size / 1e6, 1),
            "load": round(load(), 1)}


def blender_stage(out: Path, frames: int, zip_path: Path) -> dict:
    """The Blender session (blender_session) in a child process: its figures and its peak RSS."""
    figures = out / f"blender_{frames}_session.json"
    run = measured([sys.executable, __file__, "--session", str(frames), "--out", str(out), "--zip", str(zip_path),
                    "--json", str(figures)])
    report = json.loads(figures.read_text())
    report.update(peak_rss_mib=round(run["peak_rss_mib"]), session_cpu_s=round(run["cpu_seconds"], 1))
    return report


def _timings(values) -> dict:
    """Medians (and the wall time's 95th percentile and maximum) of [(wall s, CPU s)], in ms: the CPU time
    is this thread's, what a loaded machine does not inflate."""
    import numpy as np
    ms = np.asarray(values) * 1000
    return {"median_ms": round(float(np.median(ms[:, 0])), 1), "p95_ms": round(float(np.percentile(ms[:, 0], 95)), 1),
            "max_ms": round(float(ms[:, 0].max()), 1), "cpu_median_ms": round(float(np.median(ms[:, 1])), 1)}


def blender_session(out: Path, frames: int, zip_path: Path) -> dict:
    """In this process: Blender, File > Import of the video at Standard, then frame changes, save, reopen."""
    import numpy as np
    from blender_headless import addon_module, install_extension, start_blender
    user = Path(tempfile.mkdtemp(prefix="hypergs-long-clips-"))
    bpy = start_blender(user / "user")
    addon = install_extension(bpy, zip_path)
    quality, jobs = addon_module(addon, "ops.quality"), addon_module(addon, "ops.jobs")
    runtime = addon_module(addon, "hypergs_blender.runtime")
    video = video_path(out, frames)
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = SCENE_FPS, 1.0
    settings = addon_module(addon, "hypergs_blender.encode").EncodeSettings.choose("standard")
    (plan,) = quality.plan([jobs.Source("pan", str(video))], settings, runtime.Runtime())  # what the dialog shows
    report = {"frames": frames, "encoder": runtime.make_encoder().name, "load_before": round(load(), 1),
              "estimate_s_per_frame": round(plan.estimate.seconds / frames, 3),
              "estimate_threads": plan.estimate.threads}
    usage = resource.getrusage(resource.RUSAGE_SELF)
    cpu, started = usage.ru_utime + usage.ru_stime, time.perf_counter()
    result = bpy.ops.hypergs.import_video(filepath=str(video), quality="STANDARD")
    seconds = time.perf_counter() - started
    usage = resource.getrusage(resource.RUSAGE_SELF)
    obj = bpy.data.objects["pan_1920x1080_30fps_%d" % frames]
    s = obj.hypergs
    cache = addon_module(addon, "com.cache")
    report.update(result=sorted(result), s_per_frame=round(seconds / frames, 3),
                  cpu_s_per_frame=round((usage.ru_utime + usage.ru_stime - cpu) / frames, 3),
                  gaussians=s.gaussians_per_frame, load_after=round(load(), 1),
                  peak_rss_after_import_mib=round(usage.ru_maxrss / 1024),
                  scene=dict(fps=round(scene.render.fps / scene.render.fps_base, 3), frame_start=scene.frame_start,
                             frame_end=scene.frame_end),
                  cache_mb=round(os.path.getsize(cache.clip_file(obj)) / 1e6, 1))

    def changes(sequence):
        times = []
        for frame in sequence:
            t, c = time.perf_counter(), time.thread_time()
            scene.frame_set(int(frame))
            times.append((time.perf_counter() - t, time.thread_time() - c))
        return times

    rng = np.random.default_rng(0)
    first = scene.frame_start
    played = list(range(first, first + min(frames, PLAYBACK)))
    cache.FRAMES.forget()
    report["frame_change"] = {"playback": _timings(changes(played)),
                              "playback_again": _timings(changes(played[-20:])),  # decoded already (the LRU)
                              "scrub": _timings(changes(rng.integers(first, first + frames, SCRUBS)))}
    report["vertices"] = len(obj.data.vertices)
    report["rendered_mode_cpu"] = rendered_mode_cpu(bpy, addon, scene, played[:30])
    blend = out / f"blender_{frames}.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    report["blend_mb"] = round(blend.stat().st_size / 1e6, 2)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    cache.FRAMES.forget()
    report["frame_change"]["after_reopen"] = _timings(changes(rng.integers(first, first + frames, SCRUBS)))
    report["peak_rss_session_mib"] = round(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024)
    shutil.rmtree(user, ignore_errors=True)
    shutil.rmtree(out / f"blender_{frames}_hypergs", ignore_errors=True)
    return report


def rendered_mode_cpu(bpy, addon, scene, frames) -> dict:
    """What the CPU does for each new frame of playback in the viewport's Rendered mode, short of the GPU
    draw (which needs a window): the frame change, then view_draw's reading of the evaluated clips and
    the splat rows for a full-HD region (engine/draw.py). Wall and this thread's CPU ms, medians."""
    import numpy as np
    from blender_headless import addon_module
    splat_rows = addon_module(addon, "hypergs_blender.splat").splat_rows
    evaluated_clips = addon_module(addon, "engine.geometry").evaluated_clips
    wall, cpu = [], []
    for frame in frames:
        t, c = time.perf_counter(), time.thread_time()
        scene.frame_set(int(frame))
        clips = [(p, w, h) for _, p, w, h in evaluated_clips(bpy.context.evaluated_depsgraph_get())]
        splat_rows(clips, WIDTH, HEIGHT)
        wall.append(time.perf_counter() - t)
        cpu.append(time.thread_time() - c)
    return {"wall_ms": round(float(np.median(wall)) * 1000, 1), "cpu_ms": round(float(np.median(cpu)) * 1000, 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="30,300", help="clip lengths, comma-separated (e.g. 30,300,1800)")
    parser.add_argument("--stages", default="make,cli,blender", help=f"comma-separated, of {', '.join(STAGES)}")
    parser.add_argument("--backend", default="onnx", choices=("onnx", "torch", "auto"),
                        help="the CLI's network backend (Blender's is onnx)")
    parser.add_argument("--repeats", type=int, default=1, help="runs per length and stage (time: the minimum)")
    parser.add_argument("--out", default=str(ROOT / "runs" / "long_clips"))
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--session", type=int, help=argparse.SUPPRESS)  # the Blender stage's child
    parser.add_argument("--zip", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.session:
        report = blender_session(out, args.session, Path(args.zip))
        Path(args.json).write_text(json.dumps(report, indent=1))
        from blender_headless import exit_session
        exit_session()
    lengths = [int(f) for f in args.frames.split(",")]
    stages = args.stages.split(",")
    unknown = set(stages) - set(STAGES)
    if unknown:
        parser.error(f"unknown stage(s) {', '.join(sorted(unknown))}")
    encoder = os.environ.get("HYPERGS_ENCODER", "bundled")
    report = {"encoder": encoder, "cpus": os.cpu_count(), "cli": [], "blender": []}
    zip_path = Path(args.zip) if args.zip else None
    if "blender" in stages and zip_path is None:
        from build_extension import build_zip
        zip_path = build_zip(out / "dist")
    for frames in lengths:
        if "make" in stages:
            make_video(out, frames)
        for stage in ("cli", "blender"):
            if stage not in stages:
                continue
            runs = []
            for _ in range(args.repeats):
                if len(lengths) > 1 or args.repeats > 1:  # peak memory per run: each in its own tool process
                    part = out / f"{stage}_{frames}.json"
                    measured([sys.executable, __file__, "--frames", str(frames), "--stages", stage, "--backend",
                              args.backend, "--out", str(out), "--json", str(part)]
                             + (["--zip", str(zip_path)] if zip_path else []))
                    runs.append(json.loads(part.read_text())[stage][0])
                else:
                    runs.append(cli_stage(out, frames, encoder, args.backend) if stage == "cli"
                                else blender_stage(out, frames, zip_path))
            best = min(runs, key=lambda r: r["s_per_frame"])
            if len(runs) > 1:
                best = dict(best, s_per_frame_runs=[r["s_per_frame"] for r in runs])
            report[stage].append(best)
            print(json.dumps({"stage": stage, **best}), flush=True)
    print_targets(report)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


def print_targets(report: dict) -> None:
    """The issue's targets, from the figures measured (those of the lengths run)."""
    blender = {r["frames"]: r for r in report["blender"]}
    cli = {r["frames"]: r for r in report["cli"]}
    for frames, r in sorted(blender.items()):
        fc = r["frame_change"]
        print(f"{frames:5d} frames: peak RSS {r['peak_rss_mib']} MiB, .blend {r['blend_mb']} MB, "
              f"cache {r['cache_mb']} MB, frame change {fc['playback']['median_ms']} ms median "
              f"({fc['playback']['cpu_median_ms']} CPU ms; {fc['playback']['p95_ms']} p95; "
              f"from the LRU {fc['playback_again']['median_ms']}; scrub {fc['scrub']['median_ms']}; "
              f"reopened {fc['after_reopen']['median_ms']}; Rendered mode's CPU part "
              f"{r['rendered_mode_cpu']['cpu_ms']} CPU ms), scene {r['scene']}, "
              f"convert {r['s_per_frame']} s/frame ({r['cpu_s_per_frame']} CPU s; estimate "
              f"{r['estimate_s_per_frame']} on {r['estimate_threads']} threads), load {r['load_before']}")
    if len(blender) > 1:
        short, *longer = sorted(blender)
        for frames in longer:
            growth = blender[frames]["peak_rss_mib"] - blender[short]["peak_rss_mib"]
            ratio, cpu_ratio = (blender[frames]["frame_change"]["playback"][key] / max(
                0.1, blender[short]["frame_change"]["playback"][key]) for key in ("median_ms", "cpu_median_ms"))
            print(f"{short} -> {frames} frames: peak RSS +{growth} MiB (target <= 300), frame change x{ratio:.2f} "
                  f"(CPU x{cpu_ratio:.2f}; target <= 2)")
    for frames in sorted(set(blender) & set(cli)):
        b, c = blender[frames], cli[frames]
        print(f"{frames:5d} frames: Blender {b['s_per_frame']} s/frame vs CLI {c['s_per_frame']} "
              f"({100 * (b['s_per_frame'] / c['s_per_frame'] - 1):+.0f} % wall; CPU {b['cpu_s_per_frame']} vs "
              f"{c['cpu_s_per_frame']}: {100 * (b['cpu_s_per_frame'] / c['cpu_s_per_frame'] - 1):+.0f} %; "
              f"target <= +10 %)")


if __name__ == "__main__":
    sys.exit(main())
