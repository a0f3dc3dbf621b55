"""Encoding work that runs off Blender's main thread. No bpy here: a job only sees paths and the
encode settings; it streams each clip's Gaussians into a new frame cache file (io/cache.py), a group of
frames at a time, and hands back what it wrote; the operator writes to bpy on the main thread when the
job is done.

All or nothing: a job that fails or is cancelled leaves no file behind (the cache writer only renames a
complete file into place, and the caches of the clips already done are removed again), nor a folder it
made; `discard()` does the same for a finished job whose result the operator could not use. The
encoder's runtime memory is given back when a job ends (`release`: onnxruntime's arena)."""
from __future__ import annotations

import os
import threading
import time
from dataclasses import dataclass

from ..hypergs_blender.encode import EncodePlan, EncodeSettings, psnr_sample_count
from ..hypergs_blender.io import cache
from ..hypergs_blender.io.files import check_free_space, make_folders, remove_folders
from ..hypergs_blender.io.hgs import HgsHeader
from ..hypergs_blender.io.video import SHOWN, Display
from ..hypergs_blender.runtime import Runtime, describe_encoder, make_encoder


@dataclass(frozen=True)
class Source:
    """Frames [start, stop) of a video or image sequence to encode (stop None: to its end), a video's frames as
    `display` shows them (compat.MOVIE_DISPLAY: as this Blender's movie strips do); `fps`, when given, is the clip's
    frame rate instead of the source's (image files have none: the scene's)."""
    name: str
    path: str
    start: int = 0
    stop: int | None = None
    fps: float | None = None
    display: Display = SHOWN


@dataclass
class EncodeResult:
    cache: str  # the frame cache file written (absolute path)
    clip: HgsHeader  # what it holds: canvas, Gaussians per frame, frames, fps, grid, source
    psnr: float
    seconds: float
    encoder: str  # what encoded, and on which device (describe_encoder)


def run_encode(source: Source, settings: EncodeSettings, target: str, encoder, runtime: Runtime = Runtime(),
               progress=None) -> EncodeResult:
    """Encode `source` with `encoder` (make_encoder(runtime, settings.model)) into a new frame cache at `target` (its
    folder must exist), measuring the PSNR of frames spread over the clip (encode.psnr_sample_count of them) on the
    frames the encode decoded. A folder with less room than the cache's estimate is refused before any frame is
    encoded. progress(done, total) -> False cancels (raises Cancelled; no file is left)."""
    started = time.perf_counter()
    plan = EncodePlan(source.path, encoder, settings, start=source.start, stop=source.stop, display=source.display)
    check_free_space(target, plan.cache_bytes, f"the frame cache of {len(plan.indices)} frames")
    with cache.writer(target, plan.width, plan.height, plan.layout.count, source.fps or plan.fps, plan.grid,
                      plan.source) as writer:
        for _, params in plan.chunks(progress, psnr_frames=psnr_sample_count(len(plan.indices))):
            writer.write(params)
    return EncodeResult(target, writer.header, plan.psnr, time.perf_counter() - started,
                        describe_encoder(encoder, runtime))


class EncodeJob:
    """run_encode for each source in turn into its target path, on a worker thread; `cancel()` makes
    its progress callback return False. All or nothing (see the module doc): the job has `results` for
    every source, or an `error` and no file."""

    def __init__(self, sources: list[Source], targets: list[str], settings: EncodeSettings,
                 runtime: Runtime = Runtime()):
        if len(targets) != len(sources):
            raise ValueError("one target per source")
        self.sources, self.targets = list(sources), list(targets)
        self.settings = settings
        self.runtime = runtime
        self.index = 0  # the source being encoded
        self.done, self.total = 0, 0  # its frames
        self.results: list[EncodeResult] = []
        self.error: BaseException | None = None
        self._folders: list = []  # folders this job made (removed again by discard when empty)
        self._cancel = threading.Event()
        self._thread = threading.Thread(target=self._run, name="hypergs-encode", daemon=True)

    def _progress(self, done: int, total: int) -> bool:
        self.done, self.total = done, total
        return not self._cancel.is_set()

    def _run(self):
        try:
            encoder = make_encoder(self.runtime, self.settings.model)
            try:
                for self.index, (source, target) in enumerate(zip(self.sources, self.targets)):
                    self.done = self.total = 0
                    self._folders += make_folders(os.path.dirname(target))
                    self.results.append(run_encode(source, self.settings, target, encoder, self.runtime,
                                                   self._progress))
            finally:
                encoder.release()
        except BaseException as e:  # handed to the main thread, which reports it
            self.error = e
            self.discard()

    def discard(self) -> None:
        """Remove what the job wrote: its cache files, then the folders it made if they are empty."""
        for result in self.results:
            try:
                os.remove(result.cache)
            except OSError:
                pass
        self.results.clear()
        remove_folders(self._folders)
        self._folders.clear()

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
