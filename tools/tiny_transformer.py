"""Transformer weights for sessions that need the paper's design without a trained one (the Blender
test of a transformer conversion, the matrix): a tiny `HyperGS` transformer at its initialisation (its
Gaussians start as the grid floor, so a conversion gives a floor-quality picture through the whole
transformer path: windows, ONNX graph, patch grid) exported as `hypergs export` writes a model
(safetensors, card, ONNX). Needs torch (the outer Python, not Blender's).

    .venv/bin/python tools/tiny_transformer.py OUT_FOLDER
"""
from __future__ import annotations

import sys
from pathlib import Path

# canvas 32 in patches of 8, clips of 4 frames, one layer of each kind: exported in seconds
TINY = dict(canvas=32, patch=8, clip_frames=4, temporal_window=2, dim=32, heads=2, ffn=64, st_layers=1, q_layers=1)
TRAINED_RANGE = "4:400"  # Gaussians per tile its card claims (what the layout clamps to)


def export_tiny_transformer(folder, name: str = "hypergs_transformer", seed: int = 0) -> Path:
    """Write <folder>/<name>.{safetensors,json,onnx}; returns the card's path."""
    import torch

    from hypergs_blender.model import HyperGS, TransformerConfig
    from hypergs_blender.training.export import export_onnx, save_weights
    folder = Path(folder)
    torch.manual_seed(seed)
    model = HyperGS(TransformerConfig(**TINY)).eval()
    save_weights(model, folder, name, info={"train_args": {"gaussians": TRAINED_RANGE}, "untrained": True})
    export_onnx(model, folder / f"{name}.onnx")
    return folder / f"{name}.json"


if __name__ == "__main__":
    print(export_tiny_transformer(sys.argv[1]))
