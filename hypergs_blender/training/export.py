"""Training checkpoint -> the weights a runtime loads (network.py): <name>.safetensors (tensors, for
torch), <name>.json (config, regularizer thresholds, training info) and <name>.onnx (onnxruntime)."""
from __future__ import annotations

import json
from dataclasses import asdict
from pathlib import Path

from ..errors import HyperGSError, reason
from ..io.files import AtomicOutput, write_bytes
from ..network import BUNDLED_NAME, anchors_and_cell

ONNX_OPSET = 18


def save_weights(model, regularizer_state: dict, directory, name: str = BUNDLED_NAME, info: dict | None = None) -> None:
    from safetensors.torch import save_file
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    with AtomicOutput(directory / f"{name}.safetensors") as temp:
        save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(temp))
    card = dict(config=asdict(model.cfg), regularizer={k: float(v) for k, v in regularizer_state.items()},
                info=info or {})
    write_bytes(directory / f"{name}.json", (json.dumps(card, indent=2) + "\n").encode())


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
    with AtomicOutput(path) as temp:
        program.save(str(temp))


def load_checkpoint(path) -> dict:
    """A training checkpoint, loaded with weights_only=True: tensors, numbers, strings and containers
    only, so a checkpoint from elsewhere cannot run code. Raises HyperGSError naming the file."""
    import pickle

    import torch
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise HyperGSError(f"{path}: holds Python objects besides tensors and plain data; refused, as loading "
                           "it could run code") from None
    except (RuntimeError, EOFError, ValueError) as e:
        raise HyperGSError(f"{path}: not a readable checkpoint ({reason(e)})") from None
    if not isinstance(state, dict):
        raise HyperGSError(f"{path}: not a training checkpoint")
    return state


def export_checkpoint(run, out, name: str = BUNDLED_NAME) -> dict:
    """Write the weights of `run`/checkpoint.pt into `out`; returns the training info recorded."""
    import torch

    from ..model import HyperGS, ModelConfig
    checkpoint_path = Path(run) / "checkpoint.pt"
    if not checkpoint_path.is_file():
        raise HyperGSError(f"{checkpoint_path}: no checkpoint")
    state = load_checkpoint(checkpoint_path)
    model = HyperGS(ModelConfig(**state["config"]))
    model.load_state_dict(state["model"])
    train_args = {k: v for k, v in state["args"].items() if k in ("data", "batch", "lr", "gaussians", "steps", "seed")}
    info = dict(step=state["step"], wall_seconds=round(state["wall_seconds"], 1), train_args=train_args)
    save_weights(model, state["regularizer"], out, name, info)
    export_onnx(model, Path(out) / f"{name}.onnx")
    return info
