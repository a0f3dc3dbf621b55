"""What a quantized .hgs file's ranges cost: encode the first frames of videos at Quality presets with the
bundled network, then print, per video and preset, the PSNR of the float32 Gaussians, of the 8-bit .hgs
with ranges fitted to the clip (what `hypergs encode -o clip.hgs` and Blender's export write), and with
the ranges a stream fixes before its first frame (`Quantizer.default`: what `hypergs encode` wrote until
session 28), with each file's size.

    python tools/hgs_ranges.py runs/heldout720/*.mp4 ../shared/videos/*.mp4 --frames 8

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


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("videos", nargs="+")
    parser.add_argument("--quality", nargs="+", default=["standard", "high"])
    parser.add_argument("--frames", type=int, default=8)
    parser.add_argument("--bits", type=int, default=8)
    args = parser.parse_args()
    encoder = resolve_encoder()
    print("| video | preset | Gaussians | float32 | fitted ranges (MB) | fixed ranges (MB) |")
    print("| --- | --- | --- | --- | --- | --- |")
    for video in args.videos:
        for quality in args.quality:
            plan = EncodePlan(video, encoder, EncodeSettings.choose(quality), stop=args.frames)
            clip = plan.video()
            sources = [frame for _, frame in iter_frames(video, plan.indices)]

            def psnr(params) -> float:
                return float(np.mean([plan.frame_psnr(p, f) for p, f in zip(params, sources)]))

            bits = clip_bits(args.bits, plan.width, plan.height, plan.layout.count)
            row = [Path(video).stem, quality, str(plan.layout.count), f"{psnr(clip.params):.2f}"]
            for quantizer in (Quantizer.fit(clip.params, bits), Quantizer.default(plan.width, plan.height, bits)):
                with tempfile.TemporaryDirectory() as folder:
                    path = Path(folder) / "clip.hgs"
                    size = save_hgs(clip, path, quantizer=quantizer)
                    row.append(f"{psnr(load_hgs(path).params):.2f} ({size / 1e6:.2f})")
            print("| " + " | ".join(row) + " |", flush=True)


if __name__ == "__main__":
    main()
