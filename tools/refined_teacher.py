"""Refined Gaussians as a teacher for the conv network (a probe, not in the product; model card, session 34).

Refinement from the network's own prediction gains 3.6-5.5 dB on training crops at the trainer's density (50
steps, 128^2, 4-px cells), so the network is far from what its Gaussians can hold. This probe asks whether those
refined Gaussians, as targets, teach it more than the render loss alone: the trainer's loss (flat-weighted MSE of
the render, `train.training_loss`) plus WEIGHT x the distance to the refined Gaussians of the same batch (means
and covariances in cells, colours), on a fixed set of batches of the trainer's data.

    python tools/refined_teacher.py labels --batches 600 --out runs/teacher/labels.npz
    python tools/refined_teacher.py train runs/teacher/labels.npz --weight 0 --out runs/teacher/w0     # control
    python tools/refined_teacher.py train runs/teacher/labels.npz --weight 1 --out runs/teacher/w1

Labels: batch k is `make_batch(sources, SEED, k, ...)` (8 crops of 128^2), the network sees it with the
trainer's 8-bit noise (`--input-noise 2`) and its Gaussians are refined 50 steps against the clean crops
(`refine.least_squares_colours`, then `refine.fit` as `refine.refine_params` does). Training: the bundled weights,
the whole network at one rate, AdamW, gradient clipping 0.5, bfloat16, the labels' batches in turn; the trainer's
evaluation (`train.Evaluator`: val and the dev clips at N = 1024 and 4096) every 1,000 steps into OUT/log.jsonl.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np
import torch

from hypergs_blender import raster
from hypergs_blender.network import WEIGHTS_DIR, load_model
from hypergs_blender.refine import REFINE_DECAY, REFINE_WARMUP, fit, least_squares_colours, refine_steps
from hypergs_blender.training import data
from hypergs_blender.training.sources import make_batch
from hypergs_blender.training.train import Evaluator, cosine_lr, forward_autocast, training_loss, with_noise

SEED, SIZE, BATCH, NOISE, FLAT_WEIGHT = 7, 128, 8, 2.0, 10.0
DATA = "procedural:0.3,photos:0.7"
DEV = ("../shared/videos/davis_bmx-trees.mp4", "../shared/videos/davis_tennis.mp4")
COLOUR_WEIGHT = 10  # colours' squared difference against the cells' (a colour error of 0.07 weighs as a cell's 0.2)


def batch(sources, k: int) -> tuple[torch.Tensor, torch.Tensor]:
    """(clean frames, what the network sees) of label batch k, [BATCH, 1, SIZE, SIZE, 3]."""
    frames = make_batch(sources, SEED, k, 0, BATCH, 1, SIZE)
    return torch.from_numpy(frames), torch.from_numpy(with_noise(frames, NOISE, SEED, k, 0))


def make_labels(args) -> None:
    model, sources = load_model(WEIGHTS_DIR), data.build_sources(DATA, args.data)
    labels, started = [], time.perf_counter()
    for k in range(args.batches):
        frames, noisy = batch(sources, k)
        with torch.no_grad():
            params = model(noisy[:, 0])
        target = frames[:, 0]
        refined = least_squares_colours(params, target)
        refined = fit(target, refined, args.refine - 1, refine_steps(args.refine), decay=REFINE_DECAY,
                      warmup=REFINE_WARMUP)
        labels.append(refined.numpy())
        if (k + 1) % 50 == 0 or k + 1 == args.batches:
            np.savez(args.out, params=np.stack(labels))
            print(f"{k + 1} batches, {time.perf_counter() - started:.0f} s", flush=True)


def geometry(params: torch.Tensor):
    """params [B, N, 8] on the SIZE x SIZE canvas -> means and covariances (xx, xy, yy) in cells, colours."""
    cell = SIZE / (params.shape[1] ** 0.5)
    mean = (params[..., 0:2] + 1) * (SIZE / 2) / cell
    a, b = (params[..., 2] / cell) ** 2, (params[..., 3] / cell) ** 2
    c, s = torch.cos(params[..., 4]), torch.sin(params[..., 4])
    cov = torch.stack([c * c * a + s * s * b, c * s * (a - b), s * s * a + c * c * b], -1)
    return mean, cov, params[..., 5:8]


def distance(params: torch.Tensor, teacher: torch.Tensor) -> dict:
    return {name: ((p - t) ** 2).sum(-1).mean() for name, p, t in zip(("mean", "cov", "colour"), geometry(params),
                                                                      geometry(teacher))}


class Captured(torch.nn.Module):
    """The network, keeping its last output: train.training_loss computes the render loss from it, the teacher's
    distance reads it (one forward pass for both). `module` is what training_loss takes the design from."""

    def __init__(self, module):
        super().__init__()
        self.module, self.params = module, None

    def forward(self, frames):
        self.params = self.module(frames)
        return self.params


def train(args) -> None:
    labels = torch.from_numpy(np.load(args.labels)["params"])
    torch.manual_seed(0)
    model = load_model(WEIGHTS_DIR).train()
    captured = Captured(model)
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    sources = data.build_sources(DATA, args.data)
    evaluator = Evaluator(model, args.data, DEV)
    amp = forward_autocast(torch.device("cpu"), "bfloat16")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    log, cpu = open(out / "log.jsonl", "w"), time.process_time()

    def evaluate(step):
        model.eval()
        record = dict(step=step, cpu=round(time.process_time() - cpu), eval=evaluator(model, torch.device("cpu")))
        model.train()
        log.write(json.dumps(record) + "\n")
        log.flush()
        print(record, flush=True)

    evaluate(0)
    for step in range(args.steps):
        k = step % len(labels)
        frames, noisy = batch(sources, k)
        for group in optimizer.param_groups:
            group["lr"] = cosine_lr(step, args.steps, 50, args.lr, 0.05)
        with amp:
            render_loss, _, _ = training_loss(captured, frames, None, None, noisy, "mse", FLAT_WEIGHT)
        d = distance(captured.params.float(), labels[k])
        teacher = d["mean"] + d["cov"] + COLOUR_WEIGHT * d["colour"]
        loss = render_loss + args.weight * 1e-3 * teacher  # weight 1: the two terms of about one size
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 0.5)
        optimizer.step()
        if (step + 1) % 1000 == 0 or step + 1 == args.steps:
            evaluate(step + 1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="data", help="the data folder of `hypergs prepare-data`")
    parser.add_argument("--threads", type=int, default=1)
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("labels", help="refine the network's Gaussians of the first BATCHES batches")
    p.add_argument("--batches", type=int, default=600)
    p.add_argument("--refine", type=int, default=50)
    p.add_argument("--out", required=True)
    p = sub.add_parser("train", help="train the bundled network on the labels' batches")
    p.add_argument("labels")
    p.add_argument("--weight", type=float, required=True, help="the teacher's distance against the render loss")
    p.add_argument("--steps", type=int, default=3000)
    p.add_argument("--lr", type=float, default=3e-5)
    p.add_argument("--out", required=True)
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    raster.set_threads(args.threads)
    (make_labels if args.command == "labels" else train)(args)


if __name__ == "__main__":
    main()
