"""Video -> GaussianVideo. What a user asks for is one `EncodeSettings`: a Quality preset (`QUALITY`), a
Gaussian count or a cell size, and refine steps; the command line (`--quality`, `--gaussians`, `--cell`,
`--refine`), Blender's dialogs and the encode all read it, and derive from it the `Layout` of a W x H
frame (with the encoder's stride and granule): a cols x rows grid of cells, one Gaussian each, whose
size (in source pixels) is the density chosen. The encoder sees the frame resized to its working size,
at which every cell is `stride` pixels, predicts the Gaussians there, and they are stretched back onto
the W x H canvas (exact covariance, gaussians.stretch_params).

`EncodePlan` is the one streaming encode of a video (decode -> encode -> refine, chunk by chunk, with
progress, cancel and the PSNR of sampled frames) that `hypergs encode`, Blender's conversions and the
benches run; `encode_frames` encodes frames already in memory (`hypergs eval`, the benches).

Encoders: the trained network through torch or onnxruntime (network.py), and the grid floor that every
model must beat (`FloorEncoder`). Each has `name`, `stride` and `predict(working frames) -> params`.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from . import metrics, optional
from .errors import Cancelled, HyperGSError
from .gaussians import COLOUR_GAIN, INITIAL_SIGMA, GaussianVideo, stretch_params
from .io.frames import iter_frames, probe, sample_indices
from .io.images import resize_exact
from .render import render_params

Progress = Callable[[int, int], bool]  # (frames done, frames total) -> False to cancel

MAX_CELL = 32.0  # source pixels per cell side; coarser would shrink frames more than 8x (untrained)
QUALITY = {  # cell size in source pixels and refine steps of each quality preset
    "draft": dict(cell=8.0, refine=0),
    "standard": dict(cell=6.0, refine=0),
    "high": dict(cell=4.0, refine=30),
}
DEFAULT_QUALITY = "standard"


@dataclass(frozen=True)
class Layout:
    """Where the Gaussians of a width x height frame go: cols x rows cells, one Gaussian each. The
    encoder sees the frame at its working size, cols * stride x rows * stride pixels."""
    width: int
    height: int
    cols: int
    rows: int
    stride: int
    note: str = ""  # why the request was changed (clamped to the trained range), for the user

    @property
    def count(self) -> int:
        return self.cols * self.rows

    @property
    def cell(self) -> float:
        """Mean cell side in source pixels."""
        return math.sqrt(self.width * self.height / self.count)

    @property
    def work_width(self) -> int:
        return self.cols * self.stride

    @property
    def work_height(self) -> int:
        return self.rows * self.stride


def plan_layout(width: int, height: int, stride: int, gaussians: int | None = None, cell: float | None = None,
                granule: int = 1) -> Layout:
    """The layout of a width x height frame for about `gaussians` Gaussians, or cells of `cell` source
    pixels (exactly one of the two). Cells are kept between `stride` source pixels (the network never
    sees an upscaled frame) and MAX_CELL; a request outside that is clamped, and `note` says so.
    cols and rows are multiples of `granule` (the network's coarsest level, in cells)."""
    if (gaussians is None) == (cell is None):
        raise HyperGSError("give a Gaussian count or a cell size, not both")
    if gaussians is not None:
        if gaussians < 1:
            raise HyperGSError(f"the Gaussian count must be at least 1, got {gaussians}")
        wanted = math.sqrt(width * height / gaussians)
        asked = f"{gaussians} Gaussians"
    else:
        if not cell > 0:
            raise HyperGSError(f"the cell size must be positive, got {cell}")
        wanted = float(cell)
        asked = f"cells of {cell:g} px"
    lo, hi = float(stride), MAX_CELL
    used = min(max(wanted, lo), hi)
    cols = max(granule, round(width / used / granule) * granule)
    rows = max(granule, round(height / used / granule) * granule)
    note = ""
    if used != wanted:
        limit = ("at most one Gaussian per {0}x{0} pixels".format(stride) if used == lo
                 else f"cells of at most {hi:g} px")
        note = (f"{asked} on {width}x{height} is outside the trained range ({limit}): "
                f"using {cols * rows} ({cols}x{rows} cells of {math.sqrt(width * height / (cols * rows)):.1f} px)")
    return Layout(width, height, cols, rows, stride, note)


@dataclass(frozen=True)
class EncodeSettings:
    """What a user asks of an encode: about `gaussians` per frame or cells of `cell` source pixels (one
    of the two), and `refine` steps after the network. `choose` reads a user's choice; `layout` is
    where the Gaussians of a frame go."""
    gaussians: int | None = None
    cell: float | None = None
    refine: int = 0
    note: str = ""  # why the settings differ from what was asked (refining needs PyTorch)

    @classmethod
    def choose(cls, quality: str | None = None, gaussians: int | None = None, cell: float | None = None,
               refine: int | None = None, default: str = DEFAULT_QUALITY) -> EncodeSettings:
        """The one reading of a user's choice: a Quality preset (a key of QUALITY: its cell size and
        refine steps), else a Gaussian count, else a cell size (a count wins over a cell size), else the
        `default` preset. `refine`, when given, replaces the preset's steps (else 0 for a count or a cell)."""
        if quality is None and gaussians is None and cell is None:
            quality = default
        if quality is not None:
            if quality not in QUALITY:
                raise HyperGSError(f"unknown quality {quality!r} ({', '.join(QUALITY)})")
            preset = QUALITY[quality]
            return cls(cell=preset["cell"], refine=preset["refine"] if refine is None else refine)
        if gaussians is not None:
            return cls(gaussians=gaussians, refine=refine or 0)
        return cls(cell=cell, refine=refine or 0)

    def runnable(self) -> EncodeSettings:
        """These settings as this Python can run them: refining needs PyTorch (Blender's Python has
        none), so without it there is no refining, and `note` says so."""
        if self.refine and not optional.torch_available():
            return replace(self, refine=0, note=f"not refined: refining needs PyTorch, which this Blender's "
                                                f"Python lacks ({self.refine} steps asked)")
        return self

    def layout(self, width: int, height: int, encoder) -> Layout:
        """The layout of a width x height frame for `encoder` (its stride and granule)."""
        return plan_layout(width, height, encoder.stride, self.gaussians, self.cell, encoder.granule)


@dataclass(frozen=True)
class EncodeCost:
    """What encoding costs, per Gaussian per frame, for the estimate shown before an encode starts
    (Blender's dialogs). Measured on the 2-core development machine (one thread: 1280x720, cells of
    6 px, the conv network ~0.85 s per frame; refine at cells of 4 px ~0.4 s per step); recalibrate when
    an encoder changes."""
    predict_s_per_gaussian: float  # the encoder's forward pass
    hgs_bytes_per_gaussian: float  # a .hgs file at 8 bits
    decode_s_per_pixel: float = 9e-8  # decoding the source frame (PyAV)
    refine_first_s_per_gaussian: float = 3e-4  # refine step 1: least-squares colours (torch, CPU)
    refine_s_per_gaussian_step: float = 7e-6  # each further refine step (Adam, torch, CPU)
    blend_bytes_per_gaussian: float = 44.0  # embedded in a .blend: float32 position, scale, rotation, RGBA, frame


ENCODE_COSTS = {  # by encoder: "floor", or "network" (both backends)
    "floor": EncodeCost(predict_s_per_gaussian=2e-5, hgs_bytes_per_gaussian=2.2),
    "network": EncodeCost(predict_s_per_gaussian=3.5e-5, hgs_bytes_per_gaussian=3.8),
}


@dataclass(frozen=True)
class Estimate:
    seconds: float
    blend_bytes: float  # the clip embedded in a .blend
    hgs_bytes: float  # the clip as a .hgs file (8 bits)


def estimate(layout: Layout, frames: int, refine: int = 0, encoder: str = "network") -> Estimate:
    """What encoding `frames` frames on `layout` with `refine` refine steps will take with `encoder` (its
    name: "floor", "network-onnx", ...): time and size, from ENCODE_COSTS."""
    cost = ENCODE_COSTS["floor" if encoder == "floor" else "network"]
    n = layout.count
    per_frame = cost.decode_s_per_pixel * layout.width * layout.height + cost.predict_s_per_gaussian * n
    if refine > 0:
        per_frame += n * (cost.refine_first_s_per_gaussian + cost.refine_s_per_gaussian_step * (refine - 1))
    return Estimate(per_frame * frames, cost.blend_bytes_per_gaussian * n * frames,
                    cost.hgs_bytes_per_gaussian * n * frames)


class FloorEncoder:
    """The floor: one Gaussian per cell at its centre, sigma INITIAL_SIGMA cells, colour the cell's mean
    times the gain that makes the overlapping kernels sum to the image. No learning (the network with
    a zero output head)."""

    name = "floor"
    stride = 4
    granule = 1

    def tile_borders(self, width: int, height: int) -> tuple[list[int], list[int]]:
        return [], []  # one pass over the whole frame

    def predict(self, frames: np.ndarray) -> np.ndarray:
        """frames float32 [B, H, W, 3] in [0, 1], H and W multiples of the stride -> params [B, N, 8]."""
        b, h, w, _ = frames.shape
        s = self.stride
        rows, cols = h // s, w // s
        out = np.empty((b, rows, cols, 8), np.float32)
        out[..., 0] = ((np.arange(cols) + 0.5) * s * 2 / w - 1)[None, None, :]
        out[..., 1] = ((np.arange(rows) + 0.5) * s * 2 / h - 1)[None, :, None]
        out[..., 2:4] = INITIAL_SIGMA * s
        out[..., 4] = 0
        out[..., 5:8] = frames.reshape(b, rows, s, cols, s, 3).mean((2, 4)) * COLOUR_GAIN
        return out.reshape(b, rows * cols, 8)


def encode_frames(frames: np.ndarray, encoder, layout: Layout, refine: int = 0) -> np.ndarray:
    """uint8 frames [T, H, W, 3] -> params [T, layout.count, 8] on the W x H canvas, refined `refine`
    steps against the frames (refine.refine_params, needs torch) when asked."""
    work = np.stack([resize_exact(f, layout.work_width, layout.work_height) for f in frames])
    params = encoder.predict(work.astype(np.float32) / 255)
    tx, ty = layout.width / layout.work_width, layout.height / layout.work_height
    if (tx, ty) != (1, 1):
        params = stretch_params(params, tx, ty)
    if refine:
        from .refine import refine_params
        params = refine_params(params, frames, refine)
    return params


def frames_layout(frames: np.ndarray, encoder, gaussians: int | None = None, cell: float | None = None) -> Layout:
    """The layout of frames [T, H, W, 3] for `gaussians` per frame or cells of `cell` pixels."""
    return EncodeSettings(gaussians, cell).layout(frames.shape[2], frames.shape[1], encoder)


class EncodePlan:
    """The encode of a video with `settings`, known before any frame is decoded (the frames to take,
    the layout, the frame rate and the source description), then run chunk by chunk (`chunks`, or
    `video` for the whole clip in memory)."""

    def __init__(self, path, encoder, settings: EncodeSettings, size: int | None = None, start: int = 0,
                 stop: int | None = None, num_frames: int | None = None):
        info = probe(path)
        self.path, self.encoder, self.settings, self.size = path, encoder, settings, size
        self.indices = sample_indices(info.num_frames, num_frames, start, stop)
        self.height, self.width = (size, size) if size else (info.height, info.width)
        self.layout = settings.layout(self.width, self.height, encoder)
        idx = self.indices
        self.fps = info.fps * (len(idx) - 1) / max(1, idx[-1] - idx[0]) if len(idx) > 1 else info.fps
        self.source = dict(path=str(path), frames=idx, size=[info.width, info.height], encoder=encoder.name)
        self.psnr_values: list[float] = []  # of the frames `chunks` measured

    @property
    def grid(self) -> tuple[int, int]:
        return self.layout.cols, self.layout.rows

    @property
    def psnr(self) -> float:
        """Mean PSNR (dB) of the frames measured, rendered at the canvas size against the source."""
        return float(np.mean(self.psnr_values)) if self.psnr_values else math.nan

    def chunks(self, progress: Progress | None = None, chunk_frames: int = 16, psnr_frames: int = 0):
        """Yield (frames uint8 [t, H, W, 3], params [t, N, 8]) chunk by chunk: frames are decoded and
        encoded (and refined) `chunk_frames` at a time, so memory does not grow with the video.
        `progress` may return False to cancel (raises Cancelled). `psnr_frames` frames, spread evenly,
        are rendered and measured against their source frame on the way (`psnr`)."""
        total = len(self.indices)
        measured = set(np.round(np.linspace(0, total - 1, min(psnr_frames, total))).astype(int).tolist())
        self.psnr_values = []
        done, buffer = 0, []

        def report():
            if progress is not None and progress(done, total) is False:
                raise Cancelled("encoding cancelled")

        def encode(frames):
            params = encode_frames(frames, self.encoder, self.layout, self.settings.refine)
            for i in sorted(p - done for p in measured if done <= p < done + len(frames)):
                image = render_params(params[i], self.width, self.height, self.width, self.height)
                self.psnr_values.append(float(metrics.psnr(image[None], frames[i][None] / np.float32(255))[0]))
            return frames, params

        report()
        for _, frame in iter_frames(self.path, self.indices, self.size):
            buffer.append(frame)
            if len(buffer) == chunk_frames:
                yield encode(np.stack(buffer))
                done += len(buffer)
                buffer.clear()
                report()
        if buffer:
            yield encode(np.stack(buffer))
            done += len(buffer)
            report()

    def video(self, progress: Progress | None = None, chunk_frames: int = 16, psnr_frames: int = 0) -> GaussianVideo:
        """Every chunk's Gaussians as one GaussianVideo in memory (the source gains `encode_seconds`)."""
        started = time.perf_counter()
        params = np.concatenate([p for _, p in self.chunks(progress, chunk_frames, psnr_frames)])
        return GaussianVideo(params, self.width, self.height, self.fps, self.grid,
                             dict(self.source, encode_seconds=time.perf_counter() - started))


def encode_video(path, encoder, settings: EncodeSettings, size: int | None = None, start: int = 0,
                 stop: int | None = None, num_frames: int | None = None, progress: Progress | None = None,
                 chunk_frames: int = 16) -> GaussianVideo:
    """Encode frames [start, stop) of a video (every frame, or `num_frames` sampled uniformly) into
    one GaussianVideo in memory. size: None keeps the native frame (the canvas is W x H); an int
    short-side-resizes and centre-crops to size x size first. See EncodePlan.chunks for the rest."""
    return EncodePlan(path, encoder, settings, size, start, stop, num_frames).video(progress, chunk_frames)
