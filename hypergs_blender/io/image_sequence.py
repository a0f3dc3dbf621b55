"""Image sequences (PNG, EXR, DPX, TIFF, JPEG... files read by images.read_image) as a video.

A sequence is named by any of
  - a frame-number pattern: `shot.####.exr` (at least that many digits, Blender's convention),
    `shot.%04d.exr` (printf), `shot.{frame}.exr` or `shot.{frame:04d}.exr` (Python format);
  - a directory holding one sequence (files `<prefix><digits><suffix>` with an image extension);
  - one file of the sequence, `shot.0001.exr`: the sequence is its siblings with the same prefix,
    suffix and a frame number (a file name without digits is a one-frame sequence).
Frames are the files that exist, in frame-number order; gaps are skipped. `probe` and `iter_frames`
mirror video.probe / video.iter_frames: frame indices are positions 0..num_frames-1 in that order
(`list_frames` gives the frame numbers).
Colour: see images.py.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import limits
from ..errors import VideoError
from .images import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS, image_size, read_image, resize_crop
from .video import VideoInfo

_PATTERN = re.compile(r"(#+)|%(0?\d*)d|\{frame(?::0?(\d*)d)?\}")
_NUMBERED = re.compile(r"^(.*?)(\d+)(\D*)$")


def is_image_sequence(path) -> bool:
    """True for what this module reads: a frame pattern, a directory, or an image file (a name with a
    video suffix such as .mp4 is never a sequence)."""
    p = Path(str(path))
    if p.suffix.lower() in VIDEO_EXTENSIONS:
        return False
    return has_frame_pattern(p.name) or p.is_dir() or p.suffix.lower() in IMAGE_EXTENSIONS


def has_frame_pattern(name: str) -> bool:
    """True for a file name with a frame-number field: `#` runs, %0Nd or {frame[:0Nd]}."""
    return bool(_PATTERN.search(name))


def _split_pattern(name: str) -> tuple[str, str] | None:
    """(prefix, suffix) around the single frame-number field of a file-name pattern, or None."""
    matches = list(_PATTERN.finditer(name))
    if not matches:
        return None
    if len(matches) > 1:
        raise VideoError(f"{name}: more than one frame-number field")
    m = matches[0]
    return name[:m.start()], name[m.end():]


def list_frames(path) -> list[tuple[int, Path]]:
    """[(frame number, file)] of the sequence, sorted by frame number. Raises VideoError if empty."""
    text = str(path)
    p = Path(text)
    parts = _split_pattern(p.name)
    if parts is None and p.is_dir():
        folder, groups = p, {}
        for f in _listdir(p):
            m = _NUMBERED.match(f.stem)
            if f.suffix.lower() in IMAGE_EXTENSIONS and m:
                groups.setdefault((m.group(1), m.group(3) + f.suffix), []).append(f)
        if not groups:
            raise VideoError(f"{p}: no numbered image files in this folder")
        if len(groups) > 1:
            names = ", ".join(sorted(f"{a}#{b}" for a, b in groups))
            raise VideoError(f"{p}: several image sequences in this folder ({names}); name one with a pattern")
        parts = next(iter(groups))
    elif parts is None:
        if not p.is_file():
            raise VideoError(f"{p}: no such image file")
        m = _NUMBERED.match(p.stem)
        if not m:
            return [(0, p)]
        folder, parts = p.parent, (m.group(1), m.group(3) + p.suffix)
    else:
        folder = p.parent
        if not folder.is_dir():
            raise VideoError(f"{folder}: no such folder")
    prefix, suffix = parts
    regex = re.compile(re.escape(prefix) + r"(\d+)" + re.escape(suffix) + r"\Z")
    frames = {}
    for f in _listdir(folder):
        m = regex.match(f.name)
        if m:
            number = int(m.group(1))
            if number in frames:
                raise VideoError(f"{folder}: frame {number} appears twice ({frames[number].name}, {f.name})")
            frames[number] = f
    if not frames:
        raise VideoError(f"{text}: no image files match this sequence")
    limits.FRAMES.check(len(frames), text)
    return sorted(frames.items())


def _listdir(folder: Path) -> list[Path]:
    try:
        return [f for f in folder.iterdir() if f.is_file()]
    except OSError as e:
        raise VideoError(f"{folder}: cannot list ({e.strerror})") from e


def probe(path, fps: float = 24.0) -> VideoInfo:
    """Size (of the first frame, read from its header), frame rate (image files have none: `fps`) and
    frame count."""
    frames = list_frames(path)
    width, height = image_size(frames[0][1])
    return VideoInfo(str(path), width, height, float(fps), len(frames))


def iter_frames(path, indices=None, size: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (index, uint8 [H, W, 3]) like video.iter_frames: indices are positions in the sequence,
    `size` short-side resizes and centre-crops to size x size. All frames must share one size."""
    frames = list_frames(path)
    wanted = range(len(frames)) if indices is None else sorted(set(int(i) for i in indices))
    shape = None
    for index in wanted:
        if not 0 <= index < len(frames):
            raise VideoError(f"{path}: frame {index} is past the end of the {len(frames)}-frame sequence")
        image = read_image(frames[index][1])
        if shape is None:
            shape = image.shape
        elif image.shape != shape:
            raise VideoError(f"{frames[index][1]}: {image.shape[1]}x{image.shape[0]} differs from the "
                             f"sequence's {shape[1]}x{shape[0]}")
        yield index, (image if size is None else resize_crop(image, size))


def frame_path(pattern, frame: int) -> str:
    """The file name for one frame: `#` runs, %0Nd and {frame[:0Nd]} are replaced by the number.
    A name without a frame field gets `_<frame:04d>` before its suffix."""
    pattern = str(pattern)
    p = Path(pattern)
    m = _PATTERN.search(p.name)
    if m is None:
        return str(p.with_name(f"{p.stem}_{frame:04d}{p.suffix}"))
    width = len(m.group(1)) if m.group(1) else int(m.group(2) or m.group(3) or 0)
    name = p.name[:m.start()] + f"{frame:0{width}d}" + p.name[m.end():]
    return str(p.with_name(name))
