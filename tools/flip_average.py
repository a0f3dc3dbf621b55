"""Test-time flips for the conv network (a probe, not in the product): `hypergs eval` with every forward pass
run on the frame and its mirror images, each mirrored output mapped back to its cell, and the Gaussians of a
cell averaged (means and colours as they are, the shape as the mean of the covariances).

    python tools/flip_average.py --flips 4 eval ../shared/videos/*.mp4 --gaussians 1000 --backend torch --json
    python tools/flip_average.py --flips 1 eval ...   # the plain network, through the same code

--flips 1: the frame alone; 2: and its left-right mirror; 4: and the up-down and both mirrors. Any arguments
after the flags are `hypergs`'s. Session 28 (model card): at N = 1000, 4 flips lose 0.43 dB on the dev clips and
3.48 on the held-out pans (Aqua 37.57 -> 30.10): neighbouring Gaussians share a cell's colour between them, and
each pass shares it differently, so the averages do not add up to the frame.
"""
from __future__ import annotations

import argparse
import sys

import torch

from hypergs_blender import model
from hypergs_blender.commands.cli import main as hypergs_main

FLIPS = ((False, False), (True, False), (False, True), (True, True))  # (left-right, up-down)


def unflip(params: torch.Tensor, rows: int, cols: int, flip_x: bool, flip_y: bool) -> torch.Tensor:
    """The params [B, rows x cols, 8] of a mirrored frame, as the Gaussians of the frame itself."""
    p = params.reshape(len(params), rows, cols, 8).clone()
    for flip, axis, coordinate in ((flip_x, 2, 0), (flip_y, 1, 1)):
        if flip:  # the cell order, the mean's coordinate and the rotation mirror
            p = p.flip(axis)
            p[..., coordinate] = -p[..., coordinate]
            p[..., 4] = -p[..., 4]
    return p.reshape(len(params), rows * cols, 8)


def average(stack: torch.Tensor) -> torch.Tensor:
    """The mean Gaussian of each cell over the leading axis of [K, B, N, 8]: means and colours averaged,
    the covariances averaged and taken apart again into scales and a rotation."""
    c, s = torch.cos(stack[..., 4]), torch.sin(stack[..., 4])
    sx2, sy2 = stack[..., 2] ** 2, stack[..., 3] ** 2
    xx = (c * c * sx2 + s * s * sy2).mean(0)
    yy = (s * s * sx2 + c * c * sy2).mean(0)
    xy = (c * s * (sx2 - sy2)).mean(0)
    half_trace, radius = 0.5 * (xx + yy), torch.sqrt((0.5 * (xx - yy)) ** 2 + xy ** 2)
    out = stack.mean(0)
    out[..., 2] = torch.sqrt(half_trace + radius)  # along the rotation: the major axis
    out[..., 3] = torch.sqrt((half_trace - radius).clamp_min(1e-12))
    out[..., 4] = 0.5 * torch.atan2(2 * xy, xx - yy)
    return out


def with_flips(forward, flips):
    def flipped_forward(self, frames: torch.Tensor) -> torch.Tensor:
        rows, cols = frames.shape[1] // self.cfg.stride, frames.shape[2] // self.cfg.stride
        outputs = []
        for flip_x, flip_y in flips:
            dims = [d for d, flip in ((2, flip_x), (1, flip_y)) if flip]
            mirrored = frames.flip(dims) if dims else frames
            outputs.append(unflip(forward(self, mirrored), rows, cols, flip_x, flip_y))
        return average(torch.stack(outputs))
    return flipped_forward


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--flips", type=int, choices=(1, 2, 4), default=4)
    args, rest = parser.parse_known_args()
    model.ConvGS.forward = with_flips(model.ConvGS.forward, FLIPS[:args.flips])
    hypergs_main(rest)


if __name__ == "__main__":
    sys.exit(main())
