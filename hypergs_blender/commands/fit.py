"""`hypergs fit`: per-frame fitting by optimisation, the baseline the network is measured against."""
from __future__ import annotations

import json
import time
from dataclasses import replace

import numpy as np
import torch

from ..encode import FloorEncoder, encode_frames, frames_layout
from ..io.frames import read_frames
from ..metrics import psnr
from ..refine import FIT_STEPS, FIT_WARMUP, fit, random_init
from ..render import render_torch
from . import options


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("fit", help="fit Gaussians to each frame by optimisation (the baseline)")
    p.add_argument("video", type=options.input_video)
    p.add_argument("--gaussians", type=options.gaussian_count, default=1000)
    p.add_argument("--iters", type=options.positive_int, default=1000)
    p.add_argument("--size", type=options.image_side, default=256, help="short-side resize + centre crop")
    p.add_argument("--frames", type=options.frame_count, default=8, help="frames sampled uniformly")
    p.add_argument("--init", default="random", choices=["random", "grid"])
    p.add_argument("--mean-step", type=options.positive_float, default=FIT_STEPS.mean_cells,
                   help="Adam's step for the means, in cells (the mean spacing of the Gaussians)")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=run)


def run(args) -> None:
    frames, _, _ = read_frames(args.video, args.frames, size=args.size)
    target = torch.from_numpy(frames).float() / 255
    t, h, w = frames.shape[:3]
    layout = frames_layout(frames, FloorEncoder(), gaussians=args.gaussians)  # both inits: the grid's count
    if args.init == "grid":
        init = encode_frames(frames, FloorEncoder(), layout)
    else:
        init = random_init(t, layout.count, w, h)
    started = time.perf_counter()
    params = fit(target, torch.from_numpy(init), args.iters, replace(FIT_STEPS, mean_cells=args.mean_step),
                 warmup=FIT_WARMUP[args.init])
    seconds = time.perf_counter() - started
    quality = psnr(render_torch(params, w, h, w, h).numpy(), frames / np.float32(255))
    result = dict(video=args.video, gaussians=layout.count, iters=args.iters, size=args.size, frames=t,
                  psnr=float(np.mean(quality)), psnr_per_frame=[round(float(q), 3) for q in quality],
                  seconds_per_frame=seconds / t, threads=torch.get_num_threads())
    if args.json:
        print(json.dumps(result, indent=2))
    else:
        print(f"{args.video}: {result['psnr']:.2f} dB after {args.iters} iterations, "
              f"{result['seconds_per_frame']:.3f} s per frame")
