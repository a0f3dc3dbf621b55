"""Training checkpoint of the conv network -> the weights the runtime loads (network.py):
<name>.safetensors (tensors, for torch), <name>.json (the card: config, the tiling geometry, training
info) and <name>.onnx (onnxruntime; one graph for every frame size, hence every Gaussian count)."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import HyperGSError
from ..network import BUNDLED_NAME

ONNX_OPSET = 18


def card_of(model, info: dict | None = None) -> dict:
    from ..model import model_config
    cfg = model.cfg
    return dict(config=model_config(model), geometry=dict(stride=cfg.stride, multiple=cfg.multiple, reach=cfg.reach),
                info=info or {})


def save_weights(model, directory, name: str = BUNDLED_NAME, info: dict | None = None) -> None:
    from safetensors.torch import save_file
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(directory / f"{name}.safetensors"))
    (directory / f"{name}.safetensors").chmod(0o644)  # safetensors writes 0600; the weights are for everyone
    (directory / f"{name}.json").write_text(json.dumps(card_of(model, info), indent=2) + "\n")


def export_onnx(model, path) -> None:
    """The conv network with dynamic batch, height and width (multiples of its `multiple`)."""
    import torch

    m = model.cfg.multiple
    frames = torch.rand(2, 4 * m, 6 * m, 3)
    batch = torch.export.Dim("batch", max=4096)
    rows, cols = torch.export.Dim("rows", max=8192 // m), torch.export.Dim("cols", max=8192 // m)
    program = torch.onnx.export(model.eval(), (frames,), input_names=["frames"], output_names=["params"],
                                opset_version=ONNX_OPSET, dynamo=True, external_data=False,
                                dynamic_shapes={"frames": {0: batch, 1: m * rows, 2: m * cols}})
    program.save(str(path))


def export_checkpoint(run, out, name: str = BUNDLED_NAME) -> dict:
    """Write the weights of `run`/checkpoint.pt into `out`; returns the training info recorded."""
    import torch

    from ..model import ConvGS, build_model
    checkpoint_path = Path(run) / "checkpoint.pt"
    if not checkpoint_path.is_file():
        raise HyperGSError(f"{checkpoint_path}: no checkpoint")
    state = torch.load(checkpoint_path, map_location="cpu", weights_only=True)
    model = build_model(json.loads(state["config"]))
    if not isinstance(model, ConvGS):
        raise HyperGSError(f"{checkpoint_path}: a {type(model).__name__} (the paper's design); the runtime encodes "
                           "with the conv network, so only conv runs export (the trainer evaluates the others)")
    model.load_state_dict(state["model"])
    args = json.loads(state["args"])
    train_args = {k: args[k] for k in ("data", "batch", "size", "lr", "clip", "steps", "seed", "preset") if k in args}
    info = dict(step=int(state["step"]), cpu_hours=round(float(state["cpu_seconds"]) / 3600, 3),
                wall_hours=round(float(state["wall_seconds"]) / 3600, 3), train_args=train_args)
    save_weights(model, out, name, info)
    export_onnx(model, Path(out) / f"{name}.onnx")
    return info
