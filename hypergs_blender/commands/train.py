"""`hypergs train` (resumable training, one process or torchrun), `hypergs export` (checkpoint ->
bundled weights), `hypergs export-onnx` (weights -> ONNX model) and `hypergs rebox` (weights trained for
another render box -> this one's)."""
from __future__ import annotations

import argparse
from pathlib import Path

from ..model import PRESETS
from ..network import BUNDLED_NAME, DEFAULT_NAMES, WEIGHTS_DIR
from ..training.data import DEFAULT_SPEC
from ..training.sources import DEFAULT_ROOT
from ..training.train import LOSSES, PRECISIONS
from . import options


class _StoreGiven(argparse._StoreAction):
    """argparse's store, also naming the option in `args.given`: a resumed run takes the options its
    command line does not give from its checkpoint (training.train.resume_options)."""

    def __call__(self, parser, namespace, values, option_string=None):
        super().__call__(parser, namespace, values, option_string)
        namespace.given = namespace.given | {self.dest}


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("train", help="train the HyperGS network; with the --out of a run, continue it with "
                                            "the options it started with, but those given again")
    p.register("action", None, _StoreGiven)
    p.set_defaults(given=frozenset())
    p.add_argument("--out", default="runs/small", type=options.run_folder,
                   help="run folder (checkpoint, log); resumes from it")
    p.add_argument("--preset", default="conv", choices=sorted(PRESETS),
                   help="conv: the default network; small / paper: the paper's transformer design")
    p.add_argument("--parametrization", choices=["local", "paper"], help="override a transformer preset's")
    p.add_argument("--config", nargs="+", default=[], metavar="FIELD=VALUE", type=options.config_item,
                   help="override fields of the preset's config for a new run, e.g. mid=32 stem=128")
    p.add_argument("--init-from", default=None, type=options.InputFile((".safetensors",)),
                   help="start a new run from these weights (.safetensors), e.g. the bundled model's: "
                        "the tensors whose name and shape the network has (new parts keep their initialisation)")
    p.add_argument("--distill", default=None, type=options.InputFile((".safetensors",)),
                   help="train the network (all but its head, kept as --init-from gave it) to reproduce the cell "
                        "features of these weights (.safetensors with its .json beside it), e.g. to move a trained "
                        "network onto a cheaper stem or thinner blocks; then train it on the renders")
    p.add_argument("--data", default=DEFAULT_SPEC, type=options.text, help="training.data.build_sources spec")
    p.add_argument("--data-root", default=DEFAULT_ROOT, type=options.text)
    p.add_argument("--eval-videos", nargs="*", default=[], type=options.input_video,
                   help="videos whose PSNR is logged at every evaluation (reporting only)")
    p.add_argument("--steps", type=options.schedule_steps, default=20000,
                   help="total steps of the cosine schedule; auto (with --minutes): as many as the sitting's time "
                        "allows at the warm-up's step rate (a lent GPU, a CPU session's background)")
    p.add_argument("--minutes", type=options.non_negative_float, default=None,
                   help="stop (with a checkpoint) after this wall time")
    p.add_argument("--batch", type=options.positive_int, default=None,
                   help="clips per step per process (conv 8, transformer 4)")
    p.add_argument("--size", type=options.image_side, default=128, help="crop size of the conv network's training frames")
    p.add_argument("--lr", type=options.positive_float, default=None,
                   help="peak learning rate (conv 1e-3 AdamW, transformer 2e-3 LAMB)")
    p.add_argument("--lr-scale", nargs="+", default=[], metavar="PART=FACTOR", type=options.lr_scale,
                   help="conv, a new run: the learning rate of a part of the network times FACTOR, e.g. stem=3 "
                        "(a new stem on warm-started blocks); the most specific part decides: encoder=0.1 "
                        "encoder.0.4=1 (a new block at the full rate)")
    p.add_argument("--train-only", nargs="+", default=[], metavar="PART", type=options.part,
                   help="conv, a new run: train only these parts of the network (dotted module names), the rest kept as "
                        "--init-from gave them, e.g. error_pass (a second pass on a trained first)")
    p.add_argument("--clip", type=options.positive_float, default=None,
                   help="gradient norm clipping (conv 0.5, transformer 1.0)")
    p.add_argument("--loss", choices=LOSSES, default=None,
                   help="the data term: mse, the pixels' mean squared error; psnr, the frames' mean PSNR (each "
                        "frame's error weighted by the inverse of its MSE: smooth frames count as much in dB "
                        "as detailed ones) (conv mse, transformer mse)")
    p.add_argument("--warmup", type=options.non_negative_int, default=200)
    p.add_argument("--min-lr-ratio", type=options.fraction, default=0.1)
    p.add_argument("--gaussians", default="64:1024", type=options.gaussian_range,
                   help="transformer: N per frame, log-uniform in MIN:MAX per step (conv: one per 4x4 pixels)")
    p.add_argument("--seed", type=options.non_negative_int, default=0)
    p.add_argument("--input-noise", type=options.non_negative_float, default=0.0,
                   help="conv: the network sees each frame with Gaussian noise of a std up to this (1/255), "
                        "quantised to 8 bits; the render is compared with the clean frame")
    p.add_argument("--flat-weight", type=options.non_negative_float, default=0.0,
                   help="the squared error of a flat pixel (the clean frame's std under 1/255 around it, "
                        "eval's flat-ripple criterion) counts 1 + this times a detailed one's: flat regions "
                        "rendered flat")
    p.add_argument("--precision", choices=PRECISIONS, default="auto",
                   help="the network's forward pass: auto, bfloat16 on CUDA and float32 on a CPU; bfloat16 on a "
                        "CPU pays where it has AMX (Intel Xeon since Sapphire Rapids); the render and the "
                        "weights stay float32")
    p.add_argument("--int8", action="store_true",
                   help="conv, a new run: train with the convolutions rounded as the int8 ONNX model runs them "
                        "(activation ranges calibrated at the start; `export` then writes that model), e.g. "
                        "--init-from a float network for a few thousand steps at a low --lr")
    p.add_argument("--ema", type=options.decay, default=0.0, metavar="DECAY",
                   help="also keep an exponential moving average of the weights (e.g. 0.999: about the last 1,000 "
                        "steps); evaluated beside them (ema_* in the log), and what `export` writes; 0: none. Given "
                        "to a resumed run without one, it starts from the run's weights")
    p.add_argument("--log-every", type=options.positive_int, default=20)
    p.add_argument("--eval-every", type=options.positive_int, default=250)
    p.add_argument("--checkpoint-every", type=options.positive_int, default=100)
    p.add_argument("--threads", type=options.positive_int, default=None,
                   help="CPU threads of torch and of the numba rasterizer")
    p.add_argument("--loader-threads", type=options.positive_int, default=1,
                   help="threads drawing the next batches (1 on a 2-core machine; ~8 on a GPU machine)")
    p.add_argument("--profile", type=options.positive_int, default=None, metavar="STEPS",
                   help="profile this many steps (after one warm-up step) and write OUT/profile.txt: the ops "
                        "and the phases (data, forward, backward, optimizer, raster plan) by their own time")
    p.set_defaults(func=_train_command)

    p = subparsers.add_parser("export", help="training checkpoint (either design) -> weights (safetensors + JSON "
                                             "card + ONNX)")
    p.add_argument("run", type=options.input_folder, help="run folder holding checkpoint.pt")
    p.add_argument("--out", default=None, type=options.output_folder,
                   help="folder of the weights (default: RUN/export; the bundled model's is hypergs_blender/weights, "
                        "named only on purpose)")
    p.add_argument("--name", default=None, type=options.name,
                   help=f"file name (default: {', '.join(f'{v} for the {k} design' for k, v in DEFAULT_NAMES.items())})")
    p.add_argument("--trained", action="store_true",
                   help="the trained weights, where the run also keeps their moving average (train --ema; "
                        "exported by default)")
    p.set_defaults(func=_export_command)

    p = subparsers.add_parser("export-onnx", help="weights (safetensors) -> <name>.onnx beside them")
    p.add_argument("--weights", default=str(WEIGHTS_DIR), type=options.input_folder)
    p.add_argument("--name", default=BUNDLED_NAME, type=options.name)
    p.set_defaults(func=_export_onnx_command)

    p = subparsers.add_parser("rebox", help="weights trained for another render box -> this HyperGS's box, in place")
    p.add_argument("--weights", default=str(WEIGHTS_DIR), type=options.input_folder)
    p.add_argument("--name", default=BUNDLED_NAME, type=options.name)
    p.set_defaults(func=_rebox_command)


def _train_command(args) -> None:
    from dataclasses import fields

    from ..errors import HyperGSError
    from ..training.train import run
    known = {f.name for f in fields(PRESETS[args.preset])}
    unknown = sorted({field for field, _ in args.config} - known)
    if unknown:
        raise HyperGSError(f"--config: {', '.join(unknown)} not fields of the {args.preset} preset's config")
    args.config = dict(args.config)
    args.lr_scale = dict(args.lr_scale)
    run(args)


def _export_command(args) -> None:
    from ..training.export import export_checkpoint
    args.out = args.out or str(Path(args.run) / "export")
    name, info = export_checkpoint(args.run, args.out, args.name, trained=args.trained)
    weights = f" (the weights' moving average, decay {info['ema']['decay']})" if "ema" in info else ""
    print(f"exported step {info['step']}{weights} to {args.out}/{name}.{{safetensors,json,onnx}}")


def _export_onnx_command(args) -> None:
    from ..network import load_model, read_card
    from ..training.export import export_onnx
    path = Path(args.weights) / f"{args.name}.onnx"
    export_onnx(load_model(args.weights, args.name), path, read_card(args.weights, args.name).get("int8"))
    print(f"wrote {path}")


def _rebox_command(args) -> None:
    from ..raster import SIGMA_CUTOFF
    from ..training.export import rebox
    old = rebox(args.weights, args.name)
    where = Path(args.weights) / args.name
    print(f"{where}: already for the {SIGMA_CUTOFF:g}-sigma box" if old is None
          else f"{where}: colours converted from the {old:g}-sigma box to {SIGMA_CUTOFF:g} (safetensors, card, ONNX)")
