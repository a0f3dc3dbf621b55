"""Numba CPU kernels of the additive rasterizer (conventions: see raster.py). float32 in and out.

Per Gaussian, along one pixel row (fixed dy = y - my), the exponent is a quadratic in dx = x - mx:

    power(dx) = -1/2 (u^2 + v^2),  u = dx / l11,  v = (dy - l21 u) / l22
              = -A dx^2 + Bq dx + Cq,   A = 1/2 (1/l11^2 + k^2/l22^2),  k = l21 / l11,
                                        Bq = k dy / l22^2,  Cq = -1/2 dy^2 / l22^2.

Two things make the kernels fast:
- Each row is restricted to the pixels where power >= -POWER_CUTOFF (roots of the quadratic), intersected
  with the 3-sigma box. exp(-20) = 2e-9 is far below float32 resolution of any pixel the Gaussian
  matters for, and a rotated needle then costs ~1 pixel per row instead of its whole bounding box.
- No exp per pixel: g(dx + 1) = g(dx) r(dx), r(dx + 1) = r(dx) q with r = exp(power(dx+1) - power(dx))
  and q = exp(-2A). Walking the clipped row left to right in float64 is safe: every power on the row lies
  in [-POWER_CUTOFF, 0], so 1/r and r stay below exp(POWER_CUTOFF) (no overflow), and the relative error
  after n steps is ~n^2 * 1e-16 (nothing a float32 image can see).

The 3-sigma boxes (and invalid Gaussians: non-finite values, l11 = 0 or l22 = 0) are resolved once by
`_prepare`, compiled without fastmath so that NaN checks are honoured; the hot kernels only see finite,
valid Gaussians and integer pixel ranges inside the image, so they cannot index out of bounds.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

SIGMA_CUTOFF = 3.0  # the 3-sigma box (must match raster.SIGMA_CUTOFF)
POWER_CUTOFF = 20.0  # skip pixels with power < -20, i.e. g < 2e-9
BAND_ROWS = 16  # forward work unit: one frame x 16 rows

# Per-Gaussian constants computed by _prepare: [B, N, NCONST] float64.
_MX, _MY, _A, _KB, _HC, _Q = range(6)  # mean x/y, A, k/l22^2, 1/(2 l22^2), exp(-2A)
NCONST = 6

_FASTMATH = True


@njit(parallel=True, cache=True)
def _prepare(means, chol, width, height):
    """Clipped pixel boxes [B, N, 4] int32 (x0, x1, y0, y1; empty when x0 > x1) and constants."""
    B, N = means.shape[0], means.shape[1]
    boxes = np.empty((B, N, 4), np.int32)
    consts = np.zeros((B, N, NCONST), np.float64)
    for idx in prange(B * N):
        b = idx // N
        n = idx - b * N
        mx = np.float64(means[b, n, 0])
        my = np.float64(means[b, n, 1])
        l11 = np.float64(chol[b, n, 0])
        l21 = np.float64(chol[b, n, 1])
        l22 = np.float64(chol[b, n, 2])
        boxes[b, n, 0] = 1
        boxes[b, n, 1] = 0
        boxes[b, n, 2] = 1
        boxes[b, n, 3] = 0
        # Written so that NaN fails every test (no fastmath here).
        if not (abs(mx) < 1e30 and abs(my) < 1e30 and abs(l11) < 1e30 and abs(l21) < 1e30
                and abs(l22) < 1e30 and l11 != 0.0 and l22 != 0.0):
            continue
        # Same radii as raster.box_radii (computed in float32 like the reference on float32 input).
        rx = np.float64(np.float32(SIGMA_CUTOFF) * np.float32(abs(chol[b, n, 0])))
        ry = np.float64(np.float32(SIGMA_CUTOFF) * np.float32(math.sqrt(
            np.float32(chol[b, n, 1]) * np.float32(chol[b, n, 1])
            + np.float32(chol[b, n, 2]) * np.float32(chol[b, n, 2]))))
        # Pixel k is inside when |k + 0.5 - m| <= r. Clamp in float before converting to int.
        fx0 = min(max(math.ceil(mx - rx - 0.5), -1.0), width + 1.0)
        fx1 = min(max(math.floor(mx + rx - 0.5), -1.0), width + 1.0)
        fy0 = min(max(math.ceil(my - ry - 0.5), -1.0), height + 1.0)
        fy1 = min(max(math.floor(my + ry - 0.5), -1.0), height + 1.0)
        x0, x1, y0, y1 = int(fx0), int(fx1), int(fy0), int(fy1)
        # Settle the rounding of the edge pixels exactly as the reference's test decides it.
        while x0 <= x1 and abs(np.float32(x0 + 0.5) - np.float32(means[b, n, 0])) > rx:
            x0 += 1
        while x1 >= x0 and abs(np.float32(x1 + 0.5) - np.float32(means[b, n, 0])) > rx:
            x1 -= 1
        while y0 <= y1 and abs(np.float32(y0 + 0.5) - np.float32(means[b, n, 1])) > ry:
            y0 += 1
        while y1 >= y0 and abs(np.float32(y1 + 0.5) - np.float32(means[b, n, 1])) > ry:
            y1 -= 1
        x0 = max(x0, 0)
        x1 = min(x1, width - 1)
        y0 = max(y0, 0)
        y1 = min(y1, height - 1)
        if x0 > x1 or y0 > y1:
            continue
        k = l21 / l11
        inv22 = 1.0 / (l22 * l22)
        A = 0.5 * (1.0 / (l11 * l11) + k * k * inv22)
        boxes[b, n, 0] = x0
        boxes[b, n, 1] = x1
        boxes[b, n, 2] = y0
        boxes[b, n, 3] = y1
        consts[b, n, _MX] = mx
        consts[b, n, _MY] = my
        consts[b, n, _A] = A
        consts[b, n, _KB] = k * inv22
        consts[b, n, _HC] = 0.5 * inv22
        consts[b, n, _Q] = math.exp(-2.0 * A)
    return boxes, consts


@njit(parallel=True, cache=True)
def _order(boxes, width):
    """Per frame, the visible Gaussians sorted by their box's top row (then left column): order [B, N]
    int64 (the first count[b] entries are the visible ones), count [B] and the tallest box [B].
    Both kernels walk Gaussians in this order: neighbours in the order touch neighbouring memory
    (grad_out rows in the backward, 2x faster at 1080p), and a forward band finds its Gaussians by
    bisection instead of testing all N."""
    B, N = boxes.shape[0], boxes.shape[1]
    order = np.empty((B, N), np.int64)
    count = np.zeros(B, np.int64)
    tallest = np.zeros(B, np.int64)
    big = np.int64(1) << 62
    for b in prange(B):
        keys = np.empty(N, np.int64)
        for n in range(N):
            if boxes[b, n, 0] > boxes[b, n, 1]:
                keys[n] = big
            else:
                keys[n] = np.int64(boxes[b, n, 2]) * (width + 1) + boxes[b, n, 0]
                count[b] += 1
                tallest[b] = max(tallest[b], boxes[b, n, 3] - boxes[b, n, 2] + 1)
        order[b] = np.argsort(keys, kind="mergesort")
    return order, count, tallest


@njit(inline="always", fastmath=_FASTMATH, cache=True)
def _row_span(cst, x0, x1, dy):
    """Pixels [j0, j1] of the row at offset dy where power >= -POWER_CUTOFF, within [x0, x1],
    and the row's quadratic coefficients Bq, Cq. j0 > j1 when the row is empty."""
    A = cst[_A]
    bq = cst[_KB] * dy
    cq = -cst[_HC] * dy * dy
    disc = bq * bq + 4.0 * A * (cq + POWER_CUTOFF)
    if disc <= 0.0:
        return 1, 0, bq, cq
    s = math.sqrt(disc)
    inv2a = 0.5 / A
    mx = cst[_MX]
    lo = mx + (bq - s) * inv2a - 0.5  # pixel index whose centre is at the left root
    hi = mx + (bq + s) * inv2a - 0.5
    # Clamp before the int conversion (values stay finite for valid Gaussians, but may be huge).
    lo = min(max(lo, x0 - 1.0), x1 + 1.0)
    hi = min(max(hi, x0 - 1.0), x1 + 1.0)
    j0 = max(int(math.ceil(lo)), x0)
    j1 = min(int(math.floor(hi)), x1)
    return j0, j1, bq, cq


@njit(parallel=True, fastmath=_FASTMATH, cache=True)
def _forward_kernel(boxes, consts, order, count, tallest, colors, height, width, out):
    B, N, C = colors.shape
    nbands = (height + BAND_ROWS - 1) // BAND_ROWS
    for unit in prange(B * nbands):
        b = unit // nbands
        r0 = (unit - b * nbands) * BAND_ROWS
        r1 = min(r0 + BAND_ROWS, height) - 1
        # `out` comes uninitialised: each unit zeroes its own band (first touch in parallel, no extra pass)
        out[b, r0:r1 + 1] = 0.0
        # Boxes starting above r0 - tallest + 1 end above the band: bisect to the first one that may not.
        lo, hi = 0, count[b]
        while lo < hi:
            mid = (lo + hi) // 2
            if boxes[b, order[b, mid], 2] < r0 - tallest[b] + 1:
                lo = mid + 1
            else:
                hi = mid
        for k in range(lo, count[b]):
            n = order[b, k]
            x0, x1, y0, y1 = boxes[b, n, 0], boxes[b, n, 1], boxes[b, n, 2], boxes[b, n, 3]
            if y0 > r1:
                break  # sorted by y0: all the rest start below the band
            if y1 < r0:
                continue
            cst = consts[b, n]
            A = cst[_A]
            q = cst[_Q]
            mx = cst[_MX]
            my = cst[_MY]
            col = colors[b, n]
            for i in range(max(y0, r0), min(y1, r1) + 1):
                dy = i + 0.5 - my
                j0, j1, bq, cq = _row_span(cst, x0, x1, dy)
                if j0 > j1:
                    continue
                dx = j0 + 0.5 - mx
                g = math.exp((-A * dx + bq) * dx + cq)
                r = math.exp(-A * (2.0 * dx + 1.0) + bq)  # power(dx + 1) - power(dx)
                orow = out[b, i]
                if C == 3:
                    c0, c1, c2 = col[0], col[1], col[2]
                    for j in range(j0, j1 + 1):
                        gf = np.float32(g)
                        orow[j, 0] += gf * c0
                        orow[j, 1] += gf * c1
                        orow[j, 2] += gf * c2
                        g *= r
                        r *= q
                else:
                    for j in range(j0, j1 + 1):
                        gf = np.float32(g)
                        for c in range(C):
                            orow[j, c] += gf * col[c]
                        g *= r
                        r *= q


@njit(parallel=True, fastmath=_FASTMATH, cache=True)
def _backward_kernel(boxes, consts, order, chol, colors, grad_out, g_means, g_chol, g_colors):
    """One Gaussian per iteration: it reads grad_out over its pixels and writes only its own grads.

    Per row we accumulate R0 = sum gp, R1 = sum gp dx, R2 = sum gp dx^2 with gp = g * <grad_out, color>;
    since u = dx / l11 and l22 v = dy - k dx, the sums the gradients need follow per row:
    S_u = R1 / l11, S_v = (dy R0 - k R1) / l22, S_uu = R2 / l11^2, S_uv = (dy R1 - k R2) / (l11 l22),
    S_vv = (dy^2 R0 - 2 k dy R1 + k^2 R2) / l22^2, and then (power = -(u^2 + v^2) / 2)
    d/dmx = S_u / l11 - S_v l21 / (l22 l11), d/dmy = S_v / l22, d/dl11 = S_uu / l11 - S_uv l21 / (l22 l11),
    d/dl21 = S_uv / l22, d/dl22 = S_vv / l22, d/dcolor_c = sum grad_out_c g.
    """
    B, N, C = colors.shape
    for idx in prange(B * N):
        b = idx // N
        n = order[b, idx - b * N]
        x0, x1, y0, y1 = boxes[b, n, 0], boxes[b, n, 1], boxes[b, n, 2], boxes[b, n, 3]
        gc = g_colors[b, n]
        for c in range(C):
            gc[c] = 0.0
        if x0 > x1:
            g_means[b, n, 0] = 0.0
            g_means[b, n, 1] = 0.0
            g_chol[b, n, 0] = 0.0
            g_chol[b, n, 1] = 0.0
            g_chol[b, n, 2] = 0.0
            continue
        cst = consts[b, n]
        A = cst[_A]
        q = cst[_Q]
        mx = cst[_MX]
        my = cst[_MY]
        l11 = np.float64(chol[b, n, 0])
        l21 = np.float64(chol[b, n, 1])
        l22 = np.float64(chol[b, n, 2])
        k = l21 / l11
        col = colors[b, n]
        c0, c1, c2 = 0.0, 0.0, 0.0
        if C == 3:
            c0, c1, c2 = np.float64(col[0]), np.float64(col[1]), np.float64(col[2])
        gc0, gc1, gc2 = 0.0, 0.0, 0.0
        s_u = 0.0
        s_v = 0.0
        s_uu = 0.0
        s_uv = 0.0
        s_vv = 0.0
        for i in range(y0, y1 + 1):
            dy = i + 0.5 - my
            j0, j1, bq, cq = _row_span(cst, x0, x1, dy)
            if j0 > j1:
                continue
            dx0 = j0 + 0.5 - mx
            g = math.exp((-A * dx0 + bq) * dx0 + cq)
            r = math.exp(-A * (2.0 * dx0 + 1.0) + bq)
            grow = grad_out[b, i]
            # Offsets t = j - j0 (small numbers: less cancellation than dx), shifted back below.
            r0 = 0.0
            r1 = 0.0
            r2 = 0.0
            if C == 3:
                for j in range(j0, j1 + 1):
                    go0 = np.float64(grow[j, 0])
                    go1 = np.float64(grow[j, 1])
                    go2 = np.float64(grow[j, 2])
                    gp = g * (go0 * c0 + go1 * c1 + go2 * c2)
                    t = np.float64(j - j0)
                    r0 += gp
                    r1 += gp * t
                    r2 += gp * t * t
                    gc0 += go0 * g
                    gc1 += go1 * g
                    gc2 += go2 * g
                    g *= r
                    r *= q
            else:
                for j in range(j0, j1 + 1):
                    s = 0.0
                    for c in range(C):
                        go = np.float64(grow[j, c])
                        s += go * col[c]
                        gc[c] += go * g
                    gp = g * s
                    t = np.float64(j - j0)
                    r0 += gp
                    r1 += gp * t
                    r2 += gp * t * t
                    g *= r
                    r *= q
            # Moments about dx = dx0 + t.
            m1 = r1 + dx0 * r0  # sum gp dx
            m2 = r2 + 2.0 * dx0 * r1 + dx0 * dx0 * r0  # sum gp dx^2
            w1 = dy * r0 - k * m1  # sum gp (dy - k dx) = l22 S_v
            s_u += m1
            s_v += w1
            s_uu += m2
            s_uv += dy * m1 - k * m2  # sum gp dx (dy - k dx)
            s_vv += dy * w1 - k * (dy * m1 - k * m2)  # sum gp (dy - k dx)^2
        s_u /= l11
        s_v /= l22
        s_uu /= l11 * l11
        s_uv /= l11 * l22
        s_vv /= l22 * l22
        g_means[b, n, 0] = s_u / l11 - s_v * l21 / (l22 * l11)
        g_means[b, n, 1] = s_v / l22
        g_chol[b, n, 0] = s_uu / l11 - s_uv * l21 / (l22 * l11)
        g_chol[b, n, 1] = s_uv / l22
        g_chol[b, n, 2] = s_vv / l22
        if C == 3:
            gc[0] = gc0
            gc[1] = gc1
            gc[2] = gc2


def _f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def forward(means, chol, colors, width: int, height: int) -> np.ndarray:
    """means [B, N, 2], chol [B, N, 3], colors [B, N, C] (numpy) -> images [B, H, W, C] float32."""
    means, chol, colors = _f32(means), _f32(chol), _f32(colors)
    boxes, consts = _prepare(means, chol, int(width), int(height))
    order, count, tallest = _order(boxes, int(width))
    out = np.empty((means.shape[0], int(height), int(width), colors.shape[-1]), np.float32)
    if out.size:
        _forward_kernel(boxes, consts, order, count, tallest, colors, int(height), int(width), out)
    return out


def backward(means, chol, colors, grad_out, width: int, height: int):
    """Gradients (d_means, d_chol, d_colors) float32 of sum(grad_out * forward(...))."""
    means, chol, colors, grad_out = _f32(means), _f32(chol), _f32(colors), _f32(grad_out)
    boxes, consts = _prepare(means, chol, int(width), int(height))
    B, N, C = colors.shape
    g_means = np.empty((B, N, 2), np.float64)
    g_chol = np.empty((B, N, 3), np.float64)
    g_colors = np.empty((B, N, C), np.float64)
    order = _order(boxes, int(width))[0]
    _backward_kernel(boxes, consts, order, chol, colors, grad_out, g_means, g_chol, g_colors)
    return g_means.astype(np.float32), g_chol.astype(np.float32), g_colors.astype(np.float32)
