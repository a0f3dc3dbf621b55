"""The trained network as an encoder: weights on disk (JSON card + safetensors for torch + ONNX for
onnxruntime), the torch and onnxruntime backends behind one `predict(frames, n)` interface, and
`resolve_encoder`, the one place that picks an encoder (and says plainly why one cannot load).

Only the ONNX backend works without torch: inside Blender torch is usually absent (and the extension
ships no safetensors), and this module imports torch lazily.
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


def anchors_and_cell(n: int) -> tuple[np.ndarray, np.ndarray]:
    return grid_anchors(n), np.array([2.0 / math.sqrt(n)], np.float32)


class TorchEncoder:
    name = "network-torch"
    stride = 4  # STAND-IN for the lead's network (see encode.py)

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
    stride = 4  # STAND-IN for the lead's network (see encode.py)

    def __init__(self, onnx_path, card: dict, providers: list[str] | None = None, threads: int = 0):
        """providers: onnxruntime execution providers, best first (default: the CPU's); threads: the CPU
        provider's intra-op threads (0: onnxruntime's default, one per core)."""
        import onnxruntime as ort
        options = ort.SessionOptions()
        options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
        options.intra_op_num_threads = threads
        self.session = ort.InferenceSession(str(onnx_path), options,
                                            providers=providers or ["CPUExecutionProvider"])
        # What runs: onnxruntime leaves out a provider that cannot start here (a missing CUDA library).
        self.provider = self.session.get_providers()[0]
        self.canvas, self.clip_frames = card["config"]["canvas"], card["config"]["clip_frames"]

    def predict(self, frames: np.ndarray, n: int) -> np.ndarray:
        anchors, cell = anchors_and_cell(n)
        return self.session.run(["params"], {"frames": frames.astype(np.float32), "anchors": anchors, "cell": cell})[0]


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


BACKENDS = ("auto", "torch", "onnx")


def resolve_encoder(kind: str = "network", backend: str = "auto", weights=None, device=None,
                    providers: list[str] | None = None, threads: int = 0):
    """The encoder to use. kind: "network" (the trained network in `weights`, default the bundled one)
    or "floor" (the no-learning grid floor). backend for the network: "torch" (needs torch and the
    .safetensors weights), "onnx" (needs onnxruntime and the .onnx model), or "auto": torch where both
    are there, else onnx. providers, threads: onnxruntime's execution providers and CPU threads (see
    OnnxEncoder). What cannot load raises HyperGSError saying why; nothing falls back to another kind
    of encoder."""
    if kind == "floor":
        from .encode import FloorEncoder
        return FloorEncoder()
    if kind != "network":
        raise HyperGSError(f"unknown encoder {kind!r} (network or floor)")
    if backend not in BACKENDS:
        raise HyperGSError(f"unknown encoder backend {backend!r} ({', '.join(BACKENDS)})")
    directory = Path(weights or WEIGHTS_DIR)
    if backend == "auto":
        backend = "torch" if _torch_importable() and (directory / f"{BUNDLED_NAME}.safetensors").is_file() else "onnx"
    try:
        if backend == "torch":
            import torch
            device = device or ("cuda" if torch.cuda.is_available() else "cpu")
            return TorchEncoder(load_model(directory), device)
        onnx_path = directory / f"{BUNDLED_NAME}.onnx"
        if not onnx_path.is_file():
            raise HyperGSError(f"no ONNX model at {onnx_path}: run `hypergs export-onnx`")
        return OnnxEncoder(onnx_path, read_card(directory), providers, threads)
    except HyperGSError:
        raise
    except Exception as e:  # a missing package or a broken weights file, said plainly
        raise HyperGSError(f"the trained network could not be loaded with {backend} "
                           f"({type(e).__name__}: {e})") from e


def _torch_importable() -> bool:
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True
