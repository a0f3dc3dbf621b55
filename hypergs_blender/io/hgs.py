"""The .hgs container: a compressed GaussianVideo, written and read as a stream, with random access.

Layout (all integers little-endian; no pickle, nothing executable):

  header   fixed part (`_HEADER`): magic b"\\x89HGS\\r\\n\\x1a\\n", version, codec, canvas width and
           height, fps, N (Gaussians per frame), grid (columns, rows), frame count, group size,
           8 bit depths, 8 coding transforms (codec.TRANSFORMS), 8 (lo, hi) ranges as float64,
           offset of the frame index, length of the JSON part;
           then the JSON part (UTF-8 object: {"source": {...}, "writer": ...});
           then CRC32 of everything before it.
  chunks   one per group of up to `group_size` frames: b"HGSC", first frame, frame count, payload
           length, payload, CRC32 of the chunk header and payload.
  index    b"HGSI", chunk count, then per chunk (file offset, chunk length, first frame, frame count),
           then CRC32 of the index. The index runs to the end of the file.

Two codecs (the payloads, codec.py), one version each, so a reader that knows only version 1 says
"update the add-on" for the other instead of decoding garbage:
  QUANTIZED (version 1, codec field 0): quantized to the header's bit depths and ranges, residuals,
           ANS (codec.encode_group). Small, lossy; a frame decodes with the frames before it in its
           group. Exported clips.
  FLOAT16   (version 2, codec field 1): means float32, the rest float16, per-frame zlib
           (codec.encode_float16_group); the header's bits and ranges are unused. Visually lossless,
           about 2x the size, and any frame decodes alone in a few ms: the frame cache Blender reads
           on every frame change (io/cache.py), written with one frame per chunk.

The writer writes the header first (frame count 0, index offset 0), streams chunks as groups fill,
then writes the index and rewrites the header with the real frame count and index offset; it writes
a temporary file beside the output and renames it on success (files.AtomicOutput), so an interrupted
or failed write never leaves a half file under the final name nor touches the file there. The reader
checks every size against the file length, and the canvas, Gaussian, frame and metadata counts
against limits.py, before it allocates; it verifies each CRC before decoding, and raises HgsError (a
HyperGSError) for anything wrong: a damaged or truncated file, a wrong version, a file that is not
.hgs; LimitError for a clip past the limits.
"""
from __future__ import annotations

import io
import json
import math
import os
import struct
import tempfile
import zlib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import limits
from .codec import (ROTATION_PERIOD, TRANSFORMS, CodecError, Quantizer, clip_bits, decode_float16_group,
                    decode_group, encode_float16_group, encode_group)
from .files import AtomicOutput, StreamingWriter
from ..errors import HyperGSError
from ..gaussians import MAX_FPS, MAX_GRID, NUM_PARAMS, GaussianVideo

MAGIC = b"\x89HGS\r\n\x1a\n"
QUANTIZED, FLOAT16 = 0, 1  # codecs
CODECS = {"quantized": QUANTIZED, "float16": FLOAT16}
VERSIONS = {QUANTIZED: 1, FLOAT16: 2}  # the version a file of each codec has
VERSION = max(VERSIONS.values())  # the newest this reader reads
DEFAULT_GROUP_SIZE = 16
MAX_GROUP_SIZE = 64

_HEADER = struct.Struct("<8sHHIIdIHHIHH8B8B16dQI")
_CHUNK = struct.Struct("<4sIHHI")  # magic, first frame, frames, reserved, payload length
_INDEX = struct.Struct("<4sI")  # magic, chunk count
_ENTRY = struct.Struct("<QIII")  # offset, chunk length (header + payload + crc), first frame, frames
_CRC = struct.Struct("<I")
CHUNK_MAGIC, INDEX_MAGIC = b"HGSC", b"HGSI"
_MIN_CHUNK = _CHUNK.size + _CRC.size


class HgsError(HyperGSError):
    """A .hgs file that cannot be read: not .hgs, another version, truncated or damaged."""


@dataclass
class HgsHeader:
    canvas_width: int
    canvas_height: int
    fps: float
    num_gaussians: int
    grid: tuple[int, int]
    quantizer: Quantizer
    group_size: int = DEFAULT_GROUP_SIZE
    num_frames: int = 0
    index_offset: int = 0
    source: dict = field(default_factory=dict)
    codec: int = QUANTIZED
    json_bytes: bytes = b""

    @property
    def version(self) -> int:
        return VERSIONS[self.codec]

    def pack(self) -> bytes:
        if not self.json_bytes:
            try:
                self.json_bytes = json.dumps({"source": self.source, "writer": "hypergs-blender"},
                                             default=_json_default).encode()
            except (TypeError, ValueError) as e:
                raise HgsError(f"clip metadata cannot be stored: {e}") from e
        limits.METADATA.check(len(self.json_bytes), "clip metadata")
        ranges = [v for pair in zip(self.quantizer.lo, self.quantizer.hi) for v in pair]
        codec = self.codec if self.version > 1 else 0
        fixed = _HEADER.pack(MAGIC, self.version, codec, self.canvas_width, self.canvas_height, float(self.fps),
                             self.num_gaussians, self.grid[0], self.grid[1], self.num_frames, self.group_size, 0,
                             *self.quantizer.bits, *TRANSFORMS, *ranges, self.index_offset, len(self.json_bytes))
        body = fixed + self.json_bytes
        return body + _CRC.pack(zlib.crc32(body))

    @property
    def size(self) -> int:
        return _HEADER.size + len(self.json_bytes) + _CRC.size

    @classmethod
    def read(cls, f, file_size: int) -> "HgsHeader":
        fixed = f.read(_HEADER.size)
        if len(fixed) < len(MAGIC) or fixed[:len(MAGIC)] != MAGIC:
            raise HgsError("not a .hgs Gaussian video file (wrong magic bytes)")
        if len(fixed) >= 10:
            (version,) = struct.unpack_from("<H", fixed, 8)
            if version not in VERSIONS.values():
                newer = " (written by a newer HyperGS: update the add-on)" if version > VERSION else ""
                raise HgsError(f"unsupported .hgs version {version}; this reader reads versions "
                               f"{', '.join(map(str, sorted(VERSIONS.values())))}{newer}")
        if len(fixed) < _HEADER.size:
            raise HgsError("file is truncated inside the header")
        v = _HEADER.unpack(fixed)
        (_, version, codec, cw, ch, fps, n, gc, gr, frames, group, _res), rest = v[:12], v[12:]
        codec = QUANTIZED if version == 1 else codec  # version 1's field was unused
        bits, transforms, ranges = rest[:8], rest[8:16], rest[16:32]
        index_offset, json_len = rest[32], rest[33]
        if _HEADER.size + json_len + _CRC.size > file_size:
            raise HgsError(f"damaged header: metadata length {json_len} does not fit the file")
        limits.METADATA.check(json_len, "header")
        json_bytes = f.read(json_len)
        crc = f.read(_CRC.size)
        if len(json_bytes) != json_len or len(crc) != _CRC.size:
            raise HgsError("file is truncated inside the header")
        if _CRC.unpack(crc)[0] != zlib.crc32(fixed + json_bytes):
            raise HgsError("damaged header (checksum mismatch)")
        problems = []
        if VERSIONS.get(codec) != version:
            problems.append(f"codec {codec} in a version {version} file")
        if not (cw >= 1 and ch >= 1):
            problems.append(f"canvas {cw}x{ch}")
        if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
            problems.append(f"fps {fps}")
        if not n >= 1:
            problems.append(f"{n} Gaussians per frame")
        if not (1 <= gc <= MAX_GRID and 1 <= gr <= MAX_GRID):
            problems.append(f"grid {gc}x{gr}")
        if not 1 <= group <= MAX_GROUP_SIZE:
            problems.append(f"group size {group}")
        if tuple(transforms) != TRANSFORMS:
            problems.append(f"parameter transforms {transforms}")
        if problems:
            raise HgsError("damaged or unsupported header: " + ", ".join(problems))
        limits.check_image_size(cw, ch, "canvas")
        limits.GAUSSIANS.check(n, "header")
        limits.FRAMES.check(frames, "header")
        try:
            quantizer = Quantizer(bits, ranges[0::2], ranges[1::2])
            meta = json.loads(json_bytes.decode("utf-8"))
        except (CodecError, ValueError, RecursionError) as e:
            raise HgsError(f"damaged header: {e}") from e
        source = meta.get("source", {}) if isinstance(meta, dict) else None
        if not isinstance(source, dict):
            raise HgsError("damaged header: metadata is not a JSON object")
        return cls(cw, ch, fps, n, (gc, gr), quantizer, group, frames, index_offset, source, codec, json_bytes)


def _json_default(value):
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, (Path, tuple)):
        return str(value) if isinstance(value, Path) else list(value)
    raise TypeError(f"cannot store {type(value).__name__} in .hgs metadata")


class HgsWriter(StreamingWriter):
    """Streaming .hgs writer: `write(params)` any number of frames at a time; memory holds one group.

        with HgsWriter(path, 256, 256, 1000, Quantizer.fit(params, 8)) as w:
            w.write(params)

    codec: "quantized" or "float16" (see the module doc; zlib_level 0 stores float16 frames uncompressed).
    quantizer (quantized only): the ranges go into the header before any frame is seen; `Quantizer.fit`
    on the whole clip when you have it, `Quantizer.default(w, h, bits)` otherwise. Values outside the
    ranges (quantized) or float16's (float16) are clipped and counted in `clipped`. On an exception inside
    `with`, or `abort()`, the partial file is removed and the file at `path`, if any, stays as it was."""

    def __init__(self, path, canvas_width: int, canvas_height: int, num_gaussians: int,
                 quantizer: Quantizer | None = None, fps: float = 24.0, grid=(1, 1), source: dict | None = None,
                 group_size: int = DEFAULT_GROUP_SIZE, mode: str = "auto", bits=8, codec: str = "quantized",
                 zlib_level: int = 1):
        if codec not in CODECS:
            raise HgsError(f"unknown .hgs codec {codec!r} (use {' or '.join(CODECS)})")
        if not 1 <= group_size <= MAX_GROUP_SIZE:
            raise HgsError(f"group size must be in 1..{MAX_GROUP_SIZE}, got {group_size}")
        if num_gaussians < 1:
            raise HgsError(f"a .hgs clip holds at least one Gaussian per frame, got {num_gaussians}")
        limits.GAUSSIANS.check(num_gaussians, str(path))
        limits.check_image_size(canvas_width, canvas_height, f"{path}: canvas")
        if not (math.isfinite(fps) and 0 < fps <= MAX_FPS):
            raise HgsError(f"fps {fps} out of range")
        grid = tuple(int(g) for g in grid)
        if len(grid) != 2 or not all(1 <= g <= MAX_GRID for g in grid):
            raise HgsError(f"grid {grid} out of range")
        self.path = Path(path)
        if CODECS[codec] == FLOAT16:  # the header's bits and ranges are unused: valid placeholders
            quantizer = Quantizer(16, (0.0,) * 8, (0.0,) * 4 + (ROTATION_PERIOD,) + (0.0,) * 3)
        quantizer = quantizer or Quantizer.default(canvas_width, canvas_height,
                                                   clip_bits(bits, canvas_width, canvas_height,
                                                             num_gaussians))
        self.header = HgsHeader(int(canvas_width), int(canvas_height), float(fps), int(num_gaussians), grid,
                                quantizer, int(group_size), source=dict(source or {}), codec=CODECS[codec])
        self.mode = mode
        self.zlib_level = zlib_level  # the float16 codec's (codec.encode_float16_group)
        self.clipped = 0
        self._pending: list[np.ndarray] = []  # quantized frames of the group being filled
        self._entries: list[tuple[int, int, int, int]] = []
        header = self.header.pack()
        self._output = AtomicOutput(self.path, streamed=True)
        self._file = self._output.open()
        self._write(header)
        self._offset = len(header)

    def _write(self, data: bytes) -> None:
        try:
            self._file.write(data)
        except OSError as e:
            self.abort()
            raise HgsError(f"{self.path}: cannot write ({e.strerror})") from None

    @property
    def num_frames(self) -> int:
        return sum(e[3] for e in self._entries) + len(self._pending)

    def write(self, params: np.ndarray) -> None:
        """Append frames: float [T, N, 8] or one frame [N, 8]."""
        if self._file is None:
            raise HgsError("writer is closed")
        params = np.asarray(params, dtype=np.float32)
        if params.ndim == 2:
            params = params[None]
        n = self.header.num_gaussians
        if params.ndim != 3 or params.shape[1:] != (n, NUM_PARAMS):
            raise HgsError(f"expected frames of [{n}, {NUM_PARAMS}] parameters, got {params.shape}")
        if self.header.codec == FLOAT16:
            q = params  # checked and converted when its group is written
        else:
            try:
                q, clipped = self.header.quantizer.quantize(params)
            except CodecError as e:
                raise HgsError(str(e)) from e
            self.clipped += clipped
        for frame in q:
            self._pending.append(frame)
            if len(self._pending) == self.header.group_size:
                self._flush()

    def _flush(self) -> None:
        if not self._pending:
            return
        first = self.num_frames - len(self._pending)
        if self.header.codec == FLOAT16:
            try:
                payload, clipped = encode_float16_group(np.stack(self._pending), self.zlib_level)
            except CodecError as e:
                raise HgsError(str(e)) from e
            self.clipped += clipped
        else:
            payload = encode_group(np.stack(self._pending), self.header.quantizer.bits, self.mode)
        if len(payload) >= 1 << 32:
            raise HgsError("a group is too large for the .hgs format; use a smaller group size")
        head = _CHUNK.pack(CHUNK_MAGIC, first, len(self._pending), 0, len(payload))
        chunk = head + payload + _CRC.pack(zlib.crc32(payload, zlib.crc32(head)))
        self._write(chunk)
        self._entries.append((self._offset, len(chunk), first, len(self._pending)))
        self._offset += len(chunk)
        self._pending = []

    def close(self) -> None:
        """Write the last group and the index, then move the file into place."""
        if self._file is None:
            return
        try:
            self._flush()
            index = _INDEX.pack(INDEX_MAGIC, len(self._entries)) + b"".join(_ENTRY.pack(*e) for e in self._entries)
            self._write(index + _CRC.pack(zlib.crc32(index)))
            self.header.num_frames = sum(e[3] for e in self._entries)
            self.header.index_offset = self._offset
            self._file.seek(0)
            self._file.write(self.header.pack())
        except OSError as e:
            self.abort()
            raise HgsError(f"{self.path}: cannot write ({e.strerror})") from None
        except BaseException:
            self.abort()
            raise
        self._file = None
        self._output.commit()

    def abort(self) -> None:
        """Stop without producing a file (the file at the path, if any, stays as it was)."""
        self._file = None
        self._output.discard()


class HgsReader:
    """Random-access .hgs reader. Opening reads and checks the header and the frame index only;
    frames are decoded on demand, one group at a time (`read_frame`, `iter_frames`), and reading the
    frames of a group in order decodes each frame once. Not thread-safe: one reader per thread."""

    def __init__(self, source):
        """source: a path, the bytes of a .hgs file (e.g. a clip packed inside a .blend), or a binary
        file object (read, seek, close; its `name` names it in errors), which the reader then owns."""
        if isinstance(source, (bytes, bytearray, memoryview)):
            self.path = Path("<bytes>")
            self._file = io.BytesIO(bytes(source))
        elif hasattr(source, "read"):
            self.path = Path(getattr(source, "name", "<file>"))
            self._file = source
        else:
            self.path = Path(source)
            try:
                self._file = open(self.path, "rb")
            except FileNotFoundError:
                raise HgsError(f"{self.path}: no such file") from None
            except OSError as e:
                raise HgsError(f"{self.path}: cannot open ({e.strerror})") from e
        try:
            self.file_size = self._file.seek(0, os.SEEK_END)
            self._file.seek(0)
            self.header = HgsHeader.read(self._file, self.file_size)
            self._entries = self._read_index()
        except HyperGSError as e:  # HgsError, LimitError
            self._file.close()
            raise type(e)(f"{self.path}: {e}") from None
        except BaseException:
            self._file.close()
            raise
        self._cursor = None  # (chunk number, next frame within it, frame generator)
        self._last = None  # (frame, params) of the frame read last

    # header shortcuts
    canvas_width = property(lambda self: self.header.canvas_width)
    canvas_height = property(lambda self: self.header.canvas_height)
    fps = property(lambda self: self.header.fps)
    num_gaussians = property(lambda self: self.header.num_gaussians)
    num_frames = property(lambda self: self.header.num_frames)
    grid = property(lambda self: self.header.grid)
    source = property(lambda self: self.header.source)
    codec = property(lambda self: next(name for name, c in CODECS.items() if c == self.header.codec))
    quantizer = property(lambda self: self.header.quantizer)

    def _read_index(self) -> list[tuple[int, int, int, int]]:
        h = self.header
        if h.index_offset == 0:
            raise HgsError("incomplete file: the writer did not finish (no frame index)")
        if not h.size <= h.index_offset <= self.file_size - _INDEX.size - _CRC.size:
            raise HgsError("damaged file: frame index offset outside the file")
        self._file.seek(h.index_offset)
        head = self._file.read(_INDEX.size)
        magic, count = _INDEX.unpack(head)
        if magic != INDEX_MAGIC:
            raise HgsError("damaged file: no frame index where the header says")
        if _INDEX.size + count * _ENTRY.size + _CRC.size != self.file_size - h.index_offset:
            raise HgsError("damaged or truncated file: frame index size does not match the file size")
        body = self._file.read(count * _ENTRY.size)
        (crc,) = _CRC.unpack(self._file.read(_CRC.size))
        if crc != zlib.crc32(body, zlib.crc32(head)):
            raise HgsError("damaged file: frame index checksum mismatch")
        entries = [_ENTRY.unpack_from(body, i * _ENTRY.size) for i in range(count)]
        offset, frame = h.size, 0
        for off, length, first, frames in entries:
            if off != offset or length < _MIN_CHUNK or first != frame or not 1 <= frames <= h.group_size:
                raise HgsError("damaged file: inconsistent frame index")
            offset, frame = off + length, frame + frames
        if offset != h.index_offset or frame != h.num_frames:
            raise HgsError("damaged file: frame index does not cover the clip")
        return entries

    def _payload(self, chunk: int) -> bytes:
        off, length, first, frames = self._entries[chunk]
        self._file.seek(off)
        data = self._file.read(length)  # length is bounded by the file size (checked in _read_index)
        if len(data) != length:
            raise HgsError(f"{self.path}: file is truncated (changed while open?)")
        magic, c_first, c_frames, _, payload_len = _CHUNK.unpack_from(data)
        if magic != CHUNK_MAGIC or c_first != first or c_frames != frames or payload_len != length - _MIN_CHUNK:
            raise HgsError(f"{self.path}: damaged chunk for frames {first}..{first + frames - 1}")
        (crc,) = _CRC.unpack_from(data, length - _CRC.size)
        if crc != zlib.crc32(data[:length - _CRC.size]):
            raise HgsError(f"{self.path}: damaged chunk for frames {first}..{first + frames - 1} (checksum mismatch)")
        return data[_CHUNK.size:length - _CRC.size]

    def _chunk_of(self, frame: int) -> int:
        lo, hi = 0, len(self._entries) - 1
        while lo < hi:
            mid = (lo + hi + 1) // 2
            if self._entries[mid][2] <= frame:
                lo = mid
            else:
                hi = mid - 1
        return lo

    def _group_frames(self, chunk: int) -> Iterator[np.ndarray]:
        _, _, first, frames = self._entries[chunk]
        payload = self._payload(chunk)
        h = self.header
        try:
            if h.codec == FLOAT16:
                yield from decode_float16_group(payload, frames, h.num_gaussians)
            else:
                for q in decode_group(payload, frames, h.num_gaussians, h.quantizer.bits):
                    yield h.quantizer.dequantize(q)
        except CodecError as e:
            raise HgsError(f"{self.path}: frames {first}..{first + frames - 1}: {e}") from None

    def read_frame(self, frame: int) -> np.ndarray:
        """float32 [N, 8] parameters of one frame (0-based)."""
        frame = int(frame)
        if not 0 <= frame < self.num_frames:
            raise HgsError(f"{self.path}: frame {frame} is outside the clip's {self.num_frames} frames")
        if self._file is None:
            raise HgsError(f"{self.path}: reader is closed")
        if self._last is not None and self._last[0] == frame:
            return self._last[1].copy()
        chunk = self._chunk_of(frame)
        first = self._entries[chunk][2]
        if self._cursor is None or self._cursor[0] != chunk or self._cursor[1] > frame - first:
            self._cursor = [chunk, 0, self._group_frames(chunk)]
        try:
            while True:
                params = next(self._cursor[2])
                self._cursor[1] += 1
                if self._cursor[1] > frame - first:
                    break
        except BaseException:
            self._cursor = None
            raise
        self._last = (frame, params)
        return params.copy()

    def iter_frames(self, start: int = 0, stop: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
        """Yield (frame, float32 [N, 8]) for frames [start, stop), decoding each group once."""
        stop = self.num_frames if stop is None else min(stop, self.num_frames)
        for frame in range(max(0, start), stop):
            yield frame, self.read_frame(frame)

    def read_frames(self, start: int = 0, stop: int | None = None) -> np.ndarray:
        """float32 [T, N, 8] for frames [start, stop); refuses more than limits.BYTES of output (read
        frame by frame then)."""
        stop = self.num_frames if stop is None else min(stop, self.num_frames)
        count = max(0, stop - max(0, start))
        limits.check_clip_size(count, self.num_gaussians, str(self.path))
        out = np.empty((count, self.num_gaussians, NUM_PARAMS), np.float32)
        for i, (_, params) in enumerate(self.iter_frames(start, stop)):
            out[i] = params
        return out

    def read_all(self) -> GaussianVideo:
        return GaussianVideo(self.read_frames(), self.canvas_width, self.canvas_height,
                             self.fps, self.grid, dict(self.source))

    def verify(self) -> None:
        """Check every chunk's checksum and decode it; raises HgsError on the first problem."""
        for chunk in range(len(self._entries)):
            for _ in self._group_frames(chunk):
                pass

    def info(self) -> dict:
        h, q = self.header, self.header.quantizer
        names = ("x", "y", "scale_x", "scale_y", "rotation", "r", "g", "b")
        ranges = {}
        for p, name in enumerate(names):
            lo, hi = q.lo[p], q.hi[p]
            if p in (2, 3):
                lo, hi = math.exp(lo), math.exp(hi)
            ranges[name] = [lo, hi]
        quantized = h.codec == QUANTIZED
        chunk_bytes = [e[1] for e in self._entries]
        frame_pixels = h.canvas_width * h.canvas_height * max(1, h.num_frames)
        return {
            "path": str(self.path), "format": "hgs", "version": h.version, "file_bytes": self.file_size,
            "canvas": [h.canvas_width, h.canvas_height], "fps": h.fps, "num_frames": h.num_frames,
            "duration_s": h.num_frames / h.fps, "num_gaussians": h.num_gaussians, "grid": list(h.grid),
            "codec": self.codec, **({"bits": list(q.bits), "ranges": ranges} if quantized else {}),
            "group_size": h.group_size, "groups": len(self._entries),
            "group_bytes": {"min": min(chunk_bytes, default=0), "max": max(chunk_bytes, default=0)},
            "bits_per_gaussian": 8 * self.file_size / max(1, h.num_frames * h.num_gaussians),
            "bpp_at_canvas": 8 * self.file_size / frame_pixels,
            "source": h.source,
        }

    def close(self) -> None:
        if self._file is not None:
            self._file.close()
            self._file = None
        self._cursor = self._last = None

    def __enter__(self) -> "HgsReader":
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def save_hgs(video: GaussianVideo, path, bits=8, group_size: int = DEFAULT_GROUP_SIZE, mode: str = "auto",
             quantizer: Quantizer | None = None, codec: str = "quantized") -> int:
    """Write a whole clip (quantized: ranges fitted to it unless a quantizer is given); returns the file
    size."""
    if video.num_frames == 0:
        raise HgsError("cannot save an empty clip (no frames)")
    if codec == "quantized":
        try:
            quantizer = quantizer or Quantizer.fit(video.params, clip_bits(bits, video.canvas_width,
                                                                           video.canvas_height, video.num_gaussians))
        except CodecError as e:
            raise HgsError(str(e)) from e
    with HgsWriter(path, video.canvas_width, video.canvas_height, video.num_gaussians, quantizer, video.fps,
                   video.grid, video.source, group_size, mode, codec=codec) as writer:
        for start in range(0, video.num_frames, group_size):
            writer.write(video.params[start:start + group_size])
    return Path(path).stat().st_size


def load_hgs(source) -> GaussianVideo:
    """A whole clip from a .hgs path or the bytes of one."""
    with HgsReader(source) as reader:
        return reader.read_all()


def hgs_bytes(video: GaussianVideo, bits=8, group_size: int = DEFAULT_GROUP_SIZE, mode: str = "auto") -> bytes:
    """The .hgs file of a clip as bytes (to pack inside another file, e.g. a .blend)."""
    with tempfile.TemporaryDirectory(prefix="hypergs-") as tmp:
        path = Path(tmp) / "clip.hgs"
        save_hgs(video, path, bits, group_size, mode)
        return path.read_bytes()
