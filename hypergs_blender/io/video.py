"""Video files with PyAV: probing and streamed decoding, with the short-side resize + centre crop
done while converting each frame to RGB. `frames.py` dispatches between this and image sequences.

Frames come as a viewer shows them (`Display`), so that a converted clip matches its strip frame for frame:
- upright: a phone's portrait video is stored as landscape frames with a display rotation in its container, which
  players, ffmpeg and Blender's Sequencer from 4.4 on apply (4.2's and 4.3's ignore it); sizes are the shown ones too;
- on the nominal rate's grid (`frame_grid`, `on_grid`): a phone's variable-rate video skips slots, where the frame
  before is held;
- HDR (BT.2020 with HLG or PQ, `hdr_transfer`) as the sRGB picture of its light (colour.hdr_to_srgb_u8), as Blender 5
  colour-manages it (4.2 to 4.5 show the coded values).
What the Blender running the extension shows is com/compat.py's MOVIE_DISPLAY."""
from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np

from .. import limits
from ..colour import hdr_to_srgb_u8
from ..errors import VideoError


@dataclass(frozen=True)
class Display:
    """What a viewer does to a video's coded frames before showing them: turn them by the container's display
    rotation, and colour-manage HDR video (the sRGB picture of its light). Players, ffmpeg and Blender 5's
    Sequencer do both (the default); what older Blenders do is com/compat.py's MOVIE_DISPLAY."""
    rotation: bool = True
    hdr: bool = True


SHOWN = Display()  # as players show a video


@dataclass(frozen=True)
class VideoInfo:
    """What `probe` tells of a video or an image sequence: the size of its frames as shown (Display)."""
    path: str
    width: int
    height: int
    fps: float
    num_frames: int
    hdr: str | None = None  # "hlg" or "pq" (hdr_transfer) where read as the sRGB picture of its light, at a cost


# ffmpeg's codes of the HDR video Blender 5 colour-manages (movie_read.cc): BT.2020 primaries with a transfer
HDR_TRANSFERS = {18: "hlg", 16: "pq"}  # AVCOL_TRC_ARIB_STD_B67, AVCOL_TRC_SMPTEST2084
BT2020_PRIMARIES = 9  # AVCOL_PRI_BT2020


def hdr_transfer(frame) -> str | None:
    """"hlg" or "pq" for a frame of HDR video (BT.2020 primaries), else None."""
    return HDR_TRANSFERS.get(int(frame.color_trc)) if int(frame.color_primaries) == BT2020_PRIMARIES else None


def quarter_turns(frame, display: Display = SHOWN) -> int:
    """Counter-clockwise quarter turns that make a decoded frame as `display` shows it (its display rotation,
    0-3, or 0 where the rotation is not applied)."""
    return round(frame.rotation / 90) % 4 if display.rotation else 0


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


def frame_grid(container, stream) -> tuple[float, int]:
    """(rate, count): the frames a video shows, as Blender's movie strips show them (movie_read.cc): `rate` a
    second, ffmpeg's guess of the nominal rate (a phone's variable-rate video averages less), and as many as the
    stream's duration (else the container's, less the video's delay after the audio) holds; count 0 where the
    file says neither."""
    import av

    rate = float(stream.guessed_rate or stream.average_rate or 24)
    if not stream.time_base:  # no timestamps to place frames by
        return rate, 0
    if stream.duration is not None:
        seconds = float(stream.duration * stream.time_base)
    elif container.duration is not None:
        start = lambda s: float(s.start_time * s.time_base) if s.start_time is not None else 0.0  # noqa: E731
        audio = next((start(a) for a in container.streams.audio), 0.0)
        seconds = container.duration / av.time_base - max(0.0, start(stream) - audio)
    else:
        return rate, 0
    return rate, math.floor(seconds * rate + 0.5)


def probe(path, display: Display = SHOWN) -> VideoInfo:
    """Size as `display` shows the frames, frame rate, frame count on the grid of `frame_grid`, and the HDR transfer
    `display` colour-manages. Decodes the first frame (which carries the container's display rotation and colour
    tags), and counts by decoding when the file does not say."""
    import av

    container, stream = _open(path)
    with container:
        width, height = stream.codec_context.width, stream.codec_context.height
        if width > 0 and height > 0:  # before decoding anything
            limits.check_image_size(width, height, str(path))
        fps, count = frame_grid(container, stream)
        try:
            frames = container.decode(stream)
            first = next(frames, None)
            if count <= 0:
                count = (first is not None) + sum(1 for _ in frames)
        except av.error.FFmpegError as e:
            raise VideoError(f"{path}: cannot decode video ({e})") from e
    if first is None or count <= 0 or width <= 0 or height <= 0:
        raise VideoError(f"{path}: video has no decodable frames")
    if quarter_turns(first, display) % 2:
        width, height = height, width
    limits.FRAMES.check(count, str(path))
    return VideoInfo(str(path), width, height, fps, count, hdr_transfer(first) if display.hdr else None)


def iter_frames(path, indices=None, size: int | None = None,
                display: Display = SHOWN) -> Iterator[tuple[int, np.ndarray]]:
    """Yield (index, frame) with frame uint8 [H, W, 3] RGB as `display` shows it, decoding one frame at a time.

    indices: sorted frame indices to yield (None: every frame). size: short side resized to `size`
    and the frame centre-cropped to size x size (None: native size).
    """
    import av

    wanted = None if indices is None else sorted(set(indices))
    container, stream = _open(path)
    with container:
        try:
            rate, count = frame_grid(container, stream)
            decoded = container.decode(stream)
            position = 0
            for index, frame in (on_grid(decoded, stream, rate, count, path) if count else enumerate(decoded)):
                if wanted is not None:
                    if position >= len(wanted):
                        break
                    if index != wanted[position]:
                        continue
                    position += 1
                limits.check_image_size(frame.width, frame.height, f"{path}: frame {index}")
                yield index, to_canvas(frame, size, display)
        except av.error.FFmpegError as e:
            raise VideoError(f"{path}: cannot decode video ({e})") from e
    if wanted is not None and position < len(wanted):
        raise VideoError(f"{path}: frame {wanted[position]} is past the end of the video")


def on_grid(decoded, stream, rate: float, count: int, path):
    """(k, the frame shown k / rate seconds after the stream's start) for k < count, as Blender's movie strip
    picks it: the last frame whose timestamp is not later. A variable-rate video's frame is held where it skips a
    slot, and frames that come faster than the rate are passed over; a constant-rate video gives each frame once,
    in order (a frame without a timestamp takes the next slot); the last frame is held to the stated duration's
    end. Raises VideoError where the frames end more than a second before it (a cut-off file)."""
    ticks_per_frame = 1 / (rate * float(stream.time_base))
    start = stream.start_time or 0
    ticks = lambda frame, n: frame.pts if frame.pts is not None else start + round(n * ticks_per_frame)  # noqa: E731
    shown, upcoming, taken = None, next(decoded, None), 0
    for k in range(count):
        due = start + round(k * ticks_per_frame)
        while upcoming is not None and (shown is None or ticks(upcoming, taken) <= due):
            shown, upcoming, taken = upcoming, next(decoded, None), taken + 1
        if shown is None:
            return
        last_end = ticks(shown, taken - 1) + max(shown.duration or 0, ticks_per_frame)
        if upcoming is None and due >= last_end + rate * ticks_per_frame:  # more missing than a rounding's second
            raise VideoError(f"{path}: only {taken} of its {count} frames can be decoded: the file is cut off")
        yield k, shown


def to_canvas(frame, size: int | None, display: Display = SHOWN) -> np.ndarray:
    """An av.VideoFrame as RGB uint8 as `display` shows it; resized (short side = size, area filter) and
    centre-cropped. Colour-managed HDR video is decoded at 16 bits and mapped to the sRGB picture Blender 5 shows
    of it (colour.hdr_to_srgb_u8)."""
    turns = quarter_turns(frame, display)
    if size is None:
        rgb = np.rot90(rgb_of(frame, display.hdr), turns)
        return np.ascontiguousarray(rgb)
    w, h = (frame.height, frame.width) if turns % 2 else (frame.width, frame.height)  # as shown
    scale = size / min(w, h)
    rw, rh = max(size, round(w * scale)), max(size, round(h * scale))
    stored_w, stored_h = (rh, rw) if turns % 2 else (rw, rh)  # resized as stored, then turned
    rgb = np.rot90(rgb_of(frame, display.hdr, width=stored_w, height=stored_h, interpolation="AREA"), turns)
    y0, x0 = (rh - size) // 2, (rw - size) // 2
    return np.ascontiguousarray(rgb[y0:y0 + size, x0:x0 + size])


def rgb_of(frame, hdr: bool = True, **resize) -> np.ndarray:
    """The frame as uint8 RGB (swscale's `resize` arguments, if any), HDR mapped to sRGB where `hdr`, else its
    coded values."""
    transfer = hdr_transfer(frame) if hdr else None
    if transfer is None:
        return frame.to_ndarray(format="rgb24", **resize)
    return hdr_to_srgb_u8(frame.to_ndarray(format="rgb48le", **resize), transfer)
