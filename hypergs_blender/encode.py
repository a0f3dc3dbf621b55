"""Video -> GaussianVideo. What a user asks for is one `EncodeSettings`: a Quality preset (`QUALITY`), a
Gaussian count or a cell size, and refine steps; the command line (`--quality`, `--gaussians`, `--cell`,
`--refine`), Blender's dialogs and the encode all read it, and derive from it the `Layout` of a W x H
frame (with the encoder's stride and granule): a cols x rows grid of cells, one Gaussian each, whose
size (in source pixels) is the density chosen. The encoder sees the frame resized to its working size,
at which every cell is `stride` pixels, predicts the Gaussians there, and they are stretched back onto
the W x H canvas (exact covariance, gaussians.stretch_params).

The paper's transformer (network.TransformerEncoder) has a fixed input canvas instead: its frame is
the paper's patch grid of tiles (`TileLayout`, the settings' `grid`, `--grid`), the working frame a
grid of canvas x canvas tiles, with a k x k lattice of Gaussians in each, chosen by a count per tile
or a cell size. `encoder_layout` plans either.

`EncodePlan` is the one streaming encode of a video (decode -> encode -> refine, chunk by chunk, with
progress, cancel and the PSNR of sampled frames) that `hypergs encode`, Blender's conversions and the
benches run; `encode_frames` encodes frames already in memory (`hypergs eval`, the benches). A long
refinement by the conv network starts from a content-adaptive placement of the count (`refine_frames`,
placement.py).

Encoders: the trained networks through torch or onnxruntime (network.py), and the grid floor that
every model must beat (`FloorEncoder`). Each has `name`, `tile_borders`, `release` and
`predict(working frames, cells) -> params`; the conv network and the floor a `stride` and `granule`,
the transformer a `canvas` and `clip_frames`.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from . import limits, metrics, optional
from .errors import Cancelled, HyperGSError
from .gaussians import COLOUR_GAIN, INITIAL_SIGMA, GaussianVideo, stretch_params
from .io.frames import SHOWN, Display, iter_frames, probe, sample_indices
from .io.images import resize_exact
from .placement import SPLIT_FRACTION, choose_start, pixel_errors, split_may_pay
from .render import render_params

Progress = Callable[[int, int], bool]  # (frames done, frames total) -> False to cancel

# The filter of the resize to the working size. The area filter averages fractional pixels, a blur at the
# ratios between 1 and 2 that training never shows the network (its crops are warped from an image
# pyramid); Lanczos keeps the frame as sharp as those crops. Session 11, same weights: dev / held-out
# 256² at N = 3000 (ratio 1.16) +0.27 / +0.19 dB, 720p Standard (1.5) +0.09, Draft and N = 1000 (2) +0.03
# to +0.06, flat ripple unchanged (model card).
WORKING_INTERPOLATION = "LANCZOS"
BATCH_PIXELS = 1 << 20  # working pixels per forward pass and per float32 batch (bounds memory: one 720p frame)
MAX_CELL = 32.0  # source pixels per cell side; coarser would shrink frames more than 8x (untrained)
QUALITY = {  # cell size in source pixels and refine steps of each quality preset
    "draft": dict(cell=8.0, refine=0),
    "standard": dict(cell=6.0, refine=0),
    "high": dict(cell=4.0, refine=30),
}
DEFAULT_QUALITY = "standard"
# A refinement this long starts from the content-adaptive placement (placement.py). Session 29 (256², N = 1000,
# dev / held-out clips, without placement.choose_start's check; the split against the grid): refine 1 (the
# least-squares colours alone) 28.30 against 28.75 dB on the dev clips, refine 10 29.37 / 32.49 against 29.22 /
# 33.19, refine 20 30.37 / 34.12 against 29.95 / 33.74, refine 30 31.20 / 35.36 against 30.60 / 34.24, refine 50
# 32.23 / 36.49 against 31.37 / 34.85.
ADAPTIVE_MIN_REFINE = 20
MODELS = ("conv", "transformer")  # the designs a user chooses between (network.DEFAULT_NAMES names their weights)


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
    windows: int = 0  # the encoder's canvas-sized windows per frame (its forward passes; 0: not known)

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
    columns, rows = grid or default_grid(width, height, canvas)
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


def default_grid(width: int, height: int, canvas: int) -> tuple[int, int]:
    """The transformer's patch grid when none is asked for: tiles of about `canvas` source pixels (the
    frame at its own resolution)."""
    return max(1, round(width / canvas)), max(1, round(height / canvas))


def encoder_layout(encoder, width: int, height: int, gaussians: int | None = None, cell: float | None = None,
                   grid: tuple[int, int] | None = None) -> Layout:
    """The layout `encoder` encodes a width x height frame on: the transformer's patch grid (`grid`:
    (columns, rows), default the frame at its resolution), or cells at a density (plan_layout)."""
    if hasattr(encoder, "canvas"):
        layout = plan_tile_layout(width, height, encoder.canvas, gaussians, cell, grid, encoder.gaussians)
        return replace(layout, windows=encoder.windows(layout.work_width, layout.work_height))
    if grid is not None and tuple(grid) != (1, 1):
        raise HyperGSError(f"the patch grid is the transformer's; the {encoder.name} encoder encodes at a density "
                           "(a Gaussian count or a cell size)")
    return plan_layout(width, height, encoder.stride, gaussians, cell, encoder.granule)


@dataclass(frozen=True)
class EncodeSettings:
    """What a user asks of an encode: about `gaussians` per frame (the transformer: per tile) or cells
    of `cell` source pixels (one of the two), `refine` steps after the network, and the transformer's
    patch `grid` (columns, rows; None: tiles of its canvas size); `model`, which design encodes (one
    of MODELS: an application's encoder, runtime.make_encoder; the command line names weights instead).
    `choose` reads a user's choice; `layout` is where the Gaussians of a frame go."""
    gaussians: int | None = None
    cell: float | None = None
    refine: int = 0
    note: str = ""  # why the settings differ from what was asked (refining needs PyTorch)
    grid: tuple[int, int] | None = None
    model: str = MODELS[0]
    adaptive: bool = True  # a long refinement starts from the content-adaptive placement (False: the grid)

    @classmethod
    def choose(cls, quality: str | None = None, gaussians: int | None = None, cell: float | None = None,
               refine: int | None = None, default: str = DEFAULT_QUALITY,
               grid: tuple[int, int] | None = None, model: str = MODELS[0]) -> EncodeSettings:
        """The one reading of a user's choice: a Quality preset (a key of QUALITY: its cell size and
        refine steps), else a Gaussian count, else a cell size (a count wins over a cell size), else the
        `default` preset. `refine`, when given, replaces the preset's steps (else 0 for a count or a cell).
        `grid` is the transformer's patch grid (any of the three), `model` one of MODELS."""
        if model not in MODELS:
            raise HyperGSError(f"unknown model {model!r} ({', '.join(MODELS)})")
        grid = None if grid is None else (int(grid[0]), int(grid[1]))
        if grid is not None and min(grid) < 1:
            raise HyperGSError(f"the patch grid must be at least 1x1, got {grid[0]}x{grid[1]}")
        if quality is None and gaussians is None and cell is None:
            quality = default
        if quality is not None:
            if quality not in QUALITY:
                raise HyperGSError(f"unknown quality {quality!r} ({', '.join(QUALITY)})")
            preset = QUALITY[quality]
            return cls(cell=preset["cell"], refine=preset["refine"] if refine is None else refine, grid=grid,
                       model=model)
        if gaussians is not None:
            return cls(gaussians=gaussians, refine=refine or 0, grid=grid, model=model)
        return cls(cell=cell, refine=refine or 0, grid=grid, model=model)

    def runnable(self) -> EncodeSettings:
        """These settings as this Python can run them: refining needs PyTorch (Blender's Python has
        none), so without it there is no refining, and `note` says so."""
        if self.refine and not optional.torch_available():
            return replace(self, refine=0, note=f"not refined: refining needs PyTorch, which this Blender's "
                                                f"Python lacks ({self.refine} steps asked)")
        return self

    def layout(self, width: int, height: int, encoder) -> Layout:
        """The layout of a width x height frame for `encoder` (encoder_layout: its stride and granule, or
        the transformer's canvas and patch grid)."""
        return encoder_layout(encoder, width, height, self.gaussians, self.cell, self.grid)


@dataclass(frozen=True)
class EncodeCost:
    """What encoding costs, per Gaussian per frame, for the estimate shown before an encode starts
    (Blender's dialogs): the wall time on an otherwise idle machine. Measured on the idle 2-core
    development machine, 1920 x 1080 at Standard (57,600 Gaussians): the network (round 3's with its error
    pass at 4x4 points per cell and session 30's render, onnxruntime, opset 20) 0.395 s per frame on one
    thread, 0.242-0.250 s on two (`hypergs bench encode --sizes 1080p --presets standard --backends onnx
    --threads 1|2`; session 21's render 0.424 / 0.26, session 20's 2x2-point error pass 0.36 / 0.24, without
    the error pass 0.286 / 0.193); decoding 0.04 s; writing the frame cache 0.025 s; the floor 0.043 s. What
    these leave out (the frames' handling between decoder and network) is in decode_s_per_pixel. The
    estimate, 0.342 s per frame on two threads, against whole conversions in Blender on the idle machine
    (`tools/long_clips.py --frames 30,300 --stages blender,cli`, session 30): 0.378 s per frame for 30 frames
    (start-up included), 0.317 for 300. Recalibrate when an encoder changes (`tools/long_clips.py` prints the
    estimate beside the measured conversion)."""
    predict_s_per_gaussian: float  # the encoder's forward pass (with the resize to its working size), one thread
    cache_bytes_per_gaussian: float  # the frame cache (float16 .hgs, io/cache.py)
    threaded: bool = True  # whether more CPU threads make the forward pass faster (THREAD_GAIN each)
    decode_s_per_pixel: float = 4e-8  # decoding the source frame (PyAV) and handing it to the encoder
    # HDR video's extra (VideoInfo.hdr: decoded at 16 bits and mapped through colour.hdr_to_srgb_u8's tables), one
    # thread: 76 ms of CPU per 1080p frame, a 10-bit BT.2020 HLG H.264 against the same video untagged (12 frames,
    # median of 5 whole-process runs each, session 34).
    hdr_decode_s_per_pixel: float = 3.7e-8
    write_s_per_gaussian: float = 4.4e-7  # writing the frame cache
    # Refinement (torch, CPU, one thread; threads speed it up as they do the network: 1.45-1.65x on two), per
    # Gaussian and frame: step 1, the least-squares colours (refine.LS_ITERATIONS), and each further Adam step.
    # Session 28, 720p High (57,600 Gaussians, 4 frames of a held-out pan; `hypergs encode --quality high
    # --refine 0|1|11` on 1 and 2 threads): 1.8e-5 and 2.8e-6 (two threads: 1.1e-5 and 1.9e-6).
    refine_first_s_per_gaussian: float = 1.8e-5
    refine_s_per_gaussian_step: float = 2.8e-6
    blend_bytes_per_gaussian: float = 40.0  # the frame a clip's mesh holds: float32 position, scale, rotation, RGBA
    # The transformer pays per canvas-sized window (TileLayout.windows) of n = k x k Gaussians:
    # predict_s_per_window + predict_s_per_gaussian n + predict_s_per_pair n^2 (its query attention).
    predict_s_per_window: float = 0.0
    predict_s_per_pair: float = 0.0
    content_adaptive: bool = False  # a long refinement starts from two more runs (adaptive_start_applies)


ENCODE_COSTS = {  # by encoder kind: "floor", "network" (the conv network) or "transformer" (both backends)
    "floor": EncodeCost(predict_s_per_gaussian=7.5e-7, cache_bytes_per_gaussian=6.0, threaded=False),
    "network": EncodeCost(predict_s_per_gaussian=6.9e-6, cache_bytes_per_gaussian=12.4, content_adaptive=True),
    # The `small` preset (canvas 128, clips of 4 frames), onnxruntime on one thread, 4 frames of 256 x 256
    # in 1 or 9 windows at 256 / 1024 / 3025 per window: 0.033 / 0.088 / 0.39 CPU s per window and
    # frame (three trainings ran beside).
    "transformer": EncodeCost(predict_s_per_gaussian=3.5e-5, predict_s_per_window=0.022, predict_s_per_pair=2.8e-8,
                              cache_bytes_per_gaussian=12.4),
}
THREAD_GAIN = 0.7  # what each CPU thread past the first adds to the network's speed (session 20's model: 0.234 s
# on 2 vs 0.405 on 1; session 21's: 0.262-0.268 vs 0.421-0.427, a gain of 0.6, within the sittings' spread)


@dataclass(frozen=True)
class Estimate:
    seconds: float
    threads: int  # the CPU threads the time assumes
    cache_bytes: float  # the clip's frame cache (beside the .blend)
    blend_bytes: float  # what the clip adds to the .blend (the frame its mesh holds)


def encode_cost(encoder: str) -> EncodeCost | None:
    """ENCODE_COSTS' entry for an encoder by its name ("network-onnx", "floor", "transformer-torch", ...)."""
    return ENCODE_COSTS.get(encoder.partition("-")[0])


def adaptive_start_applies(encoder: str, layout: Layout, steps: int) -> bool:
    """Whether a refinement of `steps` steps on `layout` by `encoder` (its name: "network-onnx", "floor", ...)
    starts from the content-adaptive placement (`adaptive_start`): one of ADAPTIVE_MIN_REFINE steps or more by an
    encoder whose cost says so (the conv network), above the finest cell, where the fine run would hold no more
    than the count."""
    cost = encode_cost(encoder)
    return (steps >= ADAPTIVE_MIN_REFINE and cost is not None and cost.content_adaptive
            and layout.cell > layout.stride)


def estimate(layout: Layout, frames: int, refine: int = 0, encoder: str = "network", threads: int = 1,
             hdr: bool = False) -> Estimate:
    """What encoding `frames` frames on `layout` with `refine` refine steps will take with `encoder` (its
    name: "floor", "network-onnx", "transformer-onnx", ...) on `threads` CPU threads: time and size, from
    ENCODE_COSTS. hdr: the source is HDR video (VideoInfo.hdr), which costs more to decode."""
    cost = encode_cost(encoder)
    if cost is None:
        raise ValueError(f"no encoding cost for the encoder {encoder!r} (ENCODE_COSTS: {', '.join(ENCODE_COSTS)})")
    n, threads = layout.count, max(1, int(threads))
    gain = 1 + THREAD_GAIN * (threads - 1)  # of a threaded network's pass, and of refinement (torch) after any encoder
    speedup = gain if cost.threaded else 1.0
    windows = getattr(layout, "windows", 0)
    if windows:  # the transformer: each window predicts its k x k lattice points
        per_window = layout.per_tile
        predict = windows * (cost.predict_s_per_window + cost.predict_s_per_gaussian * per_window
                             + cost.predict_s_per_pair * per_window ** 2)
    else:
        predict = cost.predict_s_per_gaussian * n
        if adaptive_start_applies(encoder, layout, refine):
            predict *= 1 + 5 * SPLIT_FRACTION  # adaptive_start's runs at most: the coarse one (f) and the fine (4f)
    refine_s = 0.0
    if refine > 0:
        refine_s = n * (cost.refine_first_s_per_gaussian + cost.refine_s_per_gaussian_step * (refine - 1))
    decode = cost.decode_s_per_pixel + (cost.hdr_decode_s_per_pixel if hdr else 0.0)
    per_frame = (decode * layout.width * layout.height + cost.write_s_per_gaussian * n
                 + predict / speedup + refine_s / gain)
    return Estimate(per_frame * frames, threads, cost.cache_bytes_per_gaussian * n * frames,
                    cost.blend_bytes_per_gaussian * n)


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

    def release(self) -> None:
        """Nothing to give back (the network's encoders free their runtime's memory here)."""

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


def working_frames(frames: np.ndarray, width: int, height: int) -> np.ndarray:
    """uint8 frames [T, H, W, 3] -> what the network sees: float32 [T, height, width, 3] in [0, 1], resized
    with WORKING_INTERPOLATION (the runtime's encode and the trainer's evaluation alike)."""
    work = np.stack([resize_exact(f, width, height, WORKING_INTERPOLATION) for f in frames]).astype(np.float32)
    work /= 255
    return work


def encode_frames(frames: np.ndarray, encoder, layout: Layout, refine: int = 0, adaptive: bool = True) -> np.ndarray:
    """uint8 frames [T, H, W, 3] -> params [T, layout.count, 8] on the W x H canvas, refined `refine`
    steps against the frames when asked (`refine_frames`, from the content-adaptive start unless `adaptive`
    is False)."""
    params = predict_frames(frames, encoder, layout)
    return refine_frames(frames, encoder, layout, params, refine, adaptive=adaptive) if refine else params


def refine_frames(frames: np.ndarray, encoder, layout: Layout, params: np.ndarray, steps: int, device: str = "cpu",
                  adaptive: bool = True) -> np.ndarray:
    """The encoder's params [T, layout.count, 8] of uint8 frames [T, H, W, 3] refined `steps` steps against
    them (refine.refine_params, needs torch). A refinement of at least ADAPTIVE_MIN_REFINE steps by the conv
    network starts from the content-adaptive placement where it pays (`adaptive_start`; `adaptive=False`:
    from `params`, the network's grid)."""
    if adaptive and adaptive_start_applies(encoder.name, layout, steps):
        params = adaptive_start(frames, encoder, layout, params)
    from .refine import refine_params
    return refine_params(params, frames, steps, device=device)


def predict_frames(frames: np.ndarray, encoder, layout: Layout) -> np.ndarray:
    """uint8 frames [T, H, W, 3] -> the encoder's params [T, layout.count, 8] on the W x H canvas. Frames go
    to the encoder as float32 working frames of at most BATCH_PIXELS pixels at a time (at least one frame;
    whole clips of the transformer's `clip_frames`): memory does not grow with T (16 working frames of 1080p at
    Standard were 700 MB as float32), and the network's own passes are no larger."""
    clip = getattr(encoder, "clip_frames", 1)
    per_pass = max(1, BATCH_PIXELS // (layout.work_width * layout.work_height * clip)) * clip
    params = np.empty((len(frames), layout.count, 8), np.float32)
    for start in range(0, len(frames), per_pass):
        work = working_frames(frames[start:start + per_pass], layout.work_width, layout.work_height)
        params[start:start + len(work)] = encoder.predict(work, (layout.cols, layout.rows))
    tx, ty = layout.width / layout.work_width, layout.height / layout.work_height
    if (tx, ty) != (1, 1):
        params = stretch_params(params, tx, ty)
    return params


def adaptive_start(frames: np.ndarray, encoder, layout: Layout, grid: np.ndarray) -> np.ndarray:
    """The start of a refinement (placement.py): for the frames whose grid (the encoder's params [T,
    layout.count, 8] on `layout`) renders below placement.SPLIT_MAX_PSNR, the encoder's runs at SPLIT_FRACTION
    of the count and at half that cell, split where the coarse run's render errs most, where that pays
    (placement.choose_start); else the grid. Near the finest cell, where the fine run would hold no more than
    the count, the grid."""
    h, w = frames.shape[1:3]
    coarse_layout = encoder_layout(encoder, w, h, gaussians=max(1, round(SPLIT_FRACTION * layout.count)))
    fine_layout = encoder_layout(encoder, w, h, cell=coarse_layout.cell / 2)
    if not coarse_layout.count < layout.count < fine_layout.count:
        return grid

    def render(params):
        return render_params(params, w, h, w, h)

    def target(i):  # a frame at a time: a chunk's float frames would be 25 MB each at 1080p
        return frames[i] / np.float32(255)

    grid_errors = {}  # of the frames that may split
    for i in range(len(frames)):
        frame = target(i)
        error = float(pixel_errors(render(grid[i]), frame).sum())
        if split_may_pay(error, frame):
            grid_errors[i] = error
    if not grid_errors:
        return grid
    picked = list(grid_errors)
    coarse = predict_frames(frames[picked], encoder, coarse_layout)
    fine = predict_frames(frames[picked], encoder, fine_layout)
    params = grid.copy()
    for j, i in enumerate(picked):
        params[i] = choose_start(grid[i], grid_errors[i], coarse[j], fine[j], target(i), coarse_layout.cols,
                                 coarse_layout.rows, render)
    return params


def frames_layout(frames: np.ndarray, encoder, gaussians: int | None = None, cell: float | None = None,
                  grid: tuple[int, int] | None = None) -> Layout:
    """The layout of frames [T, H, W, 3] for `gaussians` per frame (per tile) or cells of `cell` pixels."""
    return EncodeSettings(gaussians, cell, grid=grid).layout(frames.shape[2], frames.shape[1], encoder)


# The PSNR a conversion reports is measured on a sample of its frames, at most PSNR_SAMPLE_MOST and one per
# PSNR_SAMPLE_EVERY converted, so that the check costs a bounded share of the conversion at any clip length: each
# sampled frame is a full render, 0.59 s per 1080p Standard frame through the numpy rasterizer (Blender has no
# numba) against the network's ~0.35 s per frame, so one per 32 frames is about 5 % (eight frames made a 30-frame
# 1080p Import 12-27 % slower than the command line, session 23).
PSNR_SAMPLE_MOST = 8
PSNR_SAMPLE_EVERY = 32


def psnr_sample_count(frames: int) -> int:
    """How many of a conversion's `frames` frames have their PSNR measured (EncodePlan.chunks' psnr_frames)."""
    return min(PSNR_SAMPLE_MOST, -(-frames // PSNR_SAMPLE_EVERY)) if frames > 0 else 0


def psnr_frame_picks(total: int, count: int) -> list[int]:
    """Which of `total` frames (indices 0..total-1) a PSNR check of `count` frames measures: spread evenly,
    first and last included, no index twice."""
    if total <= 0 or count <= 0:
        return []
    return np.unique(np.round(np.linspace(0, total - 1, min(count, total))).astype(int)).tolist()


class EncodePlan:
    """The encode of a video (its frames as `display` shows them) with `settings`, known before any frame is
    decoded (the frames to take, the layout, the frame rate and the source description), then run chunk by chunk
    (`chunks`, or `video` for the whole clip in memory)."""

    def __init__(self, path, encoder, settings: EncodeSettings, size: int | None = None, start: int = 0,
                 stop: int | None = None, num_frames: int | None = None, display: Display = SHOWN):
        info = probe(path, display)
        self.path, self.encoder, self.settings, self.size, self.display = path, encoder, settings, size, display
        self.indices = sample_indices(info.num_frames, num_frames, start, stop)
        self.height, self.width = (size, size) if size else (info.height, info.width)
        self.layout = settings.layout(self.width, self.height, encoder)
        idx = self.indices
        self.fps = info.fps * (len(idx) - 1) / max(1, idx[-1] - idx[0]) if len(idx) > 1 else info.fps
        self.source = dict(path=str(path), frames=idx, size=[info.width, info.height], encoder=encoder.name)
        self.psnr_values: list[float] = []  # of the frames `chunks` measured

    @property
    def grid(self) -> tuple[int, int]:
        """What the clip records as its grid: the Gaussians' lattice (cols, rows), one per cell."""
        return self.layout.cols, self.layout.rows

    @property
    def cache_bytes(self) -> float:
        """The estimated size of this encode's frame cache (encode.estimate), for checking a folder's room before
        the work starts (io.files.check_free_space)."""
        return estimate(self.layout, len(self.indices), encoder=self.encoder.name).cache_bytes

    @property
    def psnr(self) -> float:
        """Mean PSNR (dB) of the frames measured, rendered at the canvas size against the source."""
        return float(np.mean(self.psnr_values)) if self.psnr_values else math.nan

    def chunks(self, progress: Progress | None = None, chunk_frames: int = 16, psnr_frames: int = 0):
        """Yield (frames uint8 [t, H, W, 3], params [t, N, 8]) chunk by chunk: frames are decoded and
        encoded (and refined) `chunk_frames` at a time (rounded up to whole clips of the encoder's
        `clip_frames`), so memory does not grow with the video. `progress` may return False to cancel
        (raises Cancelled). `psnr_frames` frames, spread evenly, are rendered and measured against
        their source frame on the way (`psnr`)."""
        clip = getattr(self.encoder, "clip_frames", 1)
        chunk_frames = -(-chunk_frames // clip) * clip
        total = len(self.indices)
        measured = set(psnr_frame_picks(total, psnr_frames))
        self.psnr_values = []
        done, buffer = 0, []

        def report():
            if progress is not None and progress(done, total) is False:
                raise Cancelled("encoding cancelled")

        def encode(frames):
            params = encode_frames(frames, self.encoder, self.layout, self.settings.refine, self.settings.adaptive)
            for i in sorted(p - done for p in measured if done <= p < done + len(frames)):
                self.psnr_values.append(self.frame_psnr(params[i], frames[i]))
            return frames, params

        report()
        for _, frame in iter_frames(self.path, self.indices, self.size, self.display):
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

    def frame_psnr(self, params: np.ndarray, frame: np.ndarray) -> float:
        """PSNR (dB) of one frame's Gaussians [N, 8], rendered at the canvas size, against its source frame (uint8)."""
        image = render_params(params, self.width, self.height, self.width, self.height)
        return float(metrics.psnr(image[None], frame[None] / np.float32(255))[0])

    def write_hgs(self, path, bits=8, progress: Progress | None = None, chunk_frames: int = 16, psnr_frames: int = 0,
                  on_chunk: Callable[[np.ndarray, np.ndarray], None] | None = None) -> None:
        """Encode into a quantized .hgs file at `path` (`bits`: an int or 8 depths, as clips.save_clip takes them)
        whose ranges are fitted to the whole clip, as Blender's export fits them, with memory bounded by a
        chunk whatever the clip's length. The Gaussians stream into a float16 .hgs under the output's temporary
        name (uncompressed: read once, soon), the ranges are fitted on the way, and a second pass quantizes that
        file (clips.save_clip). A folder without room for both files is refused before the work starts. Ranges
        fixed before the first frame (Quantizer.default: scales from 1/8 pixel to the canvas, colours in
        [-1, 2]) cost a smooth held-out 720p clip 2.9 dB at Standard and 6.6 at High (model card, session 28).
        `psnr_frames` frames are measured as the file holds them (`psnr`). on_chunk(frames, params) after each
        chunk is encoded."""
        from .io import cache
        from .io.clips import ClipFrames, save_clip
        from .io.codec import Quantizer, clip_bits, float16_frame_bytes
        from .io.files import AtomicOutput, check_free_space
        from .io.hgs import HgsError, HgsReader
        total = len(self.indices)
        check_free_space(path, float16_frame_bytes(self.layout.count) * total + self.cache_bytes,
                         f"the float16 file of its {total} frames' Gaussians and the .hgs quantized from it")
        picks, sources, done = set(psnr_frame_picks(total, psnr_frames)), {}, 0
        held = AtomicOutput(path, streamed=True)  # a temporary name of the output's: the float16 frames

        def streamed(frames_file):  # each chunk's Gaussians, written on the way to the ranges' fit
            nonlocal done
            for frames, params in self.chunks(progress, chunk_frames):
                sources.update((done + i, frames[i]) for i in range(len(frames)) if done + i in picks)
                frames_file.write(params)
                done += len(frames)
                if on_chunk is not None:
                    on_chunk(frames, params)
                yield params

        try:
            with cache.writer(held.temp, self.width, self.height, self.layout.count, self.fps, self.grid,
                              self.source, zlib_level=0) as frames_file:
                quantizer = Quantizer.fit(streamed(frames_file),
                                          clip_bits(bits, self.width, self.height, self.layout.count))
            with HgsReader(held.temp) as reader:
                save_clip(ClipFrames.of(reader), path, quantizer=quantizer)
        except HgsError as e:  # a full disk while the float16 frames were written: the user knows the output's name
            raise HgsError(str(e).replace(str(held.temp), str(held.path))) from None
        finally:
            held.discard()
        if sources:
            with HgsReader(path) as reader:
                self.psnr_values = [self.frame_psnr(reader.read_frame(i), sources[i]) for i in sorted(sources)]

    def video(self, progress: Progress | None = None, chunk_frames: int = 16, psnr_frames: int = 0) -> GaussianVideo:
        """Every chunk's Gaussians as one GaussianVideo in memory (the source gains `encode_seconds`)."""
        started = time.perf_counter()
        params = np.concatenate([p for _, p in self.chunks(progress, chunk_frames, psnr_frames)])
        return GaussianVideo(params, self.width, self.height, self.fps, self.grid,
                             dict(self.source, encode_seconds=time.perf_counter() - started))


def encode_video(path, encoder, settings: EncodeSettings, size: int | None = None, start: int = 0,
                 stop: int | None = None, num_frames: int | None = None, progress: Progress | None = None,
                 chunk_frames: int = 16, display: Display = SHOWN) -> GaussianVideo:
    """Encode frames [start, stop) of a video (every frame, or `num_frames` sampled uniformly; as `display` shows
    them) into one GaussianVideo in memory. size: None keeps the native frame (the canvas is W x H); an int
    short-side-resizes and centre-crops to size x size first. See EncodePlan.chunks for the rest."""
    return EncodePlan(path, encoder, settings, size, start, stop, num_frames, display).video(progress, chunk_frames)
