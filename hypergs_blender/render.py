"""Render Gaussians at any size: `render_frames` with the numpy-only rasterizer path (no torch, as
in Blender), `render_torch` differentiably through torch (any device)."""
from __future__ import annotations

import numpy as np

from .gaussians import GaussianVideo, render_inputs


def render_frames(video: GaussianVideo, width: int, height: int, frames=None) -> np.ndarray:
    """float32 [T, height, width, 3] (unclipped additive sums) for the chosen frame indices."""
    from .raster import rasterize_numpy

    params = video.params if frames is None else video.params[frames]
    means, chol, colors = render_inputs(params, video.canvas_width, video.canvas_height, width, height)
    return rasterize_numpy(means, chol, colors, width, height)


def render_torch(params, canvas_width: int, canvas_height: int, width: int, height: int):
    """Differentiable render of torch params [..., N, 8] on a canvas_width x canvas_height canvas at
    width x height -> [..., height, width, 3]."""
    from .raster import rasterize

    means, chol, colors = render_inputs(params, canvas_width, canvas_height, width, height)
    return rasterize(means, chol, colors, width, height)
