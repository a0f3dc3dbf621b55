"""Video -> GaussianVideo: tiles frames onto the network's canvas, runs a predictor in T-frame
clips, merges tiles back onto the frame. Backends: the bundled network through torch or
onnxruntime (`Encoder`), and the grid floor that every model must beat (`FloorEncoder`).

Gaussian counts are per frame: with a G x G patch grid each tile gets N / G^2 of them.
"""
from __future__ import annotations

import math
import time
from typing import Callable

import numpy as np

from .errors import HyperGSError
from .gaussians import GaussianVideo, grid_anchors, merge_tiles, tile_bounds
from .video import iter_frames, probe, sample_indices

Progress = Callable[[int, int], bool]  # (frames done, frames total) -> False to cancel


class Cancelled(HyperGSError):
    """The user cancelled an encode; nothing was written."""


class FloorEncoder:
    """The floor: N Gaussians on a regular grid, colours sampled from the area-averaged frame and
    scaled so the overlapping kernels sum to the image. No learning."""

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
    from .video import resize_exact
    h, w = frame.shape[:2]
    xb, yb = tile_bounds(w, grid), tile_bounds(h, grid)
    tiles = np.empty((grid, grid, canvas, canvas, 3), np.float32)
    for r in range(grid):
        for c in range(grid):
            tiles[r, c] = resize_exact(frame[yb[r]:yb[r + 1], xb[c]:xb[c + 1]], canvas, canvas) / 255.0
    return tiles


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


def encode_video(path, encoder, gaussian_count: int = 1000, grid: int = 1, size: int | None = None,
                 start: int = 0, stop: int | None = None, num_frames: int | None = None,
                 progress: Progress | None = None, chunk_clips: int = 4, refine: int = 0) -> GaussianVideo:
    """Encode frames [start, stop) of a video (every frame, or `num_frames` sampled uniformly).

    size: None keeps the native frame (the canvas is W x H); an int short-side-resizes and
    centre-crops to size x size first. Frames are decoded and encoded `chunk_clips` clips at a time,
    so memory does not grow with the video. `progress` may return False to cancel (raises Cancelled).
    """
    info = probe(path)
    indices = sample_indices(info.num_frames, num_frames, start, stop)
    chunk = chunk_clips * encoder.clip_frames
    started = time.perf_counter()
    out, buffer = [], []

    def flush():
        frames = np.stack(buffer)
        params = encode_frames(frames, encoder, gaussian_count, grid)
        if refine:
            from .fit import refine_params
            params = refine_params(params, frames, refine)
        out.append(params)
        buffer.clear()
        if progress is not None and progress(sum(len(p) for p in out), len(indices)) is False:
            raise Cancelled("encoding cancelled")

    if progress is not None and progress(0, len(indices)) is False:
        raise Cancelled("encoding cancelled")
    for _, frame in iter_frames(path, indices, size):
        buffer.append(frame)
        if len(buffer) == chunk:
            flush()
    if buffer:
        flush()
    h, w = (size, size) if size else (info.height, info.width)
    fps = info.fps * (len(indices) - 1) / max(1, indices[-1] - indices[0]) if len(indices) > 1 else info.fps
    return GaussianVideo(np.concatenate(out), w, h, fps, (grid, grid),
                         dict(path=str(path), frames=indices, size=[info.width, info.height],
                              encoder=getattr(encoder, "name", type(encoder).__name__),
                              encode_seconds=time.perf_counter() - started))


def default_encoder(backend: str = "auto"):
    """The bundled network: torch when importable (backend 'torch'), else onnxruntime ('onnx')."""
    from .network import load_bundled_encoder
    return load_bundled_encoder(backend)


def add_encoder_arguments(parser) -> None:
    parser.add_argument("--encoder", default="network", choices=["network", "floor"],
                        help="the bundled network, or the grid floor (no learning)")
    parser.add_argument("--backend", default="auto", choices=["auto", "torch", "onnx"])
    parser.add_argument("--weights", default=None, help="folder with <name>.json/.safetensors/.onnx")
    parser.add_argument("--refine", type=int, default=0, help="per-frame refinement steps after the prediction")


def make_encoder(args):
    if args.encoder == "floor":
        return FloorEncoder()
    from .network import WEIGHTS_DIR, load_bundled_encoder
    return load_bundled_encoder(args.backend, args.weights or WEIGHTS_DIR)


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("encode", help="video -> Gaussian video file (.npz, .hgs)")
    p.add_argument("video")
    p.add_argument("-o", "--output", required=True)
    p.add_argument("--gaussians", type=int, default=1000)
    p.add_argument("--grid", type=int, default=1)
    p.add_argument("--size", type=int, default=None, help="square canvas (short-side resize + crop); default native")
    p.add_argument("--start", type=int, default=0)
    p.add_argument("--stop", type=int, default=None)
    p.add_argument("--bits", type=int, default=8, choices=[4, 6, 8], help="quantization bits (.hgs)")
    add_encoder_arguments(p)
    p.set_defaults(func=_encode_command)

    p = subparsers.add_parser("render", help="Gaussian video file -> image frames")
    p.add_argument("clip")
    p.add_argument("-o", "--output", required=True, help="folder for frame_0000.png ...")
    p.add_argument("--width", type=int, default=None)
    p.add_argument("--height", type=int, default=None)
    p.add_argument("--format", default="png", choices=["png", "exr"])
    p.set_defaults(func=_render_command)


def _encode_command(args) -> None:
    from .clip_io import save_clip
    from tqdm import tqdm
    encoder = make_encoder(args)
    bar = tqdm(unit="frame", dynamic_ncols=True)

    def progress(done, total):
        bar.total = total
        bar.n = done
        bar.refresh()
        return True

    video = encode_video(args.video, encoder, args.gaussians, args.grid, args.size, args.start, args.stop,
                         progress=progress, refine=args.refine)
    bar.close()
    save_clip(video, args.output, bits=args.bits)
    print(f"{args.output}: {video.num_frames} frames x {video.num_gaussians} Gaussians "
          f"({video.source['encode_seconds']:.2f} s)")


def _render_command(args) -> None:
    from pathlib import Path

    from .clip_io import load_clip
    from .image_sequence import write_image
    from .render import render_frames
    video = load_clip(args.clip)
    width = args.width or video.canvas_width
    height = args.height or round(width * video.canvas_height / video.canvas_width)
    out = Path(args.output)
    out.mkdir(parents=True, exist_ok=True)
    for t in range(video.num_frames):
        frame = render_frames(video, width, height, [t])[0]
        write_image(out / f"frame_{t:04d}.{args.format}", frame)
    print(f"{video.num_frames} frames at {width}x{height} -> {out}")
