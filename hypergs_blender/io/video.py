"""Video files with PyAV: probing and streamed decoding, with the short-side resize + centre crop
done while converting each frame to RGB. `frames.py` dispatches between this and image sequences."""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import limits
from ..errors import VideoError


@dataclass(frozen=True)
class VideoInfo:
    """What `probe` tells of a video or an image sequence."""
    path: str
    width: int
    height: int
    fps: float
    num_frames: int


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
    """Size, frame rate and frame count. Counts by decoding when the container does not say."""
    import av

    container, stream = _open(path)
    with container:
        fps = float(stream.average_rate or stream.guessed_rate or 24)
        width, height = stream.codec_context.width, stream.codec_context.height
        if width > 0 and height > 0:  # before decoding anything
            limits.check_image_size(width, height, str(path))
        count = stream.frames
        if count <= 0:
            try:
                count = sum(1 for _ in container.decode(stream))
            except av.error.FFmpegError as e:
                raise VideoError(f"{path}: cannot decode video ({e})") from e
    if count <= 0 or width <= 0 or height <= 0:
        raise VideoError(f"{path}: video has no decodable frames")
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
    """An av.VideoFrame as RGB uint8; resized (short side = size, area filter) and centre-cropped."""
    if size is None:
        return frame.to_ndarray(format="rgb24")
    w, h = frame.width, frame.height
    scale = size / min(w, h)
    rw, rh = max(size, round(w * scale)), max(size, round(h * scale))
    rgb = frame.to_ndarray(format="rgb24", width=rw, height=rh, interpolation="AREA")
    y0, x0 = (rh - size) // 2, (rw - size) // 2
    return np.ascontiguousarray(rgb[y0:y0 + size, x0:x0 + size])
