"""Encoding work that runs off Blender's main thread. No bpy here: a job only sees a path and numbers,
and hands back a GaussianVideo; the operator writes to bpy on the main thread when the job is done."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from ..hypergs_blender import encode as _encode
from ..hypergs_blender.encode import Cancelled
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.gaussians import GaussianVideo
from ..hypergs_blender.metrics import psnr
from ..hypergs_blender.render import render_frames
from ..hypergs_blender.video import iter_frames
from .encoder import encoder_name, make_encoder

PSNR_FRAMES = 8  # frames rendered after encoding to measure the clip's PSNR


@dataclass
class EncodeRequest:
    path: str
    gaussian_count: int
    grid: int
    start: int = 0
    stop: int | None = None


@dataclass
class EncodeResult:
    video: GaussianVideo
    psnr: float
    seconds: float
    encoder: str


def split_count(gaussian_count: int, grid: int) -> int:
    """The Gaussian count actually used: the nearest multiple of grid^2 (each tile gets an equal share)."""
    return max(1, round(gaussian_count / (grid * grid))) * grid * grid


def measure_psnr(video: GaussianVideo, path: str, max_frames: int = PSNR_FRAMES, keep_going=lambda: True) -> float:
    """Mean PSNR (dB) of up to `max_frames` evenly spread frames, rendered at the source size."""
    indices = list(video.source.get("frames", range(video.num_frames)))
    picks = sorted(set(np.round(np.linspace(0, len(indices) - 1, min(max_frames, len(indices)))).astype(int)))
    wanted = {indices[p]: p for p in picks}
    values = []
    for index, frame in iter_frames(path, sorted(wanted)):
        if not keep_going():
            raise Cancelled("encoding cancelled")
        image = render_frames(video, video.canvas_width, video.canvas_height, [wanted[index]])
        values.append(float(psnr(image, frame[None] / np.float32(255))[0]))
    return float(np.mean(values))


def run_encode(request: EncodeRequest, progress=None) -> EncodeResult:
    """Encode and measure. progress(done, total) -> False cancels (raises Cancelled)."""
    started = time.perf_counter()
    encoder = make_encoder()
    video = _encode.encode_video(request.path, encoder, split_count(request.gaussian_count, request.grid),
                                 request.grid, start=request.start, stop=request.stop, progress=progress)
    total = video.num_frames

    def keep_going():
        return progress is None or progress(total, total) is not False

    value = measure_psnr(video, request.path, keep_going=keep_going)
    return EncodeResult(video, value, time.perf_counter() - started, encoder_name(encoder))


class EncodeJob:
    """run_encode on a worker thread; `cancel()` makes its progress callback return False."""

    def __init__(self, request: EncodeRequest):
        self.request = request
        self.done, self.total = 0, 0
        self.result: EncodeResult | None = None
        self.error: BaseException | None = None
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hypergs-encode", daemon=True)

    def _progress(self, done: int, total: int) -> bool:
        self.done, self.total = done, total
        return not self._cancel.is_set()

    def _run(self):
        try:
            self.result = run_encode(self.request, self._progress)
        except BaseException as e:  # handed to the main thread, which reports it
            self.error = e

    def start(self):
        self._thread.start()
        return self

    def run(self):
        """Synchronously, on the calling thread (background mode, scripts)."""
        self._run()
        return self

    def cancel(self):
        self._cancel.set()

    @property
    def finished(self) -> bool:
        return not self._thread.is_alive() and (self.result is not None or self.error is not None)

    def join(self, timeout=None):
        self._thread.join(timeout)

    @property
    def fraction(self) -> float:
        return self.done / self.total if self.total else 0.0


def describe(error: BaseException) -> str:
    """The message the user sees for an error (no traceback)."""
    if isinstance(error, HyperGSError):
        return str(error)
    return f"{type(error).__name__}: {error}"
