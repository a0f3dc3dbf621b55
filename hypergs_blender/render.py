"""Render a GaussianVideo's frames at any size with the numpy-only rasterizer path (no torch)."""
from __future__ import annotations

import numpy as np

from .gaussians import GaussianVideo, render_inputs


def render_frames(video: GaussianVideo, width: int, height: int, frames=None) -> np.ndarray:
    """float32 [T, height, width, 3] (unclipped additive sums) for the chosen frame indices."""
    from .raster import rasterize_numpy

    params = video.params if frames is None else video.params[frames]
    means, chol, colors = render_inputs(params, video.canvas_width, video.canvas_height, width, height)
    return rasterize_numpy(means, chol, colors, width, height)
