"""Clips linked to an external .hgs file: a small cache of open files, shared by the render engine
(F12 and the viewport), the panel and the operators. No bpy here: callers pass absolute paths.

Design: a linked clip's Gaussians live only in the file, which is the one source of truth. Its
object's mesh holds no Gaussians, just the image plane's outline (so it can be seen, selected and
placed in Solid mode); the engine decodes the frame for the scene frame from the file at render
time, and the viewport's Rendered mode shows it the same way. We do *not* copy the current frame
into the mesh from a frame_change_post handler: that would rewrite mesh data on every frame change
(undo steps, a modified .blend, and a data race with the render thread during Ctrl-F12, where
handlers run while the engine reads), and edits made to those points would be lost silently on the
next frame change. To edit a linked clip, embed it (hypergs.embed_clip).

Files are read lazily: opening one reads its header and frame index only, and a frame's group of
frames is read from the file when that frame is first decoded (HgsReader keeps the decoded group, so
playing forward is cheap). Each read opens the file and closes it again (`_FileOnDemand`), so no
handle is held: the file can be overwritten (e.g. exported again) or deleted while Blender runs, on
every platform. A cheap size check (its size and modification time, from os.stat) tells whether the
file changed since it was opened; only then is its header read again. So drawing the panel costs a
stat, never a read of the whole file, and the checksums catch a file changed between two reads.
Every problem is a HyperGSError naming the file; the last one per file is kept for the panel.
"""
from __future__ import annotations

import os
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io.hgs import HgsError, HgsReader

MAX_OPEN = 8  # files kept decoded-ready; the least recently used is dropped first


@dataclass
class _Entry:
    key: tuple | None  # (size, mtime_ns) of what was read, None when it could not be read
    reader: HgsReader | None
    error: str | None  # the last problem with this file (opening it, or decoding a frame)


_lock = threading.RLock()  # render thread and main thread share the readers (not thread-safe)
_files: "OrderedDict[str, _Entry]" = OrderedDict()


def _stat_key(path: str) -> tuple:
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise HgsError(f"{path}: no such file") from None
    except OSError as e:
        raise HgsError(f"{path}: cannot read ({e.strerror})") from None
    if not os.path.isfile(path):
        raise HgsError(f"{path}: not a file")
    return st.st_size, st.st_mtime_ns


class _FileOnDemand:
    """A read-only binary file that holds no handle: every read opens the file, seeks, reads and closes
    it again. What HgsReader needs of a file (read, seek, tell, close, name)."""

    def __init__(self, path: str, size: int):
        self.name, self._size, self._position = path, size, 0

    def seek(self, offset: int, whence: int = os.SEEK_SET) -> int:
        base = {os.SEEK_SET: 0, os.SEEK_CUR: self._position, os.SEEK_END: self._size}[whence]
        self._position = base + offset
        return self._position

    def tell(self) -> int:
        return self._position

    def read(self, size: int = -1) -> bytes:
        try:
            with open(self.name, "rb") as f:
                f.seek(self._position)
                data = f.read() if size is None or size < 0 else f.read(size)
        except OSError as e:
            raise HgsError(f"{self.name}: cannot read ({e.strerror})") from None
        self._position += len(data)
        return data

    def close(self) -> None:
        pass


def _open(path: str, size: int) -> HgsReader:
    return HgsReader(_FileOnDemand(path, size))  # header and index only; HgsError names the file


def _entry(path: str) -> _Entry:
    """The cache entry for `path`, (re)opened when the file changed. Raises HyperGSError."""
    if not path:
        raise HyperGSError("no linked file set")
    entry = _files.get(path)
    try:
        key = _stat_key(path)
    except HyperGSError as e:
        _files[path] = _Entry(None, None, str(e))
        _trim()
        raise
    if entry is None or entry.key != key or entry.reader is None:
        if entry is not None and entry.key == key:  # unchanged and known to be broken
            raise HgsError(entry.error)
        try:
            entry = _Entry(key, _open(path, key[0]), None)
        except HyperGSError as e:
            _files[path] = _Entry(key, None, str(e))
            _trim()
            raise
        _files[path] = entry
    _files.move_to_end(path)
    _trim()
    return entry


def _trim() -> None:
    while len(_files) > MAX_OPEN:
        _files.popitem(last=False)


def reader(path: str) -> HgsReader:
    """The open reader of a linked file (header and index checked). Raises HyperGSError."""
    with _lock:
        return _entry(path).reader


def read_frame(path: str, frame: int) -> tuple[np.ndarray, int, int]:
    """(params [N, 8], canvas width, canvas height) of one frame of a linked file.
    Raises HyperGSError for a missing or damaged file (and remembers it for `problem`)."""
    with _lock:
        entry = _entry(path)
        try:
            params = entry.reader.read_frame(frame)
        except HyperGSError as e:
            entry.error = str(e)
            raise
        except Exception as e:  # the reader is fuzz-tested; still, never let a file crash a render
            entry.error = f"{path}: cannot decode frame {frame} ({type(e).__name__}: {e})"
            raise HgsError(entry.error) from e
        return params, entry.reader.canvas_width, entry.reader.canvas_height


def verify(path: str) -> HgsReader:
    """Open and decode every frame once (at import: a damaged file is refused up front)."""
    with _lock:
        entry = _entry(path)
        try:
            entry.reader.verify()
        except HyperGSError as e:
            entry.error = str(e)
            raise
        return entry.reader


def problem(path: str) -> str | None:
    """What is wrong with a linked file now, or None: checks that it exists, is unchanged or still
    opens, and reports the last decoding error seen for this version of the file."""
    with _lock:
        try:
            return _entry(path).error
        except HyperGSError as e:
            return str(e)


def forget(path: str | None = None) -> None:
    """Drop one cached file (or all): the next access reads it again."""
    with _lock:
        if path is None:
            _files.clear()
        else:
            _files.pop(path, None)
