"""`hypergs eval`: PSNR / SSIM / MS-SSIM of encode -> render against the source frames, with timings."""
from __future__ import annotations

import json

import numpy as np

from ..evaluate import evaluate_video, warm_up
from . import options
from .options import add_encoder_arguments, encoder_from_args


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("eval", help="quality and speed of encode -> render on videos")
    p.add_argument("videos", nargs="+", type=options.input_video)
    p.add_argument("--gaussians", type=options.gaussian_count, default=1000,
                   help="Gaussians per frame (split over grid tiles)")
    p.add_argument("--grid", type=int, default=1, help="G x G patch-grid encoding")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--size", type=options.image_side, default=256,
                      help="short-side resize + centre crop to SIZE x SIZE")
    size.add_argument("--native", action="store_true",
                      help="centre crop at the video's own short side, no resize (zero-shot high resolution)")
    p.add_argument("--frames", type=options.frame_count, default=8, help="frames sampled uniformly from each video")
    p.add_argument("--json", action="store_true")
    add_encoder_arguments(p)
    p.set_defaults(func=run)


def run(args) -> None:
    encoder = encoder_from_args(args)
    warm_up(encoder)
    size = None if args.native else args.size
    rows = [evaluate_video(v, encoder, args.gaussians, args.grid, size, args.frames, args.refine)
            for v in args.videos]
    keys = ["psnr", "ssim", "ms_ssim", "floor_bilinear_psnr", "encode_seconds", "decode_seconds", "encode_fps", "decode_fps"]
    mean = {k: float(np.mean([r[k] for r in rows])) for k in keys}
    report = dict(encoder=getattr(encoder, "name", "?"), gaussians=args.gaussians, grid=args.grid,
                  size="native" if args.native else args.size, frames=args.frames, videos=rows, mean=mean)
    if args.json:
        print(json.dumps(report, indent=2))
        return
    for r in rows + [dict(video="mean", size=report["size"], **mean)]:
        print(f"{r['video']:40s} {r['psnr']:6.2f} dB (bilinear floor {r['floor_bilinear_psnr']:.2f})  "
              f"SSIM {r['ssim']:.4f}  MS-SSIM {r['ms_ssim']:.4f}  "
              f"encode {r['encode_fps']:7.1f} fps  decode {r['decode_fps']:7.1f} fps")
