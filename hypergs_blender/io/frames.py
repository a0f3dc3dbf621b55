"""Frames of a video file or an image sequence, through one interface: `probe`, `iter_frames` (streamed,
one frame at a time) and `read_frames`, with frame ranges, uniform sampling and the short-side resize
+ centre crop to a square. Image sequences are a frame-number pattern, a folder or one file of the
sequence (see image_sequence.py); anything else is decoded as a video with PyAV (video.py)."""
from __future__ import annotations

from typing import Iterator

import numpy as np

from ..errors import VideoError
from . import image_sequence, video
from .video import SHOWN, Display, VideoInfo

__all__ = ["Display", "SHOWN", "VideoInfo", "probe", "iter_frames", "read_frames", "sample_indices"]


def probe(path, display: Display = SHOWN) -> VideoInfo:
    """Size, frame rate and frame count of a video (its frames as `display` shows them) or an image sequence."""
    if image_sequence.is_image_sequence(path):
        return image_sequence.probe(path)
    return video.probe(path, display)


def iter_frames(path, indices=None, size: int | None = None,
                display: Display = SHOWN) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (index, frame) with frame uint8 [H, W, 3] RGB, decoding one frame at a time (a video's as `display`
    shows it).

    indices: sorted frame indices to yield (None: every frame). size: short side resized to `size`
    and the frame centre-cropped to size x size (None: native size)."""
    if image_sequence.is_image_sequence(path):
        return image_sequence.iter_frames(path, indices, size)
    return video.iter_frames(path, indices, size, display)


def sample_indices(num_available: int, num_frames: int | None, start: int = 0, stop: int | None = None) -> list[int]:
    """Frame indices in [start, stop): all of them, or `num_frames` spread uniformly."""
    stop = num_available if stop is None else min(stop, num_available)
    if not 0 <= start < stop:
        raise VideoError(f"empty frame range [{start}, {stop}) of a {num_available}-frame video")
    if num_frames is None or num_frames >= stop - start:
        return list(range(start, stop))
    return np.round(np.linspace(start, stop - 1, num_frames)).astype(int).tolist()


def read_frames(path, num_frames: int | None = None, start: int = 0, stop: int | None = None,
                size: int | None = None) -> tuple[np.ndarray, VideoInfo, list[int]]:
    """Decode `num_frames` uniformly sampled frames of [start, stop) (all when None) as uint8 [T, H, W, 3]."""
    info = probe(path)
    indices = sample_indices(info.num_frames, num_frames, start, stop)
    frames = np.stack([f for _, f in iter_frames(path, indices, size)])
    return frames, info, indices
