"""`hypergs bench <what> [--json]`: the benchmarks of bench/ on the command line.

Adding a benchmark: write `bench_<what>(...) -> dict` in bench/, and here a `_<what>(parser)` that adds
its options and returns `args -> report dict`, then add one line to BENCH_COMMANDS. `--json` and
printing are shared; reports with a Markdown table under "table" print just that.
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from ..bench.common import DEFAULT_BITS, DEFAULT_CRFS, DEFAULT_GAUSSIANS, write_report
from .. import limits
from ..bench.vs_fit import DEFAULT_FIT_BUDGET, DEFAULT_FIT_ITERS, DEFAULT_REFINE_STEPS, DEFAULT_SIZES, FIT_INITS
from ..network import DEFAULT_NAMES, WEIGHTS_DIR
from . import options


CRF = options.Integer(0, high=63)  # x264 / x265 constant rate factor
GROUP_SIZE = options.Integer(1, high=64)  # .hgs frames per group (hgs.MAX_GROUP_SIZE)
POSITION_BITS = options.Integer(0, high=16)  # 0: none


def _bench_options(parser, default: str = "network") -> None:
    parser.add_argument("--encoder", default=default, choices=["network", "floor"],
                        help="the bundled network, or the grid floor (no learning)")
    options.add_backend_arguments(parser)
    options.add_model_arguments(parser)
    parser.add_argument("--device", default="auto", type=options.text, help="auto (cuda when available), cpu, cuda")
    parser.add_argument("-o", "--output", default=None, type=options.OutputFile((".json",)),
                        help="also write the JSON report here")


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _raster(parser):
    parser.add_argument("--device", choices=["cpu", "cuda"], default="cpu")

    def run(args):
        from ..bench.raster import bench_raster
        return bench_raster(device=args.device)
    return run


def _encode(parser):
    from ..bench.encode import FRAME_SIZES
    from ..encode import QUALITY
    parser.add_argument("--sizes", nargs="+", default=list(FRAME_SIZES), choices=list(FRAME_SIZES),
                        help="frame sizes: 256 (256 x 256) at --gaussians, 720p and 1080p at the --presets' densities")
    parser.add_argument("--gaussians", nargs="+", type=options.gaussian_count, default=list(DEFAULT_GAUSSIANS))
    parser.add_argument("--presets", nargs="+", default=list(QUALITY), choices=list(QUALITY))
    parser.add_argument("--backends", nargs="+", default=["torch", "onnx"], choices=["torch", "onnx"])
    options.add_precision_argument(parser)  # of the torch rows; onnxruntime's run float32
    parser.add_argument("--frames", type=options.frame_count, default=8, help="frames per call at 256²")
    parser.add_argument("--large-frames", type=options.frame_count, default=2, help="frames per call at 720p and 1080p")
    parser.add_argument("--repeats", type=options.positive_int, default=3)
    parser.add_argument("--threads", type=options.non_negative_int, default=0,
                        help="torch and onnxruntime CPU threads (0: one per core)")
    options.add_model_arguments(parser)
    parser.add_argument("-o", "--output", default=None, type=options.OutputFile((".json",)),
                        help="also write the JSON report here")

    def run(args):
        from ..bench.encode import bench_encode
        return write_report(bench_encode(args.backends, args.gaussians, args.presets, args.sizes, args.frames,
                                         args.large_frames, args.repeats, options.weights_from_args(args),
                                         args.threads, args.precision), args.output)
    return run


def _rate_arguments(parser):
    """The videos and the rates both codec benches sweep: .hgs bit depths at each Gaussian count, x265's CRFs."""
    parser.add_argument("videos", nargs="+", type=options.input_video)
    parser.add_argument("--gaussians", type=options.gaussian_count, nargs="+", default=list(DEFAULT_GAUSSIANS))
    parser.add_argument("--bits", type=int, nargs="+", default=list(DEFAULT_BITS), choices=[4, 6, 8])
    parser.add_argument("--crf", type=CRF, nargs="+", default=list(DEFAULT_CRFS))


def _codec(parser):
    _rate_arguments(parser)
    parser.add_argument("--size", type=options.image_side, default=256,
                        help="square frame size (short-side resize + centre crop)")
    parser.add_argument("--frames", type=options.frame_count, default=None,
                        help="frames sampled uniformly (default: all)")
    parser.add_argument("--codec", default="libx265", type=options.text,
                        help="FFmpeg reference encoder (libx264 when libx265 is missing)")
    parser.add_argument("--preset", default="medium", type=options.text)
    parser.add_argument("--group-size", type=GROUP_SIZE, default=16)
    parser.add_argument("--position-bits", type=POSITION_BITS, default=10,
                        help="also rows with the means at this many bits (0: none)")
    _bench_options(parser)

    def run(args) -> dict:
        from ..bench.codec import bench_codec, format_codec_table
        from ..network import resolve_encoder
        encoder = resolve_encoder(args.encoder, args.backend, options.weights_from_args(args),
                                  None if args.device == "auto" else args.device, precision=args.precision)
        report = bench_codec(args.videos, args.gaussians, args.bits, args.crf, args.size, args.frames, encoder,
                             args.codec, args.preset, args.group_size, args.position_bits or None, progress=_progress)
        report["table"] = format_codec_table(report)
        return write_report(report, args.output)
    return run


def _vs_fit(parser):
    parser.add_argument("videos", nargs="+", type=options.input_video)
    parser.add_argument("--gaussians", type=options.gaussian_count, nargs="+", default=list(DEFAULT_GAUSSIANS))
    parser.add_argument("--refine-steps", type=options.non_negative_int, nargs="*", default=list(DEFAULT_REFINE_STEPS),
                        help="K values for feedforward + refine (1: least-squares colours only)")
    parser.add_argument("--fit-iters", type=options.positive_int, nargs="+", default=list(DEFAULT_FIT_ITERS),
                        help="fitting rungs (iterations), each its own run")
    parser.add_argument("--fit-inits", nargs="+", default=list(FIT_INITS), choices=FIT_INITS,
                        help="fitting baselines: from random initial values, from the Gaussian grid")
    parser.add_argument("--sizes", nargs="+", default=list(DEFAULT_SIZES), type=options.frame_size,
                        help="frames: square sizes (short-side resize + crop), 'cropN' (N x N centre crop at the "
                             "video's resolution), 'native' (whole frames)")
    parser.add_argument("--frames", type=options.frame_count, default=4, help="consecutive frames per video")
    parser.add_argument("--start", type=options.frame_index, default=0, help="first frame")
    parser.add_argument("--fit-budget", type=options.non_negative_float, default=DEFAULT_FIT_BUDGET,
                        help="seconds of fitting per (video, size, N, init): rungs predicted to exceed it are skipped "
                             f"(default {DEFAULT_FIT_BUDGET:g}; 0: no limit)")
    parser.add_argument("--fit-all", action="store_true",
                        help="run every rung (default: stop once fitting reaches ours' best PSNR)")
    parser.add_argument("--threads", type=options.positive_int, default=1,
                        help="CPU threads of every method: the network's and the rasterizer's (fitting, refine)")
    _bench_options(parser)

    def run(args) -> dict:
        from ..bench.common import use_threads
        from ..bench.vs_fit import bench_vs_fit
        use_threads(args.threads)
        return write_report(bench_vs_fit(args.videos, args.gaussians, args.refine_steps, args.fit_iters, args.sizes,
                                   args.frames, args.start, args.encoder, args.backend, options.weights_from_args(args),
                                   args.device,
                                   args.fit_budget or None, args.fit_all, args.fit_inits, args.threads,
                                   args.precision, progress=_progress),
                            args.output)
    return run


def _vs_x265(parser):
    _rate_arguments(parser)
    parser.add_argument("--refine-steps", type=options.non_negative_int, nargs="+", default=[0],
                        help="rows of ours at these refine K (0: the feedforward prediction)")
    parser.add_argument("--sizes", "--size", dest="size", default="256", type=options.frame_size,
                        help="frames: a square size (short-side resize + crop), 'cropN' or 'native'")
    parser.add_argument("--frames", type=options.Integer(0, limit=limits.FRAMES), default=24,
                        help="consecutive frames per video (0: all)")
    parser.add_argument("--start", type=options.frame_index, default=0)
    parser.add_argument("--codec", default="libx265", type=options.text)
    parser.add_argument("--preset", default="medium", type=options.text)
    parser.add_argument("--group-size", type=GROUP_SIZE, default=16)
    parser.add_argument("--position-bits", type=POSITION_BITS, default=0,
                        help="bits of the means where --bits is lower (0: the depths `hypergs encode` writes, "
                             "enough for the Gaussians' spacing)")
    _bench_options(parser)

    def run(args) -> dict:
        from ..bench.vs_x265 import bench_vs_x265
        return write_report(bench_vs_x265(args.videos, args.gaussians, args.bits, args.crf, args.size, args.frames or None,
                                    args.start, args.refine_steps, args.encoder, args.backend,
                                    options.weights_from_args(args),
                                    args.device, args.codec, args.preset, args.group_size,
                                    position_bits=args.position_bits or None, precision=args.precision,
                                    progress=_progress), args.output)
    return run


def _scale(parser):
    parser.add_argument("video", nargs="?", default=None, type=options.input_video,
                        help="a video (default: a synthetic pan, made in a temp dir)")
    parser.add_argument("--seconds", type=options.positive_float, default=60.0, help="length of the synthetic video")
    parser.add_argument("--resolution", default="1280x720", type=options.resolution,
                        help="W x H of the synthetic video")
    parser.add_argument("--fps", type=options.Integer(1, high=1000), default=24)
    parser.add_argument("--gaussians", type=options.gaussian_count, default=None,
                        help="Gaussians per frame (default: --cell)")
    parser.add_argument("--cell", type=options.positive_float, default=6.0, help="source pixels per Gaussian cell side")
    parser.add_argument("--chunk-frames", type=options.positive_int, default=16)
    parser.add_argument("--refine", type=options.non_negative_int, default=0)
    parser.add_argument("--bits", type=int, default=8, choices=[4, 6, 8])
    parser.add_argument("--render", default="1920x1080", type=options.resolution, help="render size")
    parser.add_argument("--render-frames", type=options.Integer(0, limit=limits.FRAMES), default=48,
                        help="frames rendered (0: all)")
    parser.add_argument("--keep", default=None, type=options.output_folder,
                        help="folder to keep the video and the .hgs in")
    parser.add_argument("--also-encode-video", action="store_true",
                        help="also measure `hypergs encode`'s path (encode_video holds the clip, then save_clip)")
    _bench_options(parser)

    def run(args) -> dict:
        (w, h), (rw, rh) = args.resolution, args.render
        from ..bench.scale import bench_scale
        return write_report(bench_scale(args.video, args.seconds, w, h, args.fps, args.gaussians, args.cell, args.chunk_frames,
                                  args.refine, args.bits, rw, rh, args.render_frames or None, 8, args.encoder,
                                  args.backend, options.weights_from_args(args), args.device, args.keep,
                                  args.also_encode_video, args.precision,
                                  progress=_progress), args.output)
    return run


def _picture(parser):
    parser.add_argument("video", type=options.input_video)
    parser.add_argument("--size", default=(864, 480), type=options.resolution,
                        help="render size W x H (the Blender scene's)")
    parser.add_argument("--frames", type=options.frame_count, default=4, help="consecutive frames encoded")
    parser.add_argument("--crop", type=options.image_side, default=None, help="encode a CROP x CROP centre crop")
    parser.add_argument("--picture", default=None, type=options.OutputFile((".png",)),
                        help="write the picture here (.png)")
    _bench_options(parser)

    def run(args) -> dict:
        from ..bench.picture import bench_presets, save_picture
        from ..network import resolve_encoder
        width, height = args.size
        encoder = resolve_encoder(args.encoder, args.backend, options.weights_from_args(args),
                                  None if args.device == "auto" else args.device, precision=args.precision)
        report = bench_presets(args.video, width=width, height=height, frames=args.frames, encoder=encoder,
                               crop=args.crop)
        if args.picture:
            report["picture"] = str(save_picture(report, args.picture))
        report = {k: v for k, v in report.items() if not k.startswith("_")}
        return write_report(report, args.output)
    return run


def _splat(parser):
    parser.add_argument("--size", default=(1920, 1080), type=options.resolution, help="render size WxH")
    parser.add_argument("--gaussians", type=options.gaussian_count, default=100_000, help="Gaussians per frame")
    parser.add_argument("--repeats", type=options.positive_int, default=5,
                        help="timed renders per path (after a warm-up one)")
    parser.add_argument("-o", "--output", default=None, type=options.OutputFile((".json",)),
                        help="also write the JSON report here")

    def run(args) -> dict:  # Blender runs in tools/bench_splat.py's sessions
        import tempfile
        from pathlib import Path

        from .checkout import run_tool
        with tempfile.TemporaryDirectory(prefix="hypergs-bench-splat-") as tmp:
            report = Path(tmp) / "report.json"
            run_tool("bench_splat.py", "--size", "x".join(map(str, args.size)), "--gaussians", args.gaussians,
                     "--repeats", args.repeats, "--report", report)
            return write_report(json.loads(report.read_text()), args.output)
    return run


def _designs(parser):
    from ..bench.designs import DEFAULT_GRIDS, DEFAULT_REFINE_STEPS
    parser.add_argument("videos", nargs="+", type=options.input_video,
                        help="videos; each folder is one set of the table (the dev clips, the held-out pans)")
    parser.add_argument("--conv", default=None, type=options.model_weights,
                        help="the conv network: a weights folder or a model's card (default: the bundled one)")
    parser.add_argument("--transformer", default=None, type=options.model_weights,
                        help="the transformer: a weights folder or a model's card (default: the bundled one)")
    parser.add_argument("--gaussians", type=options.gaussian_count, nargs="+", default=list(DEFAULT_GAUSSIANS),
                        help="Gaussians per frame")
    parser.add_argument("--grids", type=options.Integer(1, high=16), nargs="+", default=list(DEFAULT_GRIDS),
                        help="the transformer's patch grids (G x G tiles, N / G^2 Gaussians per tile)")
    parser.add_argument("--refine-steps", type=options.positive_int, nargs="+", default=list(DEFAULT_REFINE_STEPS),
                        help="the conv network's refine ladder (its PSNR at the transformer's encode time)")
    parser.add_argument("--size", type=options.image_side, default=256, help="square frames (short-side resize + crop)")
    parser.add_argument("--frames", type=options.Integer(2, limit=limits.FRAMES), default=8,
                        help="consecutive frames per video")
    parser.add_argument("--start", type=options.frame_index, default=0)
    options.add_backend_arguments(parser)
    parser.add_argument("--device", default="auto", type=options.text, help="auto (cuda when available), cpu, cuda")
    parser.add_argument("--threads", type=options.positive_int, default=1,
                        help="CPU threads of either backend and of the rasterizer (refine)")
    parser.add_argument("-o", "--output", default=None, type=options.OutputFile((".json",)),
                        help="also write the JSON report here")
    parser.add_argument("--table", default=None, type=options.OutputFile((".md",)),
                        help="also write the Markdown table here (docs/designs.md)")

    def run(args) -> dict:
        from ..bench.common import resolve_device, use_threads
        from ..bench.designs import bench_designs
        from ..io.files import write_bytes
        from ..network import read_card, resolve_encoder, weights_name
        use_threads(args.threads)
        device = resolve_device(args.device)
        conv = resolve_encoder("network", args.backend, args.conv, device, threads=args.threads,
                               precision=args.precision)
        weights = Path(args.transformer or WEIGHTS_DIR / f"{DEFAULT_NAMES['transformer']}.json")
        transformer = resolve_encoder("network", args.backend, weights, device, threads=args.threads,
                                      precision=args.precision)
        folder, name = (weights.parent, weights.stem) if weights.suffix == ".json" else (weights, weights_name(weights))
        report = bench_designs(args.videos, conv, transformer, args.gaussians, args.grids, args.refine_steps,
                               args.size, args.frames, args.start, device, progress=_progress,
                               training=read_card(folder, name).get("info"))
        if args.table:
            write_bytes(args.table, ("# The paper's transformer against the conv network\n\nWritten by `hypergs bench "
                                     f"designs` (the command: README).\n\n{report['table']}\n").encode())
        return write_report(report, args.output)
    return run


def _plots(parser):
    from .checkout import ROOT
    parser.add_argument("--bench", dest="reports", default=str(ROOT / "docs" / "bench"), type=options.input_folder,
                        help="folder of the JSON reports")  # (dest: `bench` names the bench subcommand)
    parser.add_argument("--out", default=str(ROOT / "docs"), type=options.output_folder, help="folder for the PNGs")

    def run(args) -> dict:
        from ..bench.plots import make_plots
        from ..errors import HyperGSError
        written = make_plots(args.reports, args.out)
        if not written:
            raise HyperGSError(f"no vs-fit / vs-x265 / scale reports in {args.reports}")
        return {"written": [str(p) for p in written]}
    return run


# name -> (help, function adding the options and returning `args -> report dict`)
BENCH_COMMANDS = {
    "raster": ("rasterizer frames/s: numba / torch paths, numpy-only path, dense reference", _raster),
    "encode": ("network encode s/frame (torch and onnxruntime): 256² at N in {250, 1000, 3000}, 720p and 1080p at "
               "the Quality presets", _encode),
    "codec": (".hgs rate-distortion at 8/6/4 bits next to x265 (bpp, PSNR, frames/s)", _codec),
    "vs-fit": ("feedforward vs feedforward + refine vs per-frame fitting: PSNR, s/frame, ratio at matched PSNR",
               _vs_fit),
    "vs-x265": ("matched-quality pairs, .hgs vs x265: bpp, PSNR, SSIM, encode/decode frames/s", _vs_x265),
    "scale": ("a long (default synthetic 60 s 720p) video end to end: frames/s, peak memory, 1080p render", _scale),
    "picture": ("each quality preset on a video, rendered at the scene's size: PSNR, s/frame, a picture", _picture),
    "splat": ("Blender F12 s/frame, GPU splats vs numpy path (1920x1080, 100k Gaussians), viewport draw time",
              _splat),
    "designs": ("the paper's transformer vs the conv network at equal N and equal encode time: PSNR, SSIM, Δ-PSNR",
                _designs),
    "plots": ("plots (docs/*.png) and docs/bench/tables.md from the JSON reports in docs/bench", _plots),
}


def _print_report(report: dict, indent: int = 0) -> None:
    for key, value in report.items():
        if isinstance(value, dict):
            print(" " * indent + f"{key}:")
            _print_report(value, indent + 2)
        else:
            print(" " * indent + f"{key}: {value}")


def add_commands(subparsers) -> None:
    bench = subparsers.add_parser("bench", help="benchmarks")
    kinds = bench.add_subparsers(dest="bench", required=True)
    for name, (help_text, add_options) in BENCH_COMMANDS.items():
        parser = kinds.add_parser(name, help=help_text, description=help_text)
        parser.add_argument("--json", action="store_true", help="print the report as JSON")
        run = add_options(parser)

        def func(args, run=run):
            report = run(args)
            if args.json:
                print(json.dumps(report, indent=2))
            elif isinstance(report.get("table"), str):
                print(report["table"])
            else:
                _print_report(report)
        parser.set_defaults(func=func)
