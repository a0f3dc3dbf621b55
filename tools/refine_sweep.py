"""Experiment (issue 18, sessions 10 and 27): refinement's step sizes, warm-up and decay, swept on the
network's predictions. Each variant is refine.refine_params with its Adam steps changed: the step sizes
of refine.refine_steps(K) times per-group factors, a linear warm-up of W steps and a decay over the last
D share of the steps (refine.REFINE_WARMUP and refine.REFINE_DECAY are the product's). Prints the mean
PSNR over the dev clips and over the held-out pans (8 frames from frame 0 of each, 256^2 or a 480^2
centre crop).

    OMP_NUM_THREADS=1 .venv/bin/python tools/refine_sweep.py --steps 50 --gaussians 1000 \\
        --dev ../shared/videos/*.mp4 --held runs/heldout720/*.mp4 \\
        --variant warmup=0,decay=0,mean=0.952,scale=0.333,rotation=0.333,colour=0.667 \\
        --variant warmup=10,decay=0,mean=0.667,scale=0.667,rotation=0.667,colour=0.667 --variant warmup=10,decay=0.2

(the first variant is session 9's refinement: no warm-up, means 0.02 cells, log-scales 0.005, rotation
0.01; the second session 10's; the third today's.) Variant fields: warmup (steps), decay (a share of
the steps), cg (the least-squares colours' conjugate-gradient iterations, refine.LS_ITERATIONS),
mean / scale / rotation / colour (factors of refine_steps(K)'s mean_cells / log_scale / rotation / colour).
"""
from __future__ import annotations

import argparse

import numpy as np
import torch

from hypergs_blender import raster
from hypergs_blender.bench.common import load_frames, psnr_of, render
from hypergs_blender.encode import encode_frames, frames_layout
from hypergs_blender.network import resolve_encoder
from hypergs_blender.refine import LS_ITERATIONS, StepSizes, refine_params, refine_steps

FIELDS = {"mean": "mean_cells", "scale": "log_scale", "rotation": "rotation", "colour": "colour"}


def parse_variant(text: str) -> dict:
    variant = {"warmup": 0, "decay": 0.0, "cg": LS_ITERATIONS}
    for item in filter(None, text.split(",")):
        key, _, value = item.partition("=")
        if key not in variant and key not in FIELDS:
            raise SystemExit(f"unknown variant field {key!r} (warmup, decay, cg, {', '.join(FIELDS)})")
        variant[key] = int(value) if key in ("warmup", "cg") else float(value)
    return variant


def refine_variant(params: np.ndarray, frames: np.ndarray, steps: int, variant: dict) -> np.ndarray:
    """refine.refine_params(params, frames, steps) with the variant's step sizes, warm-up, decay and CG iterations."""
    base = refine_steps(steps)
    sizes = StepSizes(**{name: getattr(base, name) * variant.get(key, 1.0) for key, name in FIELDS.items()})
    return refine_params(params, frames, steps, sizes=sizes, warmup=variant["warmup"], decay=variant["decay"],
                         ls_iterations=variant["cg"])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dev", nargs="+", default=[], help="the dev videos")
    parser.add_argument("--held", nargs="+", default=[], help="the held-out videos")
    parser.add_argument("--steps", type=int, default=50, help="refine steps K")
    parser.add_argument("--gaussians", type=int, default=1000)
    parser.add_argument("--crop", type=int, default=None, help="a centre crop of this size (else 256^2 frames)")
    parser.add_argument("--variant", action="append", type=parse_variant, required=True)
    args = parser.parse_args()
    torch.set_num_threads(1)
    raster.set_threads(1)
    sets = {"dev": args.dev, "held-out": args.held}
    encoder = resolve_encoder("network", "torch", None, "cpu", threads=1)
    scores = {name: [[] for _ in args.variant] for name in sets}
    for name, videos in sets.items():
        for video in videos:
            frames = load_frames(video, 8, None if args.crop else 256, crop=args.crop)[0]
            h, w = frames.shape[1:3]
            params = encode_frames(frames, encoder, frames_layout(frames, encoder, gaussians=args.gaussians))
            for i, variant in enumerate(args.variant):
                refined = refine_variant(params, frames, args.steps, variant)
                scores[name][i].append(float(psnr_of(render(refined, w, h), frames).mean()))
    for i, variant in enumerate(args.variant):
        row = "  ".join(f"{name} {np.mean(s[i]):.2f}" for name, s in scores.items() if s[i])
        print(f"{variant}: {row}")


if __name__ == "__main__":
    main()
