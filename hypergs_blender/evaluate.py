"""Quality and speed of encode -> render against the source frames (what `hypergs eval` reports):
PSNR / SSIM / MS-SSIM, the floors every model must clear, the artefact checks (seams at tile borders,
a lattice in flat regions, dark frame edges), the temporal figures (on consecutive frames: the PSNR of
the frame differences, the change where the source is still), and timings."""
from __future__ import annotations

import time

import numpy as np

from . import metrics
from .encode import EncodeSettings, encode_frames, frames_layout
from .io.frames import probe, read_frames
from .render import render_params


def bilinear_floor_psnr(frames: np.ndarray, n: int) -> float:
    """The floor every model must clear: the frames average-pooled to about N colours (cells of the
    frame's aspect) and upsampled bilinearly. Mean PSNR over the frames."""
    import torch
    import torch.nn.functional as F
    h, w = frames.shape[1:3]
    x = torch.from_numpy(frames).float().permute(0, 3, 1, 2) / 255
    cell = np.sqrt(h * w / n)
    pooled = F.adaptive_avg_pool2d(x, (max(1, round(h / cell)), max(1, round(w / cell))))
    up = F.interpolate(pooled, size=(h, w), mode="bilinear", align_corners=False)
    return float(np.mean(metrics.psnr(up.permute(0, 2, 3, 1).numpy(), frames / np.float32(255))))


def read_eval_frames(path, frames: int, size: int | None = 256, crop: int | None = None,
                     consecutive: bool = False) -> np.ndarray:
    """`frames` frames spread over the video (consecutive: `frames` consecutive frames from the middle
    of the video): short-side resized and centre-cropped to size x size, or (crop) a crop x crop centre
    crop at the video's own resolution, or (neither) whole frames."""
    if consecutive:
        start = max(0, (probe(path).num_frames - frames) // 2)
        source, _, _ = read_frames(path, None, start, start + frames, size=size)
    else:
        source, _, _ = read_frames(path, frames, size=size)
    if crop:
        h, w = source.shape[1:3]
        y0, x0 = max(0, (h - crop) // 2), max(0, (w - crop) // 2)
        source = np.ascontiguousarray(source[:, y0:y0 + crop, x0:x0 + crop])
    return source


def evaluate_frames(source: np.ndarray, encoder, settings: EncodeSettings) -> dict:
    """Encode uint8 frames [T, H, W, 3] with `settings`, render them at H x W, and measure."""
    t, h, w = source.shape[:3]
    layout = settings.layout(w, h, encoder)
    rendered, encode_seconds, decode_seconds = encode_render(source, encoder, layout, settings.refine,
                                                             settings.adaptive)
    target = source / np.float32(255)
    xs, ys = encoder.tile_borders(layout.work_width, layout.work_height)
    sx, sy = w / layout.work_width, h / layout.work_height
    artefacts = {"seam_ratio": metrics.seam_ratio(rendered, target, [round(x * sx) for x in xs],
                                                  [round(y * sy) for y in ys]),
                 "tiles": [len(xs) + 1, len(ys) + 1],
                 "flat_ripple": metrics.flat_ripple(rendered, target, window=round(2 * layout.cell)),
                 "edge_bias": metrics.edge_bias(rendered, target)}
    tiles = dict(grid=list(layout.tiles), per_tile=layout.per_tile) if hasattr(layout, "tiles") else {}
    return dict(width=w, height=h, frames=t, gaussians=layout.count, cells=[layout.cols, layout.rows], **tiles,
                cell=round(layout.cell, 3), note=layout.note, refine=settings.refine, **metrics.summary(rendered, target),
                floor_bilinear_psnr=bilinear_floor_psnr(source, layout.count), **artefacts,
                encode_seconds=encode_seconds, decode_seconds=decode_seconds,
                encode_fps=t / encode_seconds, decode_fps=t / decode_seconds)


def encode_render(source: np.ndarray, encoder, layout, refine: int = 0,
                  adaptive: bool = True) -> tuple[np.ndarray, float, float]:
    """Encode uint8 frames [T, H, W, 3] on `layout` (refined `refine` steps, from the content-adaptive start unless
    `adaptive` is False: encode.refine_frames) and render them at H x W:
    (renders float32 [T, H, W, 3], unclipped; encode seconds; render seconds)."""
    h, w = source.shape[1:3]
    started = time.perf_counter()
    params = encode_frames(source, encoder, layout, refine, adaptive)
    encode_seconds = time.perf_counter() - started
    started = time.perf_counter()
    rendered = render_params(params, w, h, w, h)
    return rendered, encode_seconds, time.perf_counter() - started


def evaluate_temporal(source: np.ndarray, encoder, settings: EncodeSettings) -> dict:
    """Temporal figures of consecutive uint8 frames [T, H, W, 3] (T >= 2): the PSNR of the frame
    differences (metrics.delta_psnr) next to the per-frame PSNR of the same frames, and the render's
    change where the source is still (metrics.still_change)."""
    h, w = source.shape[1:3]
    rendered, _, _ = encode_render(source, encoder, settings.layout(w, h, encoder), settings.refine, settings.adaptive)
    target = source / np.float32(255)
    return dict(frames=len(source), psnr=float(np.mean(metrics.psnr(rendered, target))),
                delta_psnr=metrics.delta_psnr(rendered, target), still_change=metrics.still_change(rendered, target))


def evaluate_video(path, encoder, settings: EncodeSettings, size: int | None = 256, crop: int | None = None,
                   frames: int = 8, temporal_frames: int = 8) -> dict:
    """evaluate_frames on `frames` frames spread over the video, and (temporal_frames >= 2)
    evaluate_temporal on that many consecutive frames from its middle."""
    result = dict(video=str(path), **evaluate_frames(read_eval_frames(path, frames, size, crop), encoder, settings))
    if temporal_frames >= 2:
        run = read_eval_frames(path, temporal_frames, size, crop, consecutive=True)
        if len(run) >= 2:
            result["temporal"] = evaluate_temporal(run, encoder, settings)
    return result


def warm_up(encoder) -> None:
    """One tiny encode + render, so one-time costs (JIT compilation, thread pools) stay out of the timings."""
    blank = np.zeros((1, 32, 32, 3), np.uint8)
    layout = frames_layout(blank, encoder, gaussians=16)
    render_params(encode_frames(blank, encoder, layout), 32, 32, 32, 32)
