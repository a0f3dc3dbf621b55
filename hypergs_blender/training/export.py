"""Training checkpoint of the conv network -> the weights the runtime loads (network.py):
<name>.safetensors (tensors, for torch), <name>.json (the card: config, the tiling geometry, training
info) and <name>.onnx (onnxruntime; one graph for every frame size, hence every Gaussian count)."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import HyperGSError, reason
from ..io.files import AtomicOutput, write_bytes
from ..network import BUNDLED_NAME

# Opset 20 has GELU as one op (Gelu): at 18 the exporter spells it out (Erf, Mul, Add), which onnxruntime
# does not fuse back, and around each of those ops its NCHWc conv layout is reordered; the one op cuts a
# 1080p Standard frame's CPU time by 21 % (0.84 -> 0.65 s, one thread), with the same output.
ONNX_OPSET = 20


def card_of(model, info: dict | None = None) -> dict:
    from ..model import model_config
    cfg = model.cfg
    return dict(config=model_config(model), geometry=dict(stride=cfg.stride, multiple=cfg.multiple, reach=cfg.reach),
                info=info or {})


def save_weights(model, directory, name: str = BUNDLED_NAME, info: dict | None = None) -> None:
    from safetensors.torch import save_file
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    with AtomicOutput(directory / f"{name}.safetensors") as temp:
        save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(temp))
    (directory / f"{name}.safetensors").chmod(0o644)  # safetensors writes 0600; the weights are for everyone
    write_bytes(directory / f"{name}.json", (json.dumps(card_of(model, info), indent=2) + "\n").encode())


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

    from ..model import ConvGS, build_model
    checkpoint_path = Path(run) / "checkpoint.pt"
    if not checkpoint_path.is_file():
        raise HyperGSError(f"{checkpoint_path}: no checkpoint")
    state = load_checkpoint(checkpoint_path)
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
