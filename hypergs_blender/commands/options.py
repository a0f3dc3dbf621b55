"""Arguments several subcommands share, parsed the same way everywhere."""
from __future__ import annotations

from ..network import BACKENDS, resolve_encoder


def add_encoder_arguments(parser) -> None:
    parser.add_argument("--encoder", default="network", choices=["network", "floor"],
                        help="the trained network, or the grid floor (no learning)")
    parser.add_argument("--backend", default="auto", choices=BACKENDS)
    parser.add_argument("--weights", default=None, help="folder with <name>.json/.safetensors/.onnx")
    parser.add_argument("--refine", type=int, default=0, help="per-frame refinement steps after the prediction")


def add_density_arguments(parser, default_cell: float | None = None) -> None:
    """How many Gaussians: a count per frame, or a cell size (one Gaussian per cell x cell source pixels)."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--gaussians", type=int, default=None, help="Gaussians per frame (about; on a grid of cells)")
    group.add_argument("--cell", type=float, default=None,
                       help=f"source pixels per Gaussian cell side (default {default_cell:g})" if default_cell
                       else "source pixels per Gaussian cell side")
    parser.set_defaults(default_cell=default_cell)


def density_from_args(args) -> dict:
    if args.gaussians is None and args.cell is None:
        return dict(cell=args.default_cell)
    return dict(gaussians=args.gaussians, cell=args.cell)


def encoder_from_args(args, device=None):
    return resolve_encoder(args.encoder, args.backend, args.weights, device)
