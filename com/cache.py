"""The session's frame cache (hypergs_blender/io/cache.py): the files clips read their frames from,
open lazily, and a small LRU of decoded frames, shared by the render engine, the panel and the
operators."""
from __future__ import annotations

from ..hypergs_blender.io.cache import FrameCache

FRAMES = FrameCache()
