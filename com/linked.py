"""Clips linked to an external .hgs file, read through the session's frame cache (com/cache.py over
hypergs_blender/io/cache.py: files opened lazily, no handle held, a small LRU of decoded frames).
Callers pass absolute paths."""
from __future__ import annotations

import numpy as np

from ..hypergs_blender.io.hgs import HgsReader
from .cache import FRAMES


def reader(path: str) -> HgsReader:
    """The open reader of a linked file (header and index checked). Raises HyperGSError."""
    return FRAMES.reader(path)


def read_frame(path: str, frame: int) -> tuple[np.ndarray, int, int]:
    """(params [N, 8], read-only, canvas width, canvas height) of one frame of a linked file.
    Raises HyperGSError for a missing or damaged file (and remembers it for `problem`)."""
    params = FRAMES.read_frame(path, frame)
    opened = FRAMES.reader(path)
    return params, opened.canvas_width, opened.canvas_height


def verify(path: str) -> HgsReader:
    """Open and decode every frame once (at import: a damaged file is refused up front)."""
    return FRAMES.verify(path)


def problem(path: str) -> str | None:
    """What is wrong with a linked file now, or None."""
    return FRAMES.problem(path)


def forget(path: str | None = None) -> None:
    """Drop one cached file (or all): the next access reads it again."""
    FRAMES.forget(path)
