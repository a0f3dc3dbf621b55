"""GaussianVideo: T frames x N Gaussians x 8 parameters, and the maths to render it at any size.

Parameter layout per Gaussian (float32), `PARAMS`:
  0-1  mean x, y   in canvas coordinates [-1, 1]; (-1, -1) is the canvas' top-left corner,
                   (1, 1) its bottom-right corner (see raster.py for the pixel-centre convention)
  2-3  scale x, y  standard deviations along the Gaussian's own axes, in canvas pixels
  4    rotation    radians in [0, 2*pi): the angle from the image x axis to the Gaussian's x axis
  5-7  r, g, b     additive colour (sRGB-encoded values, like the source frames)

The canvas is the network's input size (canvas_width x canvas_height). Rendering at W x H stretches
by T = diag(W / canvas_width, H / canvas_height): means scale with the frame and the covariance
becomes T Sigma T, plus the pixel filter of a render smaller than the canvas (`render_inputs`). Its
Cholesky factor goes to the rasterizer.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from . import limits
from .errors import HyperGSError
from .raster import SIGMA_CUTOFF

PARAMS = ("x", "y", "scale_x", "scale_y", "rotation", "r", "g", "b")
NUM_PARAMS = len(PARAMS)
# A grid of Gaussians with sigma INITIAL_SIGMA x the spacing, each with colour COLOUR_GAIN x c, sums to c
# on average: the grid floor, where models start. The gain is 1 / the mean over a cell of the kernels'
# sum, each cut at its box (raster.SIGMA_CUTOFF) as the rasterizer does (about spacing^2 / (2 pi sigma^2),
# less the 0.1 % the cut-off drops); the box is separable, so the sum is a 1D sum squared.
INITIAL_SIGMA = 0.6
# A pixel shows the picture averaged over its area, as a camera's sensor and an area resize do: a box of one
# pixel, whose variance is 1/12 px^2 along each axis. The Gaussians are fitted to the canvas' pixels, which
# hold that average at their own size already; a render smaller than the canvas by t along an axis adds the
# rest, (1 - t^2) / 12 of its pixels^2 (render_inputs). Blender's F12 of held-out 720p clips at 50 % against the
# area-resized source (session 32): High +0.48 to +1.48 dB, Standard +0.11 to +0.43; 1/12 beats larger variances
# wherever the area resize is exactly that box (2:1), and loses at most 0.11 dB against a Lanczos resize.
PIXEL_VARIANCE = 1 / 12


def lattice_gain(sigma: float, cutoff: float = SIGMA_CUTOFF) -> float:
    x = (np.arange(4096) + 0.5) / 4096
    d = x[:, None] - np.arange(-8, 9)[None, :]
    kernel = np.where(np.abs(d) <= cutoff * sigma, np.exp(-0.5 * (d / sigma) ** 2), 0.0)
    return float(1.0 / kernel.sum(1).mean() ** 2)


COLOUR_GAIN = lattice_gain(INITIAL_SIGMA)
MAX_FPS = 10000.0
MAX_GRID = 1 << 15  # a lattice side: a Gaussian per pixel of the longest side images may have (limits.SIDE)


@dataclass
class GaussianVideo:
    params: np.ndarray  # [T, N, 8] float32
    canvas_width: int
    canvas_height: int
    fps: float = 24.0
    grid: tuple[int, int] = (1, 1)  # the Gaussians' lattice (columns, rows) the clip was encoded on
    source: dict = field(default_factory=dict)  # free-form: path, frame range, size, psnr, model

    def __post_init__(self):
        self.params = np.ascontiguousarray(self.params, dtype=np.float32)
        if self.params.ndim != 3 or self.params.shape[-1] != NUM_PARAMS:
            raise ValueError(f"GaussianVideo params must be [T, N, {NUM_PARAMS}], got {self.params.shape}")
        self.grid = tuple(int(g) for g in self.grid)

    @classmethod
    def checked(cls, where, params, canvas_width, canvas_height, fps=24.0, grid=(1, 1), source=None) -> "GaussianVideo":
        """A clip read from a file (`where` names it in errors), every part checked: parameters as
        `param_problem` wants them, at least one frame and one Gaussian and within the limits, a canvas
        within the image limits, a finite positive fps, a grid of two positive integers, a dict source.
        Raises HyperGSError. Readers check the sizes before they allocate, this checks the values."""
        params = np.asarray(params)
        if params.ndim != 3 or params.shape[-1] != NUM_PARAMS:
            raise HyperGSError(f"{where}: Gaussian parameters must be [frames, Gaussians, {NUM_PARAMS}], "
                               f"got shape {params.shape}")
        if params.shape[0] < 1 or params.shape[1] < 1:
            raise HyperGSError(f"{where}: an empty clip ({params.shape[0]} frames of {params.shape[1]} Gaussians)")
        limits.check_clip_size(params.shape[0], params.shape[1], where)
        if not all(isinstance(v, (int, np.integer)) and not isinstance(v, bool) for v in (canvas_width, canvas_height)):
            raise HyperGSError(f"{where}: the canvas must be two integers, got {canvas_width!r} x {canvas_height!r}")
        limits.check_image_size(int(canvas_width), int(canvas_height), f"{where}: canvas")
        if isinstance(fps, bool) or not isinstance(fps, (int, float, np.number)) or not 0 < fps <= MAX_FPS:
            raise HyperGSError(f"{where}: fps must be a number in (0, {MAX_FPS:g}], got {fps!r}")
        if (not isinstance(grid, (list, tuple)) or len(grid) != 2
                or not all(isinstance(g, (int, np.integer)) and 1 <= g <= MAX_GRID for g in grid)):
            raise HyperGSError(f"{where}: the grid must be two integers in 1..{MAX_GRID}, got {grid!r}")
        if not isinstance(source if source is not None else {}, dict):
            raise HyperGSError(f"{where}: the source description must be a JSON object")
        problem = param_problem(params)
        if problem:
            raise HyperGSError(f"{where}: {problem}")
        return cls(params, int(canvas_width), int(canvas_height), float(fps), tuple(grid), dict(source or {}))

    @property
    def num_frames(self) -> int:
        return self.params.shape[0]

    @property
    def num_gaussians(self) -> int:
        return self.params.shape[1]

    def frames(self, start: int, stop: int) -> "GaussianVideo":
        return GaussianVideo(self.params[start:stop], self.canvas_width, self.canvas_height, self.fps,
                             self.grid, dict(self.source))


def param_problem(params) -> str | None:
    """What makes Gaussian parameters [..., 8] unusable, or None: values that are not real
    floating-point numbers, are NaN or infinite (also after conversion to float32: 1e300 is), or
    scales <= 0.
    The message names the first bad value (frame, Gaussian, parameter)."""
    params = np.asarray(params)
    if params.dtype.kind != "f":
        return f"Gaussian parameters must be real floating-point numbers, not {params.dtype}"
    if params.shape[-1:] != (NUM_PARAMS,):
        return f"Gaussian parameters must have {NUM_PARAMS} values each, got shape {params.shape}"
    with np.errstate(over="ignore"):
        values = params.astype(np.float32, copy=False)
    bad = ~np.isfinite(values)
    if bad.any():
        what = "Gaussian parameters contain NaN or infinite values"
    else:
        bad = np.zeros(values.shape, bool)
        bad[..., 2:4] = values[..., 2:4] <= 0
        if not bad.any():
            return None
        what = "Gaussian scales must be > 0"
    index = np.unravel_index(np.argmax(bad), bad.shape)
    place = ", ".join(f"{name} {i}" for name, i in zip(("frame", "Gaussian")[-(len(index) - 1):], index[:-1]))
    return f"{what} ({place + ': ' if place else ''}{PARAMS[index[-1]]} = {params[index]})"

def covariance(scale: np.ndarray, rotation: np.ndarray, stretch=(1.0, 1.0)) -> np.ndarray:
    """[..., 2, 2] covariance T R diag(s^2) R^T T for scales [..., 2] and rotations [...]."""
    c, s = np.cos(rotation), np.sin(rotation)
    sx2, sy2 = scale[..., 0] ** 2, scale[..., 1] ** 2
    tx, ty = stretch
    xx = (c * c * sx2 + s * s * sy2) * tx * tx
    yy = (s * s * sx2 + c * c * sy2) * ty * ty
    xy = c * s * (sx2 - sy2) * tx * ty
    return np.stack([np.stack([xx, xy], -1), np.stack([xy, yy], -1)], -2)


def inverse_covariance(scale: np.ndarray, rotation: np.ndarray, stretch=(1.0, 1.0)) -> np.ndarray:
    cov = covariance(scale, rotation, stretch)
    det = cov[..., 0, 0] * cov[..., 1, 1] - cov[..., 0, 1] ** 2
    inv = np.empty_like(cov)
    inv[..., 0, 0] = cov[..., 1, 1] / det
    inv[..., 1, 1] = cov[..., 0, 0] / det
    inv[..., 0, 1] = inv[..., 1, 0] = -cov[..., 0, 1] / det
    return inv


def render_inputs(params, canvas_width: int, canvas_height: int, width: int, height: int, pixel_filter: bool = True):
    """Map [..., N, 8] parameters (numpy or torch) to the rasterizer's (means_px, chol, colors) at W x H.

    The covariance is T Sigma T, and where the render is smaller than the canvas (t < 1 along an axis),
    plus V = diag(PIXEL_VARIANCE (1 - t^2)) for each such axis: each Gaussian convolved with what a pixel
    of the render averages over. Its colour then scales by sqrt(det S / det(S + V)), so that its sum over
    the image stays what it was. At the canvas' size or larger, V = 0 and nothing else changes.
    pixel_filter=False: point samples whatever the size (the error pass's render, render.local_render).

    Uses the closed form of the Cholesky factor: l11 = sqrt(S_xx), l21 = S_xy / l11,
    l22 = sqrt(det S) / l11 with sqrt(det S) = sx sy tx ty, which stays exact for needle-thin Gaussians
    where sqrt(S_yy - l21^2) would cancel catastrophically (and det(S + V) adds only positive terms to det S).
    """
    xp = _array_module(params)
    tx, ty = width / canvas_width, height / canvas_height
    mx = (params[..., 0] + 1) * (0.5 * width)
    my = (params[..., 1] + 1) * (0.5 * height)
    sx, sy, rot = params[..., 2], params[..., 3], params[..., 4]
    c, s = xp.cos(rot), xp.sin(rot)
    sx2, sy2 = sx * sx, sy * sy
    cov_xx = (c * c * sx2 + s * s * sy2) * (tx * tx)
    cov_xy = (c * s * (sx2 - sy2)) * (tx * ty)
    root_det = sx * sy * (tx * ty)
    colors = params[..., 5:8]
    vx = vy = 0.0
    if pixel_filter:
        vx, vy = PIXEL_VARIANCE * max(0.0, 1 - tx * tx), PIXEL_VARIANCE * max(0.0, 1 - ty * ty)
    if vx or vy:  # a Python branch: a canvas-sized render (training's, refinement's) is as it was
        cov_yy = (s * s * sx2 + c * c * sy2) * (ty * ty)
        filtered_root_det = xp.sqrt(root_det * root_det + vx * cov_yy + vy * cov_xx + vx * vy)
        colors = colors * (root_det / filtered_root_det)[..., None]
        cov_xx, root_det = cov_xx + vx, filtered_root_det
    l11 = xp.sqrt(cov_xx)
    l21 = cov_xy / l11
    l22 = root_det / l11
    means = xp.stack([mx, my], -1)
    chol = xp.stack([l11, l21, l22], -1)
    return means, chol, colors


def _array_module(a):
    if isinstance(a, np.ndarray):
        return np
    import torch
    return torch


def grid_anchors(n: int, aspect: float = 1.0) -> np.ndarray:
    """N points in rows over [-1, 1]^2 (width / height = aspect): round(sqrt(N / aspect)) rows, each
    holding N // rows or one more points at its cell centres, so any N covers the canvas without
    holes. [N, 2] float32, row-major from the top-left."""
    rows = min(n, max(1, round(math.sqrt(n / aspect))))
    counts = np.full(rows, n // rows)
    counts[np.round(np.linspace(0, rows - 1, n % rows)).astype(int) if n % rows else []] += 1
    points = [np.stack([(np.arange(k) + 0.5) / k * 2 - 1, np.full(k, (r + 0.5) / rows * 2 - 1)], -1)
              for r, k in enumerate(counts)]
    return np.concatenate(points).astype(np.float32)


def lattice_anchors(k: int, phase) -> np.ndarray:
    """k x k anchors over [-1, 1]^2 for each row of phase [B, 2] (x, y, in cells, in [0, 1)): the points
    (j + phase) 2 / k - 1, j = 0 .. k - 1, row-major from the top-left -> [B, k * k, 2] float32.
    Phase 0.5 is grid_anchors(k * k); any other is a window of a larger lattice of the same spacing
    cut at any offset (a window k cells wide holds exactly k of its points per axis): how the
    transformer sees the windows of a tiled frame (network.TransformerEncoder), and trains."""
    phase = np.asarray(phase, np.float64).reshape(-1, 2)
    j = np.arange(k)
    out = np.empty((len(phase), k, k, 2), np.float32)
    out[..., 0] = ((j + phase[:, 0:1]) * (2.0 / k) - 1)[:, None, :]
    out[..., 1] = ((j + phase[:, 1:2]) * (2.0 / k) - 1)[:, :, None]
    return out.reshape(-1, k * k, 2)


def with_covariance(params: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """params with their scales and rotations replaced by the factors R diag(s^2) R^T of the covariances
    cov [..., 2, 2] (exactly: s_x along the rotation, rotation in [0, 2 pi))."""
    a, b, d = cov[..., 0, 0], cov[..., 0, 1], cov[..., 1, 1]
    theta = 0.5 * np.arctan2(2 * b, a - d)
    c, s = np.cos(theta), np.sin(theta)
    out = params.copy()
    out[..., 2] = np.sqrt(np.maximum(a * c * c + 2 * b * s * c + d * s * s, 0))
    out[..., 3] = np.sqrt(np.maximum(a * s * s - 2 * b * s * c + d * c * c, 0))
    out[..., 4] = np.mod(theta, 2 * np.pi)
    return out


def stretch_params(params: np.ndarray, tx: float, ty: float) -> np.ndarray:
    """Scales and rotations of the Gaussians stretched by T = diag(tx, ty): the covariance T Sigma T
    re-factored as R diag(s^2) R^T, exactly. Means and colours are returned unchanged (means are in
    [-1, 1] coordinates, which do not change when the canvas they refer to stretches)."""
    cov = covariance(params[..., 2:4].astype(np.float64), params[..., 4].astype(np.float64), (tx, ty))
    return with_covariance(params, cov)
