"""Gaussian-video codec: per-parameter quantization, cross-frame residuals, ANS entropy coding.

Quantization (`Quantizer`): each of the 8 parameters gets `bits` bits (8, 6 or 4 usually) over a
range stored in the .hgs header. The range is taken in a per-parameter domain:
  - mean x, y and colour r, g, b: linear, q = round((v - lo) / step), step = (hi - lo) / (2^bits - 1);
  - scale x, y: log(scale), so the relative error is the same for small and large Gaussians (and a
    decoded scale is always > 0);
  - rotation: an angle modulo pi (the covariance R diag(s^2) R^T does not change when the rotation
    turns by pi), q = round(theta / pi * 2^bits) mod 2^bits. Decoded rotations lie in [0, pi).
Decoding is within half a step of the input in that domain (`Quantizer.max_error`).

Residuals (`encode_group` / `decode_group`): a group is up to `group_size` consecutive frames. For every
frame and parameter, the quantized values are coded as one of
  INTRA     the values themselves (frame 0 of a group is always INTRA: the group's anchor);
  ANCHOR    the residual to the group's latest INTRA frame of that parameter (the HyperGS scheme);
  PREVIOUS  the residual to the previous (reconstructed, i.e. quantized) frame.
Residuals are taken modulo 2^bits and centred, so they stay in a 2^bits alphabet and decoding is exact
in the quantized domain. The choice is made per frame and parameter to minimise the coded size
(`mode="auto"`), or forced for comparisons. Each (parameter, kind) stream used in a group has its own
symbol histogram (stored as 8-bit counts over the used symbol span), and all symbols of the group go
through one ANS coder (constriction's `AnsCoder` with `Categorical(perfect=False)` models), in frame
order, so a reader can decode a group one frame at a time in O(N) memory.

The float16 payload (`encode_float16_group`, the frame cache's) is described at its code.

This module is numpy + constriction + zlib only (no torch, no bpy).
"""
from __future__ import annotations

import math
import struct
import zlib
from dataclasses import dataclass
from typing import Iterator

import numpy as np

from ..errors import HyperGSError
from ..gaussians import NUM_PARAMS, param_problem

LINEAR, LOG, ANGLE = 0, 1, 2
TRANSFORMS = (LINEAR, LINEAR, LOG, LOG, ANGLE, LINEAR, LINEAR, LINEAR)  # per parameter, fixed by the format
ROTATION_PERIOD = math.pi
INTRA, ANCHOR, PREVIOUS = 0, 1, 2
KINDS = (INTRA, ANCHOR, PREVIOUS)
MODES = ("auto", "intra", "anchor", "previous")
MAX_BITS = 16
LINEAR_LIMIT = 1e30  # ranges stay inside +-this (so steps are finite)
LOG_LIMIT = 69.0  # log-scale ranges: scales between 1e-30 and 1e30 pixels


class CodecError(HyperGSError):
    """Data that cannot be coded, or a coded group that is damaged."""


def _bits_tuple(bits) -> tuple[int, ...]:
    if isinstance(bits, (int, np.integer)):
        bits = (int(bits),) * NUM_PARAMS
    bits = tuple(int(b) for b in bits)
    if len(bits) != NUM_PARAMS or not all(1 <= b <= MAX_BITS for b in bits):
        raise CodecError(f"bits must be an integer in 1..{MAX_BITS} or {NUM_PARAMS} of them, got {bits}")
    return bits


# The means' quantization step, at most: MEAN_STEP_PX canvas pixels and MEAN_STEP_CELL of the Gaussians'
# spacing (see clip_bits). The spacing is what sets the error: on held-out 1280x720 pans at 864x480-like
# canvases (cells of 4-6 px) a step of 1/27 cell cost 1-4 dB against the float clip, 1/55 0.3-2, 1/109
# 0.1-0.9, each halving about 7 % more bytes.
MEAN_STEP_PX = 0.25
MEAN_STEP_CELL = 0.01


def clip_bits(bits, canvas_width: int, canvas_height: int, gaussians: int | None = None) -> tuple[int, ...]:
    """The bit depths of a clip of `gaussians` per frame on a canvas_width x canvas_height canvas: one
    depth for every parameter (`bits` an integer) except the means, which get enough bits for steps of
    at most MEAN_STEP_PX and MEAN_STEP_CELL of the spacing sqrt(width x height / gaussians) over the
    default range (1.25 canvas half-widths either side): a fixed depth would move the means of a large
    canvas by pixels (8 bits on a 1280 px canvas: 5 px steps, 39 -> 22 dB), and a step that is large
    next to the Gaussians blurs a fine clip (quarter-pixel steps at 4 px cells: 46.9 -> 42.6 dB).
    Explicit depths (8 of them) are kept as given."""
    if not isinstance(bits, (int, np.integer)):
        return _bits_tuple(bits)
    step = MEAN_STEP_PX
    if gaussians:
        step = min(step, MEAN_STEP_CELL * math.sqrt(canvas_width * canvas_height / gaussians))
    means = [min(MAX_BITS, max(int(bits), math.ceil(math.log2(2.5 * side / 2 / step + 1))))
             for side in (canvas_width, canvas_height)]
    return _bits_tuple(tuple(means) + (int(bits),) * (NUM_PARAMS - 2))


@dataclass(frozen=True)
class Quantizer:
    """Per-parameter bit depths and [lo, hi] ranges (in each parameter's coding domain, see module doc).

    For the rotation, lo and hi are unused (0, pi)."""

    bits: tuple[int, ...]
    lo: tuple[float, ...]
    hi: tuple[float, ...]

    def __post_init__(self):
        object.__setattr__(self, "bits", _bits_tuple(self.bits))
        lo, hi = tuple(float(v) for v in self.lo), tuple(float(v) for v in self.hi)
        if len(lo) != NUM_PARAMS or len(hi) != NUM_PARAMS:
            raise CodecError(f"a quantizer needs {NUM_PARAMS} ranges")
        limits = [LOG_LIMIT if t == LOG else LINEAR_LIMIT for t in TRANSFORMS]
        if not all(-m <= a <= b <= m for a, b, m in zip(lo, hi, limits)):  # also rejects NaN
            raise CodecError(f"invalid quantizer ranges lo={lo} hi={hi}")
        object.__setattr__(self, "lo", lo)
        object.__setattr__(self, "hi", hi)

    @classmethod
    def fit(cls, params, bits=8) -> "Quantizer":
        """Ranges that just cover `params` [..., N, 8], or an iterable of such arrays (e.g. a clip's frames
        read one at a time from its cache): every value is then within half a step."""
        lo, hi = np.zeros(NUM_PARAMS), np.zeros(NUM_PARAMS)
        seen = False
        for part in [params] if isinstance(params, np.ndarray) else params:
            check_params(part)
            flat = to_domain(np.asarray(part).reshape(-1, NUM_PARAMS))
            if flat.shape[0]:
                lo = np.minimum(lo, flat.min(axis=0)) if seen else flat.min(axis=0)
                hi = np.maximum(hi, flat.max(axis=0)) if seen else flat.max(axis=0)
                seen = True
        limits = np.array([LOG_LIMIT if t == LOG else LINEAR_LIMIT for t in TRANSFORMS])
        lo, hi = np.clip(lo, -limits, limits), np.clip(hi, -limits, limits)  # values past them get clipped
        lo[4], hi[4] = 0.0, ROTATION_PERIOD
        return cls(bits, tuple(lo), tuple(hi))

    @classmethod
    def default(cls, canvas_width: int, canvas_height: int, bits=8) -> "Quantizer":
        """Ranges for a streaming writer that has not seen the data: means a little past the canvas,
        scales from 1/8 pixel to the canvas size, colours in [-1, 2]. Values outside are clipped."""
        big = float(max(canvas_width, canvas_height))
        lo = (-1.25, -1.25, math.log(0.125), math.log(0.125), 0.0, -1.0, -1.0, -1.0)
        hi = (1.25, 1.25, math.log(big), math.log(big), ROTATION_PERIOD, 2.0, 2.0, 2.0)
        return cls(bits, lo, hi)

    @property
    def levels(self) -> np.ndarray:
        return np.array([1 << b for b in self.bits], np.int64)

    @property
    def steps(self) -> np.ndarray:
        """Step between neighbouring levels, per parameter, in the coding domain."""
        levels = self.levels
        steps = (np.array(self.hi) - np.array(self.lo)) / np.maximum(levels - 1, 1)
        steps[4] = ROTATION_PERIOD / levels[4]
        return steps

    def max_error(self) -> np.ndarray:
        """Largest decoding error per parameter in the coding domain (for the rotation: the circular
        distance modulo pi; for scales: |log(decoded) - log(input)|), for values inside the ranges."""
        return self.steps / 2

    def quantize(self, params: np.ndarray) -> tuple[np.ndarray, int]:
        """params [..., 8] float -> (int32 levels [..., 8], number of values clipped to the ranges)."""
        check_params(params)
        d = to_domain(params)
        levels, lo, steps = self.levels, np.array(self.lo), self.steps
        q = np.empty(d.shape, np.int64)
        for p in range(NUM_PARAMS):
            if TRANSFORMS[p] == ANGLE:
                q[..., p] = np.round(d[..., p] / steps[p]).astype(np.int64) % levels[p]
            elif steps[p] == 0:  # a one-value range: anything else is clipped to it (and counted)
                q[..., p] = np.sign(d[..., p] - lo[p]).astype(np.int64) * levels[p]
            else:
                q[..., p] = np.round((d[..., p] - lo[p]) / steps[p]).astype(np.int64)
        clipped = q < 0
        clipped |= q >= levels
        np.clip(q, 0, levels - 1, out=q)
        return q.astype(np.int32), int(clipped.sum())

    def dequantize(self, q: np.ndarray) -> np.ndarray:
        """int levels [..., 8] -> float32 params [..., 8] (computed per parameter in float64)."""
        out = np.empty(q.shape, np.float32)
        steps = self.steps
        for p in range(NUM_PARAMS):
            lo = 0.0 if TRANSFORMS[p] == ANGLE else self.lo[p]
            d = lo + q[..., p].astype(np.float64) * steps[p]
            out[..., p] = np.exp(d) if TRANSFORMS[p] == LOG else d
        return out


def check_params(params: np.ndarray) -> None:
    problem = param_problem(params)
    if problem:
        raise CodecError(problem)


def to_domain(params: np.ndarray) -> np.ndarray:
    """float64 copy of params [..., 8] in the coding domain (log scales, rotation modulo pi)."""
    d = np.array(params, dtype=np.float64)
    d[..., 2:4] = np.log(d[..., 2:4])
    d[..., 4] = np.mod(d[..., 4], ROTATION_PERIOD)
    return d


# ---- residuals and entropy coding ------------------------------------------------------------------

def _centre(r: np.ndarray, level: int) -> np.ndarray:
    """Residual modulo `level`, as a signed value in [-level/2, level/2)."""
    half = level // 2
    return (r + half) % level - half


def _candidate_symbols(q: np.ndarray, level: int, p: int, f: int, anchor: np.ndarray) -> dict:
    cands = {INTRA: q[f, :, p].astype(np.int64)}
    if f > 0:
        cands[ANCHOR] = _centre(q[f, :, p].astype(np.int64) - anchor, level)
        cands[PREVIOUS] = _centre(q[f, :, p].astype(np.int64) - q[f - 1, :, p], level)
    return cands


def _table(symbols: np.ndarray) -> tuple[int, np.ndarray]:
    """(first symbol, uint8 counts over [first, last]) for the symbols; max count scaled to 255."""
    lo, hi = int(symbols.min()), int(symbols.max())
    counts = np.bincount(symbols - lo, minlength=hi - lo + 1).astype(np.float64)
    scaled = np.where(counts > 0, np.maximum(1, np.round(counts * 255 / counts.max())), 0)
    return lo, scaled.astype(np.uint8)


def _table_bits(counts: np.ndarray) -> np.ndarray:
    """Code length in bits of each symbol of a table (what the ANS coder will spend, approximately)."""
    p = counts.astype(np.float64) / counts.sum()
    return np.where(p > 0, -np.log2(np.maximum(p, 1e-300)), 24.0)


def _choose_kinds(q: np.ndarray, levels: np.ndarray, mode: str) -> np.ndarray:
    """[G, 8] reference kind per frame and parameter."""
    g = q.shape[0]
    kinds = np.zeros((g, NUM_PARAMS), np.uint8)
    if mode == "intra" or g == 1:
        return kinds
    if mode in ("anchor", "previous"):
        kinds[1:] = ANCHOR if mode == "anchor" else PREVIOUS
        return kinds
    for p in range(NUM_PARAMS):
        # Greedy in frame order (a later frame's ANCHOR depends on the latest INTRA), costing each
        # candidate by its empirical entropy; then refine with shared per-kind tables (k-means style).
        anchor = q[0, :, p].astype(np.int64)
        for f in range(1, g):
            cands = _candidate_symbols(q, int(levels[p]), p, f, anchor)
            costs = {k: _entropy_bits(s) for k, s in cands.items()}
            kinds[f, p] = min(costs, key=costs.get)
            if kinds[f, p] == INTRA:
                anchor = q[f, :, p].astype(np.int64)
        for _ in range(2):
            streams = _streams(q, kinds, levels, p)
            tables = {k: _table(np.concatenate(s)) for k, s in streams.items()}
            anchor = q[0, :, p].astype(np.int64)
            for f in range(1, g):
                cands = _candidate_symbols(q, int(levels[p]), p, f, anchor)
                costs = {}
                for k, s in cands.items():
                    if k in tables:
                        lo, counts = tables[k]
                        inside = (s >= lo) & (s < lo + len(counts))
                        if inside.all():
                            costs[k] = float(_table_bits(counts)[s - lo].sum())
                            continue
                    costs[k] = _entropy_bits(s) + 8.0 * _span(s)  # would need its own (wider) table
                kinds[f, p] = min(costs, key=costs.get)
                if kinds[f, p] == INTRA:
                    anchor = q[f, :, p].astype(np.int64)
    return kinds


def _span(s: np.ndarray) -> int:
    return int(s.max() - s.min() + 1)


def _entropy_bits(s: np.ndarray) -> float:
    counts = np.bincount(s - s.min())
    counts = counts[counts > 0].astype(np.float64)
    return float(-(counts * np.log2(counts / counts.sum())).sum())


def _streams(q: np.ndarray, kinds: np.ndarray, levels: np.ndarray, p: int) -> dict:
    """{kind: [symbols of each frame coded with that kind]} for parameter p."""
    streams: dict = {}
    anchor = None
    for f in range(q.shape[0]):
        kind = int(kinds[f, p])
        cur = q[f, :, p].astype(np.int64)
        if kind == INTRA:
            anchor, sym = cur, cur
        else:
            ref = anchor if kind == ANCHOR else q[f - 1, :, p]
            sym = _centre(cur - ref, int(levels[p]))
        streams.setdefault(kind, []).append(sym)
    return streams


_TABLE_HEAD = struct.Struct("<iI")  # first symbol, span
_WORDS_HEAD = struct.Struct("<I")  # number of 32-bit ANS words


def encode_group(q: np.ndarray, bits, mode: str = "auto") -> bytes:
    """Quantized levels int [G, N, 8] (each in [0, 2^bits)) -> the group's payload bytes.

    mode "auto" codes the group with the per-frame choice of references and with each single kind
    (all INTRA, all ANCHOR, all PREVIOUS) and keeps the smallest; the others force one kind.

    Payload: kinds uint8 [G, 8]; then for each parameter and each kind it uses (INTRA, ANCHOR,
    PREVIOUS order) a table: int32 first symbol, uint32 span, span uint8 counts (none when span is 1:
    the stream is constant and costs nothing more); then uint32 word count and the ANS words."""
    if mode not in MODES:
        raise CodecError(f"unknown residual mode {mode!r} (use one of {', '.join(MODES)})")
    levels = np.array([1 << b for b in _bits_tuple(bits)], np.int64)
    q = np.asarray(q)
    if q.ndim != 3 or q.shape[2] != NUM_PARAMS or q.shape[0] < 1:
        raise CodecError(f"a group must be [frames, N, {NUM_PARAMS}] levels, got {q.shape}")
    if q.size and (q.min() < 0 or np.any(q.max(axis=(0, 1)) >= levels)):
        raise CodecError("quantized levels out of range")
    if q.shape[1] == 0 or q.shape[0] == 1:
        return _encode_kinds(q, levels, np.zeros((q.shape[0], NUM_PARAMS), np.uint8))
    candidates = [mode] if mode != "auto" else MODES
    return min((_encode_kinds(q, levels, _choose_kinds(q, levels, m)) for m in candidates), key=len)


def _encode_kinds(q: np.ndarray, levels: np.ndarray, kinds: np.ndarray) -> bytes:
    import constriction

    g, n = q.shape[:2]
    out = [kinds.tobytes()]
    coded = []  # (frame, param) -> (symbols in [0, span), model) for the streams that need coding
    for p in range(NUM_PARAMS):
        streams = _streams(q, kinds, levels, p)
        tables = {}
        for kind in KINDS:
            if kind in streams:
                lo, counts = _table(np.concatenate(streams[kind])) if n else (0, np.zeros(1, np.uint8))
                out.append(_TABLE_HEAD.pack(lo, len(counts)))
                model = None
                if len(counts) > 1:
                    out.append(counts.tobytes())
                    model = constriction.stream.model.Categorical(counts.astype(np.float64), perfect=False)
                tables[kind] = (lo, model)
        for kind, frames in streams.items():
            lo, model = tables[kind]
            if model is not None:
                for f, sym in zip(np.flatnonzero(kinds[:, p] == kind), frames):
                    coded.append((int(f), p, (sym - lo).astype(np.int32), model))
    ans = constriction.stream.stack.AnsCoder()
    for _, _, sym, model in sorted(coded, key=lambda c: (c[0], c[1]), reverse=True):
        ans.encode_reverse(sym, model)  # a stack: the last pushed is decoded first
    words = ans.get_compressed().astype("<u4")
    out.append(_WORDS_HEAD.pack(len(words)))
    out.append(words.tobytes())
    return b"".join(out)


class _Reader:
    """Bounds-checked cursor over a payload."""

    def __init__(self, data: bytes):
        self.data, self.pos = memoryview(data), 0

    def take(self, size: int) -> memoryview:
        if size < 0 or self.pos + size > len(self.data):
            raise CodecError("damaged group: data ends early")
        view = self.data[self.pos:self.pos + size]
        self.pos += size
        return view


def decode_group(payload: bytes, num_frames: int, num_gaussians: int, bits) -> Iterator[np.ndarray]:
    """Yield the group's quantized levels frame by frame (int32 [N, 8] each), in O(N) memory.

    Every field is validated before use; a damaged payload raises CodecError."""
    import constriction

    levels = [1 << b for b in _bits_tuple(bits)]
    g, n = int(num_frames), int(num_gaussians)
    if g < 1 or n < 0:
        raise CodecError(f"damaged group: {g} frames of {n} Gaussians")
    r = _Reader(payload)
    kinds = np.frombuffer(r.take(g * NUM_PARAMS), np.uint8).reshape(g, NUM_PARAMS)
    if np.any(kinds > PREVIOUS) or np.any(kinds[0] != INTRA):
        raise CodecError("damaged group: invalid reference kinds")
    tables = {}  # (param, kind) -> (first symbol, model or None)
    min_bits = 0.0
    for p in range(NUM_PARAMS):
        half = levels[p] // 2
        for kind in KINDS:
            if not np.any(kinds[:, p] == kind):
                continue
            lo, span = _TABLE_HEAD.unpack(r.take(_TABLE_HEAD.size))
            low, high = (0, levels[p]) if kind == INTRA else (-half, levels[p] - half)
            if not (1 <= span <= levels[p] and low <= lo and lo + span <= high):
                raise CodecError("damaged group: invalid symbol table")
            model = None
            if span > 1:
                counts = np.frombuffer(r.take(span), np.uint8)
                if counts[0] == 0 or counts[-1] == 0:  # the encoder's tables span exactly the used symbols
                    raise CodecError("damaged group: invalid symbol table")
                model = constriction.stream.model.Categorical(counts.astype(np.float64), perfect=False)
                # Every symbol costs at least -log2(largest probability) bits: a lower bound on the
                # data this stream needs, checked below before anything of size N is decoded.
                cost = -math.log2(int(counts.max()) / int(counts.sum(dtype=np.int64)))
                min_bits += cost * n * int(np.sum(kinds[:, p] == kind))
            tables[p, kind] = (lo, model)
    (num_words,) = _WORDS_HEAD.unpack(r.take(_WORDS_HEAD.size))
    if num_words * 4 != len(r.data) - r.pos:
        raise CodecError("damaged group: wrong length")
    if 32 * num_words < 0.98 * min_bits - 64:
        raise CodecError("damaged group: too little data for the declared number of Gaussians")
    words = np.frombuffer(r.take(num_words * 4), "<u4").astype(np.uint32)
    try:
        ans = constriction.stream.stack.AnsCoder(words)
    except ValueError as e:
        raise CodecError(f"damaged group: {e}") from e
    anchor = np.zeros((n, NUM_PARAMS), np.int32)
    prev = anchor
    for f in range(g):
        cur = np.empty((n, NUM_PARAMS), np.int32)
        for p in range(NUM_PARAMS):
            kind = int(kinds[f, p])
            lo, model = tables[p, kind]
            if model is None:
                sym = np.full(n, lo, np.int32)
            else:
                sym = ans.decode(model, n) + np.int32(lo)
            if kind == INTRA:
                cur[:, p] = sym
                anchor[:, p] = sym
            else:
                ref = anchor[:, p] if kind == ANCHOR else prev[:, p]
                cur[:, p] = (ref + sym) % levels[p]  # levels <= 2^16: no int32 overflow
        prev = cur
        yield cur.copy()
    if not ans.is_empty():
        raise CodecError("damaged group: data left over after the last frame")


# ---- the float16 payload (the frame cache: .hgs version 2) ---------------------------------------
#
# Visually lossless and fast to decode, for a cache read on every frame change: the means stay float32
# (float16 would move them by up to 1/4 pixel on a 1080p canvas: -0.4 dB), the other six parameters are
# float16 (relative error <= 2^-11; the rotation taken modulo pi first, as the quantizer does). A frame is
# stored as byte planes (every value's first byte, then every second byte, ...: similar bytes side by
# side) compressed with zlib at level 1, one zlib stream per frame, so any frame decodes on its own.
# Payload of a group: per frame, uint32 length and the zlib stream. A file read once soon after it is
# written (`hypergs encode -o clip.hgs`'s float16 frames, EncodePlan.write_hgs) stores its streams at level 0:
# 1.8x the bytes, and a 57,600-Gaussian frame written in 1 ms instead of 14, read in 0.4 instead of 2.9.

FLOAT16_MAX = 65504.0
FLOAT16_TINY = 2.0 ** -14  # the smallest normal float16: smaller scales are raised to it (and counted)
_FLOAT32_PARAMS = 2  # the means
_FRAME_HEAD = struct.Struct("<I")


def float16_frame_bytes(num_gaussians: int) -> int:
    """Bytes of one frame of N Gaussians before compression."""
    return num_gaussians * (4 * _FLOAT32_PARAMS + 2 * (NUM_PARAMS - _FLOAT32_PARAMS))


def _byte_planes(values: np.ndarray) -> bytes:
    """[N, k] little-endian values -> their bytes grouped by parameter, then by byte position."""
    columns = np.ascontiguousarray(values.T)
    k, n = columns.shape
    return columns.view(np.uint8).reshape(k, n, values.dtype.itemsize).transpose(0, 2, 1).tobytes()


def _from_byte_planes(data: np.ndarray, k: int, n: int, dtype) -> np.ndarray:
    """The inverse of _byte_planes: [n, k] values of `dtype` (a view)."""
    planes = data.reshape(k, np.dtype(dtype).itemsize, n)
    # Stacking the byte planes as the last axis is 3x faster than a transposed copy.
    return np.stack([planes[:, i] for i in range(planes.shape[1])], -1).view(dtype)[..., 0].T


def encode_float16_group(params: np.ndarray, zlib_level: int = 1) -> tuple[bytes, int]:
    """params float [G, N, 8] -> (the group's payload, number of values clipped to float16's range).
    Refuses NaN, infinite values and scales <= 0 (CodecError); scales are kept within
    [FLOAT16_TINY, FLOAT16_MAX] and the other float16 values within +-FLOAT16_MAX. zlib_level 0 stores the
    frames uncompressed (a file read soon and removed, see above)."""
    params = np.asarray(params)
    if params.ndim != 3 or params.shape[2] != NUM_PARAMS or params.shape[0] < 1:
        raise CodecError(f"a group must be [frames, N, {NUM_PARAMS}] parameters, got {params.shape}")
    check_params(params)
    low = np.full(NUM_PARAMS - _FLOAT32_PARAMS, -FLOAT16_MAX, np.float32)
    low[:2] = FLOAT16_TINY
    out, clipped = [], 0
    for frame in params.astype(np.float32, copy=False):
        rest = frame[:, _FLOAT32_PARAMS:].copy()
        rest[:, 2] = np.mod(rest[:, 2], np.float32(ROTATION_PERIOD))
        kept = np.clip(rest, low, np.float32(FLOAT16_MAX))
        clipped += int(np.count_nonzero(kept != rest))
        data = zlib.compress(_byte_planes(frame[:, :_FLOAT32_PARAMS].astype("<f4"))
                             + _byte_planes(kept.astype("<f2")), zlib_level)
        out += [_FRAME_HEAD.pack(len(data)), data]
    return b"".join(out), clipped


def decode_float16_group(payload: bytes, num_frames: int, num_gaussians: int) -> Iterator[np.ndarray]:
    """Yield the group's frames, float32 [N, 8] each. A damaged payload (wrong lengths, a zlib stream
    that is broken or inflates to another size, values that are not Gaussians) raises CodecError."""
    g, n = int(num_frames), int(num_gaussians)
    if g < 1 or n < 0:
        raise CodecError(f"damaged group: {g} frames of {n} Gaussians")
    expected = float16_frame_bytes(n)
    r = _Reader(payload)
    for _ in range(g):
        (length,) = _FRAME_HEAD.unpack(r.take(_FRAME_HEAD.size))
        inflater = zlib.decompressobj()
        try:
            raw = inflater.decompress(r.take(length), expected + 1)  # never more than a frame's bytes
        except zlib.error as e:
            raise CodecError(f"damaged group: {e}") from None
        if len(raw) != expected or not inflater.eof or inflater.unused_data:
            raise CodecError("damaged group: a frame's data does not hold its Gaussians")
        data = np.frombuffer(raw, np.uint8)
        split = 4 * _FLOAT32_PARAMS * n
        frame = np.empty((n, NUM_PARAMS), np.float32)
        frame[:, :_FLOAT32_PARAMS] = _from_byte_planes(data[:split], _FLOAT32_PARAMS, n, "<f4")
        frame[:, _FLOAT32_PARAMS:] = _from_byte_planes(data[split:], NUM_PARAMS - _FLOAT32_PARAMS, n, "<f2")
        if not (np.isfinite(frame).all() and (frame[:, 2:4] > 0).all()):  # param_problem says which, slower
            raise CodecError(f"damaged group: {param_problem(frame)}")
        yield frame
    if r.pos != len(r.data):
        raise CodecError("damaged group: data left over after the last frame")


# ---- measurements -----------------------------------------------------------------------------------

def order_stability(params: np.ndarray, canvas_width: int, canvas_height: int, max_queries: int = 2000,
                    seed: int = 0) -> dict:
    """How stable the Gaussian order is across frames (residual coding pays off only when it is).

    For each pair of consecutive frames (t, t + 1) and up to `max_queries` Gaussians i of frame t:
    is Gaussian i of frame t + 1 the nearest one (by mean position) to Gaussian i of frame t?
    Returns `same_index_nearest` (mean fraction over the pairs, 1.0 = perfectly stable order),
    its minimum over the pairs, `per_pair` (one fraction per pair), and `median_shift_px` (median
    distance in canvas pixels that the same-index Gaussian moves between frames)."""
    params = np.asarray(params)
    t, n = params.shape[:2]
    if t < 2 or n == 0:
        return {"same_index_nearest": 1.0, "min_pair": 1.0, "per_pair": [], "median_shift_px": 0.0}
    rng = np.random.default_rng(seed)
    idx = np.sort(rng.choice(n, min(n, max_queries), replace=False))
    half = np.array([canvas_width / 2, canvas_height / 2])
    fractions, shifts = [], []
    for f in range(t - 1):
        a = params[f, idx, :2].astype(np.float64) * half
        b = params[f + 1, :, :2].astype(np.float64) * half
        same = np.sqrt(((a - b[idx]) ** 2).sum(-1))
        hits = 0
        for s in range(0, len(idx), 256):
            d = ((a[s:s + 256, None, :] - b[None, :, :]) ** 2).sum(-1)
            # nearest: no other Gaussian strictly closer than the same-index one (ties count as stable)
            hits += int(np.sum(d.min(axis=1) >= same[s:s + 256] ** 2 - 1e-12))
        fractions.append(hits / len(idx))
        shifts.append(same)
    return {"same_index_nearest": float(np.mean(fractions)), "min_pair": float(np.min(fractions)),
            "per_pair": [round(x, 4) for x in fractions],
            "median_shift_px": float(np.median(np.concatenate(shifts)))}
