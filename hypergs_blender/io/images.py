"""Single images through OpenImageIO (reading and writing) and resizing through PyAV: the one place
that decides how an image file becomes RGB uint8 pixels.

Reading: integer files (PNG, TIFF, DPX, JPEG) are display-referred (sRGB-encoded) code values; float
files (EXR, float TIFF) are scene-linear, encoded with the sRGB transfer curve and clipped to [0, 1],
unless their colour space says sRGB. No other colour management (a log DPX stays log). Alpha is
dropped after OpenImageIO's premultiplication (the image composited over black); grey is replicated
to RGB. The pixels come as stored, an EXIF orientation tag ignored: Blender's images and image strips
ignore it (measured on 4.2.23, 5.0.1, 5.2.3 and 5.3.0: a file tagged "rotate 90" shows as stored), so a
converted strip shows what the strip showed. The size in the file's header is checked against the
limits (limits.py) before any pixel is decoded.

Writing goes through files.AtomicOutput: a temporary file renamed onto the name when complete.
"""
from __future__ import annotations

import threading
from pathlib import Path

import numpy as np

from .. import limits, optional
from ..colour import linear_to_srgb, srgb_to_linear
from ..errors import HyperGSError, VideoError, one_line
from .files import AtomicOutput

IMAGE_EXTENSIONS = (".png", ".exr", ".dpx", ".tif", ".tiff", ".jpg", ".jpeg", ".bmp", ".tga", ".hdr", ".cin",
                    ".webp")
VIDEO_EXTENSIONS = (".mp4", ".mov", ".mkv", ".avi", ".webm", ".m4v")


def list_files(folder, extensions) -> list[Path]:
    """Files anywhere under `folder` whose names end in one of `extensions` (any case), sorted."""
    return sorted(p for p in Path(folder).rglob("*") if p.is_file() and p.suffix.lower() in extensions)


def list_images(folder) -> list[Path]:
    """Image files anywhere under `folder`, sorted."""
    return list_files(folder, IMAGE_EXTENSIONS)


def _open(path):
    """(ImageInput, spec) of an image file whose size is within the limits; raises VideoError or
    LimitError naming the file."""
    oiio = optional.require("OpenImageIO")

    inp = oiio.ImageInput.open(str(path))
    if inp is None:
        raise VideoError(f"{path}: not a readable image ({one_line(oiio.geterror()) or 'unknown error'})")
    spec = inp.spec()
    try:
        if spec.width <= 0 or spec.height <= 0 or spec.nchannels <= 0:
            raise VideoError(f"{path}: image has no pixels")
        if spec.depth > 1:
            raise VideoError(f"{path}: a volume image ({spec.depth} slices) is not a picture")
        limits.check_image_size(spec.width, spec.height, str(path))
        limits.BYTES.check(spec.width * spec.height * min(spec.nchannels, 3) * 4, str(path))
    except BaseException:
        inp.close()
        raise
    return inp, spec


def image_size(path) -> tuple[int, int]:
    """(width, height) of an image file, from its header (no pixels decoded)."""
    inp, spec = _open(path)
    inp.close()
    return spec.width, spec.height


def read_image(path, max_short_side: int | None = None) -> np.ndarray:
    """One image file -> uint8 [H, W, 3] RGB (see the module doc), area-downscaled so that its short
    side is at most `max_short_side` when given. Raises VideoError naming the file."""
    oiio = optional.require("OpenImageIO")

    inp, spec = _open(path)
    try:
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
        raise VideoError(f"{path}: cannot decode image ({one_line(oiio.geterror()) or 'unknown error'})")
    pixels = np.asarray(pixels).reshape(spec.height, spec.width, channels)
    if channels == 1:
        pixels = np.repeat(pixels, 3, axis=-1)
    if pixels.dtype != np.uint8:
        values = np.nan_to_num(pixels.astype(np.float32), nan=0.0, posinf=1.0, neginf=0.0)
        if linear:
            values = linear_to_srgb(values)
        pixels = np.round(np.clip(values, 0, 1) * 255).astype(np.uint8)
    if max_short_side and min(pixels.shape[:2]) > max_short_side:
        pixels = downscale(pixels, max_short_side)
    return np.ascontiguousarray(pixels)


def downscale(rgb: np.ndarray, short_side: int) -> np.ndarray:
    """Area-downscale uint8 RGB so that its short side is `short_side` (integer box reduction first,
    which is cheap for very large images, then an area resize)."""
    h, w = rgb.shape[:2]
    k = min(h, w) // short_side
    if k >= 2:
        hh, ww = h // k * k, w // k * k
        rgb = rgb[:hh, :ww].reshape(hh // k, k, ww // k, k, 3).mean((1, 3), dtype=np.float32)
        rgb = (rgb + 0.5).astype(np.uint8)
        h, w = rgb.shape[:2]
    scale = short_side / min(h, w)
    return resize_exact(rgb, max(1, round(w * scale)), max(1, round(h * scale)))


def write_image(path, rgb: np.ndarray) -> None:
    """Write [H, W, 3] pixels to one image file: uint8 code values, or float sRGB-encoded values (a
    render). The suffix picks the format:
      .exr        half float, converted to scene-linear (extended sRGB decoding: values past [0, 1] kept)
      .tif/.tiff  16-bit, .dpx 10-bit, others (.png, .jpg...) 8-bit: clipped to [0, 1], sRGB-encoded."""
    oiio = optional.require("OpenImageIO")

    path = Path(path)
    rgb = np.asarray(rgb)
    if rgb.ndim != 3 or rgb.shape[2] != 3 or rgb.shape[0] == 0 or rgb.shape[1] == 0:
        raise HyperGSError(f"write_image needs [H, W, 3] pixels, got {rgb.shape}")
    rgb = rgb.astype(np.float32) / 255 if rgb.dtype == np.uint8 else rgb.astype(np.float32)
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
        raise HyperGSError(f"{path}: no image format for {ext!r} ({one_line(oiio.geterror())})")
    spec = oiio.ImageSpec(width, height, 3, fmt)
    spec.attribute("oiio:ColorSpace", space)
    if ext == ".dpx":
        spec.attribute("oiio:BitsPerSample", 10)
    with AtomicOutput(path) as temp:
        if not out.open(str(temp), spec):
            raise HyperGSError(f"{path}: cannot write ({one_line(out.geterror() or oiio.geterror())})")
        ok = out.write_image(np.ascontiguousarray(pixels))
        error = out.geterror()
        out.close()
        if not ok:
            raise HyperGSError(f"{path}: cannot write ({one_line(error)})")


def resize_exact(image: np.ndarray, width: int, height: int, interpolation: str = "AREA") -> np.ndarray:
    """RGB uint8 array resized to exactly width x height (aspect not kept) with one of swscale's filters
    (PyAV's names: AREA, the default, averages what each output pixel covers; LANCZOS, BICUBIC, ...)."""
    import av

    if image.shape[1] == width and image.shape[0] == height:
        return image
    frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image), format="rgb24")
    resized = kept_reformatter().reformat(frame, format="rgb24", width=width, height=height,
                                          interpolation=interpolation)
    return resized.to_ndarray()


_thread_state = threading.local()


def kept_reformatter():
    """This thread's av VideoReformatter. A frame's own `to_ndarray(width=...)` builds a new swscale
    context, filter tables included, on every call: that was 3/4 of a small frame's resize (256² to
    220², Lanczos: 11 ms against 2.7 ms with a kept one, the same pixels). The kept one rebuilds only
    when the sizes or filter change; one per thread, as a context must not be used by two at once."""
    from av.video.reformatter import VideoReformatter

    if not hasattr(_thread_state, "reformatter"):
        _thread_state.reformatter = VideoReformatter()
    return _thread_state.reformatter


def resize_crop(image: np.ndarray, size: int) -> np.ndarray:
    """RGB uint8 short side resized to `size` (area filter) and centre-cropped to size x size."""
    h, w = image.shape[:2]
    scale = size / min(w, h)
    rw, rh = max(size, round(w * scale)), max(size, round(h * scale))
    rgb = resize_exact(image, rw, rh)
    y0, x0 = (rh - size) // 2, (rw - size) // 2
    return np.ascontiguousarray(rgb[y0:y0 + size, x0:x0 + size])
