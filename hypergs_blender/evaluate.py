"""Quality and speed of encode -> render against the source frames (what `hypergs eval` reports):
PSNR / SSIM / MS-SSIM, the bilinear floor every model must clear, and timings."""
from __future__ import annotations

import time

import numpy as np

from . import metrics
from .encode import encode_frames
from .gaussians import GaussianVideo
from .io.frames import probe, read_frames
from .render import render_frames


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
    source, _, _ = read_frames(path, frames, size=size)
    started = time.perf_counter()
    params = encode_frames(source, encoder, gaussians, grid)
    if refine:
        from .refine import refine_params
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
