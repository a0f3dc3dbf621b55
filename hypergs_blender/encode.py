"""Video -> GaussianVideo: tiles frames onto the network's canvas, runs a predictor in T-frame
clips, merges tiles back onto the frame. Predictors: the bundled network through torch or
onnxruntime (network.py), and the grid floor that every model must beat (`FloorEncoder`).

Gaussian counts are per frame: with a G x G patch grid each tile gets N / G^2 of them.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np

from .errors import HyperGSError
from .gaussians import GaussianVideo, grid_anchors, merge_tiles, tile_bounds
from .io.frames import iter_frames, probe, sample_indices
from .io.images import resize_exact

Progress = Callable[[int, int], bool]  # (frames done, frames total) -> False to cancel

# ----------------------------------------------------------------------------------------------------
# STAND-IN for the lead's density API (issue 11), so the Blender glue can be written against it on this
# branch: QUALITY, Layout, plan_layout and the encoders' `stride` as the lead's branch defines them.
# Drop this block (and the `stride` lines in FloorEncoder and network.py) in favour of the lead's.
MAX_CELL = 32.0  # source pixels per cell side
QUALITY = {  # cell size in source pixels and refine steps of each quality preset
    "draft": dict(cell=8.0, refine=0),
    "standard": dict(cell=6.0, refine=0),
    "high": dict(cell=4.0, refine=30),
}


@dataclass(frozen=True)
class Layout:
    """Where the Gaussians of a width x height frame go: cols x rows cells, one Gaussian each."""
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


def plan_layout(width: int, height: int, stride: int, gaussians: int | None = None,
                cell: float | None = None) -> Layout:
    """The layout of a width x height frame for about `gaussians` Gaussians, or cells of `cell` source
    pixels (exactly one of the two), cells kept between `stride` and MAX_CELL source pixels."""
    if (gaussians is None) == (cell is None):
        raise HyperGSError("give a Gaussian count or a cell size, not both")
    if gaussians is not None and gaussians < 1:
        raise HyperGSError(f"the Gaussian count must be at least 1, got {gaussians}")
    if cell is not None and not cell > 0:
        raise HyperGSError(f"the cell size must be positive, got {cell}")
    wanted = math.sqrt(width * height / gaussians) if gaussians is not None else float(cell)
    used = min(max(wanted, float(stride)), MAX_CELL)
    cols, rows = max(1, round(width / used)), max(1, round(height / used))
    note = ""
    if used != wanted:
        note = (f"{gaussians} Gaussians" if gaussians is not None else f"cells of {cell:g} px") + \
            f" on {width}x{height} is outside the trained range: using {cols * rows} ({cols}x{rows} cells)"
    return Layout(width, height, cols, rows, stride, note)
# END OF STAND-IN


@dataclass(frozen=True)
class EncodeCost:
    """What encoding costs, per Gaussian per frame, for the estimate shown before an encode starts
    (Blender's dialogs). Measured on the 2-core development machine (DAVIS tennis, 432x240); recalibrate
    when an encoder changes (the network's forward pass dominates without refinement)."""
    predict_s_per_gaussian: float  # the encoder's forward pass
    hgs_bytes_per_gaussian: float  # a .hgs file at 8 bits
    decode_s_per_pixel: float = 9e-8  # decoding the source frame (PyAV)
    refine_first_s_per_gaussian: float = 3e-4  # refine step 1: least-squares colours (torch, CPU)
    refine_s_per_gaussian_step: float = 2e-5  # each further refine step (Adam, torch, CPU)
    blend_bytes_per_gaussian: float = 44.0  # embedded in a .blend: float32 position, scale, rotation, RGBA, frame


ENCODE_COSTS = {  # by encoder: "floor", or "network" (both backends)
    "floor": EncodeCost(predict_s_per_gaussian=2e-5, hgs_bytes_per_gaussian=2.2),
    "network": EncodeCost(predict_s_per_gaussian=5e-4, hgs_bytes_per_gaussian=3.8),
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
# ----------------------------------------------------------------------------------------------------


class Cancelled(HyperGSError):
    """The user cancelled an encode; nothing was written."""


class FloorEncoder:
    """The floor: N Gaussians on a regular grid, colours sampled from the area-averaged frame and
    scaled so the overlapping kernels sum to the image. No learning."""

    name = "floor"
    stride = 4  # STAND-IN (see above)

    def __init__(self, canvas: int = 128, clip_frames: int = 4, sigma_per_spacing: float = 0.6):
        self.canvas, self.clip_frames, self.sigma_per_spacing = canvas, clip_frames, sigma_per_spacing

    def predict(self, frames: np.ndarray, n: int) -> np.ndarray:
        """frames float32 [B, T, c, c, 3] in [0, 1] -> params [B, T, n, 8]."""
        anchors = grid_anchors(n)
        c = self.canvas
        spacing = c / math.sqrt(n)
        sigma = self.sigma_per_spacing * spacing
        gain = spacing * spacing / (2 * math.pi * sigma * sigma)
        px = np.clip(((anchors + 1) * 0.5 * c).astype(int), 0, c - 1)
        colours = _box_blur(frames, max(1, round(spacing)))[..., px[:, 1], px[:, 0], :] * gain
        out = np.empty(frames.shape[:2] + (n, 8), np.float32)
        out[..., 0:2] = anchors
        out[..., 2:4] = sigma
        out[..., 4] = 0
        out[..., 5:8] = colours
        return out


def _box_blur(frames: np.ndarray, k: int) -> np.ndarray:
    """Mean over a k x k window around each pixel (edges clamped), via cumulative sums."""
    pad = np.pad(frames, [(0, 0)] * (frames.ndim - 3) + [(k // 2, k - 1 - k // 2)] * 2 + [(0, 0)], mode="edge")
    cs = np.cumsum(np.cumsum(pad, axis=-3), axis=-2)
    cs = np.pad(cs, [(0, 0)] * (frames.ndim - 3) + [(1, 0), (1, 0), (0, 0)])
    h, w = frames.shape[-3:-1]
    total = cs[..., k:k + h, k:k + w, :] - cs[..., :h, k:k + w, :] - cs[..., k:k + h, :w, :] + cs[..., :h, :w, :]
    return total / (k * k)


def canvas_tiles(frame: np.ndarray, grid: int, canvas: int) -> np.ndarray:
    """uint8 frame [H, W, 3] -> [G, G, canvas, canvas, 3] float32 tiles, each resized (area filter)."""
    h, w = frame.shape[:2]
    xb, yb = tile_bounds(w, grid), tile_bounds(h, grid)
    tiles = np.empty((grid, grid, canvas, canvas, 3), np.float32)
    for r in range(grid):
        for c in range(grid):
            tiles[r, c] = resize_exact(frame[yb[r]:yb[r + 1], xb[c]:xb[c + 1]], canvas, canvas) / 255.0
    return tiles


def split_count(gaussian_count: int, grid: int) -> int:
    """The Gaussian count a G x G grid encodes for a requested count: the nearest multiple of G^2
    (halves round up; each tile gets an equal share, at least one)."""
    return max(1, int(gaussian_count / (grid * grid) + 0.5)) * grid * grid


def encode_frames(frames: np.ndarray, encoder, gaussian_count: int, grid: int = 1) -> np.ndarray:
    """uint8 frames [T, H, W, 3] -> params [T, gaussian_count, 8] on a W x H canvas.

    The frames are cut into T-frame clips (the last one padded by repeating its final frame) and every
    tile of every clip goes through the predictor in one batch."""
    if gaussian_count % (grid * grid):
        raise HyperGSError(f"{gaussian_count} Gaussians do not split evenly over a {grid}x{grid} grid")
    per_tile = gaussian_count // (grid * grid)
    t, h, w = frames.shape[:3]
    clip = encoder.clip_frames
    padded = np.concatenate([frames, np.repeat(frames[-1:], (-t) % clip, axis=0)])
    tiles = np.stack([canvas_tiles(f, grid, encoder.canvas) for f in padded])  # [Tp, G, G, c, c, 3]
    tiles = tiles.reshape(-1, clip, grid * grid, encoder.canvas, encoder.canvas, 3).transpose(0, 2, 1, 3, 4, 5)
    batch = tiles.reshape(-1, clip, encoder.canvas, encoder.canvas, 3)  # [clips * G*G, T, c, c, 3]
    params = encoder.predict(np.ascontiguousarray(batch), per_tile)  # [clips * G*G, T, n, 8]
    params = params.reshape(-1, grid, grid, clip, per_tile, 8).transpose(1, 2, 0, 3, 4, 5)
    params = params.reshape(grid, grid, -1, per_tile, 8)[:, :, :t]
    return merge_tiles(params, (grid, grid), w, h, encoder.canvas)


class EncodePlan:
    """What encoding a video will produce, known before any frame is decoded: the frames to take,
    the canvas, the frame rate and the source description."""

    def __init__(self, path, encoder, gaussian_count: int = 1000, grid: int = 1, size: int | None = None,
                 start: int = 0, stop: int | None = None, num_frames: int | None = None):
        info = probe(path)
        self.path, self.encoder, self.gaussian_count, self.grid, self.size = path, encoder, gaussian_count, grid, size
        self.indices = sample_indices(info.num_frames, num_frames, start, stop)
        self.height, self.width = (size, size) if size else (info.height, info.width)
        idx = self.indices
        self.fps = info.fps * (len(idx) - 1) / max(1, idx[-1] - idx[0]) if len(idx) > 1 else info.fps
        self.source = dict(path=str(path), frames=idx, size=[info.width, info.height],
                           encoder=getattr(encoder, "name", type(encoder).__name__))

    def chunks(self, progress: Progress | None = None, chunk_clips: int = 4, refine: int = 0):
        """Yield (frames uint8 [t, H, W, 3], params [t, N, 8]) chunk by chunk: frames are decoded and
        encoded `chunk_clips` clips at a time, so memory does not grow with the video. `progress` may
        return False to cancel (raises Cancelled)."""
        chunk = chunk_clips * self.encoder.clip_frames
        done, buffer = 0, []

        def report():
            if progress is not None and progress(done, len(self.indices)) is False:
                raise Cancelled("encoding cancelled")

        def encode(frames):
            params = encode_frames(frames, self.encoder, self.gaussian_count, self.grid)
            if refine:
                from .refine import refine_params
                params = refine_params(params, frames, refine)
            return frames, params

        report()
        for _, frame in iter_frames(self.path, self.indices, self.size):
            buffer.append(frame)
            if len(buffer) == chunk:
                yield encode(np.stack(buffer))
                done += len(buffer)
                buffer.clear()
                report()
        if buffer:
            yield encode(np.stack(buffer))
            done += len(buffer)
            report()


def encode_video(path, encoder, gaussian_count: int = 1000, grid: int = 1, size: int | None = None,
                 start: int = 0, stop: int | None = None, num_frames: int | None = None,
                 progress: Progress | None = None, chunk_clips: int = 4, refine: int = 0) -> GaussianVideo:
    """Encode frames [start, stop) of a video (every frame, or `num_frames` sampled uniformly) into
    one GaussianVideo in memory. size: None keeps the native frame (the canvas is W x H); an int
    short-side-resizes and centre-crops to size x size first. See EncodePlan.chunks for the rest."""
    started = time.perf_counter()
    plan = EncodePlan(path, encoder, gaussian_count, grid, size, start, stop, num_frames)
    params = np.concatenate([p for _, p in plan.chunks(progress, chunk_clips, refine)])
    return GaussianVideo(params, plan.width, plan.height, plan.fps, (grid, grid),
                         dict(plan.source, encode_seconds=time.perf_counter() - started))
