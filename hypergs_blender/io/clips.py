"""Load and save GaussianVideo clips, choosing the format by file suffix:
  .hgs              compressed (codec.py / hgs.py); options: bits (8, 6, 4 or 8 values), group_size, mode
  .npz              uncompressed float32 (npz.py); options are ignored
  .usd/.usda/.usdc  UsdGeomPoints with a time sample per frame (usd.py); option: start_frame

`save_clip` takes a whole clip in memory (GaussianVideo) or one read a frame at a time (`ClipFrames`:
e.g. Blender's frame cache with the user's edited frames), which .hgs and USD files stream: memory
holds a group of frames whatever the clip's length (.npz files are written whole, within limits.py).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Iterator

import numpy as np

from .. import limits
from ..errors import HyperGSError
from ..gaussians import GaussianVideo, param_problem


@dataclass(frozen=True)
class ClipFrames:
    """A clip read a frame at a time: `frames()` starts a new pass over its frames, yielding params
    [num_gaussians, 8] float32 for each in order (a writer may make two passes: .hgs fits its ranges
    first). The header fields are those of a GaussianVideo."""
    frames: Callable[[], Iterator[np.ndarray]]
    num_frames: int
    num_gaussians: int
    canvas_width: int
    canvas_height: int
    fps: float = 24.0
    grid: tuple[int, int] = (1, 1)
    source: dict = field(default_factory=dict)

    @classmethod
    def of(cls, clip) -> "ClipFrames":
        """The frames of a GaussianVideo, or of an open HgsReader (read as they are wanted)."""
        if isinstance(clip, GaussianVideo):
            frames = lambda: iter(clip.params)  # noqa: E731
        else:
            frames = lambda: (params for _, params in clip.iter_frames())  # noqa: E731
        return cls(frames, clip.num_frames, clip.num_gaussians, clip.canvas_width, clip.canvas_height, clip.fps,
                   tuple(clip.grid), dict(clip.source))

    def checked_frames(self, where) -> Iterator[np.ndarray]:
        """frames(), each checked as save_clip checks a whole clip (HyperGSError naming `where` and the
        frame); their count must be num_frames."""
        count = 0
        for count, params in enumerate(self.frames(), 1):
            params = np.asarray(params, np.float32)
            if params.shape != (self.num_gaussians, 8):
                raise HyperGSError(f"{where}: frame {count - 1} holds {params.shape} parameters, "
                                   f"expected ({self.num_gaussians}, 8)")
            problem = param_problem(params)
            if problem:
                raise HyperGSError(f"{where}: frame {count - 1}: {problem}")
            yield params
        if count != self.num_frames:
            raise HyperGSError(f"{where}: {count} frames read, expected {self.num_frames}")

CLIP_SUFFIXES = (".hgs", ".npz", ".usd", ".usda", ".usdc")
_SAVE_OPTIONS = {".hgs": {"bits", "group_size", "mode", "quantizer"}, ".npz": {"bits"},
                 ".usd": {"start_frame", "bits"}}


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".usda", ".usdc"):
        return ".usd"
    if suffix not in CLIP_SUFFIXES:
        raise HyperGSError(f"{path}: unknown Gaussian video format {path.suffix!r} (use {', '.join(CLIP_SUFFIXES)})")
    return suffix


def save_clip(video: GaussianVideo | ClipFrames, path, **options) -> None:
    """Write `video` (whole, or read a frame at a time) to `path` in the format its suffix names. `bits`
    only matters for .hgs."""
    path = Path(path)
    suffix = _suffix(path)
    unknown = set(options) - _SAVE_OPTIONS[suffix]
    if unknown:
        raise HyperGSError(f"{path}: option(s) {', '.join(sorted(unknown))} do not apply to {suffix} files")
    if isinstance(video, ClipFrames):
        return _save_frames(video, path, suffix, options)
    problem = param_problem(video.params)
    if problem:  # a file that no reader would accept
        raise HyperGSError(f"{path}: {problem}")
    if suffix == ".hgs":
        from .hgs import save_hgs
        save_hgs(video, path, **options)
    elif suffix == ".npz":
        from .npz import save_npz
        save_npz(video, path)
    else:
        from .usd import export_usd
        export_usd(video, path, start_frame=options.get("start_frame", 1))


def _save_frames(clip: ClipFrames, path: Path, suffix: str, options: dict) -> None:
    if clip.num_frames < 1:
        raise HyperGSError(f"{path}: cannot save an empty clip (no frames)")
    header = (clip.canvas_width, clip.canvas_height, clip.num_gaussians)
    if suffix == ".npz":  # written whole
        limits.check_clip_size(clip.num_frames, clip.num_gaussians, str(path))
        from .npz import save_npz
        params = np.stack(list(clip.checked_frames(path)))
        save_npz(GaussianVideo(params, *header[:2], clip.fps, clip.grid, clip.source), path)
        return
    if suffix == ".hgs":
        from .codec import CodecError, Quantizer, clip_bits
        from .hgs import DEFAULT_GROUP_SIZE, HgsError, HgsWriter
        try:  # a first pass fits the quantizer's ranges to the whole clip, as save_hgs does
            quantizer = options.get("quantizer") or Quantizer.fit(
                clip.checked_frames(path), clip_bits(options.get("bits", 8), *header))
        except CodecError as e:
            raise HgsError(str(e)) from e
        writer = HgsWriter(path, *header, quantizer, clip.fps, clip.grid, clip.source,
                           options.get("group_size", DEFAULT_GROUP_SIZE), options.get("mode", "auto"))
    else:
        from .usd import UsdWriter
        writer = UsdWriter(path, *header, clip.fps, clip.grid, clip.source, options.get("start_frame", 1))
    with writer:
        for params in clip.checked_frames(path):
            writer.write(params)


def load_clip(path) -> GaussianVideo:
    path = Path(path)
    suffix = _suffix(path)
    if not path.is_file():
        raise HyperGSError(f"{path}: no such file")
    if suffix == ".hgs":
        from .hgs import load_hgs
        return load_hgs(path)
    if suffix == ".usd":
        from .usd import import_usd
        return import_usd(path)
    from .npz import load_npz
    return load_npz(path)
