"""Additive 2D Gaussian rasterizer: I(p) = sum_i c_i exp(-1/2 d^T Sigma_i^-1 d), opacity 1.

Conventions (shared by every implementation here):
- Pixel (row i, column j) has its centre at (x, y) = (j + 0.5, i + 0.5) in pixel units; the image's
  top-left corner is (0, 0) and its bottom-right corner is (W, H). Rows run top to bottom.
- A Gaussian is given by its mean (x, y) in those pixel units, the lower Cholesky factor
  L = [[l11, 0], [l21, l22]] of its pixel-space covariance Sigma = L L^T, stored as (l11, l21, l22),
  and C colour channels. Then d^T Sigma^-1 d = |L^-1 d|^2, which stays well conditioned for
  needle-thin Gaussians where inverting Sigma would not.
- Each Gaussian is culled to its box of SIGMA_CUTOFF (4) sigmas: it touches the pixels whose centres
  satisfy |x - mx| <= 4 sqrt(Sigma_xx) and |y - my| <= 4 sqrt(Sigma_yy). Outside the box it
  contributes nothing.
- Shapes: means [B, N, 2], chol [B, N, 3], colors [B, N, C] -> images [B, H, W, C] (channels last,
  float32). B is any number of frames (clips x time flattened); every frame has N Gaussians.

`rasterize_reference` evaluates every Gaussian at every pixel (slow, obviously correct): the fast
kernels are tested against it.

Entry points (all accept any leading batch shape: means [..., N, 2] -> images [..., H, W, C]):
- `rasterize` (torch, differentiable): numba kernels for CPU tensors (_raster_numba.py, forward and a
  hand-written backward); on CUDA, or without numba, a pure-torch patch renderer (below).
- `rasterize_numpy` (numpy only, forward): what the Blender render engine uses, where neither torch nor
  numba may exist: the numba forward when numba imports, else a vectorised numpy patch renderer.
Importing this module imports neither torch nor numba; both are loaded on first use.

Patch renderers (torch and numpy): every Gaussian is evaluated on a rectangle of pixels covering its
clipped box plus a one-pixel margin, where the reference's own test |dx| <= r decides membership.
Gaussians are grouped by patch size (rounded up on a ladder of sizes, see _patch_plan) and each group is
evaluated in fixed-size chunks: a Python loop over size groups and chunks, none over frames or
Gaussians, and memory bounded by the chunk size.

Invalid Gaussians (non-finite values, l11 = 0 or l22 = 0, |mean| or box radius >= MAX_EXTENT px)
contribute nothing and get zero gradients in every fast path (the reference would spread NaN over
their box).

Limits (limits.py), checked before anything is allocated: the output size (SIDE, PIXELS, BYTES) in
both entry points, and in `rasterize_numpy` the work of each frame (WORK: `box_work`, the pixels its
Gaussians' clipped boxes cover). `rasterize_numpy(..., keep_going=f)` renders a heavy batch as a sum
over slices of its Gaussians (the render is additive), calling f() before each slice (about 0.1 s of
work), and raises errors.Cancelled when it returns False: a renderer's Esc, inside a long frame.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from . import limits
from .errors import Cancelled

if TYPE_CHECKING:
    import torch

# The box's half-width in sigmas (_raster_numba.SIGMA_CUTOFF must be the same number: numba freezes a
# module's globals into its cached machine code, so that file holds its own copy). At 3 sigma the kernel is
# still 1.1 % of its peak at the box's edge: in flat regions the similar Gaussians' cut edges lined up into a
# 1-px column per cell, 41 % of the flat ripple on Kleiber's sky (MODEL_CARD.md, session 16); at 3.5 sigma
# the edge is 0.2 %, still a lattice pattern on smooth gradients that the network's error pass, which reads
# an uncut render, cannot see; at 4 sigma (0.03 %) the flat ripple at Standard falls from 1.79x the source's
# to 1.15x at the same PSNR, 1.04x once trained under it (session 22), for 1.31x 3.5's box area (5 sigma
# measured no better).
SIGMA_CUTOFF = 4.0
MAX_EXTENT = 1e7  # fast paths treat Gaussians with |mean| or box radius >= 1e7 px as invalid


def box_radii(chol):
    """Half-widths (rx, ry) of each Gaussian's box (SIGMA_CUTOFF sigmas), from (l11, l21, l22) [..., 3]:
    numpy or torch, computed in chol's dtype (float32 input gives the float32 radii every float32 path tests
    against)."""
    if isinstance(chol, np.ndarray):
        xp = np
    else:
        import torch as xp
    l11, l21, l22 = chol[..., 0], chol[..., 1], chol[..., 2]
    return xp.stack([SIGMA_CUTOFF * xp.abs(l11), SIGMA_CUTOFF * xp.sqrt(l21 * l21 + l22 * l22)], -1)


def touching(means: np.ndarray, chol: np.ndarray, width: int, height: int):
    """Which Gaussians (float64 means [M, 2], chol [M, 3]) can touch a pixel of a width x height image, and
    the pixel bounds (x0, x1, y0, y1) [M] (float, unclipped) of their boxes with one pixel of margin
    either side: the exact |dx| <= r test is the caller's. Invalid Gaussians touch nothing (`valid`)."""
    with np.errstate(invalid="ignore", over="ignore"):
        rx, ry = box_radii(chol).T
        ok = valid(means, chol, rx, ry)
        x0 = np.floor(means[:, 0] - rx - 0.5)
        x1 = np.ceil(means[:, 0] + rx - 0.5)
        y0 = np.floor(means[:, 1] - ry - 0.5)
        y1 = np.ceil(means[:, 1] + ry - 0.5)
        ok &= (x1 >= 0) & (x0 <= width - 1) & (y1 >= 0) & (y0 <= height - 1)
    return ok, (x0, x1, y0, y1)


def valid(means: np.ndarray, chol: np.ndarray, rx: np.ndarray, ry: np.ndarray) -> np.ndarray:
    """The Gaussians every fast path draws: finite, l11 != 0 and l22 != 0, |mean| and box radii (rx, ry)
    below MAX_EXTENT px (as the numba path). (NaN and inf fail the comparisons with MAX_EXTENT.)"""
    with np.errstate(invalid="ignore"):
        return ((np.abs(means[:, 0]) < MAX_EXTENT) & (np.abs(means[:, 1]) < MAX_EXTENT) & (rx < MAX_EXTENT)
                & (ry < MAX_EXTENT) & (chol[:, 0] != 0) & (chol[:, 2] != 0))


def box_pixels(means: np.ndarray, chol: np.ndarray, columns: tuple[int, int], rows: tuple[int, int]):
    """The pixels inside each Gaussian's box, exactly as the rasterizers decide them (the float32 test
    |k + 0.5 - m| <= r on float32 means [M, 2] and chol [M, 3]), within the columns [c0, c1) and rows [r0, r1)
    of an image: ok [M] (valid and not empty there), and the first and last column and row (x0, x1, y0, y1)
    [M] int32 (meaningful where ok)."""
    means = np.asarray(means, np.float32)
    chol = np.asarray(chol, np.float32)
    radii = box_radii(chol)
    half = np.float32(0.5)
    with np.errstate(invalid="ignore", over="ignore"):
        ok = valid(means, chol, radii[:, 0], radii[:, 1])
        spans = []
        for axis, (start, stop) in enumerate((columns, rows)):
            m, r = means[:, axis], radii[:, axis]

            def inside(k):
                return np.abs((k + half) - m) <= r

            # The edges in exact arithmetic (float64 holds m -+ r - 0.5 exactly), kept near the window. The
            # float32 test rounds k + 0.5 - m to nearest, which never passes r (a float32 itself): it can only
            # let in one more pixel at either end.
            lo = np.clip(np.ceil((m.astype(np.float64) - r) - 0.5), start - 1, stop).astype(np.float32)
            hi = np.clip(np.floor((m.astype(np.float64) + r) - 0.5), start - 1, stop).astype(np.float32)
            lo -= inside(lo - 1)
            hi += inside(hi + 1)
            lo, hi = np.maximum(lo, start), np.minimum(hi, stop - 1)
            ok &= lo <= hi
            spans += [np.where(ok, lo, 0).astype(np.int32), np.where(ok, hi, 0).astype(np.int32)]
    return ok, tuple(spans)


def rasterize_reference(means: "torch.Tensor", chol: "torch.Tensor", colors: "torch.Tensor",
                        width: int, height: int) -> "torch.Tensor":
    """Dense reference: every Gaussian at every pixel, then the box mask. Differentiable."""
    import torch

    dtype = means.dtype
    xs = torch.arange(width, dtype=dtype, device=means.device) + 0.5
    ys = torch.arange(height, dtype=dtype, device=means.device) + 0.5
    dx = xs[None, None, None, :] - means[..., 0, None, None]  # [B, N, 1, W]
    dy = ys[None, None, :, None] - means[..., 1, None, None]  # [B, N, H, 1]
    l11, l21, l22 = (chol[..., k, None, None] for k in range(3))
    u = dx / l11
    v = (dy - l21 * u) / l22
    g = torch.exp(-0.5 * (u * u + v * v))  # [B, N, H, W]
    radii = box_radii(chol)
    inside = (dx.abs() <= radii[..., 0, None, None]) & (dy.abs() <= radii[..., 1, None, None])
    g = torch.where(inside, g, torch.zeros((), dtype=dtype, device=means.device))
    return torch.einsum("bnhw,bnc->bhwc", g, colors)


# ----------------------------------------------------------------------------------------------------
# numba (optional)

_NUMBA = None  # the _raster_numba module, False when numba is missing, None before the first try


def numba_available() -> bool:
    global _NUMBA
    if _NUMBA is None:
        try:
            from . import _raster_numba
            _NUMBA = _raster_numba
        except ImportError:
            _NUMBA = False
    return _NUMBA is not False


def set_threads(threads: int) -> None:
    """The numba kernels' CPU threads in the calling thread (numba's setting is per thread; the kernels
    run where `rasterize` is called); nothing without numba. torch.set_num_threads does not reach them."""
    if numba_available():
        import numba
        numba.set_num_threads(min(threads, numba.config.NUMBA_NUM_THREADS))


def _check_shapes(means, chol, colors):
    if means.shape[-1] != 2 or chol.shape[-1] != 3 or colors.ndim < 2:
        raise ValueError(f"rasterize: expected means [..., N, 2], chol [..., N, 3], colors [..., N, C]; "
                         f"got {tuple(means.shape)}, {tuple(chol.shape)}, {tuple(colors.shape)}")
    if means.shape[:-1] != chol.shape[:-1] or means.shape[:-1] != colors.shape[:-1]:
        raise ValueError(f"rasterize: leading shapes differ: {tuple(means.shape)}, {tuple(chol.shape)}, "
                         f"{tuple(colors.shape)}")


# ----------------------------------------------------------------------------------------------------
# Patch plan, shared by the torch and numpy patch renderers

# Patch sizes are rounded up to a ladder so that Gaussians fall into few size groups: the coarse one
# (x1.5 steps, <= 2.25x wasted area) keeps the number of groups, i.e. of kernel launches on a GPU, small;
# the fine one (x2^(1/4) steps, <= 1.41x) suits the numpy renderer, whose cost is per evaluated pixel.
LADDER_COARSE = np.array(sorted({int(round(v)) for k in range(40) for v in (2 ** k, 1.5 * 2 ** k)}), np.int64)
LADDER_FINE = np.array(sorted({int(math.ceil(2 ** (k / 4) - 1e-9)) for k in range(160)}), np.int64)


def _clipped_boxes(means: np.ndarray, chol: np.ndarray, width: int, height: int):
    """For flattened Gaussians means [M, 2], chol [M, 3] (float64): which are drawn (valid and on
    screen), and their pixel boxes x0, x1, y0, y1 (int64 [M]: the box and one pixel of margin
    either side, clipped to the image; 0 for the others)."""
    ok, (fx0, fx1, fy0, fy1) = touching(means, chol, width, height)  # the exact test happens on the patch
    x0 = np.clip(np.where(ok, fx0, 0), 0, width - 1).astype(np.int64)
    x1 = np.clip(np.where(ok, fx1, 0), 0, width - 1).astype(np.int64)
    y0 = np.clip(np.where(ok, fy0, 0), 0, height - 1).astype(np.int64)
    y1 = np.clip(np.where(ok, fy1, 0), 0, height - 1).astype(np.int64)
    return ok, x0, x1, y0, y1


def box_work(means, chol, width: int, height: int) -> np.ndarray:
    """The cost of rendering, known before rendering: per frame, the pixels its Gaussians' clipped
    boxes cover. means [..., N, 2], chol [..., N, 3] -> float64 [frames] (flattened leading shape).
    With numba, from the kernels' own boxes; else in numpy (the patch plan's boxes, one pixel of
    margin wider)."""
    means, chol = np.asarray(means), np.asarray(chol)
    n = means.shape[-2]
    if numba_available() and n:
        return _NUMBA.box_work(_NUMBA.prepare(means.reshape(-1, n, 2), chol.reshape(-1, n, 3), width, height)[0])
    ok, x0, x1, y0, y1 = _clipped_boxes(means.reshape(-1, 2).astype(np.float64),
                                        chol.reshape(-1, 3).astype(np.float64), width, height)
    area = np.where(ok, (x1 - x0 + 1) * (y1 - y0 + 1), 0).astype(np.float64)
    return area.reshape(-1, n).sum(axis=1) if n else np.zeros(math.prod(means.shape[:-2]))


def check_render_size(width: int, height: int, frames: int, channels: int = 3) -> None:
    """Refuses (LimitError) a render whose frames are past the image limits or whose output would be
    past the memory limit."""
    limits.check_image_size(width, height, "render")
    limits.BYTES.check(frames * width * height * channels * 4, f"render of {frames:,} frames at {width} x {height}")


def _patch_plan(means: np.ndarray, chol: np.ndarray, width: int, height: int, budget: int,
                ladder: np.ndarray = LADDER_COARSE):
    """For flattened Gaussians means [M, 2], chol [M, 3] (float64): patch origins (x0, y0) [M] int64 and a
    list of chunks (indices, kh, kw) such that chunk size * kh * kw <= budget (or one Gaussian).
    Invalid (non-finite, l11 = 0 or l22 = 0) and off-screen Gaussians are in no chunk."""
    ok, x0, x1, y0, y1 = _clipped_boxes(means, chol, width, height)
    idx = np.nonzero(ok)[0]
    kw = np.minimum(ladder[np.searchsorted(ladder, x1[idx] - x0[idx] + 1)], width)
    kh = np.minimum(ladder[np.searchsorted(ladder, y1[idx] - y0[idx] + 1)], height)
    key = kh * (width + 1) + kw
    order = np.argsort(key, kind="stable")
    idx, key, kw, kh = idx[order], key[order], kw[order], kh[order]
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]]) if len(key) else np.zeros(0, np.int64)
    chunks = []
    for s, e in zip(starts, np.r_[starts[1:], len(key)]):
        h, w = int(kh[s]), int(kw[s])
        step = max(1, budget // (h * w))
        for c in range(s, e, step):
            chunks.append((idx[c:min(c + step, e)], h, w))
    return x0, y0, chunks


def _flatten(means, chol, colors):
    """[..., N, k] -> [B, N, k] views, and the leading shape."""
    lead = tuple(means.shape[:-2])
    b, n = math.prod(lead), means.shape[-2]
    return (means.reshape(b, n, 2), chol.reshape(b, n, 3), colors.reshape(b, n, colors.shape[-1]), lead)


# ----------------------------------------------------------------------------------------------------
# numpy-only entry point

def rasterize_numpy(means, chol, colors, width: int, height: int, *, backend: str = "auto",
                    keep_going=None) -> np.ndarray:
    """Forward only, numpy in and out: means [..., N, 2], chol [..., N, 3], colors [..., N, C] ->
    float32 images [..., H, W, C]. backend: "auto" (numba when it imports, else numpy), "numba" or
    "numpy" (the pure-numpy patch renderer, also what runs where numba is missing).
    keep_going: None, or a function () -> bool called between pieces of the work; False cancels
    (raises errors.Cancelled). Raises LimitError for a render past the limits (see the module doc)."""
    if backend not in ("auto", "numba", "numpy"):
        raise ValueError(f"rasterize_numpy: unknown backend {backend!r}")
    means, chol, colors = (np.asarray(a) for a in (means, chol, colors))
    _check_shapes(means, chol, colors)
    width, height = int(width), int(height)
    m, c, col, lead = _flatten(means, chol, colors)
    check_render_size(width, height, m.shape[0], col.shape[-1])
    if backend == "numba" or (backend == "auto" and numba_available()):
        if not numba_available():
            raise ImportError("rasterize_numpy(backend='numba'): numba is not installed")
        prepared = _NUMBA.prepare(m, c, width, height)  # the kernels' boxes: the work, and the render's start
        work, piece = _NUMBA.box_work(prepared[0]), PIECE_WORK_NUMBA

        def forward(part, whole):
            return _NUMBA.forward(m[:, part], c[:, part], col[:, part], width, height, prepared if whole else None)
    else:
        work, piece = box_work(m, c, width, height), PIECE_WORK_NUMPY

        def forward(part, whole):
            return _numpy_forward(m[:, part], c[:, part], col[:, part], width, height)
    if len(work):
        frame = int(np.argmax(work))
        limits.WORK.check(work[frame], f"a {width} x {height} render" + (f", frame {frame}" if len(work) > 1 else ""))
    n = m.shape[1]
    slices = 1 if keep_going is None else int(min(max(1, math.ceil(work.sum() / piece)), max(n, 1)))
    out = None
    for s in range(slices):  # the render is additive: a sum over slices of the Gaussians
        if keep_going is not None and not keep_going():
            raise Cancelled("rendering cancelled")
        image = forward(slice(s * n // slices, (s + 1) * n // slices), slices == 1)
        out = image if out is None else np.add(out, image, out=out)
    return out.reshape(lead + out.shape[1:])


# With keep_going, a render runs in slices of about this many Gaussian-pixels (~0.1 s on 2 cores).
PIECE_WORK_NUMBA = 1 << 25
PIECE_WORK_NUMPY = 1 << 22


_NUMPY_BUDGET = 1 << 18  # pixels per chunk: temporaries of ~1 MB stay in cache


def _numpy_forward(means, chol, colors, width, height, budget=_NUMPY_BUDGET):
    """Patch renderer in numpy. Per evaluated pixel: 6 float32 array ops for the Gaussian (in the
    reference's order, so the box test agrees with it bit for bit) and, per channel, a multiply and an
    unbuffered np.add.at into a planar image (the scatter dominates: ~3 ns per pixel and channel)."""
    B, N, C = colors.shape
    M = B * N
    means = np.asarray(means, np.float32).reshape(M, 2)
    chol = np.asarray(chol, np.float32).reshape(M, 3)
    colors = np.asarray(colors, np.float32).reshape(M, C)
    x0, y0, chunks = _patch_plan(means.astype(np.float64), chol.astype(np.float64), width, height, budget,
                                 LADDER_FINE)
    # Flat index of each patch origin; a patch cell right of the image wraps into the next row and one
    # below it into the next frame or the padding: such cells have g = 0, so they add nothing.
    origin = ((np.arange(M) // max(N, 1)) * height + y0) * width + x0
    pad = (height + 1) * width
    planes = np.zeros((C, B * height * width + pad), np.float32)
    f32 = np.float32
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        for idx, kh, kw in chunks:
            m, l = means[idx], chol[idx]
            jx = x0[idx, None] + np.arange(kw)  # [n, kw]
            iy = y0[idx, None] + np.arange(kh)  # [n, kh]
            dx = (jx.astype(f32) + f32(0.5)) - m[:, 0, None]
            dy = (iy.astype(f32) + f32(0.5)) - m[:, 1, None]
            rx, ry = box_radii(l).T
            u = dx / l[:, 0, None]
            # Outside the box: u^2 = inf (columns), dy = inf (rows), so that exp(-0.5 (u^2 + v^2)) = 0.
            uu = np.where((np.abs(dx) <= rx[:, None]) & (jx < width), u * u, f32(np.inf))
            dy = np.where((np.abs(dy) <= ry[:, None]) & (iy < height), dy, f32(np.inf))
            v = dy[:, :, None] - (l[:, 1, None] * u)[:, None, :]  # [n, kh, kw]
            v /= l[:, 2, None, None]
            v *= v
            v += uu[:, None, :]
            v *= f32(-0.5)
            g = np.exp(v, out=v)
            pix = (origin[idx, None, None] + (np.arange(kh) * width)[None, :, None]
                   + np.arange(kw)[None, None, :]).ravel()
            for c in range(C):
                np.add.at(planes[c], pix, (g * colors[idx, c, None, None]).ravel())
    out = planes[:, :B * height * width].reshape(C, B, height, width)
    return np.ascontiguousarray(out.transpose(1, 2, 3, 0))


# ----------------------------------------------------------------------------------------------------
# torch entry point

def rasterize(means: "torch.Tensor", chol: "torch.Tensor", colors: "torch.Tensor", width: int, height: int,
              *, backend: str = "auto") -> "torch.Tensor":
    """Differentiable rasterizer: means [..., N, 2], chol [..., N, 3], colors [..., N, C] -> images
    [..., H, W, C] in the inputs' (promoted) dtype. backend: "auto" (numba on CPU tensors when numba
    imports, else torch), "numba" (computes in float32) or "torch" (the patch renderer, in the inputs'
    dtype, on any device; its backward recomputes chunk by chunk, so memory stays bounded)."""
    import torch

    if backend not in ("auto", "numba", "torch"):
        raise ValueError(f"rasterize: unknown backend {backend!r}")
    _check_shapes(means, chol, colors)
    check_render_size(int(width), int(height), math.prod(means.shape[:-2]), colors.shape[-1])
    dtype = torch.promote_types(torch.promote_types(means.dtype, chol.dtype), colors.dtype)
    if not dtype.is_floating_point:
        dtype = torch.float32
    width, height = int(width), int(height)
    on_cpu = means.device.type == "cpu" and chol.device.type == "cpu" and colors.device.type == "cpu"
    if backend == "numba" or (backend == "auto" and on_cpu and numba_available()):
        if not numba_available():
            raise ImportError("rasterize(backend='numba'): numba is not installed")
        if not on_cpu:
            raise ValueError("rasterize(backend='numba') needs CPU tensors")
        fn = _numba_function()
    else:
        fn = _torch_function()
    m, c, col, lead = _flatten(means.to(dtype), chol.to(dtype), colors.to(dtype))
    out = fn.apply(m, c, col, width, height)
    return out.reshape(lead + tuple(out.shape[1:]))


_FUNCTIONS = {}


def _numba_function():
    """torch.autograd.Function around the numba kernels (built on first use: torch is imported lazily)."""
    if "numba" in _FUNCTIONS:
        return _FUNCTIONS["numba"]
    import torch

    def np32(t):
        return t.detach().to(torch.float32).contiguous().numpy()

    class NumbaRaster(torch.autograd.Function):
        @staticmethod
        def forward(ctx, means, chol, colors, width, height):
            ctx.save_for_backward(means, chol, colors)
            ctx.size = (width, height)
            out = _NUMBA.forward(np32(means), np32(chol), np32(colors), width, height)
            return torch.from_numpy(out).to(means.dtype)

        @staticmethod
        def backward(ctx, grad_out):
            means, chol, colors = ctx.saved_tensors
            if not any(ctx.needs_input_grad[:3]):
                return None, None, None, None, None
            gm, gc, gcol = _NUMBA.backward(np32(means), np32(chol), np32(colors), np32(grad_out), *ctx.size)
            grads = [torch.from_numpy(g).to(t.dtype) if need else None
                     for g, t, need in zip((gm, gc, gcol), (means, chol, colors), ctx.needs_input_grad)]
            return grads[0], grads[1], grads[2], None, None

    _FUNCTIONS["numba"] = NumbaRaster
    return NumbaRaster


def _torch_patches(means, chol, colors, frame, x0, y0, kh, kw, width, height):
    """Contributions [n, kh, kw, C] of n Gaussians to their patches, and the flat pixel indices [n, kh, kw]
    (into [B * H * W]); membership uses the reference's own arithmetic."""
    import torch

    dev, dtype = means.device, means.dtype
    jx = x0[:, None] + torch.arange(kw, device=dev)  # [n, kw]
    iy = y0[:, None] + torch.arange(kh, device=dev)  # [n, kh]
    dx = (jx.to(dtype) + 0.5) - means[:, 0, None]
    dy = (iy.to(dtype) + 0.5) - means[:, 1, None]
    radii = box_radii(chol)
    in_x = (dx.abs() <= radii[:, 0, None]) & (jx < width)
    in_y = (dy.abs() <= radii[:, 1, None]) & (iy < height)
    u = dx / chol[:, 0, None]
    v = (dy[:, :, None] - chol[:, 1, None, None] * u[:, None, :]) / chol[:, 2, None, None]
    g = torch.exp(-0.5 * (u * u)[:, None, :] - 0.5 * (v * v))
    g = torch.where(in_y[:, :, None] & in_x[:, None, :], g, torch.zeros((), dtype=dtype, device=dev))
    pix = ((frame[:, None, None] * height + iy.clamp(max=height - 1)[:, :, None]) * width
           + jx.clamp(max=width - 1)[:, None, :])
    return g[..., None] * colors[:, None, None, :], pix


def _torch_function():
    if "torch" in _FUNCTIONS:
        return _FUNCTIONS["torch"]
    import torch

    @torch.profiler.record_function("raster.plan")
    def plan(means, chol, width, height):
        budget = (1 << 24) if means.device.type == "cuda" else (1 << 20)
        x0, y0, chunks = _patch_plan(means.detach().reshape(-1, 2).to("cpu", torch.float64).numpy(),
                                     chol.detach().reshape(-1, 3).to("cpu", torch.float64).numpy(),
                                     width, height, budget, LADDER_COARSE)
        dev = means.device
        return (torch.from_numpy(x0).to(dev), torch.from_numpy(y0).to(dev),
                [(torch.from_numpy(i).to(dev), kh, kw) for i, kh, kw in chunks])

    class TorchPatchRaster(torch.autograd.Function):
        """Forward without a graph; backward re-evaluates each chunk under autograd (memory stays bounded
        by the chunk size instead of holding every patch of the forward)."""

        @staticmethod
        def forward(ctx, means, chol, colors, width, height):
            B, N, C = colors.shape
            x0, y0, chunks = plan(means, chol, width, height)
            m, c, col = means.reshape(-1, 2), chol.reshape(-1, 3), colors.reshape(-1, C)
            frame = torch.arange(B * N, device=means.device) // max(N, 1)
            out = torch.zeros(B * height * width, C, dtype=means.dtype, device=means.device)
            for idx, kh, kw in chunks:
                contrib, pix = _torch_patches(m[idx], c[idx], col[idx], frame[idx], x0[idx], y0[idx],
                                              kh, kw, width, height)
                out.index_add_(0, pix.reshape(-1), contrib.reshape(-1, C))
            ctx.save_for_backward(means, chol, colors)
            ctx.plan = (x0, y0, chunks, width, height)
            return out.reshape(B, height, width, C)

        @staticmethod
        def backward(ctx, grad_out):
            means, chol, colors = ctx.saved_tensors
            x0, y0, chunks, width, height = ctx.plan
            B, N, C = colors.shape
            m, c, col = means.reshape(-1, 2), chol.reshape(-1, 3), colors.reshape(-1, C)
            frame = torch.arange(B * N, device=means.device) // max(N, 1)
            go = grad_out.reshape(-1, C)
            gm, gc, gcol = torch.zeros_like(m), torch.zeros_like(c), torch.zeros_like(col)
            for idx, kh, kw in chunks:
                with torch.enable_grad():
                    leaves = [t[idx].detach().requires_grad_() for t in (m, c, col)]
                    contrib, pix = _torch_patches(*leaves, frame[idx], x0[idx], y0[idx], kh, kw, width,
                                                  height)
                    loss = (contrib * go[pix]).sum()
                    d = torch.autograd.grad(loss, leaves)
                gm[idx], gc[idx], gcol[idx] = d
            return gm.reshape(means.shape), gc.reshape(chol.shape), gcol.reshape(colors.shape), None, None

    _FUNCTIONS["torch"] = TorchPatchRaster
    return TorchPatchRaster
