"""The rows of `docs/eval` (README, "Quality of the bundled model"; the transformer's card, Evaluation): one
`hypergs eval ... --json` per row, for a weights folder, into a folder of JSON reports named as `docs/eval`'s; then a
comparison of each row's mean PSNR, Δ-PSNR, still-region change, flat ripple and seam ratio, and how many of its
clips gained, against another such folder.

    python tools/eval_rows.py hypergs_blender/weights --out runs/eval/NAME            # the conv network's 14 rows (about 25 minutes)
    python tools/eval_rows.py RUN/export --out runs/eval/NAME --rows dev_n1000 dev_n3000
    python tools/eval_rows.py RUN/export --design transformer --out runs/eval/NAME    # the transformer's 6 (about 8 minutes)
    python tools/eval_rows.py --compare docs/eval runs/eval/NAME                      # print the comparison only

A row whose report is already in --out is kept (a run cut short resumes). Each `hypergs eval` runs on one torch
thread, `--lanes` of them at a time. The held-out rows need `runs/heldout720/` (`tools/make_heldout_videos.py`).
"""
from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

DEV = ["../shared/videos/davis_bmx-trees.mp4", "../shared/videos/davis_tennis.mp4"]
HELD = [f"runs/heldout720/{name}.mp4" for name in ("Aqua", "Elephants_5640x3172", "Kleiber_by_Lukas_Bau", "LadyBird")]
WHOLE = ["--frames", "3", "--temporal-frames", "4", "--refine", "0"]
ROWS = {  # name (docs/eval/NAME.json) -> hypergs eval's arguments
    "dev_n250": DEV + ["--gaussians", "250"],
    "dev_n1000": DEV + ["--gaussians", "1000"],
    "dev_n1000_onnx": DEV + ["--gaussians", "1000", "--backend", "onnx"],
    "dev_n1000_refine50": DEV + ["--gaussians", "1000", "--refine", "50"],
    "dev_n3000": DEV + ["--gaussians", "3000"],
    "dev_n4000": DEV + ["--gaussians", "4000"],
    "dev_full_cell6": DEV + ["--full", "--cell", "6"],
    "held720_256_n1000": HELD + ["--gaussians", "1000"],
    "held720_256_n1000_refine50": HELD + ["--gaussians", "1000", "--refine", "50"],
    "held720_256_n3000": HELD + ["--gaussians", "3000"],
    "held720_full_draft": HELD + ["--full", "--quality", "draft"] + WHOLE,
    "held720_full_standard": HELD + ["--full", "--quality", "standard"] + WHOLE,
    "held720_crop480_n16000": HELD + ["--crop", "480", "--gaussians", "16000", "--frames", "4"],
    "held720_crop480_n16000_refine50": HELD + ["--crop", "480", "--gaussians", "16000", "--frames", "4", "--refine", "50"],
}
TRANSFORMER = ["--model", "hypergs_transformer", "--frames", "8"]
TRANSFORMER_ROWS = {  # the transformer's card's Evaluation table: N per tile on a patch grid of G x G tiles
    f"transformer_{clips}_n{n}_grid{grid}": videos + TRANSFORMER + ["--gaussians", str(n), "--grid", str(grid)]
    for clips, videos in (("dev", DEV), ("held", HELD)) for n, grid in ((1000, 1), (1000, 2), (3000, 1))
}
DESIGN_ROWS = {"conv": ROWS, "transformer": TRANSFORMER_ROWS}
ALL_ROWS = {**ROWS, **TRANSFORMER_ROWS}


def run_row(name: str, weights: str, out: Path) -> str:
    report = out / f"{name}.json"
    if report.is_file() and report.stat().st_size:
        return f"{name}: kept"
    row = ALL_ROWS[name]
    args = row + ([] if "--backend" in row else ["--backend", "torch"])
    env = dict(os.environ, OMP_NUM_THREADS="1", NUMBA_NUM_THREADS="1")
    done = subprocess.run([sys.executable, "-m", "hypergs_blender", "eval", *args, "--weights", weights, "--json"],
                          env=env, capture_output=True, text=True)
    if done.returncode:
        return f"{name}: failed ({done.stderr.strip().splitlines()[-1] if done.stderr.strip() else done.returncode})"
    partial = report.with_suffix(".json.part")
    partial.write_text(done.stdout)
    partial.replace(report)
    return f"{name}: done"


def figures(report: dict) -> str:
    mean = report["mean"]
    render, source = mean.get("flat_ripple_render_std"), mean.get("flat_ripple_source_std")
    ripple = f"{render / source:.2f}x" if render and source else "-"
    temporal = mean.get("temporal") or {}
    still = (temporal.get("still_change") or {}).get("render", math.nan)
    line = f"{mean['psnr']:.3f} dB, Δ-PSNR {temporal.get('delta_psnr', math.nan):.2f}, still {still:.2f}, ripple {ripple}"
    seams = [clip["seam_ratio"] for clip in report["videos"] if clip.get("seam_ratio") is not None]
    return line + (f", seams max {max(seams):.3f}" if seams else "")


def clips_up(report: dict, before: dict) -> str:
    """How many of the row's clips gained PSNR, and the worst change ('' when the clips differ)."""
    old = {clip["video"]: clip["psnr"] for clip in before["videos"]}
    changes = [clip["psnr"] - old[clip["video"]] for clip in report["videos"] if clip["video"] in old]
    if len(changes) != len(report["videos"]):
        return ""
    return f", {sum(c > 0 for c in changes)} of {len(changes)} clips up (worst {min(changes):+.3f})"


def compare(old: Path, new: Path) -> None:
    for path in sorted(new.glob("*.json")):
        report = json.loads(path.read_text())
        line = f"{path.stem:34s} {figures(report)}"
        if (old / path.name).is_file():
            before = json.loads((old / path.name).read_text())
            line += (f" | {old.name}: {figures(before)} | {report['mean']['psnr'] - before['mean']['psnr']:+.3f} dB"
                     + clips_up(report, before))
        print(line)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("weights", nargs="?", help="folder of the model (hypergs.json/.safetensors/.onnx, or "
                        "hypergs_transformer.* with --design transformer)")
    parser.add_argument("--out", type=Path, help="folder for the reports")
    parser.add_argument("--design", choices=sorted(DESIGN_ROWS), default="conv",
                        help="whose rows run when --rows is not given (default: conv)")
    parser.add_argument("--rows", nargs="+", choices=sorted(ALL_ROWS))
    parser.add_argument("--lanes", type=int, default=2)
    parser.add_argument("--compare", nargs=2, type=Path, metavar=("OLD", "NEW"),
                        help="print NEW's rows against OLD's (and run nothing)")
    args = parser.parse_args()
    if args.compare:
        compare(*args.compare)
        return
    if not (args.weights and args.out):
        parser.error("give a weights folder and --out (or --compare OLD NEW)")
    args.out.mkdir(parents=True, exist_ok=True)
    rows = args.rows or list(DESIGN_ROWS[args.design])
    with ThreadPoolExecutor(args.lanes) as pool:
        for line in pool.map(lambda name: run_row(name, args.weights, args.out), rows):
            print(line, flush=True)
    compare(Path("docs/eval"), args.out)


if __name__ == "__main__":
    main()
