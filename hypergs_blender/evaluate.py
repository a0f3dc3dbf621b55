"""`hypergs eval`: PSNR / SSIM / MS-SSIM of encode -> render against the source frames, with timings."""
from __future__ import annotations

import json
import time

import numpy as np

from . import metrics
from .encode import add_encoder_arguments, encode_frames, make_encoder
from .gaussians import GaussianVideo
from .render import render_frames
from .video import probe, read_clip


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("eval", help="quality and speed of encode -> render on videos")
    p.add_argument("videos", nargs="+")
    p.add_argument("--gaussians", type=int, default=1000, help="Gaussians per frame (split over grid tiles)")
    p.add_argument("--grid", type=int, default=1, help="G x G patch-grid encoding")
    size = p.add_mutually_exclusive_group()
    size.add_argument("--size", type=int, default=256, help="short-side resize + centre crop to SIZE x SIZE")
    size.add_argument("--native", action="store_true",
                      help="centre crop at the video's own short side, no resize (zero-shot high resolution)")
    p.add_argument("--frames", type=int, default=8, help="frames sampled uniformly from each video")
    p.add_argument("--json", action="store_true")
    add_encoder_arguments(p)
    p.set_defaults(func=run)


def bilinear_floor_psnr(frames: np.ndarray, n: int) -> float:
    """The floor every model must clear: the frames average-pooled to about N colours
    (sqrt(N) x sqrt(N) cells) and upsampled bilinearly. Mean PSNR over the frames."""
    import torch
    import torch.nn.functional as F
    x = torch.from_numpy(frames).float().permute(0, 3, 1, 2) / 255
    side = max(1, round(np.sqrt(n)))
    up = F.interpolate(F.adaptive_avg_pool2d(x, side), size=x.shape[-2:], mode="bilinear", align_corners=False)
    return float(np.mean(metrics.psnr(up.permute(0, 2, 3, 1).numpy(), frames / np.float32(255))))


def evaluate_video(path, encoder, gaussians: int, grid: int = 1, size: int | None = 256, frames: int = 8,
                   refine: int = 0) -> dict:
    """size None: native (short side of the video)."""
    if size is None:
        info = probe(path)
        size = min(info.width, info.height)
    source, _, _ = read_clip(path, frames, size=size)
    started = time.perf_counter()
    params = encode_frames(source, encoder, gaussians, grid)
    if refine:
        from .fit import refine_params
        params = refine_params(params, source, refine)
    encode_seconds = time.perf_counter() - started
    video = GaussianVideo(params, size, size)
    started = time.perf_counter()
    rendered = render_frames(video, size, size)
    decode_seconds = time.perf_counter() - started
    result = metrics.summary(rendered, source / np.float32(255))
    return dict(video=str(path), size=size, frames=len(source), gaussians=gaussians, grid=grid, **result,
                floor_bilinear_psnr=bilinear_floor_psnr(source, gaussians),
                encode_seconds=encode_seconds, decode_seconds=decode_seconds,
                encode_fps=len(source) / encode_seconds, decode_fps=len(source) / decode_seconds)


def warm_up(encoder) -> None:
    """One tiny encode + render, so one-time costs (JIT compilation, thread pools) stay out of the timings."""
    blank = np.zeros((encoder.clip_frames, 32, 32, 3), np.uint8)
    render_frames(GaussianVideo(encode_frames(blank, encoder, 16), 32, 32), 32, 32)


def run(args) -> None:
    encoder = make_encoder(args)
    warm_up(encoder)
    size = None if args.native else args.size
    rows = [evaluate_video(v, encoder, args.gaussians, args.grid, size, args.frames, getattr(args, "refine", 0))
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
