"""`hypergs train` (resumable training, one process or torchrun), `hypergs export` (checkpoint ->
bundled weights) and `hypergs export-onnx` (weights -> ONNX model)."""
from __future__ import annotations

from pathlib import Path

from ..model import PRESETS
from ..network import BUNDLED_NAME, WEIGHTS_DIR
from ..training.data import DEFAULT_SPEC
from ..training.sources import DEFAULT_ROOT


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("train", help="train the HyperGS network")
    p.add_argument("--out", default="runs/small", help="run folder (checkpoint, log); resumes from it")
    p.add_argument("--preset", default="conv", choices=sorted(PRESETS),
                   help="conv: the default network; small / paper: the paper's transformer design")
    p.add_argument("--parametrization", choices=["local", "paper"], help="override a transformer preset's")
    p.add_argument("--init-from", default=None,
                   help="start a new conv run from these weights (.safetensors), e.g. the bundled model's")
    p.add_argument("--data", default=DEFAULT_SPEC, help="training.data.build_sources spec")
    p.add_argument("--data-root", default=DEFAULT_ROOT)
    p.add_argument("--eval-videos", nargs="*", default=[],
                   help="videos whose PSNR is logged at every evaluation (reporting only)")
    p.add_argument("--steps", type=int, default=20000, help="total steps of the cosine schedule")
    p.add_argument("--minutes", type=float, default=None, help="stop (with a checkpoint) after this wall time")
    p.add_argument("--batch", type=int, default=None, help="clips per step per process (conv 8, transformer 4)")
    p.add_argument("--size", type=int, default=128, help="crop size of the conv network's training frames")
    p.add_argument("--lr", type=float, default=None, help="peak learning rate (conv 1e-3 AdamW, transformer 2e-3 LAMB)")
    p.add_argument("--clip", type=float, default=None, help="gradient norm clipping (conv 0.5, transformer 1.0)")
    p.add_argument("--warmup", type=int, default=200)
    p.add_argument("--min-lr-ratio", type=float, default=0.1)
    p.add_argument("--gaussians", default="64:1024",
                   help="transformer: N per frame, log-uniform in MIN:MAX per step (conv: one per 4x4 pixels)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--log-every", type=int, default=20)
    p.add_argument("--eval-every", type=int, default=250)
    p.add_argument("--checkpoint-every", type=int, default=100)
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads")
    p.set_defaults(func=_train_command)

    p = subparsers.add_parser("export", help="training checkpoint -> weights (safetensors + JSON card + ONNX)")
    p.add_argument("run", help="run folder holding checkpoint.pt")
    p.add_argument("--out", default=str(WEIGHTS_DIR))
    p.add_argument("--name", default=BUNDLED_NAME)
    p.set_defaults(func=_export_command)

    p = subparsers.add_parser("export-onnx", help="weights (safetensors) -> <name>.onnx beside them")
    p.add_argument("--weights", default=str(WEIGHTS_DIR))
    p.add_argument("--name", default=BUNDLED_NAME)
    p.set_defaults(func=_export_onnx_command)


def _train_command(args) -> None:
    from ..training.train import run
    run(args)


def _export_command(args) -> None:
    from ..training.export import export_checkpoint
    info = export_checkpoint(args.run, args.out, args.name)
    print(f"exported step {info['step']} to {args.out}/{args.name}.{{safetensors,json,onnx}}")


def _export_onnx_command(args) -> None:
    from ..network import load_model
    from ..training.export import export_onnx
    path = Path(args.weights) / f"{args.name}.onnx"
    export_onnx(load_model(args.weights, args.name), path)
    print(f"wrote {path}")
