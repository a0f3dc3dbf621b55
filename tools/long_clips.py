"""Long clips: the figures of issue 17, printed (1080p30 at the Standard quality, 30 -> 300 -> 1,800 frames).

Stages (each one process per clip length, so peak memory is that job's own):
  make     the test videos: 1080p30 camera pans over a procedural image (bench/scale.py), made once into
           --out (never the dev clips);
  cli      `hypergs encode VIDEO -o clip.hgs` at Standard: seconds per frame, peak RSS.

    .venv/bin/python tools/long_clips.py --frames 30,300 --stages make,cli
    HYPERGS_ENCODER=floor .venv/bin/python tools/long_clips.py ...   # the no-learning floor: fast, for memory

Long runs belong in the background, nice'd (`nohup nice -n 10 ... > log 2>&1 &`): 1,800 frames of 1080p
through the network is 15+ CPU minutes per conversion.
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

WIDTH, HEIGHT, FPS = 1920, 1080, 30
STAGES = ("make", "cli")


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
    """Run `cmd`; its wall time and peak RSS (MiB, the process and its children: os.wait4's rusage)."""
    started = time.perf_counter()
    proc = subprocess.Popen(cmd, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    stdout, stderr = proc.communicate()
    seconds = time.perf_counter() - started
    import resource
    peak = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss / 1024  # the largest child so far
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed (exit {proc.returncode}):\n{stderr[-3000:]}")
    return {"seconds": seconds, "peak_rss_mib": peak, "stdout": stdout, "stderr": stderr}


def cli_stage(out: Path, frames: int, encoder: str) -> dict:
    video = video_path(out, frames)
    clip = out / f"cli_{frames}.hgs"
    # One child at a time, and RUSAGE_CHILDREN keeps the largest: run each length in its own tool process.
    run = measured([sys.executable, "-m", "hypergs_blender", "encode", str(video), "-o", str(clip),
                    "--encoder", "floor" if encoder == "floor" else "network"])
    return {"frames": frames, "encoder": encoder, "seconds": round(run["seconds"], 1),
            "s_per_frame": round(run["seconds"] / frames, 3), "peak_rss_mib": round(run["peak_rss_mib"]),
            "hgs_mb": round(clip.stat().st_size / 1e6, 1)}


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--frames", default="30,300", help="clip lengths, comma-separated (e.g. 30,300,1800)")
    parser.add_argument("--stages", default="make,cli", help=f"comma-separated, of {', '.join(STAGES)}")
    parser.add_argument("--out", default=str(ROOT / "runs" / "long_clips"))
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    lengths = [int(f) for f in args.frames.split(",")]
    stages = args.stages.split(",")
    unknown = set(stages) - set(STAGES)
    if unknown:
        parser.error(f"unknown stage(s) {', '.join(sorted(unknown))}")
    encoder = os.environ.get("HYPERGS_ENCODER", "bundled")
    report = {"encoder": encoder, "cli": []}
    for frames in lengths:
        if "make" in stages:
            make_video(out, frames)
        if "cli" in stages:
            if len(lengths) > 1:  # peak memory per length: each in its own process
                child = measured([sys.executable, __file__, "--frames", str(frames), "--stages", "cli",
                                  "--out", str(out), "--json", str(out / f"cli_{frames}.json")])
                report["cli"].append(json.loads((out / f"cli_{frames}.json").read_text())["cli"][0])
                del child
            else:
                report["cli"].append(cli_stage(out, frames, encoder))
            print(json.dumps(report["cli"][-1]), flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
