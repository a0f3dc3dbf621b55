"""Encoding work that runs off Blender's main thread. No bpy here: a job only sees paths and the
encode settings, and hands back GaussianVideos; the operator writes to bpy on the main thread when
the job is done."""
from __future__ import annotations

import threading
import time
from dataclasses import dataclass

from ..hypergs_blender.encode import EncodePlan, EncodeSettings
from ..hypergs_blender.gaussians import GaussianVideo
from ..hypergs_blender.runtime import Runtime, describe_encoder, make_encoder

PSNR_FRAMES = 8  # frames (evenly spread) whose PSNR against the source is measured while encoding


@dataclass(frozen=True)
class Source:
    """Frames [start, stop) of a video or image sequence to encode (stop None: to its end)."""
    name: str
    path: str
    start: int = 0
    stop: int | None = None


@dataclass
class EncodeResult:
    video: GaussianVideo
    psnr: float
    seconds: float
    encoder: str  # what encoded, and on which device (describe_encoder)


def run_encode(source: Source, settings: EncodeSettings, runtime: Runtime = Runtime(), progress=None) -> EncodeResult:
    """Encode, measuring the PSNR of up to PSNR_FRAMES frames on the frames the encode decoded.
    runtime: where the network runs; progress(done, total) -> False cancels (raises Cancelled)."""
    started = time.perf_counter()
    encoder = make_encoder(runtime)
    plan = EncodePlan(source.path, encoder, settings, start=source.start, stop=source.stop)
    video = plan.video(progress, psnr_frames=PSNR_FRAMES)
    return EncodeResult(video, plan.psnr, time.perf_counter() - started, describe_encoder(encoder, runtime))


class EncodeJob:
    """run_encode for each source in turn, on a worker thread; `cancel()` makes its progress callback
    return False. All or nothing: the job has `results` for every source, or an `error`."""

    def __init__(self, sources: list[Source], settings: EncodeSettings, runtime: Runtime = Runtime()):
        self.sources = list(sources)
        self.settings = settings
        self.runtime = runtime
        self.index = 0  # the source being encoded
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
            for self.index, source in enumerate(self.sources):
                self.done = self.total = 0
                self.results.append(run_encode(source, self.settings, self.runtime, self._progress))
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
        return not self._thread.is_alive() and (self.error is not None or len(self.results) == len(self.sources))

    def join(self, timeout=None):
        self._thread.join(timeout)

    @property
    def fraction(self) -> float:
        part = self.done / self.total if self.total else 0.0
        return (self.index + part) / max(1, len(self.sources))

    def status(self) -> str:
        """What the job does now, for the status bar."""
        text = f"encoding frame {self.done} of {self.total}" if self.total else "starting"
        if len(self.sources) > 1:
            text += f" of clip {self.index + 1} of {len(self.sources)}"
        return text
