"""Session 19's prototype (model card, "a second pass that reads the render's error"): the bundled conv
network (pass 1, frozen) plus a small second pass that reads pass 1's render error at the working size,
what refinement's gradient reads, and adds to pass 1's head outputs. Pass 2: a 3x3 conv from [pass 1's
64 features, its 8 head outputs, the error unshuffled by cell] to 64 channels, two residual blocks (32
middle channels), a 1x1 head initialised to zero (so it starts as pass 1). Trained through the true
render on the trainer's data (128² crops, batch 8, noise 2, bfloat16 convolutions, one thread).

    python tools/error_pass.py train runs/s19/tp_a --minutes 40 [--no-error] [--half]
    python tools/error_pass.py eval runs/s19/tp_a/refiner.pt dev_n1000 held_n1000 ... [--no-error] [--half]
    python tools/error_pass.py cost      # the ONNX-shaped local render: agreement with the rasterizer, seconds

--no-error feeds zeros instead of the error (the control: the same second pass, no feedback); --half the
error at every second working pixel (a render at half the working size).
"""
from __future__ import annotations

import argparse
import glob
import json
import math
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn as nn
import torch.nn.functional as F

from hypergs_blender.commands.evaluate import mean_flat_ripple
from hypergs_blender.encode import EncodeSettings
from hypergs_blender.evaluate import evaluate_video
from hypergs_blender.gaussians import COLOUR_GAIN, INITIAL_SIGMA, render_inputs
from hypergs_blender.model import ConvGS, ResBlock
from hypergs_blender.network import load_model, torch_encoder
from hypergs_blender.render import render_torch
from hypergs_blender.training import data
from hypergs_blender.training.sources import make_batch
from hypergs_blender.training.train import Evaluator, forward_autocast, with_noise

ERROR_GAIN = 8.0  # the error (a few /255) times this: inputs of the size of the features'


class ErrorPass(ConvGS):
    def __init__(self, base: ConvGS, use_error: bool = True, error_step: int = 1, width: int = 64, mid: int = 32,
                 blocks: int = 2):
        super().__init__(base.cfg)
        self.load_state_dict(base.state_dict())
        for p in self.parameters():
            p.requires_grad_(False)
        self.use_error, self.error_step = use_error, error_step
        cells = self.cfg.stride // error_step
        self.r_in = nn.Conv2d(self.cfg.width + 8 + 3 * cells * cells, width, 3, padding=1)
        self.r_blocks = nn.Sequential(*(ResBlock(width, mid) for _ in range(blocks)))
        self.r_head = nn.Conv2d(width, 8, 1)
        nn.init.zeros_(self.r_head.weight)
        nn.init.zeros_(self.r_head.bias)

    def geometry(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """ConvGS.forward's map from head outputs [B, 8, rows, cols] to params [B, N, 8]."""
        cfg, s = self.cfg, self.cfg.stride
        height, width = x.shape[-2:]
        rows, cols = h.shape[-2:]
        ys = (torch.arange(rows, dtype=h.dtype) + 0.5) * s
        xs = (torch.arange(cols, dtype=h.dtype) + 0.5) * s
        offset = torch.tanh(h[:, 0:2]) * (cfg.offset_range * s)
        mean_x = (xs[None, :] + offset[:, 0]) * (2.0 / width) - 1
        mean_y = (ys[:, None] + offset[:, 1]) * (2.0 / height) - 1
        r = cfg.scale_range
        scale = (INITIAL_SIGMA * s) * torch.exp(r * torch.tanh(h[:, 2:4] / r))
        colour = COLOUR_GAIN * F.avg_pool2d(x, s) + h[:, 5:8]
        params = torch.cat([mean_x[:, None], mean_y[:, None], scale, h[:, 4:5] * math.pi, colour], 1)
        return params.flatten(2).transpose(1, 2)

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        x = frames.permute(0, 3, 1, 2)
        height, width = x.shape[-2:]
        e = self.error_step
        with torch.no_grad():
            features = self.features((x - 0.5) * 2)
            h0 = self.head(features).float()
            with torch.autocast(x.device.type, enabled=False):
                render = render_torch(self.geometry(h0, x), width, height, width // e, height // e)
            target = F.avg_pool2d(x, e) if e > 1 else x
            error = (target - render.permute(0, 3, 1, 2)) * ERROR_GAIN
            if not self.use_error:
                error = torch.zeros_like(error)
        z = torch.cat([features, h0.to(features.dtype), F.pixel_unshuffle(error, self.cfg.stride // e).to(features.dtype)], 1)
        return self.geometry(h0 + self.r_head(self.r_blocks(self.r_in(z))).float(), x)


def local_render(params: torch.Tensor, rows: int, cols: int, stride: int, samples: int, reach: int = 2) -> torch.Tensor:
    """The render of per-cell Gaussians (params [B, rows*cols, 8] on a (cols*stride) x (rows*stride)
    canvas) at samples x samples points per cell, each point summing the Gaussians of the (2 reach + 1)^2
    cells around its own: a loop of element-wise ops over shifted per-cell maps, the shape ONNX can hold.
    -> [B, rows*samples, cols*samples, 3]."""
    b = params.shape[0]
    w, h = cols * stride, rows * stride
    means, chol, colours = render_inputs(params, w, h, w, h)
    maps = F.pad(torch.cat([means, chol, colours], -1).transpose(1, 2).reshape(b, 8, rows, cols), (reach,) * 4)
    valid = F.pad(torch.ones(1, 1, rows, cols), (reach,) * 4)
    sub = torch.arange(samples * samples)
    oy = ((sub // samples).float() + 0.5) * (stride / samples)
    ox = ((sub % samples).float() + 0.5) * (stride / samples)
    py = torch.arange(rows).float()[None, :, None] * stride + oy[:, None, None]
    px = torch.arange(cols).float()[None, None, :] * stride + ox[:, None, None]
    out = torch.zeros(b, 3, samples * samples, rows, cols)
    for dy in range(2 * reach + 1):
        for dx in range(2 * reach + 1):
            m, ok = maps[:, :, dy:dy + rows, dx:dx + cols], valid[:, :, dy:dy + rows, dx:dx + cols]
            z1 = (px - m[:, 0:1]) / torch.where(ok > 0, m[:, 2:3], 1.0)
            z2 = (py - m[:, 1:2] - m[:, 3:4] * z1) / torch.where(ok > 0, m[:, 4:5], 1.0)
            out += (torch.exp(-0.5 * (z1 * z1 + z2 * z2)) * ok)[:, None] * m[:, 5:8, None]
    return F.pixel_shuffle(out.reshape(b, 3 * samples * samples, rows, cols), samples).permute(0, 2, 3, 1)


def train(args) -> None:
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    model = ErrorPass(load_model(), not args.no_error, 2 if args.half else 1)
    trainable = [p for p in model.parameters() if p.requires_grad]
    print(f"{sum(p.numel() for p in trainable)} trainable parameters", flush=True)
    optimizer = torch.optim.AdamW(trainable, lr=args.lr, weight_decay=0.0)
    sources = data.build_sources("procedural:0.3,photos:0.7", "data")
    evaluator = Evaluator(model, "data")
    log = open(out / "log.jsonl", "a")

    def evaluate(step, cpu):
        result = evaluator(model, "cpu")
        print(step, round(cpu), result, flush=True)
        log.write(json.dumps(dict(step=step, cpu=round(cpu, 1), eval=result)) + "\n")
        log.flush()
        torch.save({k: v for k, v in model.state_dict().items() if k.startswith("r_")}, out / "refiner.pt")

    evaluate(0, 0.0)
    start, step, budget = time.process_time(), 0, args.minutes * 60
    while (cpu := time.process_time() - start) < budget:
        frames = make_batch(sources, args.seed, step, 0, 8, 1, 128)[:, 0]
        noisy = with_noise(frames, 2.0, args.seed, step, 0)
        ramp = min(1.0, (step + 1) / 50) * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * cpu / budget)))
        for group in optimizer.param_groups:
            group["lr"] = args.lr * ramp
        with forward_autocast(torch.device("cpu"), "bfloat16"):
            params = model(torch.from_numpy(noisy)).float()
        mse = ((render_torch(params, 128, 128, 128, 128) - torch.from_numpy(frames)) ** 2).mean()
        optimizer.zero_grad(set_to_none=True)
        mse.backward()
        torch.nn.utils.clip_grad_norm_(trainable, 0.5)
        optimizer.step()
        step += 1
        if step % 1000 == 0:
            evaluate(step, time.process_time() - start)
    evaluate(step, time.process_time() - start)


ROWS = {  # name -> (videos, settings, evaluate_video options): `hypergs eval`'s rows (model card)
    "dev_n250": ("../shared/videos/*.mp4", dict(gaussians=250), {}),
    "dev_n1000": ("../shared/videos/*.mp4", dict(gaussians=1000), {}),
    "dev_n3000": ("../shared/videos/*.mp4", dict(gaussians=3000), {}),
    "held_n1000": ("runs/heldout720/*.mp4", dict(gaussians=1000), {}),
    "held_n3000": ("runs/heldout720/*.mp4", dict(gaussians=3000), {}),
    "held_draft": ("runs/heldout720/*.mp4", dict(cell=8.0), dict(size=None, frames=3)),
    "held_standard": ("runs/heldout720/*.mp4", dict(cell=6.0), dict(size=None, frames=3)),
}


def evaluate_rows(args) -> None:
    model = ErrorPass(load_model(), not args.no_error, 2 if args.half else 1)
    if args.refiner != "none":
        model.load_state_dict(torch.load(args.refiner, weights_only=True), strict=False)
    encoder = torch_encoder(model)
    for row in args.rows:
        pattern, settings, options = ROWS[row]
        results = [evaluate_video(v, encoder, EncodeSettings(**settings), temporal_frames=0, **options)
                   for v in sorted(glob.glob(pattern))]
        ripple = mean_flat_ripple([r["flat_ripple"] for r in results])
        ratio = (f"{ripple['flat_ripple_render_std'] / ripple['flat_ripple_source_std']:.2f}x"
                 if ripple["flat_ripple_blocks"] else "no flat blocks")
        per_video = ", ".join(f"{r['psnr']:.2f}" for r in results)
        print(f"{row}: {np.mean([r['psnr'] for r in results]):.3f} dB ({per_video}), flat ripple {ratio}", flush=True)


def cost(args) -> None:
    model = load_model()
    with torch.no_grad():
        params = model(torch.rand(1, 128, 128, 3))
        for samples in (4, 2):
            exact = render_torch(params, 128, 128, 32 * samples, 32 * samples)
            local = local_render(params, 32, 32, 4, samples)
            print(f"{samples}x{samples} samples per cell: {-10 * math.log10(float(((local - exact) ** 2).mean())):.1f} dB "
                  f"from the rasterizer")
        frames = torch.rand(1, 720, 1280, 3)  # 1080p at Standard: 320 x 180 cells of 4 working pixels
        start = time.perf_counter()
        params = model(frames)
        print(f"pass 1 at 1280x720: {time.perf_counter() - start:.3f} s")
        for samples in (4, 2):
            start = time.perf_counter()
            local_render(params, 180, 320, 4, samples)
            print(f"local render, {samples}x{samples} samples per cell: {time.perf_counter() - start:.3f} s")
        two = ErrorPass(model).eval()
        start = time.perf_counter()
        two(frames)
        print(f"both passes (the error by the numba rasterizer): {time.perf_counter() - start:.3f} s")


def main() -> None:
    torch.set_num_threads(1)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("train")
    p.add_argument("out")
    p.add_argument("--minutes", type=float, default=40.0, help="CPU minutes")
    p.add_argument("--lr", type=float, default=1e-3)
    p.add_argument("--seed", type=int, default=301)
    p = sub.add_parser("eval")
    p.add_argument("refiner", help="refiner.pt from train, or none (pass 1 alone)")
    p.add_argument("rows", nargs="+", choices=sorted(ROWS))
    sub.add_parser("cost")
    for p in sub.choices.values():
        p.add_argument("--no-error", action="store_true")
        p.add_argument("--half", action="store_true")
    args = parser.parse_args()
    {"train": train, "eval": evaluate_rows, "cost": cost}[args.command](args)


if __name__ == "__main__":
    main()
