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


def render_torch(params, canvas_width: int, canvas_height: int, width: int, height: int, pixel_filter: bool = True):
    """Differentiable render of torch params [..., N, 8] on a canvas_width x canvas_height canvas at
    width x height -> [..., height, width, 3] (pixel_filter: gaussians.render_inputs')."""
    from .raster import rasterize

    means, chol, colors = render_inputs(params, canvas_width, canvas_height, width, height, pixel_filter)
    return rasterize(means, chol, colors, width, height)


def local_render(params, rows: int, cols: int, stride: int, samples: int, reach: int):
    """The render of per-cell Gaussians (torch params [B, rows x cols, 8], row-major, each Gaussian of
    its cell of a (cols stride) x (rows stride) canvas, as the conv network makes them) at samples x
    samples points per cell, each point summing the Gaussians of the (2 reach + 1)^2 cells around its own
    -> [B, 3 samples^2, rows, cols], channel k samples^2 + i samples + j the colour k at the cell's point
    (i, j) (row, column; F.pixel_shuffle(out, samples) is the image). A fixed loop of element-wise ops
    over shifted per-cell maps: exportable to ONNX, and linear in the cells. Without the rasterizer's
    box, and blind to Gaussians that moved further than reach cells: close to render_torch's (its tests),
    for the error pass to read."""
    import torch
    import torch.nn.functional as F

    b = params.shape[0]
    w, h = cols * stride, rows * stride
    # point samples, as the error pass was trained to read (and w, h are symbolic in an ONNX export)
    means, chol, colours = render_inputs(params, w, h, w, h, pixel_filter=False)
    # per cell, what a point's exponent needs, with 1/2 folded in: exp(-(u^2 + v^2)) where
    # u = (x - mx) a, v = (y - my) d - c d u, a = 1 / (sqrt 2 l11), c d = l21 / l22, d = 1 / (sqrt 2 l22).
    # u depends on the point's column only and (y - my) d on its row only: both at `samples` points a
    # cell, and only v and the exponential at all samples^2 (the render 1.5x faster in onnxruntime than
    # all of it at samples^2; its element-wise ops were a third of the network's time)
    root2 = math.sqrt(2.0)
    cells = torch.stack([means[..., 0], 1 / (root2 * chol[..., 0]), means[..., 1], chol[..., 1] / chol[..., 2],
                         1 / (root2 * chol[..., 2])], -1)
    # padding cells hold no Gaussian: zero colour (and zero factors, so no division by zero anywhere)
    maps = F.pad(torch.cat([cells, colours], -1).transpose(1, 2).reshape(b, 8, rows, cols), (reach,) * 4)
    offsets = (torch.arange(samples, dtype=params.dtype, device=params.device) + 0.5) * (stride / samples)
    px = (torch.arange(cols, dtype=params.dtype, device=params.device) * stride)[None, None, :] + offsets[:, None, None]
    py = (torch.arange(rows, dtype=params.dtype, device=params.device) * stride)[None, :, None] + offsets[:, None, None]
    out = [None] * 3  # per colour channel (three accumulators run faster than one of all three), added in place
    for dy in range(2 * reach + 1):
        for dx in range(2 * reach + 1):
            # the Gaussians dy - reach rows and dx - reach columns from each cell: [B, 8, rows, cols], copied
            # (torch's broadcasting ops on the strided view take up to twice as long)
            m = maps[:, :, dy:dy + rows, dx:dx + cols].contiguous()
            u = (px - m[:, 0:1]) * m[:, 1:2]  # [B, samples (columns), rows, cols]
            row_part = (py - m[:, 2:3]) * m[:, 4:5]  # [B, samples (rows), rows, cols]
            v = row_part[:, :, None] - (u * m[:, 3:4])[:, None]  # [B, samples, samples, rows, cols]
            # fused multiply-adds at samples^2 points, in place: 1.5x faster in torch than separate ops
            exponent = torch.addcmul(-(u * u)[:, None], v, v, value=-1)
            weight = exponent.exp_().reshape(b, samples * samples, rows, cols)
            for k in range(3):
                colour = m[:, 5 + k:6 + k]
                out[k] = weight * colour if out[k] is None else out[k].addcmul_(weight, colour)
    return torch.cat(out, 1)
