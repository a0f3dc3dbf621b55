"""Image sequences through OpenImageIO: PNG, EXR, DPX, TIFF, JPEG... as a video, and single-image output.

A sequence is named by any of
  - a frame-number pattern: `shot.####.exr` (at least that many digits, Blender's convention),
    `shot.%04d.exr` (printf), `shot.{frame}.exr` or `shot.{frame:04d}.exr` (Python format);
  - a directory holding one sequence (files `<prefix><digits><suffix>` with an image extension);
  - one file of the sequence, `shot.0001.exr`: the sequence is its siblings with the same prefix,
    suffix and a frame number (a file name without digits is a one-frame sequence).
Frames are the files that exist, in frame-number order; gaps are skipped. `probe` and `iter_frames`
mirror video.probe / video.iter_frames: frame indices are positions 0..num_frames-1 in that order
(`list_frames` gives the frame numbers).

Colour: integer files (PNG, TIFF, DPX, JPEG) are taken as display-referred (sRGB-encoded) code values;
float files (EXR, float TIFF) as scene-linear, encoded with the sRGB transfer curve and clipped to
[0, 1], unless their colour space says sRGB. No other colour management (a log DPX stays log).
Alpha is dropped after OpenImageIO's premultiplication (the image composited over black); grey is
replicated to RGB.
"""
from __future__ import annotations

import re
from pathlib import Path
from typing import Iterator

import numpy as np

from .errors import HyperGSError, VideoError
from .video import VIDEO_EXTENSIONS, VideoInfo, resize_crop

IMAGE_EXTENSIONS = (".png", ".exr", ".dpx", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".tga", ".hdr", ".cin")
_PATTERN = re.compile(r"(#+)|%(0?\d*)d|\{frame(?::0?(\d*)d)?\}")
_NUMBERED = re.compile(r"^(.*?)(\d+)(\D*)$")


def is_image_sequence(path) -> bool:
    """True for what this module reads: a frame pattern, a directory, or an image file (a name with a
    video suffix such as .mp4 is never a sequence)."""
    p = Path(str(path))
    if p.suffix.lower() in VIDEO_EXTENSIONS:
        return False
    return bool(_PATTERN.search(p.name)) or p.is_dir() or p.suffix.lower() in IMAGE_EXTENSIONS


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
    return sorted(frames.items())


def _listdir(folder: Path) -> list[Path]:
    try:
        return [f for f in folder.iterdir() if f.is_file()]
    except OSError as e:
        raise VideoError(f"{folder}: cannot list ({e.strerror})") from e


def read_image(path) -> np.ndarray:
    """One image file -> uint8 [H, W, 3] RGB (see the module doc for the colour handling)."""
    import OpenImageIO as oiio

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise VideoError(f"{path}: not a readable image ({oiio.geterror() or 'unknown error'})")
    try:
        spec = inp.spec()
        if spec.width <= 0 or spec.height <= 0 or spec.nchannels <= 0:
            raise VideoError(f"{path}: image has no pixels")
        channels = min(spec.nchannels, 3) if spec.nchannels != 2 else 1
        if spec.format.basetype == oiio.UINT8:
            pixels = inp.read_image(0, 0, 0, channels, oiio.UINT8)
            linear = False
        else:
            pixels = inp.read_image(0, 0, 0, channels, oiio.FLOAT)
            space = spec.get_string_attribute("oiio:ColorSpace").lower()
            floating = spec.format.basetype in (oiio.HALF, oiio.FLOAT, oiio.DOUBLE)
            linear = "lin" in space or (floating and "srgb" not in space)
    finally:
        inp.close()
    if pixels is None:
        raise VideoError(f"{path}: cannot decode image ({oiio.geterror() or 'unknown error'})")
    pixels = np.asarray(pixels).reshape(spec.height, spec.width, channels)
    if channels == 1:
        pixels = np.repeat(pixels, 3, axis=-1)
    if pixels.dtype != np.uint8:
        values = np.nan_to_num(pixels.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
        if linear:
            values = linear_to_srgb(values)
        pixels = np.round(np.clip(values, 0, 1) * 255).astype(np.uint8)
    return np.ascontiguousarray(pixels)


def probe(path, fps: float = 24.0) -> VideoInfo:
    """Size (of the first frame), frame rate (image files have none: `fps`) and frame count."""
    frames = list_frames(path)
    first = read_image(frames[0][1])
    return VideoInfo(str(path), first.shape[1], first.shape[0], float(fps), len(frames))


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


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """sRGB decoding, extended to negatives and values above 1 (odd-symmetric, power law above 1)."""
    a = np.abs(v)
    out = np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
    return (np.sign(v) * out).astype(np.float32)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    a = np.abs(v)
    out = np.where(a <= 0.0031308, a * 12.92, 1.055 * a ** (1 / 2.4) - 0.055)
    return (np.sign(v) * out).astype(np.float32)


def write_image(path, rgb: np.ndarray) -> None:
    """Write float [H, W, 3] sRGB-encoded values (a render) to one image file; the suffix picks:
      .exr        half float, converted to scene-linear (extended sRGB decoding: values past [0, 1] kept)
      .tif/.tiff  16-bit, .dpx 10-bit, others (.png, .jpg...) 8-bit: clipped to [0, 1], sRGB-encoded."""
    import OpenImageIO as oiio

    path = Path(path)
    rgb = np.asarray(rgb, dtype=np.float32)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise HyperGSError(f"write_image needs [H, W, 3] pixels, got {rgb.shape}")
    ext = path.suffix.lower()
    height, width = rgb.shape[:2]
    if ext == ".exr":
        pixels, fmt = srgb_to_linear(np.nan_to_num(rgb)), oiio.HALF
        space = "lin_rec709"
    else:
        pixels = np.clip(np.nan_to_num(rgb), 0, 1)
        fmt = oiio.UINT16 if ext in (".tif", ".tiff", ".dpx") else oiio.UINT8
        space = "sRGB"
    out = oiio.ImageOutput.create(str(path))
    if out is None:
        raise HyperGSError(f"{path}: no image format for {ext!r} ({oiio.geterror()})")
    spec = oiio.ImageSpec(width, height, 3, fmt)
    spec.attribute("oiio:ColorSpace", space)
    if ext == ".dpx":
        spec.attribute("oiio:BitsPerSample", 10)
    if not out.open(str(path), spec):
        raise HyperGSError(f"{path}: cannot write ({out.geterror() or oiio.geterror()})")
    ok = out.write_image(np.ascontiguousarray(pixels))
    error = out.geterror()
    out.close()
    if not ok:
        raise HyperGSError(f"{path}: cannot write ({error})")
