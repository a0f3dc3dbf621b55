"""Procedural training clips: textured shapes moving over a textured background (with occlusion,
rotation, scale change, camera pan/zoom) and dead-leaves scenes (hundreds of power-law sized shapes),
rendered with anti-aliased sharp or soft edges by a Numba kernel."""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from .sources import ClipSource, retry_blank


# Per-layer shape parameters shp[L, NSHP].
S_KIND, S_SOFT, S_OPACITY, S_RX, S_RY, S_LOBES, S_AMP, S_PHASE = range(8)
NSHP = 8
K_FULL, K_ELLIPSE, K_RECT, K_POLY, K_STAR, K_HALFPLANE = range(6)
MAXV = 8  # polygon half-planes
# Per-layer texture parameters tex[L, NTEX] (texture coordinates are object pixels).
(T_PATTERN, T_R0, T_G0, T_B0, T_R1, T_G1, T_B1, T_FREQ, T_COS, T_SIN, T_PHASE, T_SHARP, T_PHASE2,
 T_NOISE, T_NSCALE, T_NOFFX, T_NOFFY, T_GRAIN, T_GRAIN_NOISE, T_GRAIN_SCALE, T_SHADEX, T_SHADEY) = range(22)
NTEX = 22
P_FLAT, P_LINEAR, P_STRIPES, P_CHECKER, P_NOISE, P_RADIAL, P_RINGS = range(7)
NOISE_SIZE = 256


@njit(nogil=True, cache=True, fastmath=True)
def _noise_at(noise, k, x, y):
    """Bilinear sample of periodic noise texture k at continuous texel coordinates (x, y)."""
    n = noise.shape[1]
    m = n - 1
    fx = math.floor(x)
    fy = math.floor(y)
    wx = x - fx
    wy = y - fy
    ix = int(fx) & m
    iy = int(fy) & m
    jx = (ix + 1) & m
    jy = (iy + 1) & m
    top = noise[k, iy, ix] + wx * (noise[k, iy, jx] - noise[k, iy, ix])
    bottom = noise[k, jy, ix] + wx * (noise[k, jy, jx] - noise[k, jy, ix])
    return top + wy * (bottom - top)


@njit(nogil=True, cache=True, fastmath=True)
def _render_layers(aff, box, shp, tex, poly, noise, out):
    """Composite L layers (layer 0 at the back) into out [T, H, W, 3] (zeros on entry; layer 0
    should be opaque). Drawn front to back with a transmittance buffer, so pixels already covered
    cost one load per hidden layer (dead leaves stack hundreds of layers).

    aff [T, L, 6]: pixel centre (x, y) -> shape coordinates u = a0 x + a1 y + a2, v = a3 x + a4 y + a5
    (the unit shape; object pixels are (u rx, v ry)). box [T, L, 4]: x0, x1, y0, y1 pixel ranges.
    Coverage = clamp(0.5 + signed pixel distance / softness) (1 px box filter for sharp edges).
    """
    T = out.shape[0]
    L = shp.shape[0]
    trans = np.empty((out.shape[1], out.shape[2]), np.float32)
    for t in range(T):
        trans[:] = 1.0
        for l in range(L - 1, -1, -1):
            x0 = box[t, l, 0]
            x1 = box[t, l, 1]
            y0 = box[t, l, 2]
            y1 = box[t, l, 3]
            if x0 >= x1 or y0 >= y1:
                continue
            a0 = aff[t, l, 0]
            a1 = aff[t, l, 1]
            a2 = aff[t, l, 2]
            a3 = aff[t, l, 3]
            a4 = aff[t, l, 4]
            a5 = aff[t, l, 5]
            kind = int(shp[l, S_KIND])
            inv_soft = 1.0 / shp[l, S_SOFT]
            opacity = shp[l, S_OPACITY]
            rx = shp[l, S_RX]
            ry = shp[l, S_RY]
            lobes = shp[l, S_LOBES]
            amp = shp[l, S_AMP]
            sphase = shp[l, S_PHASE]
            pattern = int(tex[l, T_PATTERN])
            r0 = tex[l, T_R0]
            g0 = tex[l, T_G0]
            b0 = tex[l, T_B0]
            dr = tex[l, T_R1] - r0
            dg = tex[l, T_G1] - g0
            db = tex[l, T_B1] - b0
            freq = tex[l, T_FREQ]
            dc = tex[l, T_COS]
            ds = tex[l, T_SIN]
            phase = tex[l, T_PHASE]
            sharp = tex[l, T_SHARP]
            phase2 = tex[l, T_PHASE2]
            nk = int(tex[l, T_NOISE])
            nscale = tex[l, T_NSCALE]
            noffx = tex[l, T_NOFFX]
            noffy = tex[l, T_NOFFY]
            grain = tex[l, T_GRAIN]
            gk = int(tex[l, T_GRAIN_NOISE])
            gscale = tex[l, T_GRAIN_SCALE]
            shx = tex[l, T_SHADEX]
            shy = tex[l, T_SHADEY]
            nplanes = int(lobes) if kind == K_POLY else 0
            for y in range(y0, y1):
                yc = y + 0.5
                for x in range(x0, x1):
                    tr = trans[y, x]
                    if tr < 1e-3:
                        continue
                    xc = x + 0.5
                    u = a0 * xc + a1 * yc + a2
                    v = a3 * xc + a4 * yc + a5
                    alpha = 1.0
                    if kind != K_FULL:
                        gu = 0.0
                        gv = 0.0
                        d = 0.0
                        if kind == K_ELLIPSE or kind == K_STAR:
                            rho = math.sqrt(u * u + v * v) + 1e-9
                            gu = -u / rho
                            gv = -v / rho
                            if kind == K_ELLIPSE:
                                d = 1.0 - rho
                            else:
                                theta = math.atan2(v, u)
                                d = 1.0 - amp * (0.5 + 0.5 * math.cos(lobes * theta + sphase)) - rho
                        elif kind == K_RECT:
                            du = 1.0 - abs(u)
                            dv = 1.0 - abs(v)
                            if du < dv:
                                d = du
                                gu = -1.0 if u > 0 else 1.0
                            else:
                                d = dv
                                gv = -1.0 if v > 0 else 1.0
                        elif kind == K_POLY:
                            d = 1e9
                            for k in range(nplanes):
                                dk = poly[l, k, 2] - (poly[l, k, 0] * u + poly[l, k, 1] * v)
                                if dk < d:
                                    d = dk
                                    gu = -poly[l, k, 0]
                                    gv = -poly[l, k, 1]
                        else:  # K_HALFPLANE: inside where v < 0
                            d = -v
                            gv = -1.0
                        gx = gu * a0 + gv * a3
                        gy = gu * a1 + gv * a4
                        gn = math.sqrt(gx * gx + gy * gy) + 1e-12
                        alpha = 0.5 + d / gn * inv_soft
                        if alpha <= 0.0:
                            continue
                        if alpha > 1.0:
                            alpha = 1.0
                    alpha *= opacity
                    tu = u * rx
                    tv = v * ry
                    tt = 0.0
                    if pattern == P_LINEAR:
                        tt = 0.5 + freq * (dc * tu + ds * tv) + phase
                    elif pattern == P_STRIPES:
                        tt = 0.5 + 0.5 * sharp * math.sin(freq * (dc * tu + ds * tv) + phase)
                    elif pattern == P_CHECKER:
                        pu = dc * tu + ds * tv
                        pv = dc * tv - ds * tu
                        tt = 0.5 + 0.5 * sharp * math.sin(freq * pu + phase) * math.sin(freq * pv + phase2)
                    elif pattern == P_NOISE:
                        n = _noise_at(noise, nk, tu * nscale + noffx, tv * nscale + noffy)
                        tt = 0.5 + sharp * (n - 0.5)
                    elif pattern == P_RADIAL:
                        tt = freq * math.sqrt(tu * tu + tv * tv) + phase
                    elif pattern == P_RINGS:
                        tt = 0.5 + 0.5 * sharp * math.sin(freq * math.sqrt(tu * tu + tv * tv) + phase)
                    if tt < 0.0:
                        tt = 0.0
                    elif tt > 1.0:
                        tt = 1.0
                    shade = 1.0 + shx * tu + shy * tv
                    if shade < 0.25:
                        shade = 0.25
                    elif shade > 1.75:
                        shade = 1.75
                    if grain > 0.0:
                        shade *= 1.0 + grain * (_noise_at(noise, gk, tu * gscale + noffy,
                                                          tv * gscale + noffx) - 0.5)
                    cr = (r0 + dr * tt) * shade
                    cg = (g0 + dg * tt) * shade
                    cb = (b0 + db * tt) * shade
                    cr = min(max(cr, 0.0), 1.0)
                    cg = min(max(cg, 0.0), 1.0)
                    cb = min(max(cb, 0.0), 1.0)
                    wgt = tr * alpha
                    out[t, y, x, 0] += wgt * cr
                    out[t, y, x, 1] += wgt * cg
                    out[t, y, x, 2] += wgt * cb
                    trans[y, x] = tr - wgt


def _noise_bank(count: int = 12, n: int = NOISE_SIZE, seed: int = 1234) -> np.ndarray:
    """Periodic 1/f^beta noise textures [count, n, n] float32 spanning [0, 1] (fixed seed)."""
    rng = np.random.default_rng(seed)
    fy = np.fft.fftfreq(n)[:, None]
    fx = np.fft.rfftfreq(n)[None, :]
    radius = np.sqrt(fx * fx + fy * fy)
    radius[0, 0] = 1.0
    bank = np.empty((count, n, n), np.float32)
    for k in range(count):
        beta = 1.0 + 2.2 * k / max(1, count - 1)  # rough (1) .. very smooth (3.2)
        cutoff = rng.uniform(0.15, 0.5)  # highest frequency, in cycles per texel
        spectrum = (rng.standard_normal(radius.shape) + 1j * rng.standard_normal(radius.shape))
        spectrum *= radius ** (-beta / 2 - 0.5) * np.exp(-(radius / cutoff) ** 4)
        spectrum[0, 0] = 0
        field = np.fft.irfft2(spectrum, s=(n, n))
        lo, hi = np.percentile(field, [1, 99])
        bank[k] = np.clip((field - lo) / (hi - lo), 0, 1)
    return bank


def _hsv_to_rgb(h, s, v):
    i = np.floor(h * 6.0)
    f = h * 6.0 - i
    p, q, t = v * (1 - s), v * (1 - s * f), v * (1 - s * (1 - f))
    i = i.astype(int) % 6
    r = np.choose(i, [v, q, p, p, t, v])
    g = np.choose(i, [t, v, v, q, p, p])
    b = np.choose(i, [p, p, t, v, v, q])
    return np.stack([r, g, b], -1)


def _random_colors(rng, n, value=None):
    """Natural-ish colours: any hue, mostly moderate saturation, values over the whole range."""
    h = rng.random(n)
    s = rng.beta(1.1, 1.8, n) * np.where(rng.random(n) < 0.15, 0.15, 1.0)
    v = rng.beta(1.2, 1.2, n) if value is None else value
    return _hsv_to_rgb(h, s, np.clip(v, 0.0, 1.0))


def _random_textures(rng, n, size, plain=0.3):
    """tex [n, NTEX]: two colours mixed by a pattern (flat, gradient, stripes, checker, noise, radial,
    rings) in object pixels, times a shading gradient and sometimes a noise grain."""
    tex = np.zeros((n, NTEX))
    others = np.array([0.2, 0.14, 0.08, 0.25, 0.05, 0.03])  # linear .. rings
    patterns = rng.choice([P_FLAT, P_LINEAR, P_STRIPES, P_CHECKER, P_NOISE, P_RADIAL, P_RINGS], n,
                          p=np.concatenate([[plain], others * (1 - plain) / others.sum()]))
    tex[:, T_PATTERN] = patterns
    c0 = _random_colors(rng, n)
    related = rng.random(n) < 0.5  # second colour: same hue, other value; or any colour
    c1 = np.where(related[:, None], np.clip(c0 * rng.uniform(0.1, 2.5, (n, 1)), 0, 1),
                  _random_colors(rng, n))
    tex[:, T_R0:T_B0 + 1] = c0
    tex[:, T_R1:T_B1 + 1] = c1
    angle = rng.uniform(0, 2 * np.pi, n)
    tex[:, T_COS], tex[:, T_SIN] = np.cos(angle), np.sin(angle)
    period = np.exp(rng.uniform(np.log(4.0), np.log(size * 0.6), n))  # pixels
    freq = 2 * np.pi / period
    tex[:, T_FREQ] = freq
    tex[:, T_PHASE] = rng.uniform(0, 2 * np.pi, n)
    tex[:, T_PHASE2] = rng.uniform(0, 2 * np.pi, n)
    # Stripe sharpness: sinusoid (1) .. square wave with ~1.5 px transitions.
    tex[:, T_SHARP] = np.exp(rng.uniform(0, 1, n) * np.log(np.maximum(1.0, 2.5 / (freq * 1.5))))
    gradient = patterns == P_LINEAR
    tex[gradient, T_FREQ] = 1.0 / rng.uniform(0.3, 1.5, gradient.sum()) / size
    tex[gradient, T_PHASE] = rng.uniform(-0.3, 0.3, gradient.sum())
    radial = patterns == P_RADIAL
    tex[radial, T_FREQ] = 1.0 / rng.uniform(0.2, 1.0, radial.sum()) / size
    tex[radial, T_PHASE] = rng.uniform(-0.2, 0.2, radial.sum())
    noisy = patterns == P_NOISE
    tex[noisy, T_SHARP] = np.exp(rng.uniform(0, np.log(12.0), noisy.sum()))  # smooth .. blotchy
    tex[:, T_NOISE] = rng.integers(0, 12, n)
    tex[:, T_NSCALE] = np.exp(rng.uniform(np.log(0.25), np.log(4.0), n)) * (128.0 / size)
    tex[:, T_NOFFX], tex[:, T_NOFFY] = rng.uniform(0, NOISE_SIZE, (2, n))
    tex[:, T_GRAIN] = np.where(rng.random(n) < 0.35, rng.uniform(0.05, 0.5, n), 0.0)
    tex[:, T_GRAIN_NOISE] = rng.integers(0, 6, n)
    tex[:, T_GRAIN_SCALE] = np.exp(rng.uniform(np.log(0.5), np.log(3.0), n)) * (128.0 / size)
    shade = np.where(rng.random(n) < 0.5, rng.uniform(0, 1.2, n) / size, 0.0)
    shade_angle = rng.uniform(0, 2 * np.pi, n)
    tex[:, T_SHADEX], tex[:, T_SHADEY] = shade * np.cos(shade_angle), shade * np.sin(shade_angle)
    return tex


def _contrast_with(rng, tex, background_value):
    """Half the time, push a layer's colours to the opposite brightness of the background (sharp
    dark-beside-bright edges)."""
    n = len(tex)
    flip = rng.random(n) < 0.5
    target = np.where(background_value > 0.5, rng.uniform(0.0, 0.2, n), rng.uniform(0.75, 1.0, n))
    for lo, hi in ((T_R0, T_B0 + 1), (T_R1, T_B1 + 1)):
        c = tex[:, lo:hi]
        scale = target / np.maximum(c.max(1), 1e-3)
        tex[:, lo:hi] = np.where(flip[:, None], np.clip(c * scale[:, None], 0, 1), c)
    return tex


def _poly_planes(rng, kinds):
    """Half-planes (nx, ny, c) [L, MAXV, 3] of random convex polygons inscribed in the unit circle
    (for layers of kind K_POLY), and their vertex counts."""
    L = len(kinds)
    counts = rng.integers(3, MAXV + 1, L)
    jitter = rng.uniform(-0.35, 0.35, (L, MAXV))
    k = np.arange(MAXV)[None, :]
    angles = (k + jitter) * 2 * np.pi / counts[:, None] + rng.uniform(0, 2 * np.pi, (L, 1))
    nxt = np.where(k + 1 < counts[:, None], k + 1, 0)
    a_next = np.take_along_axis(angles, nxt, 1) + np.where(nxt == 0, 2 * np.pi, 0)
    mid = 0.5 * (angles + a_next)
    half = 0.5 * (a_next - angles)
    planes = np.stack([np.cos(mid), np.sin(mid), np.cos(half)], -1)
    planes = np.where(k[..., None] < counts[:, None, None], planes, planes[:, :1])
    counts = np.where(kinds == K_POLY, counts, 0)
    return planes, counts


class ProceduralSource(ClipSource):
    """Procedural clips: 'shapes' (textured objects moving and occluding over a textured background,
    with rotation, scale change and camera pan/zoom) or 'leaves' (dead leaves: hundreds of
    power-law sized shapes, natural-image-like statistics), with static to fast motion."""

    name = "procedural"
    MOTION_CLASSES = ((0.12, 0.0, 0.0), (0.33, 0.2, 1.5), (0.33, 1.5, 5.0), (0.22, 5.0, 14.0))

    def __init__(self, mode: str = "mixed", leaves_fraction: float = 0.4):
        self.mode = mode
        self.leaves_fraction = {"mixed": leaves_fraction, "shapes": 0.0, "leaves": 1.0}[mode]
        self.noise = _noise_bank()

    def describe(self) -> str:
        return f"procedural, {self.mode}"

    def _speed(self, rng, size):
        """Pixels per frame (scaled to the canvas) of one motion class drawn at random."""
        p = np.array([c[0] for c in self.MOTION_CLASSES])
        lo, hi = self.MOTION_CLASSES[rng.choice(len(p), p=p / p.sum())][1:]
        return rng.uniform(lo, hi) * size / 128.0, hi

    def sample(self, rng, clip_frames, size):
        return retry_blank(lambda: self._sample_once(rng, clip_frames, size))

    def _sample_once(self, rng, clip_frames, size):
        out = np.empty((clip_frames, size, size, 3), np.float32)
        leaves = rng.random() < self.leaves_fraction
        layers = self._leaves(rng, clip_frames, size) if leaves else self._shapes(rng, clip_frames, size)
        aff, box, shp, tex, poly = layers
        out[:] = 0.0
        _render_layers(aff, box, shp, tex, poly, self.noise, out)
        return out

    # Scene builders return per-layer motion + appearance, turned into per-frame affines here.
    def _camera(self, rng, T, size, pan_probability):
        speed, _ = self._speed(rng, size)
        pan = speed if rng.random() < pan_probability else 0.0
        direction = rng.uniform(0, 2 * np.pi)
        t = np.arange(T) - (T - 1) / 2
        cam = np.stack([np.cos(direction), np.sin(direction)])[None, :] * pan * t[:, None]
        zoom_rate = rng.normal(0, 0.02) if rng.random() < 0.25 else 0.0
        zoom = np.exp(zoom_rate * t)
        return cam, zoom

    def _layers(self, T, size, cam, zoom, kind, soft, center, velocity, angle, spin, rx, ry,
                scale_rate, tex, rng, world=None):
        """Per-frame inverse affines and pixel boxes of L layers. world: layers drawn in world
        pixels (background, half-planes) rather than the unit shape."""
        L = len(kind)
        t = np.arange(T, dtype=np.float64)[:, None] - (T - 1) / 2  # [T, 1]
        p = center[None] + velocity[None] * t[..., None]  # [T, L, 2]
        theta = angle[None] + spin[None] * t  # [T, L]
        s = np.exp(scale_rate[None] * t)  # [T, L]
        z = zoom[:, None]  # [T, 1]
        c, si = np.cos(theta), np.sin(theta)
        if world is None:
            world = np.zeros(L, bool)
        sx = np.where(world, 1.0, rx)[None] * s
        sy = np.where(world, 1.0, ry)[None] * s
        # n = D^-1 R(-theta) ((q - size/2) / z + cam - p) / s
        m00, m01 = c / (sx * z), si / (sx * z)
        m10, m11 = -si / (sy * z), c / (sy * z)
        off = cam[:, None, :] - p - (size / 2) / z[..., None]  # [T, L, 2]
        aff = np.empty((T, L, 6))
        aff[..., 0], aff[..., 1] = m00, m01
        aff[..., 2] = (c * off[..., 0] + si * off[..., 1]) / sx
        aff[..., 3], aff[..., 4] = m10, m11
        aff[..., 5] = (-si * off[..., 0] + c * off[..., 1]) / sy
        # Boxes: image of [-1, 1]^2 plus the soft margin.
        qc = z[..., None] * (p - cam[:, None, :]) + size / 2
        hx = z * s * (np.abs(c) * rx + np.abs(si) * ry) + soft[None] + 1
        hy = z * s * (np.abs(si) * rx + np.abs(c) * ry) + soft[None] + 1
        box = np.empty((T, L, 4), np.int64)
        box[..., 0] = np.floor(qc[..., 0] - hx)
        box[..., 1] = np.ceil(qc[..., 0] + hx)
        box[..., 2] = np.floor(qc[..., 1] - hy)
        box[..., 3] = np.ceil(qc[..., 1] + hy)
        full = world | (kind == K_FULL) | (kind == K_HALFPLANE)
        box[:, full] = (0, size, 0, size)
        np.clip(box, 0, size, out=box)
        shp = np.zeros((L, NSHP))
        shp[:, S_KIND] = kind
        shp[:, S_SOFT] = soft
        shp[:, S_OPACITY] = 1.0
        shp[:, S_RX] = np.where(world, 1.0, rx)
        shp[:, S_RY] = np.where(world, 1.0, ry)
        shp[:, S_LOBES] = rng.integers(2, 7, L)
        shp[:, S_AMP] = rng.uniform(0.15, 0.6, L)
        shp[:, S_PHASE] = rng.uniform(0, 2 * np.pi, L)
        poly, counts = _poly_planes(rng, kind)
        shp[kind == K_POLY, S_LOBES] = counts[kind == K_POLY]
        return aff, box, shp, tex, poly

    def _edges(self, rng, n, size, sharp_fraction=0.75):
        """Edge softness in pixels: mostly a sharp anti-aliased 1 px edge, sometimes blurred."""
        soft = np.exp(rng.uniform(np.log(2.0), np.log(0.12 * size), n))
        return np.where(rng.random(n) < sharp_fraction, rng.uniform(1.0, 1.3, n), soft)

    def _shapes(self, rng, T, size):
        cam, zoom = self._camera(rng, T, size, pan_probability=0.4)
        speed, top = self._speed(rng, size)
        n_regions = rng.choice([0, 1, 2, 3], p=[0.3, 0.35, 0.25, 0.1])
        n_objects = int(np.exp(rng.uniform(np.log(2), np.log(32))))
        L = 1 + n_regions + n_objects
        kind = np.empty(L, np.int64)
        kind[0] = K_FULL
        kind[1:1 + n_regions] = rng.choice([K_HALFPLANE, K_ELLIPSE, K_POLY], n_regions)
        kind[1 + n_regions:] = rng.choice([K_ELLIPSE, K_RECT, K_POLY, K_STAR], n_objects,
                                          p=[0.35, 0.3, 0.25, 0.1])
        world = np.zeros(L, bool)
        world[0] = True
        world[1:1 + n_regions] = kind[1:1 + n_regions] == K_HALFPLANE
        tex = _random_textures(rng, L, size, plain=0.25)
        if tex[0, T_PATTERN] == P_FLAT and rng.random() < 0.8:  # mostly a textured background
            tex[0, T_PATTERN] = rng.choice([P_LINEAR, P_NOISE, P_STRIPES, P_CHECKER])
        bg_value = float(tex[0, T_R0:T_B0 + 1].max())
        tex[1:] = _contrast_with(rng, tex[1:], bg_value)
        # Sizes: log-uniform radii; aspect ratios up to 3:1, some thin bars.
        radius = np.exp(rng.uniform(np.log(0.04), np.log(0.45), L)) * size
        radius[1:1 + n_regions] = rng.uniform(0.5, 1.2, n_regions) * size
        aspect = np.exp(rng.uniform(-np.log(3), np.log(3), L))
        bars = (kind == K_RECT) & (rng.random(L) < 0.25)
        aspect[bars] = rng.uniform(6, 20, bars.sum())
        rx, ry = radius * np.sqrt(aspect), radius / np.sqrt(aspect)
        ry[bars] = np.maximum(ry[bars], 1.0)
        center = rng.uniform(-0.6, 0.6, (L, 2)) * size
        center[0] = 0
        # Object motion around the clip's speed class, in random directions; some stay put.
        obj_speed = speed * rng.uniform(0.3, 1.5, L) * (rng.random(L) < 0.85)
        direction = rng.uniform(0, 2 * np.pi, L)
        velocity = np.stack([np.cos(direction), np.sin(direction)], -1) * obj_speed[:, None]
        velocity[:1 + n_regions] = 0
        motion = min(1.0, top / 5.0)
        angle = rng.uniform(0, 2 * np.pi, L)
        spin = rng.normal(0, 0.04 * motion, L) * (rng.random(L) < 0.6)
        scale_rate = rng.normal(0, 0.03 * motion, L) * (rng.random(L) < 0.4)
        spin[0] = scale_rate[0] = 0
        angle[0] = rng.normal(0, 0.3)
        soft = self._edges(rng, L, size)
        soft[0] = 1.0
        return self._layers(T, size, cam, zoom, kind, soft, center, velocity, angle, spin, rx, ry,
                            scale_rate, tex, rng, world=world)

    def _leaves(self, rng, T, size):
        cam, zoom = self._camera(rng, T, size, pan_probability=0.6)
        speed, top = self._speed(rng, size)
        extent = size / 2 / zoom.min() + np.abs(cam).max() + 0.05 * size  # world half-extent seen
        rmin = max(1.2, rng.uniform(0.008, 0.03) * size)
        rmax = rng.uniform(0.15, 0.6) * size
        alpha = rng.uniform(2.6, 3.2)  # radius density ~ r^-alpha (scale invariant at 3)
        # Enough leaves that the stack covers the view about twice over (capped); the textured
        # background shows through the few holes.
        u = rng.random(4096)
        radii = (rmin ** (1 - alpha) + u * (rmax ** (1 - alpha) - rmin ** (1 - alpha))) ** (1 / (1 - alpha))
        area = np.cumsum(np.pi * radii ** 2)
        n = int(min(np.searchsorted(area, 2.0 * (2 * extent) ** 2) + 1, 1000))
        radius = np.sort(radii[:n])[::-1]  # big ones first (behind): keeps small detail visible
        radius = radius[rng.permutation(n)] if rng.random() < 0.5 else radius
        L = n + 1
        kind = np.empty(L, np.int64)
        kind[0] = K_FULL
        kind[1:] = rng.choice([K_ELLIPSE, K_RECT, K_POLY, K_STAR], n, p=[0.55, 0.15, 0.2, 0.1])
        world = np.zeros(L, bool)
        world[0] = True
        tex = _random_textures(rng, L, size, plain=0.6)
        if rng.random() < 0.5:  # a palette: leaves share a few colours (more natural statistics)
            palette = _random_colors(rng, int(rng.integers(3, 9)))
            pick = rng.integers(0, len(palette), L)
            tex[:, T_R0:T_B0 + 1] = palette[pick]
            tex[:, T_R1:T_B1 + 1] = np.clip(palette[pick] * rng.uniform(0.3, 1.6, (L, 1)), 0, 1)
        r = np.concatenate([[1.0], radius])
        aspect = np.exp(rng.normal(0, 0.35, L))
        rx, ry = r * np.sqrt(aspect), r / np.sqrt(aspect)
        center = rng.uniform(-extent, extent, (L, 2))
        center[0] = 0
        # The scene moves with the camera; the top few leaves move on their own.
        velocity = np.zeros((L, 2))
        movers = np.arange(L) >= L - int(rng.integers(0, 6))
        direction = rng.uniform(0, 2 * np.pi, L)
        velocity[movers] = (np.stack([np.cos(direction), np.sin(direction)], -1)[movers]
                            * speed * rng.uniform(0.5, 1.5, (movers.sum(), 1)))
        motion = min(1.0, top / 5.0)
        angle = rng.uniform(0, 2 * np.pi, L)
        spin = np.where(movers, rng.normal(0, 0.04 * motion, L), 0.0)
        scale_rate = np.zeros(L)
        soft = self._edges(rng, L, size, sharp_fraction=0.9)
        soft[0] = 1.0
        return self._layers(T, size, cam, zoom, kind, soft, center, velocity, angle, spin, rx, ry,
                            scale_rate, tex, rng, world=world)
