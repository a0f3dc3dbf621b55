"""What reading, writing and rendering may cost, declared once. Every reader and writer checks its
input against these before it allocates; a hostile or broken file (a 2 MB zip bomb, a 400-byte .hgs
declaring a 65535 x 65535 canvas) is refused with one line naming the file, the limit and how to
raise it, instead of exhausting memory or time.

Each limit (the list at the end of this module, tabled in the README) has a default and an
environment variable HYPERGS_LIMIT_<NAME> that raises (or lowers) it, read at every check, e.g.
`HYPERGS_LIMIT_BYTES=8e9 hypergs export-usd long.hgs long.usd`. Values are whole numbers
(`8_000_000_000` and `8e9` work too). Pure Python: no numpy, torch or bpy.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from .errors import HyperGSError, LimitError

PARAM_BYTES = 8 * 4  # one Gaussian in memory: 8 float32


@dataclass(frozen=True)
class Limit:
    name: str
    default: int
    unit: str  # what is counted, after the number: "Gaussians per frame"
    in_bytes: bool = False  # amounts print as 9,600 bytes, 3.5 MiB, 2 GiB

    @property
    def variable(self) -> str:
        return f"HYPERGS_LIMIT_{self.name}"

    @property
    def value(self) -> int:
        text = os.environ.get(self.variable, "").strip()
        if not text:
            return self.default
        try:
            value = float(text)  # also reads 8e9 and 8_000_000_000
        except ValueError:
            value = 0.0
        if not (1 <= value < float("inf") and value.is_integer()):
            raise LimitError(f"{self.variable}={text!r}: a limit must be a whole number >= 1")
        return int(value)

    def check(self, amount, where: str) -> None:
        """Raises LimitError when `amount` is over the limit; `where` names the file or option (or is
        empty, where the caller names it)."""
        limit = self.value
        if amount > limit:
            raise LimitError(f"{where + ': ' if where else ''}{self.format(amount)} {self.unit}, over the limit of "
                             f"{self.format(limit)} (set {self.variable} to raise it)")

    def format(self, amount) -> str:
        if self.in_bytes:
            return byte_text(amount)
        return f"{amount:,.0f}" if amount < 1e15 else f"{amount:.3g}"


def byte_text(amount) -> str:
    """A size for a message: bytes below 1 MiB, then MiB, then GiB."""
    if amount >= 1 << 20:
        return f"{amount / 2**30:.3g} GiB" if amount >= 1 << 30 else f"{amount / 2**20:.3g} MiB"
    return f"{amount:,.0f} bytes"


GAUSSIANS = Limit("GAUSSIANS", 1 << 20, "Gaussians per frame")
FRAMES = Limit("FRAMES", 1 << 20, "frames")  # in a clip, a video, an image sequence
SIDE = Limit("SIDE", 1 << 15, "pixels wide or high")  # an image, a canvas, a render
PIXELS = Limit("PIXELS", 1 << 26, "pixels in one image")  # 8192 x 8192
BYTES = Limit("BYTES", 1 << 30, "of data decoded at once", True)  # a whole clip, an image, a rendered batch
METADATA = Limit("METADATA", 1 << 20, "of metadata", True)  # a clip's JSON
# The sum over a frame's Gaussians of their box area (raster.SIGMA_CUTOFF) clipped to the frame: the render's cost
# (raster.box_work). 2^30 takes ~4 s with numba on 2 cores, ~40 s on the numpy-only path.
WORK = Limit("WORK", 1 << 30, "Gaussian-pixels to render in one frame")
ALL = (GAUSSIANS, FRAMES, SIDE, PIXELS, BYTES, METADATA, WORK)


def check_image_size(width: int, height: int, where: str) -> None:
    """An image, a canvas or a render of width x height: both >= 1 and within SIDE and PIXELS."""
    if width < 1 or height < 1:
        raise HyperGSError(f"{where}: {width} x {height} is not an image size (both must be at least 1)")
    SIDE.check(max(width, height), where)
    PIXELS.check(width * height, f"{where} ({width} x {height})")


def check_clip_size(frames: int, gaussians: int, where: str) -> None:
    """A clip of frames x gaussians held in memory: within FRAMES, GAUSSIANS and BYTES."""
    FRAMES.check(frames, where)
    GAUSSIANS.check(gaussians, where)
    BYTES.check(frames * gaussians * PARAM_BYTES, f"{where} ({frames:,} frames x {gaussians:,} Gaussians)")
