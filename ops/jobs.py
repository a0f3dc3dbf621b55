"""Encoding work that runs off Blender's main thread. No bpy here: a job only sees a path and numbers,
and hands back a GaussianVideo; the operator writes to bpy on the main thread when the job is done."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

import numpy as np

from ..hypergs_blender.encode import EncodePlan
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.gaussians import GaussianVideo
from ..hypergs_blender.metrics import psnr
from ..hypergs_blender.render import render_params
from .encoder import Runtime, describe_encoder, make_encoder

PSNR_FRAMES = 8  # frames (evenly spread) whose PSNR against the source is measured while encoding


@dataclass
class EncodeRequest:
    path: str
    gaussians: int | None  # Gaussians per frame, or None: one per cell x cell source pixels
    cell: float | None
    refine: int = 0  # refine steps after the network (0: none)
    start: int = 0
    stop: int | None = None


@dataclass
class EncodeResult:
    video: GaussianVideo
    psnr: float
    seconds: float
    encoder: str  # what encoded, and on which device (describe_encoder)


def run_encode(request: EncodeRequest, runtime: Runtime = Runtime(), progress=None) -> EncodeResult:
    """Encode, measuring the PSNR of up to PSNR_FRAMES frames on the frames the encode decoded.
    runtime: where the network runs; progress(done, total) -> False cancels (raises Cancelled)."""
    started = time.perf_counter()
    encoder = make_encoder(runtime)
    plan = EncodePlan(request.path, encoder, request.gaussians, None if request.gaussians else request.cell,
                      start=request.start, stop=request.stop)
    total = len(plan.indices)
    measured = set(np.round(np.linspace(0, total - 1, min(PSNR_FRAMES, total))).astype(int).tolist())
    chunks, values, done = [], [], 0
    for frames, params in plan.chunks(progress, refine=request.refine):
        for i in sorted(p - done for p in measured if done <= p < done + len(frames)):
            image = render_params(params[i], plan.width, plan.height, plan.width, plan.height)
            values.append(float(psnr(image[None], frames[i][None] / np.float32(255))[0]))
        chunks.append(params)
        done += len(frames)
    video = GaussianVideo(np.concatenate(chunks), plan.width, plan.height, plan.fps, plan.grid,
                          dict(plan.source, encode_seconds=time.perf_counter() - started))
    return EncodeResult(video, float(np.mean(values)), time.perf_counter() - started,
                        describe_encoder(encoder, runtime))


class EncodeJob:
    """run_encode for each request in turn, on a worker thread; `cancel()` makes its progress callback
    return False. All or nothing: the job has `results` for every request, or an `error`."""

    def __init__(self, requests: list[EncodeRequest], runtime: Runtime = Runtime()):
        self.requests = list(requests)
        self.runtime = runtime
        self.index = 0  # the request being encoded
        self.done, self.total = 0, 0  # its frames
        self.results: list[EncodeResult] = []
        self.error: BaseException | None = None
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hypergs-encode", daemon=True)

    def _progress(self, done: int, total: int) -> bool:
        self.done, self.total = done, total
        return not self._cancel.is_set()

    def _run(self):
        try:
            for self.index, request in enumerate(self.requests):
                self.done = self.total = 0
                self.results.append(run_encode(request, self.runtime, self._progress))
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
        return not self._thread.is_alive() and (self.error is not None or len(self.results) == len(self.requests))

    def join(self, timeout=None):
        self._thread.join(timeout)

    @property
    def fraction(self) -> float:
        part = self.done / self.total if self.total else 0.0
        return (self.index + part) / max(1, len(self.requests))

    def status(self) -> str:
        """What the job does now, for the status bar."""
        text = f"encoding frame {self.done} of {self.total}" if self.total else "starting"
        if len(self.requests) > 1:
            text += f" of clip {self.index + 1} of {len(self.requests)}"
        return text


def describe(error: BaseException) -> str:
    """The message the user sees for an error (no traceback)."""
    if isinstance(error, HyperGSError):
        return str(error)
    return f"{type(error).__name__}: {error}"
