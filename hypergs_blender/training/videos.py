"""Video training clips: random-stride, random-crop clips from a cache of short clips that
`hypergs prepare-data --videos FOLDER` pre-extracts from the user's videos (prepare.py)."""
from __future__ import annotations

import hashlib
import json
import math
from pathlib import Path

import numpy as np

from .sources import DEFAULT_ROOT, ClipSource, DataError
from .warp import warp_frame

VIDEO_CACHE_DIR = "videos_cache"
CACHE_VERSION = 1


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
            warp_frame(np.ascontiguousarray(frames[t]), aff, taps, out[t])
        return out
