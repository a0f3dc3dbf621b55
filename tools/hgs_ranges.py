"""What a quantized .hgs file's ranges cost: encode the first frames of videos at Quality presets with the
bundled network, then print, per video and preset, the PSNR of the float32 Gaussians, of the 8-bit .hgs
with ranges fitted to the clip (what `hypergs encode -o clip.hgs` and Blender's export write), and with
the ranges a stream fixes before its first frame (`Quantizer.default`: what `hypergs encode` wrote until
session 28), with each file's size.

    python tools/hgs_ranges.py runs/heldout720/*.mp4 ../shared/videos/*.mp4 --frames 8
    python tools/hgs_ranges.py VIDEOS --depths sx=1,sy=1 --depths sx=1,sy=1,rot=-1   # more columns: fitted
                                                                                   # ranges, other depths

--depths adds a column of fitted ranges with some parameters' depths moved from `--bits` (the means' from
`clip_bits`'); the parameters are named as `hypergs info` names them: x y sx sy rot r g b.
PSNR: every frame's render at the canvas size against its source frame, averaged (as `encode --psnr`).
"""
from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import numpy as np

from hypergs_blender.encode import EncodePlan, EncodeSettings
from hypergs_blender.io.codec import Quantizer, clip_bits
from hypergs_blender.io.frames import iter_frames
from hypergs_blender.io.hgs import load_hgs, save_hgs
from hypergs_blender.network import resolve_encoder


PARAMS = ("x", "y", "sx", "sy", "rot", "r", "g", "b")


def parse_depths(text: str) -> dict[int, int]:
    moves = {}
    for item in text.split(","):
        name, _, delta = item.partition("=")
        if name not in PARAMS:
            raise argparse.ArgumentTypeError(f"unknown parameter {name!r} ({' '.join(PARAMS)})")
        moves[PARAMS.index(name)] = int(delta)
    return moves


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("videos", nargs="+")
    parser.add_argument("--quality", nargs="+", default=["standard", "high"])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--bits", type=int, default=8)
    parser.add_argument("--depths", action="append", default=[], type=parse_depths,
                        help="e.g. sx=1,sy=1,rot=-1: those depths moved by those bits, in one more column")
    args = parser.parse_args()
    encoder = resolve_encoder()
    extra = [" ".join(f"{PARAMS[i]}{d:+d}" for i, d in sorted(moves.items())) for moves in args.depths]
    print("| video | preset | Gaussians | float32 | fitted ranges (MB) | fixed ranges (MB) |"
          + "".join(f" fitted, {label} (MB) |" for label in extra))
    print("| --- " * (6 + len(extra)) + "|")
    for video in args.videos:
        for quality in args.quality:
            plan = EncodePlan(video, encoder, EncodeSettings.choose(quality), stop=args.frames)
            clip = plan.video()
            sources = [frame for _, frame in iter_frames(video, plan.indices)]

            def psnr(params) -> float:
                return float(np.mean([plan.frame_psnr(p, f) for p, f in zip(params, sources)]))

            bits = clip_bits(args.bits, plan.width, plan.height, plan.layout.count)
            row = [Path(video).stem, quality, str(plan.layout.count), f"{psnr(clip.params):.2f}"]
            quantizers = [Quantizer.fit(clip.params, bits), Quantizer.default(plan.width, plan.height, bits)]
            for moves in args.depths:
                quantizers.append(Quantizer.fit(clip.params, tuple(b + moves.get(i, 0) for i, b in enumerate(bits))))
            for quantizer in quantizers:
                with tempfile.TemporaryDirectory() as folder:
                    path = Path(folder) / "clip.hgs"
                    size = save_hgs(clip, path, quantizer=quantizer)
                    row.append(f"{psnr(load_hgs(path).params):.2f} ({size / 1e6:.2f})")
            print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
