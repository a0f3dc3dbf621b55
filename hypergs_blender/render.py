"""Render Gaussians at any size: `render_params` / `render_frames` with the numpy-only rasterizer path
(no torch, as in Blender), `render_torch` differentiably through torch (any device)."""
from __future__ import annotations

import math

import numpy as np

from .gaussians import GaussianVideo, render_inputs


def render_params(params: np.ndarray, canvas_width: int, canvas_height: int, width: int, height: int,
                  keep_going=None) -> np.ndarray:
    """float32 [..., height, width, 3] (unclipped additive sums, sRGB-encoded like the colours) of
    numpy params [..., N, 8] on a canvas_width x canvas_height canvas, stretched to width x height.
    Raises LimitError for a render past the limits (its size, its memory, the work of a frame: see
    raster.py) before rendering anything; keep_going: None, or () -> bool, asked between pieces of the
    work (about 0.1 s), False cancels (raises errors.Cancelled)."""
    from .raster import check_render_size, rasterize_numpy

    params = np.asarray(params, np.float32)
    check_render_size(width, height, math.prod(params.shape[:-2]))
    if params.shape[-2] == 0:
        return np.zeros(params.shape[:-2] + (height, width, 3), np.float32)
    means, chol, colors = render_inputs(params, canvas_width, canvas_height, width, height)
    return rasterize_numpy(means, chol, colors, width, height, keep_going=keep_going)


def render_frames(video: GaussianVideo, width: int, height: int, frames=None, keep_going=None) -> np.ndarray:
    """float32 [T, height, width, 3] of the chosen frame indices of a clip (all when None)."""
    params = video.params if frames is None else video.params[frames]
    return render_params(params, video.canvas_width, video.canvas_height, width, height, keep_going)


def render_torch(params, canvas_width: int, canvas_height: int, width: int, height: int):
    """Differentiable render of torch params [..., N, 8] on a canvas_width x canvas_height canvas at
    width x height -> [..., height, width, 3]."""
    from .raster import rasterize

    means, chol, colors = render_inputs(params, canvas_width, canvas_height, width, height)
    return rasterize(means, chol, colors, width, height)
