"""Numba CPU kernels of the additive rasterizer (conventions: see raster.py). float32 in and out.

Per Gaussian, with dx = x - mx and dy = y - my, the exponent is a quadratic:

    power = -1/2 (u^2 + v^2),  u = dx / l11,  v = (dy - l21 u) / l22
          = -A dx^2 + KB dy dx - HC dy^2,   A = 1/2 (1/l11^2 + k^2/l22^2),  k = l21 / l11,
                                            KB = k / l22^2,  HC = 1/(2 l22^2).

What makes the kernels fast (measured on 2 cores; the slow alternatives were 1.2x-3x slower):
- No exp per pixel: along a row, g(dx + 1) = g(dx) r(dx) and r(dx + 1) = r(dx) q with
  r = exp(power(dx + 1) - power(dx)) and q = exp(-2A) (3x faster than an exp per pixel). This is
  walked left to right in float64 and only over pixels where power >= -POWER_CUTOFF, so every g and
  every r or 1/r it meets stays within exp(+-POWER_CUTOFF): no overflow or underflow, and the relative
  error after n steps is ~n^2 1e-16, invisible in float32.
- Rows are clipped to the pixels where power >= -POWER_CUTOFF (roots of the quadratic), intersected with
  the box: exp(-20) = 2e-9 is far below what float32 can add to a pixel the Gaussian matters
  for, and a rotated needle costs ~1 pixel per row instead of its whole bounding box.
- "Full" Gaussians, whose whole clipped box lies inside power >= -POWER_CUTOFF (all the usual, roundish
  ones: a concave quadratic is smallest at a corner of the box, so testing the 4 corners is enough),
  need no per-row roots and no per-row exp either: the value and both ratios at the box's left column
  follow the same kind of recurrence from row to row. Per-row work (2 exp, a sqrt, divisions) was half
  the time for N = 3000 Gaussians at 256 x 256; this removes it.
- Gaussians are visited in order of their box's top row (per frame): the backward reads grad_out rows
  in memory order (2x faster at 1080p), and a forward band finds its Gaussians by bisection.

Work split, race-free without atomics: the forward runs one (frame, 16-row band) per parallel unit and
each unit adds every Gaussian touching its band into its own rows; the backward runs one (frame,
Gaussian) per unit, which reads grad_out and writes only that Gaussian's gradients.

The boxes (and invalid Gaussians: non-finite values, l11 = 0 or l22 = 0, absurd sizes or shears, see
MAX_EXTENT and the 1e100 bounds) are resolved by `_prepare`,
compiled without fastmath so that NaN checks are honoured; the hot kernels only see finite, valid
Gaussians and integer pixel ranges inside the image, so they cannot index out of bounds.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit, prange

SIGMA_CUTOFF = 4.0  # the box's half-width in sigmas: raster.SIGMA_CUTOFF (see there why a copy)
POWER_CUTOFF = 40.0  # skip pixels with power < -40, i.e. g < 4e-18: below -20 (a 4-sigma box's corners on a
# rotated, elongated Gaussian) the Gaussians fell off the "full" path and rendered 1.6x slower (session 22)
MAX_EXTENT = 1e7  # Gaussians with |mean| or box radius beyond 1e7 px are treated as invalid
BAND_ROWS = 16  # forward work unit: one frame x 16 rows

# Per-Gaussian constants computed by _prepare: [B, N, NCONST] float64.
_MX, _MY, _A, _KB, _HC, _Q, _EY, _QY, _FULL = range(9)
NCONST = 9  # mean x/y, A, KB, HC, q = exp(-2A), exp(KB), exp(-2HC), 1.0 when "full" (see above)

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
        if not (rx < MAX_EXTENT and ry < MAX_EXTENT and abs(mx) < MAX_EXTENT and abs(my) < MAX_EXTENT):
            continue
        x0, x1, y0, y1 = int(fx0), int(fx1), int(fy0), int(fy1)
        # Settle the edge pixels exactly as the reference's float32 test |dx| <= r decides them.
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
        hc = 0.5 / (l22 * l22)
        kb = k * 2.0 * hc
        A = 0.5 / (l11 * l11) + k * k * hc
        # With these bounds (and pixel offsets < 2 MAX_EXTENT) nothing in the kernels can overflow.
        if not (A < 1e100 and abs(kb) < 1e100 and hc < 1e100):
            continue
        boxes[b, n, 0] = x0
        boxes[b, n, 1] = x1
        boxes[b, n, 2] = y0
        boxes[b, n, 3] = y1
        consts[b, n, _MX] = mx
        consts[b, n, _MY] = my
        consts[b, n, _A] = A
        consts[b, n, _KB] = kb
        consts[b, n, _HC] = hc
        consts[b, n, _Q] = math.exp(-2.0 * A)
        # "Full": at least 2 x 2 pixels and every corner (hence every pixel) with power >= -cutoff.
        # Then the mixed and second differences of power over the box are bounded by 2 * cutoff, so
        # exp(KB) and exp(-2 HC) cannot overflow; the clamps below only keep other cases finite.
        consts[b, n, _EY] = math.exp(min(max(kb, -600.0), 600.0))
        consts[b, n, _QY] = math.exp(max(-2.0 * hc, -600.0))
        full = x1 > x0 and y1 > y0
        for cx in (x0, x1):
            for cy in (y0, y1):
                dx = cx + 0.5 - mx
                dy = cy + 0.5 - my
                if -A * dx * dx + kb * dy * dx - hc * dy * dy < -POWER_CUTOFF:
                    full = False
        consts[b, n, _FULL] = 1.0 if full else 0.0
    return boxes, consts


@njit(parallel=True, cache=True)
def _order(boxes, width):
    """Per frame, the visible Gaussians sorted by their box's top row (then left column): order [B, N]
    int64 (the first count[b] entries are the visible ones), count [B] and the tallest box [B]."""
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
    """Pixels [j0, j1] of the row at offset dy where power >= -POWER_CUTOFF, within [x0, x1]
    (j0 > j1 when none), and the exponent's value g and ratio r at j0."""
    A = cst[_A]
    bq = cst[_KB] * dy  # power = -A dx^2 + bq dx + cq on this row
    cq = -cst[_HC] * dy * dy
    disc = bq * bq + 4.0 * A * (cq + POWER_CUTOFF)
    if disc <= 0.0:
        return 1, 0, 0.0, 0.0
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
    if j0 > j1:
        return 1, 0, 0.0, 0.0
    dx = j0 + 0.5 - mx
    g = math.exp((-A * dx + bq) * dx + cq)
    r = math.exp(-A * (2.0 * dx + 1.0) + bq)  # power(dx + 1) - power(dx)
    return j0, j1, g, r


@njit(inline="always", fastmath=_FASTMATH, cache=True)
def _corner(cst, x0, dy):
    """At the box's left column x0 and row offset dy: g, the ratio to the next pixel (rx) and to the
    next row (ry). For "full" Gaussians, rows then advance by g *= ry, ry *= exp(-2HC), rx *= exp(KB)."""
    A, kb, hc = cst[_A], cst[_KB], cst[_HC]
    dx = x0 + 0.5 - cst[_MX]
    g = math.exp(-A * dx * dx + kb * dy * dx - hc * dy * dy)
    rx = math.exp(-A * (2.0 * dx + 1.0) + kb * dy)
    ry = math.exp(kb * dx - hc * (2.0 * dy + 1.0))
    return g, rx, ry


@njit(inline="always", fastmath=_FASTMATH, cache=True)
def _add_row(orow, j0, j1, g, r, q, col):
    """orow[j] += g_j * col for j in [j0, j1], g_j by the recurrence."""
    C = col.shape[0]
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
            q = cst[_Q]
            col = colors[b, n]
            ia, ib = max(y0, r0), min(y1, r1)
            if cst[_FULL] != 0.0:
                g, rx, ry = _corner(cst, x0, ia + 0.5 - cst[_MY])
                ey, qy = cst[_EY], cst[_QY]
                for i in range(ia, ib + 1):
                    _add_row(out[b, i], x0, x1, g, rx, q, col)
                    g *= ry
                    ry *= qy
                    rx *= ey
            else:
                for i in range(ia, ib + 1):
                    j0, j1, g, r = _row_span(cst, x0, x1, i + 0.5 - cst[_MY])
                    if j0 <= j1:
                        _add_row(out[b, i], j0, j1, g, r, q, col)


@njit(inline="always", fastmath=_FASTMATH, cache=True)
def _row_moments(grow, j0, j1, g, r, q, col, gc):
    """Over j in [j0, j1] with gp = g_j <grad_out_j, col>: (R0, R1, R2) = sum gp t^k, t = j - j0,
    and sum grad_out_j g_j added into gc (for C = 3 returned as (s0, s1, s2) instead: kept in registers)."""
    C = col.shape[0]
    r0 = 0.0
    r1 = 0.0
    r2 = 0.0
    s0 = 0.0
    s1 = 0.0
    s2 = 0.0
    if C == 3:
        c0, c1, c2 = np.float64(col[0]), np.float64(col[1]), np.float64(col[2])
        for j in range(j0, j1 + 1):
            go0 = np.float64(grow[j, 0])
            go1 = np.float64(grow[j, 1])
            go2 = np.float64(grow[j, 2])
            gp = g * (go0 * c0 + go1 * c1 + go2 * c2)
            t = np.float64(j - j0)
            r0 += gp
            r1 += gp * t
            r2 += gp * t * t
            s0 += go0 * g
            s1 += go1 * g
            s2 += go2 * g
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
    return r0, r1, r2, s0, s1, s2


@njit(parallel=True, fastmath=_FASTMATH, cache=True)
def _backward_kernel(boxes, consts, order, chol, colors, grad_out, g_means, g_chol, g_colors):
    """One Gaussian per iteration: it reads grad_out over its pixels and writes only its own grads.

    Per row we get R0 = sum gp, R1 = sum gp t, R2 = sum gp t^2 (t = j - j0, dx = dx0 + t) with
    gp = g <grad_out, color>; since u = dx / l11 and l22 v = dy - k dx, the sums the gradients need follow
    per row: S_u = sum gp dx / l11, S_v = sum gp (dy - k dx) / l22, S_uu = sum gp dx^2 / l11^2,
    S_uv = sum gp dx (dy - k dx) / (l11 l22), S_vv = sum gp (dy - k dx)^2 / l22^2; and then, from
    power = -(u^2 + v^2) / 2: d/dmx = S_u / l11 - S_v l21 / (l22 l11), d/dmy = S_v / l22,
    d/dl11 = S_uu / l11 - S_uv l21 / (l22 l11), d/dl21 = S_uv / l22, d/dl22 = S_vv / l22,
    d/dcolor_c = sum grad_out_c g.
    """
    B, N, C = colors.shape
    for idx in prange(B * N):
        b = idx // N
        n = order[b, idx - b * N]
        x0, x1, y0, y1 = boxes[b, n, 0], boxes[b, n, 1], boxes[b, n, 2], boxes[b, n, 3]
        gc = g_colors[b, n]
        for c in range(C):
            gc[c] = 0.0
        s_u = 0.0
        s_v = 0.0
        s_uu = 0.0
        s_uv = 0.0
        s_vv = 0.0
        if x0 <= x1:
            cst = consts[b, n]
            q = cst[_Q]
            mx = cst[_MX]
            my = cst[_MY]
            k = np.float64(chol[b, n, 1]) / np.float64(chol[b, n, 0])
            col = colors[b, n]
            full = cst[_FULL] != 0.0
            ey, qy = cst[_EY], cst[_QY]
            gy, rx, ry = 0.0, 0.0, 0.0
            if full:  # (only then are these exps safe to take)
                gy, rx, ry = _corner(cst, x0, y0 + 0.5 - my)
            j0, j1 = x0, x1
            g, r = gy, rx
            for i in range(y0, y1 + 1):
                dy = i + 0.5 - my
                if full:
                    g, r = gy, rx
                    gy *= ry
                    ry *= qy
                    rx *= ey
                else:
                    j0, j1, g, r = _row_span(cst, x0, x1, dy)
                    if j0 > j1:
                        continue
                r0, r1, r2, s0, s1, s2 = _row_moments(grad_out[b, i], j0, j1, g, r, q, col, gc)
                if C == 3:
                    gc[0] += s0
                    gc[1] += s1
                    gc[2] += s2
                dx0 = j0 + 0.5 - mx
                m1 = r1 + dx0 * r0  # sum gp dx
                m2 = r2 + (2.0 * r1 + dx0 * r0) * dx0  # sum gp dx^2
                w1 = dy * r0 - k * m1  # sum gp (dy - k dx)
                w2 = dy * m1 - k * m2  # sum gp dx (dy - k dx)
                s_u += m1
                s_v += w1
                s_uu += m2
                s_uv += w2
                s_vv += dy * w1 - k * w2  # sum gp (dy - k dx)^2
        l11 = np.float64(chol[b, n, 0])
        l21 = np.float64(chol[b, n, 1])
        l22 = np.float64(chol[b, n, 2])
        if x0 > x1:  # invisible or invalid: zero gradients (no 0 / 0 or NaN from invalid ones)
            l11 = 1.0
            l21 = 0.0
            l22 = 1.0
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


def _f32(a):
    return np.ascontiguousarray(a, dtype=np.float32)


def prepare(means, chol, width: int, height: int):
    """(boxes [B, N, 4], constants) of the Gaussians at width x height, for `forward` and `box_work`."""
    return _prepare(_f32(means), _f32(chol), int(width), int(height))


def box_work(boxes) -> np.ndarray:
    """raster.box_work from the kernels' own boxes (prepare): float64 [B], the pixels per frame of
    the clipped boxes of the valid Gaussians."""
    w = boxes[..., 1].astype(np.int64) - boxes[..., 0] + 1
    h = boxes[..., 3].astype(np.int64) - boxes[..., 2] + 1
    return np.where((w > 0) & (h > 0), w * h, 0).sum(axis=1).astype(np.float64)


def forward(means, chol, colors, width: int, height: int, prepared=None) -> np.ndarray:
    """means [B, N, 2], chol [B, N, 3], colors [B, N, C] (numpy) -> images [B, H, W, C] float32.
    prepared: what prepare() returned for these Gaussians, when known."""
    means, chol, colors = _f32(means), _f32(chol), _f32(colors)
    width, height = int(width), int(height)
    boxes, consts = prepared if prepared is not None else _prepare(means, chol, width, height)
    order, count, tallest = _order(boxes, width)
    out = np.empty((means.shape[0], height, width, colors.shape[-1]), np.float32)
    if out.size:
        _forward_kernel(boxes, consts, order, count, tallest, colors, height, width, out)
    return out


def backward(means, chol, colors, grad_out, width: int, height: int):
    """Gradients (d_means, d_chol, d_colors) float32 of sum(grad_out * forward(...))."""
    means, chol, colors, grad_out = _f32(means), _f32(chol), _f32(colors), _f32(grad_out)
    boxes, consts = _prepare(means, chol, int(width), int(height))
    order = _order(boxes, int(width))[0]
    B, N, C = colors.shape
    g_means = np.empty((B, N, 2), np.float64)
    g_chol = np.empty((B, N, 3), np.float64)
    g_colors = np.empty((B, N, C), np.float64)
    _backward_kernel(boxes, consts, order, chol, colors, grad_out, g_means, g_chol, g_colors)
    return g_means.astype(np.float32), g_chol.astype(np.float32), g_colors.astype(np.float32)
