"""Photo training clips: smooth pan/zoom/roll camera paths over photographs (random crop scale, h-flip),
read from a uint8 cache (`hypergs prepare-data` writes it, prepare.py) and sampled from a mip pyramid
(no aliasing)."""
from __future__ import annotations

import json
import math
import os
from pathlib import Path

import numpy as np

from ..io.images import IMAGE_EXTENSIONS, read_image
from .sources import ClipSource, DataError, media_files, retry_blank
from .warp import pyramid, warp_pyramid

PHOTOS_DIR = "photos"
PHOTO_CACHE = "photos_cache.npz"
PHOTO_VAL_CACHE = "photos_val_cache.npz"
PHOTO_MAX_SHORT_SIDE = 512
CACHE_VERSION = 1


def detail(image: np.ndarray) -> float:
    """Mean absolute neighbour difference of a 128-px-wide grey version (0 for a flat image)."""
    grey = image[:: max(1, image.shape[0] // 128), :: max(1, image.shape[1] // 128)].astype(np.float32).mean(2)
    return float(np.abs(np.diff(grey, axis=0)).mean() + np.abs(np.diff(grey, axis=1)).mean())


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
            files = media_files(path, IMAGE_EXTENSIONS, f"photos={path}")
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
        self.pyramids = [pyramid(im) for im in images]
        # Detailed photos are drawn more often than near-flat graphics (sqrt of the mean gradient).
        weights = np.sqrt(np.clip([detail(im) for im in images], 1.0, 40.0))
        self.cumulative = np.cumsum(weights / weights.sum())
        self.max_rotation = max_rotation
        self.max_zoom = max_zoom
        self.min_crop_fraction = min_crop_fraction

    def describe(self) -> str:
        return f"{len(self.pyramids)} photos from {self.path}"

    def __len__(self):
        return len(self.pyramids)

    def sample(self, rng, clip_frames, size, index: int | None = None):
        return retry_blank(lambda: self._sample_once(rng, clip_frames, size, index))

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
            warp_pyramid(levels, aff, scale, out[t])
        return out
