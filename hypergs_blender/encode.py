"""Video -> GaussianVideo. A frame of W x H pixels is encoded on a `Layout`: a cols x rows grid of cells,
one Gaussian each, whose size (in source pixels) is the density a user chooses, by a Gaussian count
(`--gaussians`) or a cell size (`--cell`). The encoder sees the frame resized to its working size, at
which every cell is `stride` pixels, predicts the Gaussians there, and they are stretched back onto
the W x H canvas (exact covariance, gaussians.stretch_params).

The paper's transformer (network.TransformerEncoder) has a fixed input canvas instead: its frame is
the paper's patch grid of tiles (`TileLayout`, `--grid`), the working frame a grid of canvas x canvas
tiles, with a k x k lattice of Gaussians in each, chosen by a count per tile or a cell size.
`encoder_layout` plans either.

Encoders: the trained networks through torch or onnxruntime (network.py), and the grid floor that
every model must beat (`FloorEncoder`). Each has `name`, `tile_borders` and `predict(working frames,
cells) -> params`; the conv network and the floor a `stride` and `granule`, the transformer a
`canvas` and `clip_frames`.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from . import limits
from .errors import Cancelled, HyperGSError
from .gaussians import COLOUR_GAIN, INITIAL_SIGMA, GaussianVideo, stretch_params
from .io.frames import iter_frames, probe, sample_indices
from .io.images import resize_exact

Progress = Callable[[int, int], bool]  # (frames done, frames total) -> False to cancel

MAX_CELL = 32.0  # source pixels per cell side; coarser would shrink frames more than 8x (untrained)
QUALITY = {  # cell size in source pixels and refine steps of each quality preset
    "draft": dict(cell=8.0, refine=0),
    "standard": dict(cell=6.0, refine=0),
    "high": dict(cell=4.0, refine=30),
}


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
class TileLayout(Layout):
    """The transformer's layout: the frame as a tiles = (columns, rows) patch grid, each tile canvas x
    canvas working pixels holding a k x k lattice of Gaussians (cols = k columns, rows = k rows;
    stride = canvas / k, not always a whole number)."""
    tiles: tuple[int, int] = (1, 1)
    canvas: int = 128

    @property
    def per_tile(self) -> int:
        return self.count // (self.tiles[0] * self.tiles[1])

    @property
    def work_width(self) -> int:
        return self.tiles[0] * self.canvas

    @property
    def work_height(self) -> int:
        return self.tiles[1] * self.canvas


def plan_tile_layout(width: int, height: int, canvas: int, gaussians: int | None = None, cell: float | None = None,
                     grid: tuple[int, int] | None = None, trained: tuple[int, int] = (1, 1 << 20)) -> TileLayout:
    """The transformer's layout of a width x height frame: a grid (columns, rows) of tiles (default:
    tiles of about `canvas` source pixels, the frame at its own resolution), each with about
    `gaussians` Gaussians or cells of `cell` source pixels (exactly one of the two) on a k x k lattice.
    A count per tile outside `trained` (the range the model was trained for) is clamped, and `note`
    says so."""
    if (gaussians is None) == (cell is None):
        raise HyperGSError("give a Gaussian count or a cell size, not both")
    if gaussians is not None and gaussians < 1:
        raise HyperGSError(f"the Gaussian count must be at least 1, got {gaussians}")
    if cell is not None and not cell > 0:
        raise HyperGSError(f"the cell size must be positive, got {cell}")
    columns, rows = grid or (max(1, round(width / canvas)), max(1, round(height / canvas)))
    if columns < 1 or rows < 1:
        raise HyperGSError(f"the patch grid must be at least 1x1, got {columns}x{rows}")
    limits.check_image_size(columns * canvas, rows * canvas, f"a {columns}x{rows} patch grid of {canvas} px tiles")
    if gaussians is not None:
        wanted, asked = math.sqrt(gaussians), f"{gaussians} Gaussians per tile"
    else:
        wanted, asked = math.sqrt(width * height / (columns * rows)) / cell, f"cells of {cell:g} px"
    lo, hi = math.ceil(math.sqrt(trained[0])), max(1, math.isqrt(trained[1]))
    k = min(max(round(wanted), lo, 1), hi)
    note = ""
    if k != max(1, round(wanted)):
        note = (f"{asked} on {width}x{height} ({columns}x{rows} tiles) is outside the trained range "
                f"({trained[0]}-{trained[1]} per tile): using {k * k} per tile")
    return TileLayout(width, height, columns * k, rows * k, canvas / k, note, (columns, rows), canvas)


def encoder_layout(encoder, width: int, height: int, gaussians: int | None = None, cell: float | None = None,
                   grid: tuple[int, int] | None = None) -> Layout:
    """The layout `encoder` encodes a width x height frame on: the transformer's patch grid (`grid`:
    (columns, rows), default the frame at its resolution), or cells at a density (plan_layout)."""
    if hasattr(encoder, "canvas"):
        return plan_tile_layout(width, height, encoder.canvas, gaussians, cell, grid, encoder.gaussians)
    if grid is not None and tuple(grid) != (1, 1):
        raise HyperGSError(f"the patch grid is the transformer's; the {encoder.name} encoder encodes at a density "
                           "(a Gaussian count or a cell size)")
    return plan_layout(width, height, encoder.stride, gaussians, cell, encoder.granule)


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


def check_cells(cells: tuple[int, int] | None, cols: int, rows: int) -> None:
    """An encoder whose frame size fixes its cells (cols x rows) refuses a layout of other cells."""
    if cells is not None and tuple(cells) != (cols, rows):
        raise ValueError(f"the working frame holds {cols}x{rows} cells, not {cells[0]}x{cells[1]}")


class FloorEncoder:
    """The floor: one Gaussian per cell at its centre, sigma INITIAL_SIGMA cells, colour the cell's mean
    times the gain that makes the overlapping kernels sum to the image. No learning (the network with
    a zero output head)."""

    name = "floor"
    stride = 4
    granule = 1

    def tile_borders(self, width: int, height: int) -> tuple[list[int], list[int]]:
        return [], []  # one pass over the whole frame

    def predict(self, frames: np.ndarray, cells: tuple[int, int] | None = None) -> np.ndarray:
        """frames float32 [B, H, W, 3] in [0, 1], H and W multiples of the stride -> params [B, N, 8]
        (`cells`, the layout's (cols, rows), must be the frame's)."""
        b, h, w, _ = frames.shape
        s = self.stride
        rows, cols = h // s, w // s
        check_cells(cells, cols, rows)
        out = np.empty((b, rows, cols, 8), np.float32)
        out[..., 0] = ((np.arange(cols) + 0.5) * s * 2 / w - 1)[None, None, :]
        out[..., 1] = ((np.arange(rows) + 0.5) * s * 2 / h - 1)[None, :, None]
        out[..., 2:4] = INITIAL_SIGMA * s
        out[..., 4] = 0
        out[..., 5:8] = frames.reshape(b, rows, s, cols, s, 3).mean((2, 4)) * COLOUR_GAIN
        return out.reshape(b, rows * cols, 8)


def encode_frames(frames: np.ndarray, encoder, layout: Layout) -> np.ndarray:
    """uint8 frames [T, H, W, 3] -> params [T, layout.count, 8] on the W x H canvas."""
    work = np.stack([resize_exact(f, layout.work_width, layout.work_height) for f in frames])
    params = encoder.predict(work.astype(np.float32) / 255, (layout.cols, layout.rows))
    tx, ty = layout.width / layout.work_width, layout.height / layout.work_height
    return stretch_params(params, tx, ty) if (tx, ty) != (1, 1) else params


def frames_layout(frames: np.ndarray, encoder, gaussians: int | None = None, cell: float | None = None,
                  grid: tuple[int, int] | None = None) -> Layout:
    """encoder_layout for frames [T, H, W, 3]."""
    return encoder_layout(encoder, frames.shape[2], frames.shape[1], gaussians, cell, grid)


class EncodePlan:
    """What encoding a video will produce, known before any frame is decoded: the frames to take,
    the layout, the frame rate and the source description."""

    def __init__(self, path, encoder, gaussians: int | None = None, cell: float | None = None,
                 size: int | None = None, start: int = 0, stop: int | None = None, num_frames: int | None = None,
                 grid: tuple[int, int] | None = None):
        info = probe(path)
        self.path, self.encoder, self.size = path, encoder, size
        self.indices = sample_indices(info.num_frames, num_frames, start, stop)
        self.height, self.width = (size, size) if size else (info.height, info.width)
        self.layout = encoder_layout(encoder, self.width, self.height, gaussians, cell, grid)
        idx = self.indices
        self.fps = info.fps * (len(idx) - 1) / max(1, idx[-1] - idx[0]) if len(idx) > 1 else info.fps
        self.source = dict(path=str(path), frames=idx, size=[info.width, info.height], encoder=encoder.name)

    @property
    def grid(self) -> tuple[int, int]:
        """What the clip records as its grid: the Gaussians' lattice (cols, rows), one per cell."""
        return self.layout.cols, self.layout.rows

    def chunks(self, progress: Progress | None = None, chunk_frames: int = 16, refine: int = 0):
        """Yield (frames uint8 [t, H, W, 3], params [t, N, 8]) chunk by chunk: frames are decoded and
        encoded `chunk_frames` at a time (rounded up to whole clips of the encoder's `clip_frames`), so
        memory does not grow with the video. `progress` may return False to cancel (raises Cancelled)."""
        clip = getattr(self.encoder, "clip_frames", 1)
        chunk_frames = -(-chunk_frames // clip) * clip
        done, buffer = 0, []

        def report():
            if progress is not None and progress(done, len(self.indices)) is False:
                raise Cancelled("encoding cancelled")

        def encode(frames):
            params = encode_frames(frames, self.encoder, self.layout)
            if refine:
                from .refine import refine_params
                params = refine_params(params, frames, refine)
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


def encode_video(path, encoder, gaussians: int | None = None, cell: float | None = None, size: int | None = None,
                 start: int = 0, stop: int | None = None, num_frames: int | None = None,
                 progress: Progress | None = None, chunk_frames: int = 16, refine: int = 0,
                 grid: tuple[int, int] | None = None) -> GaussianVideo:
    """Encode frames [start, stop) of a video (every frame, or `num_frames` sampled uniformly) into
    one GaussianVideo in memory. size: None keeps the native frame (the canvas is W x H); an int
    short-side-resizes and centre-crops to size x size first. grid: the transformer's patch grid
    (encoder_layout). See EncodePlan.chunks for the rest."""
    started = time.perf_counter()
    plan = EncodePlan(path, encoder, gaussians, cell, size, start, stop, num_frames, grid)
    params = np.concatenate([p for _, p in plan.chunks(progress, chunk_frames, refine)])
    return GaussianVideo(params, plan.width, plan.height, plan.fps, plan.grid,
                         dict(plan.source, encode_seconds=time.perf_counter() - started))
