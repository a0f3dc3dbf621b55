"""Training data: random T-frame clips [T, size, size, 3] float32 in [0, 1], drawn on the fly.

Sources (each a `ClipSource` with `sample(rng, clip_frames, size)`):
- `procedural`: textured shapes moving over a textured background (with occlusion, rotation, scale
  change, camera pan/zoom) and dead-leaves scenes (hundreds of power-law sized shapes), rendered
  with anti-aliased sharp or soft edges by a Numba kernel.
- `photos`: smooth pan/zoom/roll camera paths over photographs (random crop scale, h-flip), read
  from a uint8 cache (`prepare-data` writes it) and sampled from a mip pyramid (no aliasing).
- `videos=FOLDER`: random-stride, random-crop clips from a cache of short clips that
  `prepare-data --videos FOLDER` pre-extracts from the user's videos.

`make_batch(sources, seed, step, rank, ...)` is a pure function of its arguments, so training
resumes exactly and each torchrun rank sees different data. The pixel work runs in Numba kernels
compiled with nogil=True, so a prefetch thread overlaps it with the training step.

`hypergs prepare-data` builds the default training set under data/: the wallpaper photos of a few
Debian packages (fetched with apt-get download, unpacked with dpkg -x), split into a training cache
and a held-out validation cache (`validation_clips` draws the trainer's fixed evaluation clips).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import shutil
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np
from numba import njit

from .errors import HyperGSError

DEFAULT_ROOT = "data"
DEFAULT_SPEC = "procedural:0.4,photos:0.6"
PHOTOS_DIR = "photos"
PHOTO_CACHE = "photos_cache.npz"
PHOTO_VAL_CACHE = "photos_val_cache.npz"
VIDEO_CACHE_DIR = "videos_cache"
PHOTO_MAX_SHORT_SIDE = 512
IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".webp", ".tif", ".tiff", ".bmp")
VIDEO_EXTENSIONS = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v")
WALLPAPER_PACKAGES = ("gnome-backgrounds", "mate-backgrounds", "ukui-wallpapers",
                      "lomiri-wallpapers-16.04", "lomiri-wallpapers-20.04")
VAL_PHOTO_COUNT = 4
VAL_SEED = 20240611
CACHE_VERSION = 1


class DataError(HyperGSError):
    """A bad source spec, or a missing folder or cache; the message says what to do."""


# ---------------------------------------------------------------------------------------------
# Sources and batches
# ---------------------------------------------------------------------------------------------

class ClipSource:
    """Something that draws random clips. Subclasses implement `sample`."""

    name = "source"

    def sample(self, rng: np.random.Generator, clip_frames: int, size: int) -> np.ndarray:
        """One clip, float32 [clip_frames, size, size, 3] in [0, 1], a function of rng's state."""
        raise NotImplementedError

    def __repr__(self) -> str:
        return f"{type(self).__name__}({self.describe()})"

    def describe(self) -> str:
        return self.name


def make_batch(sources, seed: int, step: int, rank: int, batch_size: int, clip_frames: int,
               size: int) -> np.ndarray:
    """[batch_size, clip_frames, size, size, 3] float32 in [0, 1]; a pure function of its arguments.

    Clip i of the batch uses its own generator spawned from default_rng([seed, step, rank]), so the
    first clips of a batch do not change with batch_size and sources never interfere.
    """
    if not sources:
        raise DataError("no training sources")
    weights = np.array([float(w) for _, w in sources], np.float64)
    if not np.all(np.isfinite(weights)) or np.any(weights < 0) or weights.sum() <= 0:
        raise DataError(f"bad source weights {weights.tolist()}")
    rng = np.random.default_rng([int(seed), int(step), int(rank)])
    children = rng.spawn(batch_size)
    cumulative = np.cumsum(weights / weights.sum())
    out = np.empty((batch_size, clip_frames, size, size, 3), np.float32)
    for i, child in enumerate(children):
        k = min(int(np.searchsorted(cumulative, child.random(), side="right")), len(sources) - 1)
        while weights[k] == 0:  # float round-off at the top end
            k -= 1
        out[i] = sources[k][0].sample(child, clip_frames, size)
    return out


def build_sources(spec: str, root=DEFAULT_ROOT) -> list[tuple[ClipSource, float]]:
    """Parse "name[=arg][:weight],..." into (source, weight) pairs.

    Names: procedural[=shapes|leaves], photos[=CACHE.npz|FOLDER] (default ROOT/photos_cache.npz),
    photos_val (ROOT/photos_val_cache.npz), videos=FOLDER (its clip cache under ROOT, made by
    `hypergs prepare-data --videos FOLDER`; or a clip-cache folder itself). Weight defaults to 1.
    """
    root = Path(root)
    items = [s.strip() for s in (spec or "").split(",")]
    if not spec or not spec.strip() or any(not s for s in items):
        raise DataError(f"bad data spec {spec!r}: expected e.g. {DEFAULT_SPEC!r}")
    sources = []
    for item in items:
        weight = 1.0
        head, sep, tail = item.rpartition(":")
        if sep:
            try:
                weight = float(tail)
                item = head
            except ValueError:
                if "=" not in head:  # a colon inside a path value is not a weight
                    raise DataError(f"bad data spec item {item!r}: weight {tail!r} is not a number") from None
        if not math.isfinite(weight) or weight < 0:
            raise DataError(f"bad data spec item {item!r}: weight must be a number >= 0")
        name, sep, arg = item.partition("=")
        name, arg = name.strip(), arg.strip()
        if sep and not arg:
            raise DataError(f"bad data spec item {item!r}: empty value after '='")
        if name == "procedural":
            mode = arg or "mixed"
            if mode not in ("mixed", "shapes", "leaves"):
                raise DataError(f"procedural={mode}: expected procedural, procedural=shapes or procedural=leaves")
            source = ProceduralSource(mode)
        elif name == "photos":
            source = PhotoSource(arg if arg else root / PHOTO_CACHE)
        elif name == "photos_val":
            source = PhotoSource(arg if arg else root / PHOTO_VAL_CACHE)
        elif name == "videos":
            if not arg:
                raise DataError("videos needs a folder: videos=/path/to/folder")
            source = VideoSource(find_video_cache(arg, root))
        else:
            raise DataError(f"unknown data source {name!r} in {spec!r}: expected procedural, photos, "
                            f"photos_val or videos=FOLDER")
        sources.append((source, weight))
    if sum(w for _, w in sources) <= 0:
        raise DataError(f"bad data spec {spec!r}: all weights are 0")
    return sources


# ---------------------------------------------------------------------------------------------
# Numba kernels (nogil: they run beside the training step in a prefetch thread)
# ---------------------------------------------------------------------------------------------

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


@njit(nogil=True, cache=True, fastmath=True)
def _warp_frame(src, aff, taps, out):
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


# ---------------------------------------------------------------------------------------------
# Procedural clips
# ---------------------------------------------------------------------------------------------

BLANK_STD = 0.04  # a first frame this flat (std over pixels and channels) is drawn again
BLANK_TRIES = 3


def _retry_blank(draw):
    """draw() again (same generator, so still deterministic) while the clip is nearly blank: a flat
    crop of a sky or of a graphic teaches the network little."""
    for _ in range(BLANK_TRIES):
        clip = draw()
        if clip[0].std() >= BLANK_STD:
            return clip
    return clip

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
        return _retry_blank(lambda: self._sample_once(rng, clip_frames, size))

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


# ---------------------------------------------------------------------------------------------
# Photos
# ---------------------------------------------------------------------------------------------

def read_image(path, max_short_side: int | None = None) -> np.ndarray:
    """Any image file OpenImageIO reads -> RGB uint8 [H, W, 3]; EXIF orientation applied, alpha
    composited over mid grey (transparent overlays stay visible whatever their colour), area-
    downscaled so its short side <= max_short_side."""
    import OpenImageIO as oiio

    from .video import resize_exact

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise DataError(f"{path}: not a readable image ({oiio.geterror()})")
    try:
        spec = inp.spec()
        pixels = inp.read_image(0, 0, 0, spec.nchannels, oiio.UINT8)
        if pixels is None:
            raise DataError(f"{path}: cannot decode image ({inp.geterror()})")
    finally:
        inp.close()
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    pixels = _orient(pixels, spec.get_int_attribute("Orientation", 1))
    channels = pixels.shape[2]
    alpha_channel = spec.alpha_channel if 0 <= spec.alpha_channel < channels else None
    if alpha_channel is None and channels in (2, 4):
        alpha_channel = channels - 1
    colour = [c for c in range(channels) if c != alpha_channel][:3]
    rgb = pixels[..., colour if len(colour) == 3 else [colour[0]] * 3]
    if alpha_channel is not None:
        # OpenImageIO associates alpha on reading: rgb is premultiplied, so "over grey" is a sum.
        a = pixels[..., alpha_channel].astype(np.uint16)
        grey = ((255 - a) * 128 + 127) // 255
        rgb = np.minimum(rgb.astype(np.uint16) + grey[..., None], 255).astype(np.uint8)
    h, w = rgb.shape[:2]
    short = min(h, w)
    if max_short_side and short > max_short_side:
        k = short // max_short_side  # integer box reduction first (cheap), then an area resize
        if k >= 2:
            hh, ww = h // k * k, w // k * k
            rgb = rgb[:hh, :ww].reshape(hh // k, k, ww // k, k, 3).mean((1, 3), dtype=np.float32)
            rgb = (rgb + 0.5).astype(np.uint8)
            h, w = rgb.shape[:2]
        scale = max_short_side / min(h, w)
        rgb = resize_exact(rgb, max(1, round(w * scale)), max(1, round(h * scale)))
    return np.ascontiguousarray(rgb)


def _orient(a: np.ndarray, orientation: int) -> np.ndarray:
    """Apply an EXIF orientation (1-8) so the array is upright."""
    ops = {2: lambda a: a[:, ::-1], 3: lambda a: a[::-1, ::-1], 4: lambda a: a[::-1],
           5: lambda a: a.transpose(1, 0, 2), 6: lambda a: np.rot90(a, -1),
           7: lambda a: a.transpose(1, 0, 2)[::-1, ::-1], 8: lambda a: np.rot90(a, 1)}
    return ops[orientation](a) if orientation in ops else a


def write_image(path, pixels: np.ndarray) -> None:
    """RGB uint8 (or float in [0, 1]) [H, W, 3] to a PNG/JPEG/... file."""
    import OpenImageIO as oiio

    if pixels.dtype != np.uint8:
        pixels = (np.clip(pixels, 0, 1) * 255 + 0.5).astype(np.uint8)
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise DataError(f"{path}: cannot write this image format")
    h, w = pixels.shape[:2]
    out.open(str(path), oiio.ImageSpec(w, h, 3, oiio.UINT8))
    out.write_image(np.ascontiguousarray(pixels))
    out.close()


def list_images(folder) -> list[Path]:
    folder = Path(folder)
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in IMAGE_EXTENSIONS)


def _thumb(image: np.ndarray, n: int = 32) -> np.ndarray:
    """Grey n x n thumbnail (box filtered), float64."""
    grey = image.astype(np.float32).mean(2)
    h, w = grey.shape
    ys = (np.arange(h) * n // h)
    xs = (np.arange(w) * n // w)
    out = np.zeros((n, n))
    np.add.at(out, (ys[:, None], xs[None, :]), grey)
    counts = np.zeros((n, n))
    np.add.at(counts, (ys[:, None], xs[None, :]), 1)
    return out / np.maximum(counts, 1)


def _detail(image: np.ndarray) -> float:
    """Mean absolute neighbour difference of a 128-px-wide grey version (0 for a flat image)."""
    grey = image[:: max(1, image.shape[0] // 128), :: max(1, image.shape[1] // 128)].astype(np.float32).mean(2)
    return float(np.abs(np.diff(grey, axis=0)).mean() + np.abs(np.diff(grey, axis=1)).mean())


def _stem_key(path: Path) -> str:
    """File name without variant suffixes (-l/-d, -dark/-light, a resolution) for grouping."""
    import re

    stem = path.stem.lower().split("__")[-1]
    stem = re.sub(r"([_-](\d+x\d+|l|d|light|dark|day|night))+$", "", stem)
    return stem


def _collect_photos(paths, log=print, max_short_side=PHOTO_MAX_SHORT_SIDE, min_short_side=128):
    """Decode, drop unreadable/flat/tiny images and duplicates; return [(path, image, info)] and
    group ids (near-duplicates and variants share a group, kept on one side of the split)."""
    records = []
    seen = {}
    for path in paths:
        data = Path(path).read_bytes()
        digest = hashlib.sha1(data).hexdigest()
        if digest in seen:
            log(f"  skip {Path(path).name}: same file as {Path(seen[digest]).name}")
            continue
        seen[digest] = path
        try:
            import OpenImageIO as oiio

            spec = oiio.ImageInput.open(str(path))
            if spec is None:
                raise DataError(oiio.geterror())
            w, h = spec.spec().width, spec.spec().height
            spec.close()
            image = read_image(path, max_short_side)
        except (DataError, RuntimeError, OSError) as e:
            log(f"  skip {Path(path).name}: unreadable ({e})")
            continue
        if min(w, h) < min_short_side:
            log(f"  skip {Path(path).name}: too small ({w}x{h})")
            continue
        if _detail(image) < 1.0:
            log(f"  skip {Path(path).name}: (almost) flat image")
            continue
        records.append({"path": Path(path), "image": image, "pixels": w * h, "digest": digest,
                        "thumb": _thumb(image)})
    # Near-duplicates (same picture at other sizes): keep the largest original.
    keep = []
    for rec in sorted(records, key=lambda r: -r["pixels"]):
        t = rec["thumb"]
        dup = None
        for other in keep:
            o = other["thumb"]
            if t.shape == o.shape and np.abs(t - o).mean() < 3.0 and \
                    abs(rec["image"].shape[1] / rec["image"].shape[0]
                        - other["image"].shape[1] / other["image"].shape[0]) < 0.02:
                dup = other
                break
        if dup is not None:
            log(f"  skip {rec['path'].name}: near-duplicate of {dup['path'].name}")
            continue
        keep.append(rec)
    keep.sort(key=lambda r: str(r["path"]))
    # Groups: correlated thumbnails (also inverted: light/dark variants) or the same name stem.
    parent = list(range(len(keep)))

    def find(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for i in range(len(keep)):
        for j in range(i):
            a, b = keep[i]["thumb"].ravel(), keep[j]["thumb"].ravel()
            corr = np.corrcoef(a, b)[0, 1] if a.std() > 0 and b.std() > 0 else 0.0
            if abs(corr) > 0.85 or _stem_key(keep[i]["path"]) == _stem_key(keep[j]["path"]):
                parent[find(i)] = find(j)
    groups = [find(i) for i in range(len(keep))]
    return keep, groups


def _split_val(keep, groups, val_count):
    """Held-out photos: val_count singleton groups (no variant of them is trained on), detailed
    JPEGs first (photographs rather than graphics), chosen by a hash of the file name (stable)."""
    sizes = {g: groups.count(g) for g in groups}

    def rank(i):  # detailed JPEGs (photographs, not flat graphics) first
        path = keep[i]["path"]
        photo = path.suffix.lower() in (".jpg", ".jpeg") and _detail(keep[i]["image"]) >= 8.0
        return (not photo, hashlib.sha1(path.name.encode()).hexdigest())

    order = sorted(range(len(keep)), key=rank)
    val = [i for i in order if sizes[groups[i]] == 1][:val_count]
    if len(val) < val_count:  # not enough singletons: take whole groups
        for i in order:
            if len(val) >= val_count:
                break
            if i not in val:
                val.extend(j for j in range(len(keep)) if groups[j] == groups[i] and j not in val)
    if len(keep) - len(val) < 1:
        val = val[:max(0, len(keep) - 1)]
    return sorted(val)


def _folder_manifest(paths, folder) -> list:
    out = []
    for p in paths:
        st = Path(p).stat()
        out.append([str(Path(p).relative_to(folder)), st.st_size, int(st.st_mtime)])
    return out


def save_photo_cache(path, images, names, meta=None) -> None:
    """Images of any sizes, uint8 [H, W, 3] each, in one uncompressed .npz (flat buffer + shapes)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    shapes = np.array([im.shape for im in images], np.int64).reshape(-1, 3)
    offsets = np.concatenate([[0], np.cumsum(shapes.prod(1))]).astype(np.int64)
    pixels = np.concatenate([im.ravel() for im in images]) if images else np.zeros(0, np.uint8)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, pixels=pixels, shapes=shapes, offsets=offsets, names=np.array(names, dtype=str),
             meta=np.array(json.dumps(meta or {})), version=np.array(CACHE_VERSION))
    os.replace(tmp, path)


def load_photo_cache(path) -> tuple[list[np.ndarray], list[str], dict]:
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            pixels, shapes, offsets = z["pixels"], z["shapes"], z["offsets"]
            names = [str(n) for n in z["names"]]
            meta = json.loads(str(z["meta"])) if "meta" in z else {}
    except (OSError, KeyError, ValueError) as e:
        raise DataError(f"{path}: not a photo cache ({e}); rebuild it with `hypergs prepare-data --force`") from e
    images = [pixels[offsets[i]:offsets[i + 1]].reshape(shapes[i]) for i in range(len(shapes))]
    return images, names, meta


def _pyramid(image: np.ndarray, min_side: int = 16) -> list[np.ndarray]:
    """[image, image/2, image/4, ...] by 2x2 box filtering, uint8."""
    levels = [np.ascontiguousarray(image)]
    while min(levels[-1].shape[:2]) >= 2 * min_side:
        a = levels[-1]
        h, w = a.shape[0] // 2 * 2, a.shape[1] // 2 * 2
        s = a[:h, :w].astype(np.uint16).reshape(h // 2, 2, w // 2, 2, 3).sum((1, 3))
        levels.append(((s + 2) // 4).astype(np.uint8))
    return levels


def _warp_pyramid(levels, aff, scale, out):
    """Sample out [h, w, 3] from a pyramid: affine `aff` in base-level pixels, `scale` = base pixels
    per output pixel (picks the level, then 1 or 2 taps per axis)."""
    level = 0
    if scale > 1.0:
        level = min(int(math.floor(math.log2(scale))), len(levels) - 1)
    f = 1.0 / (1 << level)
    a = np.asarray(aff, np.float64) * f
    residual = scale * f
    taps = 1 if residual < 1.5 else min(4, int(math.ceil(residual)))  # bilinear aliases little below 1.5
    _warp_frame(levels[level], a, taps, out)


class PhotoSource(ClipSource):
    """Pan/zoom/roll clips over photographs: a smooth random camera path (quadratic Bezier, start to
    end, constant or eased speed) of a square window at a random scale that stays inside the photo,
    h-flipped half the time, sampled with area filtering from a mip pyramid."""

    name = "photos"
    MOTION_CLASSES = ((0.1, 0.0, 0.0), (0.35, 0.2, 1.5), (0.35, 1.5, 5.0), (0.2, 5.0, 14.0))

    def __init__(self, path, max_rotation: float = 0.08, max_zoom: float = 0.35,
                 min_crop_fraction: float = 0.15):
        path = Path(path)
        if path.is_dir():
            files = list_images(path)
            if not files:
                raise DataError(f"{path}: no images ({', '.join(IMAGE_EXTENSIONS)}) in this folder")
            images = [read_image(f, PHOTO_MAX_SHORT_SIDE) for f in files]
            names = [f.name for f in files]
        elif path.is_file():
            images, names, _ = load_photo_cache(path)
        else:
            hint = " (run `hypergs prepare-data` to make it)" if path.suffix == ".npz" else ""
            raise DataError(f"{path}: no such photo cache or folder{hint}")
        if not images:
            raise DataError(f"{path}: holds no photos")
        self.path = path
        self.names = names
        self.pyramids = [_pyramid(im) for im in images]
        # Detailed photos are drawn more often than near-flat graphics (sqrt of the mean gradient).
        detail = np.sqrt(np.clip([_detail(im) for im in images], 1.0, 40.0))
        self.cumulative = np.cumsum(detail / detail.sum())
        self.max_rotation = max_rotation
        self.max_zoom = max_zoom
        self.min_crop_fraction = min_crop_fraction

    def describe(self) -> str:
        return f"{len(self.pyramids)} photos from {self.path}"

    def __len__(self):
        return len(self.pyramids)

    def sample(self, rng, clip_frames, size, index: int | None = None):
        return _retry_blank(lambda: self._sample_once(rng, clip_frames, size, index))

    def _sample_once(self, rng, clip_frames, size, index):
        T = clip_frames
        if index is None:
            k = min(int(np.searchsorted(self.cumulative, rng.random(), side="right")), len(self) - 1)
        else:
            k = index
        levels = self.pyramids[k]
        H, W = levels[0].shape[:2]
        short = min(H, W)
        p = np.array([c[0] for c in self.MOTION_CLASSES])
        lo, hi = self.MOTION_CLASSES[rng.choice(len(p), p=p / p.sum())][1:]
        speed = rng.uniform(lo, hi) * size / 128.0  # output pixels per frame
        motion = min(1.0, hi / 5.0)
        theta0 = rng.uniform(-1, 1) * self.max_rotation * (rng.random() < 0.5)
        theta1 = theta0 + rng.uniform(-1, 1) * self.max_rotation * 0.5 * motion * (rng.random() < 0.5)
        fit = max(abs(math.cos(a)) + abs(math.sin(a)) for a in (theta0, theta1))  # rotated extent
        direction = rng.uniform(0, 2 * np.pi)
        unit = np.array([math.cos(direction), math.sin(direction)])
        k = speed * (T - 1) / size  # travel in source pixels per source pixel of window side
        # The window (side w, rotated extent w * fit) and its travel k * w must fit in the photo:
        # a smaller window (zoomed in) rather than a pan stopped at the border.
        wmax = min(short / fit, W / (fit + k * abs(unit[0])), H / (fit + k * abs(unit[1])))
        wmin = min(wmax, max(0.75 * size, self.min_crop_fraction * short))
        w0 = math.exp(rng.uniform(math.log(wmin), math.log(wmax)))
        zoom = rng.uniform(-1, 1) * self.max_zoom * motion if rng.random() < 0.5 else 0.0
        w1 = min(max(w0 * math.exp(zoom), wmin), wmax)
        wm = 0.5 * (w0 + w1)
        travel = k * wm * unit
        extent = np.array([W, H], np.float64)
        e0, e1 = 0.5 * w0 * fit, 0.5 * w1 * fit
        # c0 inside the photo for w0, c1 = c0 + travel inside for w1 (the path in between stays
        # inside: the constraints are linear in (centre, w) and the path is a convex combination).
        lo = np.maximum(e0, e1 - travel)
        hi = np.minimum(extent - e0, extent - e1 - travel)
        c0 = np.where(lo <= hi, lo + rng.random(2) * (hi - lo), 0.5 * (lo + hi))
        c0 = np.clip(c0, e0, extent - e0)
        c1 = np.clip(c0 + travel, e1, extent - e1)
        bend = rng.normal(0, 0.2) * np.array([-unit[1], unit[0]]) * np.abs(travel).max()
        em = 0.5 * wm * fit
        cm = np.clip(0.5 * (c0 + c1) + bend, em, extent - em)
        s = np.linspace(0, 1, T) if T > 1 else np.zeros(1)
        if rng.random() < 0.3:
            s = s * s * (3 - 2 * s)  # ease in/out
        flip = rng.random() < 0.5
        out = np.empty((T, size, size, 3), np.float32)
        for t in range(T):
            st = s[t]
            centre = (1 - st) ** 2 * c0 + 2 * st * (1 - st) * cm + st ** 2 * c1
            w = w0 * (w1 / w0) ** st
            theta = theta0 + (theta1 - theta0) * st
            scale = w / size
            cs, sn = math.cos(theta) * scale, math.sin(theta) * scale
            fx = -1.0 if flip else 1.0
            # source = centre + R(theta) scale (q - size/2), q_x mirrored when flipped
            aff = np.array([cs * fx, -sn, 0.0, sn * fx, cs, 0.0])
            qx0 = size / 2 if not flip else -size / 2
            aff[2] = centre[0] - cs * qx0 + sn * size / 2
            aff[5] = centre[1] - sn * qx0 - cs * size / 2
            _warp_pyramid(levels, aff, scale, out[t])
        return out


# ---------------------------------------------------------------------------------------------
# Videos
# ---------------------------------------------------------------------------------------------

def list_videos(folder) -> list[Path]:
    folder = Path(folder)
    return sorted(p for p in folder.rglob("*") if p.is_file() and p.suffix.lower() in VIDEO_EXTENSIONS)


def video_cache_dir(folder, root=DEFAULT_ROOT) -> Path:
    folder = Path(folder).resolve()
    tag = hashlib.sha1(str(folder).encode()).hexdigest()[:10]
    return Path(root) / VIDEO_CACHE_DIR / f"{folder.name or 'videos'}-{tag}"


def find_video_cache(folder, root=DEFAULT_ROOT) -> Path:
    """The clip cache of a video folder (or `folder` itself when it is a clip cache)."""
    folder = Path(folder)
    if (folder / "index.json").is_file() and (folder / "clips.npy").is_file():
        return folder
    if not folder.is_dir():
        raise DataError(f"videos={folder}: no such folder")
    cache = video_cache_dir(folder, root)
    if not (cache / "index.json").is_file():
        raise DataError(f"videos={folder}: no clip cache at {cache}; run "
                        f"`hypergs prepare-data --root {root} --videos {folder}` first")
    return cache


def prepare_videos(folder, root=DEFAULT_ROOT, cache_size: int = 256, cache_frames: int = 16,
                   clips_per_video: int = 8, force: bool = False, seed: int = 0, log=print) -> Path:
    """Decode random short clips of every video in `folder` into ROOT/videos_cache/NAME-HASH/:
    clips.npy (uint8 [N, cache_frames, cache_size, cache_size, 3], a square crop at a random
    position of the frame resized to short side cache_size) and index.json. Each clip has a random
    base stride (1-4 source frames) so that sampling strides reach further in time."""
    from .video import iter_frames, probe, resize_exact
    from .errors import VideoError

    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"--videos {folder}: no such folder")
    files = list_videos(folder)
    if not files:
        raise DataError(f"--videos {folder}: no videos ({', '.join(VIDEO_EXTENSIONS)}) in this folder")
    cache = video_cache_dir(folder, root)
    params = {"cache_size": cache_size, "cache_frames": cache_frames,
              "clips_per_video": clips_per_video, "seed": seed}
    manifest = _folder_manifest(files, folder)
    index_path = cache / "index.json"
    if index_path.is_file() and not force:
        try:
            old = json.loads(index_path.read_text())
        except ValueError:
            old = {}
        if old.get("params") == params and old.get("files") == manifest and (cache / "clips.npy").is_file():
            log(f"videos: {cache} is up to date ({len(old['clips'])} clips of {len(files)} videos); "
                f"--force rebuilds it")
            return cache
    rng = np.random.default_rng([seed, 7])
    plan = []  # per video: (path, info, [(start, stride, crop)])
    for f in files:
        try:
            info = probe(f)
        except VideoError as e:
            log(f"  skip {f.name}: {e}")
            continue
        n = info.num_frames
        strides = [b for b in (1, 2, 3, 4) if (cache_frames - 1) * b + 1 <= n]
        if not strides:
            log(f"  skip {f.name}: {n} frames, fewer than the {cache_frames} a clip needs")
            continue
        k = min(clips_per_video, max(1, n // max(1, cache_frames // 2)))
        scale = cache_size / min(info.width, info.height)
        rw, rh = max(cache_size, round(info.width * scale)), max(cache_size, round(info.height * scale))
        clips = []
        for j in range(k):
            b = int(rng.choice(strides))
            span = (cache_frames - 1) * b + 1
            lo, hi = j * (n - span) // k, (j + 1) * (n - span) // k
            start = int(rng.integers(lo, hi + 1))
            crop = (int(rng.integers(0, rw - cache_size + 1)), int(rng.integers(0, rh - cache_size + 1)))
            clips.append((start, b, crop))
        plan.append((f, info, (rw, rh), clips))
    total = sum(len(c) for *_, c in plan)
    if total == 0:
        raise DataError(f"--videos {folder}: no usable videos")
    cache.mkdir(parents=True, exist_ok=True)
    tmp = cache / "clips.tmp.npy"
    arr = np.lib.format.open_memmap(tmp, mode="w+", dtype=np.uint8,
                                    shape=(total, cache_frames, cache_size, cache_size, 3))
    entries = []
    row = 0
    t0 = time.time()
    for f, info, (rw, rh), clips in plan:
        wanted = {}  # frame index -> [(row, slot, crop)]
        for j, (start, b, crop) in enumerate(clips):
            entries.append({"video": str(f.relative_to(folder)), "start": start, "stride": b,
                            "crop": list(crop), "resized": [rw, rh]})
            for slot in range(cache_frames):
                wanted.setdefault(start + slot * b, []).append((row + j, slot, crop))
        try:
            for index, frame in iter_frames(f, sorted(wanted)):
                resized = resize_exact(frame, rw, rh)
                for r, slot, (x0, y0) in wanted[index]:
                    arr[r, slot] = resized[y0:y0 + cache_size, x0:x0 + cache_size]
        except VideoError as e:
            log(f"  warning {f.name}: {e} (its clips keep the frames decoded so far)")
        row += len(clips)
        log(f"  {f.name}: {info.width}x{info.height}, {info.num_frames} frames -> {len(clips)} clips")
    arr.flush()
    del arr
    os.replace(tmp, cache / "clips.npy")
    index_path.write_text(json.dumps({"version": CACHE_VERSION, "folder": str(folder.resolve()),
                                      "params": params, "files": manifest, "clips": entries}, indent=1))
    log(f"videos: wrote {total} clips x {cache_frames} frames at {cache_size}x{cache_size} from "
        f"{len(plan)} videos to {cache} ({(cache / 'clips.npy').stat().st_size / 1e6:.0f} MB, "
        f"{time.time() - t0:.0f} s)")
    return cache


class VideoSource(ClipSource):
    """Clips from a pre-extracted clip cache: a random clip, a random temporal stride, a random
    short-side resize (no upscaling) and a random crop at the canvas size, h-flipped half the time."""

    name = "videos"

    def __init__(self, cache):
        cache = Path(cache)
        try:
            index = json.loads((cache / "index.json").read_text())
            self.clips = np.load(cache / "clips.npy", mmap_mode="r")
        except (OSError, ValueError) as e:
            raise DataError(f"{cache}: unreadable clip cache ({e}); rebuild it with "
                            f"`hypergs prepare-data --videos FOLDER --force`") from e
        self.cache = cache
        self.index = index
        if len(self.clips) == 0:
            raise DataError(f"{cache}: holds no clips")

    def describe(self) -> str:
        return f"{len(self.clips)} video clips from {self.cache}"

    def sample(self, rng, clip_frames, size):
        T = clip_frames
        n, tc, S = self.clips.shape[0], self.clips.shape[1], self.clips.shape[2]
        if T > tc:
            raise DataError(f"{self.cache}: holds {tc}-frame clips, fewer than {T}; rebuild it with "
                            f"`hypergs prepare-data --videos FOLDER --video-frames {T} --force`")
        k = int(rng.integers(n))
        max_stride = (tc - 1) // (T - 1) if T > 1 else 1
        stride = int(rng.integers(1, max_stride + 1))
        start = int(rng.integers(0, tc - (T - 1) * stride))
        frames = self.clips[k, start:start + (T - 1) * stride + 1:stride]  # [T, S, S, 3] read
        if rng.random() < 0.5:
            frames = frames[::-1]  # played backwards: as natural a motion as forwards
        crop = math.exp(rng.uniform(math.log(min(size, S)), math.log(S)))  # cache pixels
        x0, y0 = rng.uniform(0, S - crop, 2)
        scale = crop / size
        flip = rng.random() < 0.5
        if flip:
            aff = np.array([-scale, 0.0, x0 + crop, 0.0, scale, y0])
        else:
            aff = np.array([scale, 0.0, x0, 0.0, scale, y0])
        taps = 1 if scale < 1.5 else min(4, int(math.ceil(scale)))
        out = np.empty((T, size, size, 3), np.float32)
        for t in range(T):
            _warp_frame(np.ascontiguousarray(frames[t]), aff, taps, out[t])
        return out


# ---------------------------------------------------------------------------------------------
# Validation clips, previews
# ---------------------------------------------------------------------------------------------

def validation_clips(root=DEFAULT_ROOT, clip_frames: int = 4, size: int = 128, count: int = 8,
                     seed: int = VAL_SEED) -> np.ndarray:
    """Fixed evaluation clips [count, T, size, size, 3] float32: half from the held-out photos
    (ROOT/photos_val_cache.npz, each photo in turn), half procedural; the same every call.
    Without the held-out cache (prepare-data not run) all are procedural, with a warning."""
    out = np.empty((count, clip_frames, size, size, 3), np.float32)
    val_path = Path(root) / PHOTO_VAL_CACHE
    photos = None
    if val_path.is_file():
        photos = PhotoSource(val_path)
    else:
        warnings.warn(f"{val_path} is missing (run `hypergs prepare-data`): validation clips are all "
                      f"procedural", stacklevel=2)
    procedural = ProceduralSource("mixed", leaves_fraction=0.5)
    n_photo = (count + 1) // 2 if photos is not None else 0
    for i in range(count):
        rng = np.random.default_rng([seed, i])
        if i < n_photo:
            out[i] = photos.sample(rng, clip_frames, size, index=i % len(photos))
        else:
            out[i] = procedural.sample(rng, clip_frames, size)
    return out


def contact_sheet(clips: np.ndarray, pad: int = 2) -> np.ndarray:
    """[N, T, H, W, 3] -> one uint8 image, a row per clip, a column per frame."""
    clips = np.asarray(clips)
    if clips.dtype != np.uint8:
        clips = (np.clip(clips, 0, 1) * 255 + 0.5).astype(np.uint8)
    n, t, h, w, _ = clips.shape
    sheet = np.full((n * (h + pad) + pad, t * (w + pad) + pad, 3), 255, np.uint8)
    for i in range(n):
        for j in range(t):
            y, x = pad + i * (h + pad), pad + j * (w + pad)
            sheet[y:y + h, x:x + w] = clips[i, j]
    return sheet


# ---------------------------------------------------------------------------------------------
# prepare-data: the default photo set from Debian wallpaper packages
# ---------------------------------------------------------------------------------------------

def _run(cmd, cwd=None, timeout=900):
    try:
        return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired:
        return subprocess.CompletedProcess(cmd, 124, "", f"{cmd[0]} timed out after {timeout} s")


def download_wallpapers(dest, packages=WALLPAPER_PACKAGES, log=print) -> list[Path]:
    """apt-get download + dpkg -x the wallpaper packages; copy their .jpg/.png/.webp images (not
    .svg/.xml) into `dest` as PACKAGE__NAME.EXT, identical files once. Unavailable packages are
    skipped with a warning (after one `apt-get update` retry)."""
    if shutil.which("apt-get") is None or shutil.which("dpkg") is None:
        raise DataError("apt-get/dpkg not found (not a Debian-like system): put your own photos in a "
                        "folder and run `hypergs prepare-data --photo-folder FOLDER`")
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    copied, digests = [], set()
    with tempfile.TemporaryDirectory(prefix="hypergs-wallpapers-") as tmp:
        tmp = Path(tmp)
        debs = {}
        missing = list(packages)
        for attempt in range(2):
            for pkg in list(missing):
                before = set(tmp.glob("*.deb"))
                r = _run(["apt-get", "download", pkg], cwd=tmp)
                new = sorted(set(tmp.glob("*.deb")) - before)
                if r.returncode == 0 and new:
                    debs[pkg] = new[0]
                    missing.remove(pkg)
                    log(f"  downloaded {new[0].name} ({new[0].stat().st_size / 1e6:.1f} MB)")
            if not missing or attempt == 1:
                break
            log(f"  apt-get download could not fetch {', '.join(missing)}: running apt-get update")
            r = _run(["apt-get", "update"])
            if r.returncode != 0:
                log(f"  warning: apt-get update failed: {r.stderr.strip().splitlines()[-1:]}")
        for pkg in missing:
            log(f"  warning: package {pkg} is unavailable here; skipped")
        for pkg, deb in debs.items():
            root = tmp / pkg
            r = _run(["dpkg", "-x", str(deb), str(root)])
            if r.returncode != 0:
                log(f"  warning: dpkg -x {deb.name} failed: {r.stderr.strip()}; skipped")
                continue
            for f in sorted(root.rglob("*")):
                if not f.is_file() or f.is_symlink() or f.suffix.lower() not in (".jpg", ".jpeg", ".png", ".webp"):
                    continue
                digest = hashlib.sha1(f.read_bytes()).hexdigest()
                if digest in digests:
                    continue
                digests.add(digest)
                target = dest / f"{pkg}__{f.name}"
                shutil.copyfile(f, target)
                copied.append(target)
    log(f"  {len(copied)} images from {len(debs)} packages copied to {dest}")
    return copied


def prepare_photos(root=DEFAULT_ROOT, folder=None, force: bool = False, val_count: int = VAL_PHOTO_COUNT,
                   log=print) -> tuple[Path, Path]:
    """Fill ROOT/photos from the wallpaper packages (unless it has images, or `folder` is given),
    then write ROOT/photos_cache.npz (training) and ROOT/photos_val_cache.npz (val_count held-out
    photos). Skips caches that are up to date with the folder unless force (which rebuilds the
    caches, not the download)."""
    root = Path(root)
    train_path, val_path = root / PHOTO_CACHE, root / PHOTO_VAL_CACHE
    if folder is None:
        folder = root / PHOTOS_DIR
        if not list_images(folder):
            log(f"photos: downloading {len(WALLPAPER_PACKAGES)} wallpaper packages into {folder}")
            download_wallpapers(folder, log=log)
        else:
            log(f"photos: using the images in {folder} (delete it to download them again)")
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"--photo-folder {folder}: no such folder")
    files = list_images(folder)
    if not files:
        raise DataError(f"{folder}: no images ({', '.join(IMAGE_EXTENSIONS)})")
    manifest = {"folder": str(folder.resolve()), "files": _folder_manifest(files, folder),
                "val_count": val_count, "max_short_side": PHOTO_MAX_SHORT_SIDE}
    if train_path.is_file() and val_path.is_file() and not force:
        try:
            _, names, meta = load_photo_cache(train_path)
        except DataError:
            meta, names = {}, []
        if meta.get("manifest") == manifest:
            _, val_names, _ = load_photo_cache(val_path)
            log(f"photos: {train_path} ({len(names)} photos) and {val_path} ({len(val_names)}) are up "
                f"to date; --force rebuilds them")
            return train_path, val_path
        log(f"photos: {folder} changed since the caches were made; rebuilding them")
    t0 = time.time()
    log(f"photos: decoding {len(files)} images from {folder} (short side <= {PHOTO_MAX_SHORT_SIDE})")
    keep, groups = _collect_photos(files, log=log)
    if len(keep) < 2:
        raise DataError(f"{folder}: only {len(keep)} usable photos; need at least 2")
    val = _split_val(keep, groups, val_count)
    train = [i for i in range(len(keep)) if i not in val]
    meta = {"manifest": manifest}
    save_photo_cache(train_path, [keep[i]["image"] for i in train], [keep[i]["path"].name for i in train], meta)
    save_photo_cache(val_path, [keep[i]["image"] for i in val], [keep[i]["path"].name for i in val], meta)
    size_mb = (train_path.stat().st_size + val_path.stat().st_size) / 1e6
    log(f"photos: {len(train)} training photos -> {train_path}, {len(val)} held-out -> {val_path} "
        f"({size_mb:.0f} MB, {time.time() - t0:.0f} s)")
    log(f"  held out: {', '.join(keep[i]['path'].name for i in val)}")
    return train_path, val_path


# ---------------------------------------------------------------------------------------------
# CLI
# ---------------------------------------------------------------------------------------------

def add_commands(subparsers) -> None:
    p = subparsers.add_parser(
        "prepare-data", help="download and cache the default training photos (and/or your videos)",
        description="Prepare training data under ROOT. With no --photos/--videos: the default set "
                    "(wallpaper photos from Debian packages -> photos_cache.npz + photos_val_cache.npz). "
                    "Idempotent: skips caches that are up to date unless --force.")
    p.add_argument("--root", default=DEFAULT_ROOT, help="data folder (default: %(default)s)")
    p.add_argument("--photos", action="store_true", help="prepare the photo caches")
    p.add_argument("--photo-folder", default=None,
                   help="build the photo caches from this folder of images instead of ROOT/photos "
                        "(no download)")
    p.add_argument("--videos", nargs="+", default=[], metavar="FOLDER",
                   help="pre-extract a clip cache from each folder of videos (use videos=FOLDER in the "
                        "training spec)")
    p.add_argument("--val-photos", type=int, default=VAL_PHOTO_COUNT, help="held-out photos (default: %(default)s)")
    p.add_argument("--video-size", type=int, default=256,
                   help="cached clip side in pixels, about 2x the canvas (default: %(default)s)")
    p.add_argument("--video-frames", type=int, default=16, help="frames per cached clip (default: %(default)s)")
    p.add_argument("--clips-per-video", type=int, default=8, help="(default: %(default)s)")
    p.add_argument("--force", action="store_true", help="rebuild caches that exist")
    p.set_defaults(func=_cmd_prepare)

    q = subparsers.add_parser("preview-data", help="write a contact sheet of random training clips",
                              description="One row per clip of make_batch, one column per frame.")
    q.add_argument("--spec", default=DEFAULT_SPEC, help="source spec (default: %(default)s)")
    q.add_argument("--root", default=DEFAULT_ROOT, help="data folder (default: %(default)s)")
    q.add_argument("--clips", type=int, default=8)
    q.add_argument("--frames", type=int, default=4)
    q.add_argument("--size", type=int, default=128)
    q.add_argument("--seed", type=int, default=0)
    q.add_argument("--out", required=True, help="image file to write (.png)")
    q.set_defaults(func=_cmd_preview)


def _cmd_prepare(args) -> None:
    do_photos = args.photos or args.photo_folder is not None or not args.videos
    if do_photos:
        prepare_photos(args.root, folder=args.photo_folder, force=args.force, val_count=args.val_photos)
    for folder in args.videos:
        prepare_videos(folder, args.root, cache_size=args.video_size, cache_frames=args.video_frames,
                       clips_per_video=args.clips_per_video, force=args.force)
    sys.stdout.flush()


def _cmd_preview(args) -> None:
    sources = build_sources(args.spec, args.root)
    batch = make_batch(sources, args.seed, 0, 0, args.clips, args.frames, args.size)
    write_image(args.out, contact_sheet(batch))
    print(f"wrote {args.out}: {args.clips} clips x {args.frames} frames from {args.spec}")
