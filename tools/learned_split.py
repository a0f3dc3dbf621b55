"""Experiment (issue 18, item 1): a count per region learned with its seams.

The conv network runs at a fine density (one Gaussian per 4-px cell of its input); each 2x2 group of
cells is either split (its 4 Gaussians) or whole (1: the group's top-left Gaussian covers the group,
the other 3 are dropped). The network sees which (two indicator channels per cell, "alone" and
"dropped", through a zero-initialised 1x1 conv added to its cell features, and a 1x1 conv added to its
head that starts each alone Gaussian at its group's centre, twice the size), so it can learn to cover
a group with one Gaussian and to blend the borders between whole and split groups, the seams that ate
the training-free split's gain (`tools/adaptive_split.py`). At inference the groups with the most
detail (mean |gradient|) are split, as many as a budget N allows: N = G + 3 S (G groups, S split,
S = fraction x G). Warm start: the bundled weights.

    .venv/bin/python tools/learned_split.py train runs/split --steps 5000 --fractions 0:1 --all-split 0.05 --none-split 0.05
    .venv/bin/python tools/learned_split.py train runs/split --steps 13000 --fractions 0.1:0.7 --all-split 0.15
    OMP_NUM_THREADS=1 .venv/bin/python tools/learned_split.py eval runs/split --gaussians 1000 --fraction 0.3 VIDEOS...
    OMP_NUM_THREADS=1 .venv/bin/python tools/learned_split.py eval hypergs_blender/weights --gaussians 1000 VIDEOS...

A second `train` continues the run's checkpoint on a new cosine schedule to --steps (a warm restart).
`eval` prints the mean PSNR over the videos' frames (256², 8 frames: `hypergs eval`'s figures for a
plain network), for a plain network's folder (uniform, one Gaussian per cell) or a split run's.
"""
from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from hypergs_blender.evaluate import read_eval_frames
from hypergs_blender.io.images import resize_exact
from hypergs_blender.metrics import psnr, psnr_from_mse
from hypergs_blender.model import PRESETS, ConvGS
from hypergs_blender.network import load_model
from hypergs_blender.render import render_torch
from hypergs_blender.training.data import build_sources
from hypergs_blender.training.sources import make_batch
from hypergs_blender.training.train import cosine_lr, warm_start, with_noise

BUNDLED = Path(__file__).resolve().parents[1] / "hypergs_blender" / "weights" / "hypergs.safetensors"
GROUP = 8  # input pixels per 2 x 2 group of 4-px cells


class SplitConvGS(ConvGS):
    def __init__(self, cfg):
        super().__init__(cfg)
        self.mask_embed = nn.Conv2d(2, cfg.width, 1)
        self.mask_head = nn.Conv2d(2, 8, 1)
        for conv in (self.mask_embed, self.mask_head):
            nn.init.zeros_(conv.weight)
            nn.init.zeros_(conv.bias)
        with torch.no_grad():  # an alone Gaussian: tanh(0.549) = half a cell towards the group's centre, ln 2 larger
            self.mask_head.weight[0:2, 0, 0, 0] = math.atanh(0.5)
            self.mask_head.weight[2:4, 0, 0, 0] = cfg.scale_range * math.atanh(math.log(2) / cfg.scale_range)
        self.head.register_forward_hook(lambda module, inputs, out: out + self.mask_head(self._indicators))
        self._indicators = None

    def cell_features(self, x):
        return super().cell_features(x) + self.mask_embed(self._indicators)

    def forward(self, frames, split):
        """frames [B, H, W, 3], split bool [B, H / 8, W / 8] -> params [B, (H / 4) (W / 4), 8] with the
        dropped Gaussians' colour 0, and which are kept, bool [B, (H / 4) (W / 4)]."""
        cells = split.repeat_interleave(2, -1).repeat_interleave(2, -2)
        top_left = torch.zeros(cells.shape[-2:], dtype=torch.bool, device=frames.device)
        top_left[::2, ::2] = True
        alone, dropped = ~cells & top_left, ~cells & ~top_left
        self._indicators = torch.stack([alone, dropped], 1).to(frames.dtype)
        params = super().forward(frames)
        keep = ~dropped.flatten(1)
        return torch.cat([params[..., :5], params[..., 5:] * keep[..., None]], -1), keep


def group_detail(frames: torch.Tensor) -> torch.Tensor:
    """[B, H, W, 3] -> [B, H / 8, W / 8]: the grey frame's mean |gradient| in each group."""
    grey = frames.mean(-1)
    gx = F.pad((grey[:, :, 1:] - grey[:, :, :-1]).abs(), (0, 1))
    gy = F.pad((grey[:, 1:] - grey[:, :-1]).abs(), (0, 0, 0, 1))
    return F.avg_pool2d((gx + gy)[:, None], GROUP)[:, 0]


def top_split(score: torch.Tensor, count: int) -> torch.Tensor:
    """bool like score [B, rows, cols]: the `count` highest of each frame."""
    flat = score.reshape(score.shape[0], -1)
    split = torch.zeros_like(flat, dtype=torch.bool)
    if count > 0:
        split.scatter_(1, flat.topk(count, 1).indices, True)
    return split.reshape(score.shape)


def training_split(frames, rng, fractions, all_split, none_split):
    """Masks like inference's (the detail ranking, with noise of a random size in its log), the
    fraction uniform in `fractions`, or all / none of the groups split."""
    score = torch.log(group_detail(frames) + 1e-3)
    masks = []
    for s in score:
        u = rng.random()
        fraction = 0.0 if u < none_split else 1.0 if u < none_split + all_split else rng.uniform(*fractions)
        noisy = s + torch.from_numpy(rng.normal(0, rng.uniform(0, 2), s.shape).astype(np.float32))
        masks.append(top_split(noisy[None], round(fraction * s.numel()))[0])
    return torch.stack(masks)


def train(args):
    torch.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = SplitConvGS(PRESETS["conv"])
    warm_start(model, BUNDLED)
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=1e-4)
    step = 0
    if (out / "checkpoint.pt").exists():
        state = torch.load(out / "checkpoint.pt", weights_only=True)
        model.load_state_dict(state["model"])
        optimizer.load_state_dict(state["optimizer"])
        step = state["step"]
    sources = build_sources("procedural:0.3,photos:0.7", args.data_root)
    fractions = tuple(float(v) for v in args.fractions.split(":"))
    start, first, losses = time.time(), step, []
    with open(out / "log.jsonl", "a") as log:
        while step < args.steps:
            batch = make_batch(sources, args.seed, step, 0, args.batch, 1, args.size)[:, 0]
            frames, inputs = torch.from_numpy(batch), torch.from_numpy(with_noise(batch, 2.0, args.seed, step, 0))
            split = training_split(frames, np.random.default_rng([args.seed, step, 5]), fractions,
                                   args.all_split, args.none_split)
            for group in optimizer.param_groups:
                group["lr"] = cosine_lr(step - first, args.steps - first, 100, args.lr, 0.05)
            params, _ = model(inputs, split)
            loss = torch.mean((render_torch(params, args.size, args.size, args.size, args.size) - frames) ** 2)
            optimizer.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(model.parameters(), 0.5)
            optimizer.step()
            step += 1
            losses.append(float(loss.detach()))
            if step % 50 == 0:
                log.write(json.dumps(dict(step=step, wall=round(time.time() - start, 1),
                                          psnr=round(float(psnr_from_mse(np.mean(losses))), 3))) + "\n")
                log.flush()
                losses = []
            if step % 200 == 0 or step == args.steps:
                torch.save(dict(model=model.state_dict(), optimizer=optimizer.state_dict(), step=step),
                           out / "checkpoint.tmp")
                (out / "checkpoint.tmp").replace(out / "checkpoint.pt")


@torch.no_grad()
def evaluate(args):
    torch.set_num_threads(1)
    split_run = (Path(args.weights) / "checkpoint.pt").exists()
    n = args.gaussians
    if split_run:
        model = SplitConvGS(PRESETS["conv"])
        model.load_state_dict(torch.load(Path(args.weights) / "checkpoint.pt", weights_only=True)["model"])
        g = round(math.sqrt(n / (1 + 3 * args.fraction)))
        split_count = min(g * g, max(0, round((n - g * g) / 3)))
        work, count = GROUP * g, g * g + 3 * split_count
    else:
        model = load_model(Path(args.weights), "hypergs")
        g = round(math.sqrt(n))
        work, count = 4 * g, g * g
    model.eval()
    means = []
    for video in args.videos:
        target = read_eval_frames(video, args.frames, size=args.size)
        inputs = torch.from_numpy(np.stack([resize_exact(f, work, work) for f in target]).astype(np.float32) / 255)
        if split_run:
            params, keep = model(inputs, top_split(group_detail(inputs), split_count))
            params = params[keep].reshape(len(target), count, 8)
        else:
            params = model(inputs)
        means.append(float(psnr(render_torch(params, work, work, args.size, args.size), target / 255).mean()))
    print(json.dumps(dict(weights=str(args.weights), gaussians=count, fraction=args.fraction if split_run else 0.0,
                          psnr=round(float(np.mean(means)), 3), per_video=[round(p, 3) for p in means])))


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    commands = parser.add_subparsers(dest="command", required=True)
    t = commands.add_parser("train")
    t.add_argument("out")
    t.add_argument("--steps", type=int, required=True)
    t.add_argument("--fractions", default="0:1", help="LO:HI, the split fraction's range")
    t.add_argument("--all-split", type=float, default=0.0, help="share of frames with every group split")
    t.add_argument("--none-split", type=float, default=0.0, help="share of frames with no group split")
    t.add_argument("--lr", type=float, default=3e-4)
    t.add_argument("--batch", type=int, default=8)
    t.add_argument("--size", type=int, default=128)
    t.add_argument("--seed", type=int, default=71)
    t.add_argument("--threads", type=int, default=2)
    t.add_argument("--data-root", default="data")
    e = commands.add_parser("eval")
    e.add_argument("weights", help="a split run's folder, or a plain network's weights folder")
    e.add_argument("videos", nargs="+")
    e.add_argument("--gaussians", type=int, default=1000)
    e.add_argument("--fraction", type=float, default=0.3, help="share of the groups split (a split run)")
    e.add_argument("--frames", type=int, default=8)
    e.add_argument("--size", type=int, default=256)
    args = parser.parse_args()
    train(args) if args.command == "train" else evaluate(args)


if __name__ == "__main__":
    main()
