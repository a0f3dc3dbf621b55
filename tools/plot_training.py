"""A run's log.jsonl -> docs/training_curve.png (+ a CSV): evaluation PSNR against training CPU hours
(the process's CPU time, so other jobs on the machine do not stretch it), and resident memory.

    .venv/bin/python tools/plot_training.py runs/conv [runs/other ...] [--out docs/training_curve.png]
    .venv/bin/python tools/plot_training.py runs/conv runs/conv2 --chain   # conv2 started from conv's
                                                                           # weights at its last evaluation
    .venv/bin/python tools/plot_training.py runs/conv3 --chain --earlier docs/training_curve.csv
                                           # conv3 continues the chain that CSV holds (those logs may be gone)
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read_log(run: Path) -> tuple[list[dict], list[dict]]:
    """(evaluation records, step records) of a run."""
    records = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines() if line.strip()]
    return [r for r in records if "eval" in r], [r for r in records if "loss" in r]


def read_csv(path: Path) -> list[tuple[str, list[dict]]]:
    """(run name, evaluation records) of each run in a CSV this tool wrote, in its order; CPU time as written
    (a chain's offsets included)."""
    runs: dict[str, dict[int, dict]] = {}  # run -> step -> its record (the CSV has a row per metric)
    for line in path.read_text().splitlines()[1:]:
        name, step, cpu_hours, wall_hours, metric, value = line.split(",")
        record = runs.setdefault(name, {}).setdefault(
            int(step), dict(step=int(step), cpu=float(cpu_hours) * 3600, wall=float(wall_hours) * 3600, eval={}))
        record["eval"][metric] = float(value)
    return [(name, sorted(records.values(), key=lambda r: r["step"])) for name, records in runs.items()]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("runs", nargs="*", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/training_curve.png"))
    parser.add_argument("--chain", action="store_true",
                        help="each run continues the previous one from its last evaluation: its hours start there")
    parser.add_argument("--earlier", type=Path,
                        help="a CSV this tool wrote: its runs come first, as it holds them (their logs need not be "
                             "here; no memory curve), e.g. the chain a new run continues")
    args = parser.parse_args()
    fig, (ax, mem) = plt.subplots(1, 2, figsize=(11, 4.2), gridspec_kw={"width_ratios": [2, 1]})
    rows = ["run,step,cpu_hours,wall_hours,metric,psnr"]
    earlier = read_csv(args.earlier) if args.earlier else []
    offset = 0.0  # CPU seconds before this run (--chain; the CSV's runs hold theirs)
    colours: dict[str, str] = {}  # one colour per metric across runs
    runs = [(name, evals, None) for name, evals in earlier] + [(run.name, *read_log(run)) for run in args.runs]
    for name, evals, steps in runs:
        if steps is not None:  # a log: its times from the chain's offset
            evals = [dict(r, cpu=r["cpu"] + offset) for r in evals]
            steps = [dict(r, cpu=r["cpu"] + offset) for r in steps]
            mem.plot([r["cpu"] / 3600 for r in steps], [r["rss_mb"] for r in steps], lw=1, label=name)
        # every metric of any evaluation: a run may add one on the way (train --ema given at a resume: ema_*)
        for metric in sorted({m for r in evals for m in r["eval"]}):
            points = [r for r in evals if metric in r["eval"]]
            first = metric not in colours
            colour = colours.setdefault(metric, f"C{len(colours)}")
            ax.plot([r["cpu"] / 3600 for r in points], [r["eval"][metric] for r in points], marker="o", ms=3,
                    color=colour, label=(metric if first else "_nolegend_") if args.chain else f"{name}: {metric}")
            rows += [f"{name},{r['step']},{r['cpu'] / 3600:.3f},{r['wall'] / 3600:.3f},{metric},{r['eval'][metric]}"
                     for r in points]
        if args.chain and evals:
            offset = evals[-1]["cpu"]
    ax.set_xlabel("training CPU hours (process time)")
    ax.set_ylabel("PSNR (dB), 256 x 256 frames")
    ax.set_title("held-out photos (val) and the dev videos (reporting only); n = Gaussians per frame", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    mem.set_xlabel("training CPU hours")
    mem.set_ylabel("resident memory (MiB)")
    mem.set_ylim(bottom=0)
    mem.grid(alpha=0.3)
    if mem.lines:  # runs read from --earlier have no memory curve
        mem.legend(fontsize=7)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    args.out.with_suffix(".csv").write_text("\n".join(rows) + "\n")
    print(f"wrote {args.out} and {args.out.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
