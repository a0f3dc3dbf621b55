"""The Gaussians as the GPU splat shader (engine/splat.py) reads them: one quad per Gaussian over exactly the
pixels of its box (raster.SIGMA_CUTOFF), its numbers in a float texture. numpy only (no bpy, no GPU), so the
quads and the numbers are tested without Blender; the shader itself is tested against `render.render_params`.

Per Gaussian, TEXELS RGBA float texels side by side, in the rasterizer's pixel units (raster.py: y down,
pixel (row i, column j) has its centre at (j + 0.5, i + 0.5)):
  (x0, y0, x1, y1)  the quad: pixel edges around the pixels whose centres are in the box, as
                    raster.box_pixels decides them (the same float32 test as the numpy rasterizer)
  (mx, my, a, b)    the mean, and with c below s L^-1 = [[a, 0], [b, c]], where L is the Cholesky factor
                    of the stretched covariance (gaussians.render_inputs) and s = EXP2_SCALE, so that
                    exp(-1/2 d^T Sigma^-1 d) = exp2(-(u^2 + v^2)) with u = a dx, v = b dx + c dy
  (c, red, green, blue)  and the colour, sRGB-encoded (summed as such; the sum becomes scene-linear after)
The quad's corners are whole pixels, so a GPU covers exactly the pixels inside it whatever its rules for
pixels on an edge or its sub-pixel precision: the fragment shader needs no box test.
"""
from __future__ import annotations

import math

import numpy as np

from .gaussians import NUM_PARAMS, render_inputs
from .raster import box_pixels

TEXELS = 3
ROW_WIDTH = 4 * TEXELS  # floats per Gaussian
# Texture rows hold this many Gaussians (TEXELS * 1024 = 3072 texels: within every GPU Blender runs on), and
# one texture (one draw) at most CHUNK Gaussians (48 MB of RGBA32F).
GAUSSIANS_PER_ROW = 1024
CHUNK = GAUSSIANS_PER_ROW * 1024
EXP2_SCALE = math.sqrt(0.5 / math.log(2))  # exp(-q / 2) = exp2(-(EXP2_SCALE^2 q))


def splat_rows(clips, width: int, height: int, window: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """float32 [M, ROW_WIDTH]: the Gaussians of `clips` (an iterable of (params [..., N, 8], canvas width,
    canvas height)) rendered at width x height that have pixels in the window (x, y, w, h) of that image, in
    pixels from its top-left corner (default: the whole image), in the clips' order; their quads are clipped
    to the window. Invalid Gaussians (raster.valid) are left out."""
    x, y, w, h = window or (0, 0, width, height)
    out = [np.zeros((0, ROW_WIDTH), np.float32)]
    for params, canvas_width, canvas_height in clips:
        params = np.asarray(params, np.float32).reshape(-1, NUM_PARAMS)
        means, chol, colors = render_inputs(params, canvas_width, canvas_height, width, height)
        ok, (x0, x1, y0, y1) = box_pixels(means, chol, (x, x + w), (y, y + h))
        l11, l21, l22 = chol.astype(np.float64).T
        rows = np.empty((len(params), ROW_WIDTH), np.float32)
        rows[:, 0], rows[:, 1], rows[:, 2], rows[:, 3] = x0, y0, x1 + 1, y1 + 1
        rows[:, 4:6] = means
        with np.errstate(divide="ignore", invalid="ignore"):  # in rows left out
            rows[:, 6] = EXP2_SCALE / l11
            rows[:, 7] = -EXP2_SCALE * l21 / (l11 * l22)
            rows[:, 8] = EXP2_SCALE / l22
        rows[:, 9:12] = colors
        out.append(rows[ok])
    return np.concatenate(out)


def texture_rows(rows: np.ndarray) -> np.ndarray:
    """The rows of at most CHUNK Gaussians as the texture the shader reads: float32
    [ceil(M / GAUSSIANS_PER_ROW) (at least 1), TEXELS * GAUSSIANS_PER_ROW, 4], zero-padded; Gaussian i's
    texels start at row i // GAUSSIANS_PER_ROW, column TEXELS * (i % GAUSSIANS_PER_ROW)."""
    if len(rows) > CHUNK:
        raise ValueError(f"texture_rows: {len(rows)} Gaussians, at most {CHUNK} per texture")
    texture_height = max(1, -(-len(rows) // GAUSSIANS_PER_ROW))
    texture = np.zeros((texture_height * GAUSSIANS_PER_ROW, ROW_WIDTH), np.float32)
    texture[:len(rows)] = rows
    return texture.reshape(texture_height, GAUSSIANS_PER_ROW * TEXELS, 4)
