"""The frame cache: where a clip's Gaussians live while Blender shows one frame at a time, as Blender's
own caches do (Alembic / USD / OpenVDB sequences, the Mesh Sequence Cache modifier).

File: a .hgs file of the FLOAT16 codec with one frame per chunk (hgs.py): visually lossless (means
float32, the rest float16), any frame decodes on its own in a few ms, and its frame index gives
random access, so a frame change costs the same at frame 10 of a 30-frame clip and at frame 1,700 of
a 1,800-frame one. Chosen over the QUANTIZED codec (8-bit, about half the size) by measurement: a
1080p Standard frame (57,600 Gaussians) reads in ~5 ms against ~13 ms in a group of 16 (~200 ms to
reach the last frame of a group), and the quantized codec's ranges, when fixed before the first frame
(`Quantizer.default`), cost 0.3 dB there (up to 6.6 dB on smooth clips: `tools/hgs_ranges.py`) where the
float16 one costs nothing measurable (`tools/long_clips.py`). `writer` streams frames into it, one
frame in memory, and only a complete file appears under its name (files.AtomicOutput).

Reading: `FrameCache` keeps the files it has open (their header and frame index only) and a small LRU
of decoded frames, bounded in bytes, for scrubbing back and forth. It serves any .hgs file, so clips
linked to an exported (quantized) .hgs file read the same way. Files are opened lazily and no handle
is held (`_FileOnDemand`): a file can be replaced or deleted while Blender runs, on every platform; a
cheap stat (size, modification time) tells whether a file changed since it was opened, and only then
is its header read again. Every problem is a HyperGSError naming the file; the last one per file is
kept for the panel (`problem`). Thread-safe: Blender's render thread and main thread share it.
"""
from __future__ import annotations

import os
import threading
from collections import OrderedDict
from dataclasses import dataclass

import numpy as np

from ..errors import Cancelled, HyperGSError
from .clips import ClipFrames
from .hgs import HgsError, HgsHeader, HgsReader, HgsWriter

MAX_OPEN = 8  # files kept open (header and index); the least recently used is dropped first
MAX_FRAME_BYTES = 64 << 20  # decoded frames kept for scrubbing (~35 frames of 57,600 Gaussians)


def writer(path, canvas_width: int, canvas_height: int, num_gaussians: int, fps: float, grid=(1, 1),
           source: dict | None = None, zlib_level: int = 1) -> HgsWriter:
    """A streaming writer of a frame cache at `path` (use as a context manager, or close / abort); zlib_level 0
    for a file read once soon after (codec.encode_float16_group)."""
    return HgsWriter(path, canvas_width, canvas_height, num_gaussians, fps=fps, grid=grid, source=source,
                     group_size=1, codec="float16", zlib_level=zlib_level)


def write_clip(clip: ClipFrames, path, progress=None) -> HgsHeader:
    """Copy a clip (clips.ClipFrames: e.g. an exported .hgs file's frames, or a clip in memory) into a new
    frame cache at `path`, a frame at a time; returns the cache's header. progress(done, total) ->
    False cancels (raises Cancelled). Like every write here, a failure leaves no file."""
    with writer(path, clip.canvas_width, clip.canvas_height, clip.num_gaussians, clip.fps, clip.grid,
                clip.source) as out:
        for done, params in enumerate(clip.checked_frames(path)):
            if progress is not None and progress(done, clip.num_frames) is False:
                raise Cancelled("copying the clip into its cache cancelled")
            out.write(params)
    return out.header


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


@dataclass
class _Entry:
    key: tuple | None  # (size, mtime_ns) of what was read, None when it could not be read
    reader: HgsReader | None
    error: str | None  # the last problem with this file (opening it, or decoding a frame)


class FrameCache:
    """Open cache files and recently decoded frames (see the module doc). Paths are absolute."""

    def __init__(self, max_open: int = MAX_OPEN, max_frame_bytes: int = MAX_FRAME_BYTES):
        self.max_open, self.max_frame_bytes = max_open, max_frame_bytes
        self._lock = threading.RLock()
        self._files: "OrderedDict[str, _Entry]" = OrderedDict()
        self._frames: "OrderedDict[tuple, np.ndarray]" = OrderedDict()  # (path, key, frame) -> params
        self._frame_bytes = 0

    def _entry(self, path: str) -> _Entry:
        """The entry for `path`, (re)opened when the file changed. Raises HyperGSError."""
        if not path:
            raise HyperGSError("no cache file set")
        entry = self._files.get(path)
        try:
            key = _stat_key(path)
        except HyperGSError as e:
            self._remember(path, _Entry(None, None, str(e)))
            raise
        if entry is None or entry.key != key or entry.reader is None:
            if entry is not None and entry.key == key:  # unchanged and known to be broken
                raise HgsError(entry.error)
            try:  # header and index only; HgsError names the file
                entry = _Entry(key, HgsReader(_FileOnDemand(path, key[0])), None)
            except HyperGSError as e:
                self._remember(path, _Entry(key, None, str(e)))
                raise
            self._drop_frames(path)
        self._remember(path, entry)
        return entry

    def _remember(self, path: str, entry: _Entry) -> None:
        self._files[path] = entry
        self._files.move_to_end(path)
        while len(self._files) > self.max_open:
            dropped, _ = self._files.popitem(last=False)
            self._drop_frames(dropped)

    def _drop_frames(self, path: str) -> None:
        for k in [k for k in self._frames if k[0] == path]:
            self._frame_bytes -= self._frames.pop(k).nbytes

    def reader(self, path: str) -> HgsReader:
        """The open reader of a file (header and index checked). Raises HyperGSError."""
        with self._lock:
            return self._entry(path).reader

    def read_frame(self, path: str, frame: int) -> np.ndarray:
        """float32 [N, 8] parameters of one frame (read-only: the cache keeps it). Raises HyperGSError
        for a missing or damaged file or a frame outside the clip (and remembers it for `problem`)."""
        with self._lock:
            entry = self._entry(path)
            k = (path, entry.key, int(frame))
            params = self._frames.get(k)
            if params is not None:
                self._frames.move_to_end(k)
                return params
            try:
                params = entry.reader.read_frame(frame)
            except HyperGSError as e:
                entry.error = str(e)
                raise
            except Exception as e:  # the reader is fuzz-tested; still, never let a file crash a render
                entry.error = f"{path}: cannot decode frame {frame} ({type(e).__name__}: {e})"
                raise HgsError(entry.error) from e
            params.flags.writeable = False
            self._frames[k] = params
            self._frame_bytes += params.nbytes
            while self._frame_bytes > self.max_frame_bytes and len(self._frames) > 1:
                self._frame_bytes -= self._frames.popitem(last=False)[1].nbytes
            return params

    def verify(self, path: str) -> HgsReader:
        """Open and decode every frame once (a damaged file is refused up front)."""
        with self._lock:
            entry = self._entry(path)
            try:
                entry.reader.verify()
            except HyperGSError as e:
                entry.error = str(e)
                raise
            return entry.reader

    def problem(self, path: str) -> str | None:
        """What is wrong with a file now, or None: checks that it exists, is unchanged or still opens,
        and reports the last decoding error seen for this version of the file."""
        with self._lock:
            try:
                return self._entry(path).error
            except HyperGSError as e:
                return str(e)

    def forget(self, path: str | None = None) -> None:
        """Drop one file (or all) and its frames: the next access reads it again."""
        with self._lock:
            if path is None:
                self._files.clear()
                self._frames.clear()
                self._frame_bytes = 0
            else:
                self._files.pop(path, None)
                self._drop_frames(path)

    @property
    def frame_bytes(self) -> int:
        """Bytes of decoded frames held now."""
        return self._frame_bytes
