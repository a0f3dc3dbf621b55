"""Training clips: random T-frame clips [T, size, size, 3] float32 in [0, 1], drawn on the fly by
`ClipSource`s (procedural.py, photos.py, videos.py; data.py parses which ones to use).

`make_batch(sources, seed, step, rank, ...)` is a pure function of its arguments, so training
resumes exactly and each torchrun rank sees different data. The pixel work runs in Numba kernels
compiled with nogil=True, so a prefetch thread overlaps it with the training step.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import HyperGSError
from ..io.images import list_files

DEFAULT_ROOT = "data"
BLANK_STD = 0.04  # a first frame this flat (std over pixels and channels) is drawn again
BLANK_TRIES = 3


class DataError(HyperGSError):
    """A bad source spec, or a missing folder or cache; the message says what to do."""


def media_files(folder, extensions, named_by: str) -> list[Path]:
    """`io.images.list_files(folder, extensions)`, where a missing folder or one with none of them is a
    DataError that starts with `named_by`, the words that named the folder (an option or a source spec)."""
    folder = Path(folder)
    if not folder.is_dir():
        raise DataError(f"{named_by}: no such folder")
    files = list_files(folder, extensions)
    if not files:
        raise DataError(f"{named_by}: none of {', '.join(extensions)} in this folder")
    return files


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


def retry_blank(draw):
    """draw() again (same generator, so still deterministic) while the clip is nearly blank: a flat
    crop of a sky or of a graphic teaches the network little."""
    for _ in range(BLANK_TRIES):
        clip = draw()
        if clip[0].std() >= BLANK_STD:
            return clip
    return clip
