"""Video files with PyAV: probing and streamed decoding, with the short-side resize + centre crop
done while converting each frame to RGB. `frames.py` dispatches between this and image sequences.

Frames come upright: a phone's portrait video is stored as landscape frames with a display rotation in its
container, which players, ffmpeg and Blender 5's Sequencer apply (Blender 4.2's ignores it). Sizes are the
upright ones too."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import limits
from ..errors import VideoError


@dataclass(frozen=True)
class VideoInfo:
    """What `probe` tells of a video or an image sequence: the size of its frames upright."""
    path: str
    width: int
    height: int
    fps: float
    num_frames: int


def quarter_turns(frame) -> int:
    """Counter-clockwise quarter turns that make a decoded frame upright (its display rotation, 0-3)."""
    return round(frame.rotation / 90) % 4


def _open(path):
    import av

    path = Path(path)
    if not path.is_file():
        raise VideoError(f"{path}: no such video file")
    try:
        container = av.open(str(path))
    except (av.error.FFmpegError, UnicodeDecodeError) as e:
        raise VideoError(f"{path}: not a readable video ({e})") from e
    if not container.streams.video:
        container.close()
        raise VideoError(f"{path}: has no video stream")
    stream = container.streams.video[0]
    stream.thread_type = "AUTO"
    return container, stream


def probe(path) -> VideoInfo:
    """Upright size, frame rate and frame count. Decodes the first frame (which carries the container's display
    rotation), and counts by decoding when the container does not say."""
    import av

    container, stream = _open(path)
    with container:
        fps = float(stream.average_rate or stream.guessed_rate or 24)
        width, height = stream.codec_context.width, stream.codec_context.height
        if width > 0 and height > 0:  # before decoding anything
            limits.check_image_size(width, height, str(path))
        count = stream.frames
        try:
            frames = container.decode(stream)
            first = next(frames, None)
            if count <= 0:
                count = (first is not None) + sum(1 for _ in frames)
        except av.error.FFmpegError as e:
            raise VideoError(f"{path}: cannot decode video ({e})") from e
    if first is None or count <= 0 or width <= 0 or height <= 0:
        raise VideoError(f"{path}: video has no decodable frames")
    if quarter_turns(first) % 2:
        width, height = height, width
    limits.FRAMES.check(count, str(path))
    return VideoInfo(str(path), width, height, fps, count)


def iter_frames(path, indices=None, size: int | None = None) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (index, frame) with frame uint8 [H, W, 3] RGB, decoding one frame at a time.

    indices: sorted frame indices to yield (None: every frame). size: short side resized to `size`
    and the frame centre-cropped to size x size (None: native size).
    """
    import av

    wanted = None if indices is None else sorted(set(indices))
    container, stream = _open(path)
    with container:
        try:
            position = 0
            for index, frame in enumerate(container.decode(stream)):
                if wanted is not None:
                    if position >= len(wanted):
                        break
                    if index != wanted[position]:
                        continue
                    position += 1
                limits.check_image_size(frame.width, frame.height, f"{path}: frame {index}")
                yield index, to_canvas(frame, size)
        except av.error.FFmpegError as e:
            raise VideoError(f"{path}: cannot decode video ({e})") from e
    if wanted is not None and position < len(wanted):
        raise VideoError(f"{path}: frame {wanted[position]} is past the end of the video")


def to_canvas(frame, size: int | None) -> np.ndarray:
    """An av.VideoFrame as RGB uint8, upright; resized (short side = size, area filter) and centre-cropped."""
    turns = quarter_turns(frame)
    if size is None:
        return np.ascontiguousarray(np.rot90(frame.to_ndarray(format="rgb24"), turns))
    w, h = (frame.height, frame.width) if turns % 2 else (frame.width, frame.height)  # upright
    scale = size / min(w, h)
    rw, rh = max(size, round(w * scale)), max(size, round(h * scale))
    stored_w, stored_h = (rh, rw) if turns % 2 else (rw, rh)  # resized as stored, then turned
    rgb = np.rot90(frame.to_ndarray(format="rgb24", width=stored_w, height=stored_h, interpolation="AREA"), turns)
    y0, x0 = (rh - size) // 2, (rw - size) // 2
    return np.ascontiguousarray(rgb[y0:y0 + size, x0:x0 + size])
