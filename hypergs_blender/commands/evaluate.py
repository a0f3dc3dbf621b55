"""`hypergs eval`: PSNR / SSIM / MS-SSIM of encode -> render against the source frames, artefact checks,
temporal figures and timings."""
from __future__ import annotations

import json
import sys

import numpy as np

from ..errors import HyperGSError
from ..evaluate import evaluate_video, warm_up
from ..io.frames import probe
from . import options
from .options import add_encoder_arguments, add_settings_arguments, encoder_from_args, settings_from_args


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("eval", help="quality and speed of encode -> render on videos")
    p.add_argument("videos", nargs="+", type=options.input_video)
    add_settings_arguments(p, default="draft")
    frames = p.add_mutually_exclusive_group()
    frames.add_argument("--size", type=options.image_side, default=256,
                        help="short-side resize + centre crop to SIZE x SIZE")
    frames.add_argument("--crop", type=options.image_side, default=None,
                        help="centre crop CROP x CROP at the video's own resolution")
    frames.add_argument("--native", action="store_true", help="centre crop at the video's own short side")
    frames.add_argument("--full", action="store_true", help="whole frames at the video's own resolution")
    p.add_argument("--frames", type=options.frame_count, default=8, help="frames sampled uniformly from each video")
    p.add_argument("--temporal-frames", type=options.non_negative_int, default=8,
                   help="consecutive frames from the middle of each video for the temporal figures (0: none)")
    p.add_argument("--tile", type=options.positive_int, default=None,
                   help="network tile size in working pixels (tests seams)")
    p.add_argument("--json", action="store_true")
    add_encoder_arguments(p)
    p.set_defaults(func=run)


def run(args) -> None:
    encoder = encoder_from_args(args)
    if args.tile:
        if not hasattr(encoder, "tile"):
            raise HyperGSError(f"--tile sets the conv network's tiles; the {encoder.name} encoder tiles by its "
                               "patch grid (--grid)")
        encoder.tile = args.tile
    warm_up(encoder)
    size = None if (args.native or args.full or args.crop) else args.size
    settings = settings_from_args(args)
    rows = []
    for video in args.videos:
        crop = args.crop or (min(probe(video).width, probe(video).height) if args.native else None)
        rows.append(evaluate_video(video, encoder, settings, size=size, crop=crop, frames=args.frames,
                                   temporal_frames=args.temporal_frames))
    for note in sorted({r["note"] for r in rows if r["note"]}):
        print(f"hypergs: note: {note}", file=sys.stderr)
    keys = ["psnr", "ssim", "ms_ssim", "floor_bilinear_psnr", "gaussians", "edge_bias", "encode_seconds",
            "decode_seconds", "encode_fps", "decode_fps"]
    mean = {k: float(np.mean([r[k] for r in rows])) for k in keys}
    seams = [r["seam_ratio"] for r in rows if r["seam_ratio"] is not None]
    mean["seam_ratio"] = float(np.mean(seams)) if seams else None
    mean.update(mean_flat_ripple([r["flat_ripple"] for r in rows]))
    temporal = [r["temporal"] for r in rows if "temporal" in r]
    if temporal:
        still = [t["still_change"] for t in temporal if t["still_change"]["render"] is not None]
        weights = [c["fraction"] for c in still]  # over all still pixels: a video with few counts little
        mean["temporal"] = dict(psnr=float(np.mean([t["psnr"] for t in temporal])),
                                delta_psnr=float(np.mean([t["delta_psnr"] for t in temporal])),
                                still_change=dict(fraction=float(np.mean([t["still_change"]["fraction"] for t in temporal])),
                                                  **{k: float(np.average([c[k] for c in still], weights=weights))
                                                     if still else None for k in ("source", "render")}))
    report = dict(encoder=encoder.name, density=dict(gaussians=settings.gaussians, cell=settings.cell, grid=settings.grid),
                  refine=settings.refine, adaptive_start=settings.adaptive,
                  frames_from=("native" if args.native else "full" if args.full else f"crop {args.crop}" if args.crop
                               else f"size {args.size}"),
                  frames=args.frames, temporal_frames=args.temporal_frames, videos=rows, mean=mean)
    if args.json:
        print(json.dumps(report, indent=2))
        return
    for r in rows + [dict(video="mean", **mean)]:
        t = r.get("temporal")
        still = t and t["still_change"]["render"]
        print(f"{r['video']:40s} {r['psnr']:6.2f} dB (bilinear floor {r['floor_bilinear_psnr']:.2f}) "
              f"N {r['gaussians']:.0f}  SSIM {r['ssim']:.4f}  MS-SSIM {r['ms_ssim']:.4f}  "
              + (f"delta-PSNR {t['delta_psnr']:.2f} dB  " if t else "")
              + (f"still change {still:.2f}/255  " if still is not None else "")
              + f"encode {r['encode_fps']:7.2f} fps  decode {r['decode_fps']:7.1f} fps")


def mean_flat_ripple(ripples: list[dict]) -> dict:
    """The videos' flat-ripple figures (metrics.flat_ripple) over all their flat blocks together, as the
    still change is over all still pixels: a video with one flat block counts as one block, not as much
    as a video with hundreds."""
    ripples = [f for f in ripples if f["blocks"]]
    blocks = [f["blocks"] for f in ripples]
    return {f"flat_ripple_{k}": float(np.average([f[k] for f in ripples], weights=blocks)) if ripples else None
            for k in ("render_std", "source_std")} | {"flat_ripple_blocks": int(sum(blocks))}
