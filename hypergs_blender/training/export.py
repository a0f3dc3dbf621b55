"""Training checkpoint -> the weights a runtime loads (network.py): <name>.safetensors (tensors, for
torch), <name>.json (config, regularizer thresholds, training info) and <name>.onnx (onnxruntime)."""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from ..errors import HyperGSError
from ..network import BUNDLED_NAME, anchors_and_cell

ONNX_OPSET = 18


def save_weights(model, regularizer_state: dict, directory, name: str = BUNDLED_NAME, info: dict | None = None) -> None:
    from safetensors.torch import save_file
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(directory / f"{name}.safetensors"))
    card = dict(config=asdict(model.cfg), regularizer={k: float(v) for k, v in regularizer_state.items()},
                info=info or {})
    (directory / f"{name}.json").write_text(json.dumps(card, indent=2) + "\n")


def export_onnx(model, path) -> None:
    """Export with dynamic clip count, Gaussian count; fixed canvas and clip length."""
    import torch

    cfg = model.cfg
    frames = torch.rand(2, cfg.clip_frames, cfg.canvas, cfg.canvas, 3)
    anchors, cell = (torch.from_numpy(a) for a in anchors_and_cell(256))
    batch, gaussians = torch.export.Dim("batch", max=4096), torch.export.Dim("gaussians", min=4, max=65536)
    program = torch.onnx.export(model.eval(), (frames, anchors, cell), input_names=["frames", "anchors", "cell"],
                                output_names=["params"], opset_version=ONNX_OPSET, dynamo=True,
                                dynamic_shapes={"frames": {0: batch}, "anchors": {0: gaussians}, "cell": None},
                                external_data=False)
    program.save(str(path))


def export_checkpoint(run, out, name: str = BUNDLED_NAME) -> dict:
    """Write the weights of `run`/checkpoint.pt into `out`; returns the training info recorded."""
    import torch

    from ..model import HyperGS, ModelConfig
    checkpoint_path = Path(run) / "checkpoint.pt"
    if not checkpoint_path.is_file():
        raise HyperGSError(f"{checkpoint_path}: no checkpoint")
    state = torch.load(checkpoint_path, map_location="cpu", weights_only=False)
    model = HyperGS(ModelConfig(**state["config"]))
    model.load_state_dict(state["model"])
    train_args = {k: v for k, v in state["args"].items() if k in ("data", "batch", "lr", "gaussians", "steps", "seed")}
    info = dict(step=state["step"], wall_seconds=round(state["wall_seconds"], 1), train_args=train_args)
    save_weights(model, state["regularizer"], out, name, info)
    export_onnx(model, Path(out) / f"{name}.onnx")
    return info
