"""What the trainer trains on: `build_sources` parses a spec such as "procedural:0.4,photos:0.6" into
weighted clip sources, `validation_clips` draws the fixed held-out clips it evaluates on."""
from __future__ import annotations

import math
import warnings
from pathlib import Path

import numpy as np

from .photos import PHOTO_CACHE, PHOTO_VAL_CACHE, PhotoSource
from .procedural import ProceduralSource
from .sources import DEFAULT_ROOT, ClipSource, DataError
from .videos import VideoSource, find_video_cache

DEFAULT_SPEC = "procedural:0.4,photos:0.6"
VAL_SEED = 20240611


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
