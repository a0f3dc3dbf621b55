"""The trained network as an encoder: weights on disk (safetensors + JSON card), the torch and
onnxruntime backends behind one `predict(frames, n)` interface, and ONNX export.

Only `OnnxEncoder` and `load_bundled_encoder('onnx')` work without torch: inside Blender torch is
usually absent, and this module imports it lazily.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from .errors import HyperGSError
from .gaussians import grid_anchors

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
BUNDLED_NAME = "hypergs_small"
ONNX_OPSET = 18


def anchors_and_cell(n: int) -> tuple[np.ndarray, np.ndarray]:
    return grid_anchors(n), np.array([2.0 / math.sqrt(n)], np.float32)


class TorchEncoder:
    name = "network-torch"

    def __init__(self, model, device="cpu"):
        import torch
        self.model = model.to(device).eval()
        self.device = torch.device(device)
        self.canvas, self.clip_frames = model.cfg.canvas, model.cfg.clip_frames

    def predict(self, frames: np.ndarray, n: int) -> np.ndarray:
        import torch
        anchors, cell = anchors_and_cell(n)
        with torch.inference_mode():
            out = self.model(torch.from_numpy(frames).to(self.device), torch.from_numpy(anchors).to(self.device),
                             torch.from_numpy(cell).to(self.device))
        return out.float().cpu().numpy()


class OnnxEncoder:
    name = "network-onnx"

    def __init__(self, onnx_path, card: dict):
        import onnxruntime as ort
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        self.session = ort.InferenceSession(str(onnx_path), options, providers=["CPUExecutionProvider"])
        self.canvas, self.clip_frames = card["config"]["canvas"], card["config"]["clip_frames"]

    def predict(self, frames: np.ndarray, n: int) -> np.ndarray:
        anchors, cell = anchors_and_cell(n)
        return self.session.run(["params"], {"frames": frames.astype(np.float32), "anchors": anchors, "cell": cell})[0]


def save_weights(model, regularizer_state: dict, directory, name: str = BUNDLED_NAME, info: dict | None = None) -> None:
    """<name>.safetensors (model tensors) and <name>.json (config, regularizer thresholds, training info)."""
    from dataclasses import asdict

    from safetensors.torch import save_file
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(directory / f"{name}.safetensors"))
    card = dict(config=asdict(model.cfg), regularizer={k: float(v) for k, v in regularizer_state.items()},
                info=info or {})
    (directory / f"{name}.json").write_text(json.dumps(card, indent=2) + "\n")


def read_card(directory=WEIGHTS_DIR, name: str = BUNDLED_NAME) -> dict:
    path = Path(directory) / f"{name}.json"
    if not path.is_file():
        raise HyperGSError(f"no model weights at {path}: train one with `hypergs train` and `hypergs export`")
    return json.loads(path.read_text())


def load_model(directory=WEIGHTS_DIR, name: str = BUNDLED_NAME):
    from safetensors.torch import load_file

    from .model import HyperGS, ModelConfig
    card = read_card(directory, name)
    model = HyperGS(ModelConfig(**card["config"]))
    model.load_state_dict(load_file(str(Path(directory) / f"{name}.safetensors")))
    return model.eval()


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


def load_bundled_encoder(backend: str = "auto", directory=WEIGHTS_DIR, name: str = BUNDLED_NAME, device=None):
    """'torch' (needs torch), 'onnx' (needs onnxruntime), or 'auto': torch when it imports, else onnx."""
    if backend == "auto":
        try:
            import torch  # noqa: F401
            backend = "torch"
        except ImportError:
            backend = "onnx"
    if backend == "torch":
        import torch
        return TorchEncoder(load_model(directory, name), device or ("cuda" if torch.cuda.is_available() else "cpu"))
    if backend == "onnx":
        onnx_path = Path(directory) / f"{name}.onnx"
        if not onnx_path.is_file():
            raise HyperGSError(f"no ONNX model at {onnx_path}: run `hypergs export-onnx`")
        return OnnxEncoder(onnx_path, read_card(directory, name))
    raise HyperGSError(f"unknown encoder backend {backend!r} (torch, onnx or auto)")


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("export", help="training checkpoint -> weights (safetensors + JSON card + ONNX)")
    p.add_argument("run", help="run folder holding checkpoint.pt")
    p.add_argument("--out", default=str(WEIGHTS_DIR))
    p.add_argument("--name", default=BUNDLED_NAME)
    p.set_defaults(func=_export_command)
    p = subparsers.add_parser("export-onnx", help="weights (safetensors) -> <name>.onnx beside them")
    p.add_argument("--weights", default=str(WEIGHTS_DIR))
    p.add_argument("--name", default=BUNDLED_NAME)
    p.set_defaults(func=_export_onnx_command)


def _export_command(args) -> None:
    import torch

    from .model import HyperGS, ModelConfig
    checkpoint_path = Path(args.run) / "checkpoint.pt"
    if not checkpoint_path.is_file():
        raise HyperGSError(f"{checkpoint_path}: no checkpoint")
    state = torch.load(checkpoint_path, map_location="cpu", weights_only=False)
    model = HyperGS(ModelConfig(**state["config"]))
    model.load_state_dict(state["model"])
    train_args = {k: v for k, v in state["args"].items() if k in ("data", "batch", "lr", "gaussians", "steps", "seed")}
    info = dict(step=state["step"], wall_seconds=round(state["wall_seconds"], 1), train_args=train_args)
    save_weights(model, state["regularizer"], args.out, args.name, info)
    export_onnx(model, Path(args.out) / f"{args.name}.onnx")
    print(f"exported step {state['step']} to {args.out}/{args.name}.{{safetensors,json,onnx}}")


def _export_onnx_command(args) -> None:
    export_onnx(load_model(args.weights, args.name), Path(args.weights) / f"{args.name}.onnx")
    print(f"wrote {Path(args.weights) / f'{args.name}.onnx'}")
