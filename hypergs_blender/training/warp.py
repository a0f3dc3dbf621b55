"""Numba kernels that sample training frames from photos and cached video frames: an affine warp
with 1-4 taps per axis (area filtering when minifying) and mip-pyramid sampling. nogil: they run in
the trainer's prefetch thread beside the training step."""
from __future__ import annotations

import math

import numpy as np
from numba import njit


@njit(nogil=True, cache=True, fastmath=True)
def warp_frame(src, aff, taps, out):
    """out [h, w, 3] float32 = src [H, W, 3] uint8 / 255 sampled at an affine map of pixel centres.

    Output pixel centre (x, y) maps to source point (a0 x + a1 y + a2, a3 x + a4 y + a5) in source
    pixel units (centres at i + 0.5); bilinear, clamped at the border, averaged over taps x taps
    points spread over the output pixel (area filtering when the map shrinks by up to `taps`).
    """
    H = src.shape[0]
    W = src.shape[1]
    h = out.shape[0]
    w = out.shape[1]
    a0 = aff[0]
    a1 = aff[1]
    a2 = aff[2]
    a3 = aff[3]
    a4 = aff[4]
    a5 = aff[5]
    norm = 1.0 / (255.0 * taps * taps)
    for y in range(h):
        for x in range(w):
            sr = 0.0
            sg = 0.0
            sb = 0.0
            for j in range(taps):
                yc = y + (j + 0.5) / taps
                for i in range(taps):
                    xc = x + (i + 0.5) / taps
                    sx = a0 * xc + a1 * yc + a2 - 0.5
                    sy = a3 * xc + a4 * yc + a5 - 0.5
                    sx = min(max(sx, 0.0), W - 1.0)
                    sy = min(max(sy, 0.0), H - 1.0)
                    ix = min(int(sx), W - 2) if W > 1 else 0
                    iy = min(int(sy), H - 2) if H > 1 else 0
                    wx = sx - ix
                    wy = sy - iy
                    jx = min(ix + 1, W - 1)
                    jy = min(iy + 1, H - 1)
                    w00 = (1.0 - wx) * (1.0 - wy)
                    w01 = wx * (1.0 - wy)
                    w10 = (1.0 - wx) * wy
                    w11 = wx * wy
                    sr += (w00 * src[iy, ix, 0] + w01 * src[iy, jx, 0]
                           + w10 * src[jy, ix, 0] + w11 * src[jy, jx, 0])
                    sg += (w00 * src[iy, ix, 1] + w01 * src[iy, jx, 1]
                           + w10 * src[jy, ix, 1] + w11 * src[jy, jx, 1])
                    sb += (w00 * src[iy, ix, 2] + w01 * src[iy, jx, 2]
                           + w10 * src[jy, ix, 2] + w11 * src[jy, jx, 2])
            out[y, x, 0] = sr * norm
            out[y, x, 1] = sg * norm
            out[y, x, 2] = sb * norm


def pyramid(image: np.ndarray, min_side: int = 16) -> list[np.ndarray]:
    """[image, image/2, image/4, ...] by 2x2 box filtering, uint8."""
    levels = [np.ascontiguousarray(image)]
    while min(levels[-1].shape[:2]) >= 2 * min_side:
        a = levels[-1]
        h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
        s = a[:h, :w].astype(np.uint16).reshape(h // 2, 2, w // 2, 2, 3).sum((1, 3))
        levels.append(((s + 2) // 4).astype(np.uint8))
    return levels


def warp_pyramid(levels, aff, scale, out):
    """Sample out [h, w, 3] from a pyramid: affine `aff` in base-level pixels, `scale` = base pixels
    per output pixel (picks the level, then 1 or 2 taps per axis)."""
    level = 0
    if scale > 1.0:
        level = min(int(math.floor(math.log2(scale))), len(levels) - 1)
    f = 1.0 / (1 << level)
    a = np.asarray(aff, np.float64) * f
    residual = scale * f
    taps = 1 if residual < 1.5 else min(4, int(math.ceil(residual)))  # bilinear aliases little below 1.5
    warp_frame(levels[level], a, taps, out)
