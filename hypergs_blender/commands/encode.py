"""`hypergs encode` (video -> Gaussian video file) and `hypergs render` (Gaussian video file -> frames)."""
from __future__ import annotations

import sys
import time
from pathlib import Path

from .. import limits
from ..encode import EncodePlan, psnr_sample_count
from ..io.clips import CLIP_SUFFIXES
from . import options
from .options import add_encoder_arguments, add_settings_arguments, encoder_from_args, settings_from_args


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("encode", help="video -> Gaussian video file (.npz, .hgs, .usd)")
    p.add_argument("video", type=options.input_video)
    p.add_argument("-o", "--output", required=True, type=options.OutputFile(CLIP_SUFFIXES))
    add_settings_arguments(p)
    p.add_argument("--size", type=options.image_side, default=None,
                   help="square canvas (short-side resize + crop); default native")
    p.add_argument("--start", type=options.frame_index, default=0)
    p.add_argument("--stop", type=options.frame_count, default=None)
    p.add_argument("--bits", type=int, default=8, choices=[4, 6, 8], help="quantization bits (.hgs)")
    p.add_argument("--position-bits", type=int, default=None, choices=range(4, 17), metavar="{4..16}",
                   help="bits of the means (.hgs; default: steps of at most 1/4 canvas pixel and 1/100 of the "
                        "Gaussians' spacing, io/codec.clip_bits)")
    p.add_argument("--psnr", action="store_true",
                   help="measure the PSNR of one frame in 32 (at most 8) against the source, as Blender's Import "
                        "does, on the Gaussians as the file holds them; each is a full render")
    add_encoder_arguments(p)
    p.set_defaults(func=_encode_command)

    p = subparsers.add_parser("render", help="Gaussian video file -> image frames")
    p.add_argument("clip", type=options.InputFile(CLIP_SUFFIXES))
    p.add_argument("-o", "--output", required=True, type=options.output_folder, help="folder for frame_0000.png ...")
    p.add_argument("--width", type=options.image_side, default=None)
    p.add_argument("--height", type=options.image_side, default=None)
    p.add_argument("--format", default="png", choices=["png", "exr"])
    p.set_defaults(func=_render_command)


def _encode_command(args) -> None:
    from tqdm import tqdm
    encoder = encoder_from_args(args)
    started = time.perf_counter()
    plan = EncodePlan(args.video, encoder, settings_from_args(args), size=args.size, start=args.start,
                      stop=args.stop)
    if plan.layout.note:
        print(f"hypergs: note: {plan.layout.note}", file=sys.stderr)
    psnr_frames = psnr_sample_count(len(plan.indices)) if args.psnr else 0
    streamed = Path(args.output).suffix.lower() == ".hgs"
    if not streamed:  # the clip is held whole before it is written
        limits.check_clip_size(len(plan.indices), plan.layout.count, args.output)
    with tqdm(total=len(plan.indices), unit="frame", dynamic_ncols=True, disable=None) as bar:  # a bar on a terminal

        def progress(done, total):
            bar.update(done - bar.n)
            return True

        if streamed:  # memory stays bounded by a chunk; only a complete file appears under the output's name
            bits = (args.position_bits,) * 2 + (args.bits,) * 6 if args.position_bits else args.bits
            plan.write_hgs(args.output, bits, progress, psnr_frames=psnr_frames)
        else:
            from ..io.clips import save_clip
            save_clip(plan.video(progress, psnr_frames=psnr_frames), args.output)
    quality = f", PSNR {plan.psnr:.2f} dB on {len(plan.psnr_values)} frame(s)" if psnr_frames else ""
    print(f"{args.output}: {len(plan.indices)} frames x {plan.layout.count} Gaussians "
          f"({time.perf_counter() - started:.2f} s{quality})")


def _render_command(args) -> None:
    from ..errors import HyperGSError
    from ..io.clips import load_clip
    from ..io.images import write_image
    from ..raster import check_render_size
    from ..render import render_frames
    video = load_clip(args.clip)
    width = args.width or video.canvas_width
    height = args.height or max(1, round(width * video.canvas_height / video.canvas_width))
    check_render_size(width, height, 1)
    out = Path(args.output)
    out.mkdir(exist_ok=True)
    for t in range(video.num_frames):
        try:
            frame = render_frames(video, width, height, [t])[0]
        except HyperGSError as e:
            raise type(e)(f"{args.clip}, frame {t}: {e}") from None
        write_image(out / f"frame_{t:04d}.{args.format}", frame)
    print(f"{video.num_frames} frames at {width}x{height} -> {out}")
