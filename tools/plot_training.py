"""PSNR against training wall time from a run's log.jsonl -> docs/training_curve.png (+ a CSV).

    .venv/bin/python tools/plot_training.py runs/small [runs/other ...] [--out docs/training_curve.png]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402


def read_evals(run: Path) -> list[dict]:
    return [r for r in map(json.loads, (run / "log.jsonl").read_text().splitlines()) if "eval" in r]


def main() -> None:
    parser = argparse.ArgumentParser()
    parser.add_argument("runs", nargs="+", type=Path)
    parser.add_argument("--out", type=Path, default=Path("docs/training_curve.png"))
    args = parser.parse_args()
    fig, ax = plt.subplots(figsize=(7, 4.2))
    rows = ["run,step,wall_minutes,metric,psnr"]
    for run in args.runs:
        evals = read_evals(run)
        for metric in sorted(evals[0]["eval"]) if evals else []:
            if not metric.startswith("dev_") and not metric.startswith("val_"):
                continue
            minutes = [r["wall"] / 60 for r in evals]
            values = [r["eval"][metric] for r in evals]
            ax.plot(minutes, values, marker="o", ms=3, label=f"{run.name}: {metric}")
            rows += [f"{run.name},{r['step']},{r['wall'] / 60:.2f},{metric},{r['eval'][metric]}" for r in evals]
    ax.set_xlabel("training wall time (minutes, 2 CPU cores)")
    ax.set_ylabel("PSNR (dB) at the 128 px canvas")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=6, ncol=2)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out, dpi=120)
    args.out.with_suffix(".csv").write_text("\n".join(rows) + "\n")
    print(f"wrote {args.out} and {args.out.with_suffix('.csv')}")


if __name__ == "__main__":
    main()
