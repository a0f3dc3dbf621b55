"""Arguments several subcommands share, parsed the same way everywhere."""
from __future__ import annotations

from ..network import BACKENDS, resolve_encoder


def add_encoder_arguments(parser) -> None:
    parser.add_argument("--encoder", default="network", choices=["network", "floor"],
                        help="the trained network, or the grid floor (no learning)")
    parser.add_argument("--backend", default="auto", choices=BACKENDS)
    parser.add_argument("--weights", default=None, help="folder with <name>.json/.safetensors/.onnx")
    parser.add_argument("--refine", type=int, default=0, help="per-frame refinement steps after the prediction")


def encoder_from_args(args, device=None):
    return resolve_encoder(args.encoder, args.backend, args.weights, device)
