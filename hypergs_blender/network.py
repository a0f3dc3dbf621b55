"""The trained network as an encoder: weights on disk (a JSON card, .safetensors for torch, .onnx for
onnxruntime), the torch and onnxruntime backends behind one `predict(working frames) -> params`
interface (encode.py), and `resolve_encoder`, the one place that picks an encoder (and says plainly
why one cannot load).

Large frames are encoded in tiles (`tiles`): windows of at most TILE working pixels a side that
overlap by the network's reach, so every Gaussian is predicted from the same pixels as in one pass
over the whole frame (seamless by construction), and memory is bounded.

Only the ONNX backend works without torch: inside Blender torch is usually absent (and the extension
ships no safetensors), and this module imports torch lazily.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import optional
from .errors import HyperGSError

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
BUNDLED_NAME = "hypergs"
BACKENDS = ("auto", "torch", "onnx")
TILE = 1536  # working pixels per tile side, margins included (a 720p frame at any density: one pass)
BATCH_PIXELS = 1 << 21  # working pixels per forward pass (bounds memory)


def tiles(size: int, reach: int, multiple: int, tile: int = TILE) -> list[tuple[int, int, int, int]]:
    """Windows along one axis of `size` working pixels: (start, stop, core start, core stop), all of one
    length, each inside the frame, their cores covering [0, size) once, and each core at least `reach`
    pixels from its window's ends except where those are the frame's own ends. All multiples of
    `multiple`. One window when the frame fits in `tile`."""
    if size <= tile or size <= 2 * reach + multiple:
        return [(0, size, 0, size)]
    core = max(multiple, (tile - 2 * reach) // multiple * multiple)
    length = core + 2 * reach
    if length >= size:
        return [(0, size, 0, size)]
    out = []
    for c0 in range(0, size, core):
        c1 = min(size, c0 + core)
        start = min(max(0, c0 - reach), size - length)
        out.append((start, start + length, c0, c1))
    return out


class NetworkEncoder:
    """Runs `forward(frames float32 [B, h, w, 3]) -> params [B, (h/stride)(w/stride), 8]` (a network on
    any backend) over working frames of any size, tiled (see the module doc). stride, multiple and
    reach are the network's (model.ConvConfig)."""

    def __init__(self, forward, stride: int, multiple: int, reach: int, name: str, tile: int = TILE,
                 session=None):
        self.forward, self.name, self.session = forward, name, session  # session: onnxruntime's, or None
        # What runs: onnxruntime leaves out a provider that cannot start here (a missing CUDA library).
        self.provider = session.get_providers()[0] if session is not None else None
        self.stride, self.multiple, self.reach, self.tile = int(stride), int(multiple), int(reach), int(tile)
        self.granule = self.multiple // self.stride

    def tile_borders(self, width: int, height: int) -> tuple[list[int], list[int]]:
        """Where the tiles' cores meet on a working frame of width x height: (columns, rows)."""
        return tuple([c0 for _, _, c0, _ in tiles(size, self.reach, self.multiple, self.tile)][1:]
                     for size in (width, height))

    def predict(self, frames: np.ndarray) -> np.ndarray:
        """frames float32 [B, H, W, 3] in [0, 1] (H, W multiples of the network's `multiple`) -> params
        [B, N, 8] on the W x H canvas, row-major over the (H / stride) x (W / stride) cells."""
        b, h, w, _ = frames.shape
        s = self.stride
        out = np.empty((b, h // s, w // s, 8), np.float32)
        windows = [(y, x) for y in tiles(h, self.reach, self.multiple, self.tile)
                   for x in tiles(w, self.reach, self.multiple, self.tile)]
        (y0, y1, _, _), (x0, x1, _, _) = windows[0]
        per_call = max(1, BATCH_PIXELS // ((y1 - y0) * (x1 - x0)))
        jobs = [(i, win) for i in range(b) for win in windows]
        for k in range(0, len(jobs), per_call):
            batch = jobs[k:k + per_call]
            crops = np.stack([frames[i, ya:yb, xa:xb] for i, ((ya, yb, _, _), (xa, xb, _, _)) in batch])
            params = np.asarray(self.forward(np.ascontiguousarray(crops, np.float32)))
            wh, ww = crops.shape[1:3]
            params = params.reshape(len(batch), wh // s, ww // s, 8)
            for p, (i, ((ya, yb, ca, cb), (xa, xb, da, db))) in zip(params, batch):
                core = p[(ca - ya) // s:(cb - ya) // s, (da - xa) // s:(db - xa) // s].copy()
                # window canvas [-1, 1] -> the whole frame's canvas
                core[..., 0] = ((core[..., 0] + 1) * (0.5 * ww) + xa) * (2.0 / w) - 1
                core[..., 1] = ((core[..., 1] + 1) * (0.5 * wh) + ya) * (2.0 / h) - 1
                out[i, ca // s:cb // s, da // s:db // s] = core
        return out.reshape(b, -1, 8)


def read_card(directory=WEIGHTS_DIR, name: str = BUNDLED_NAME) -> dict:
    path = Path(directory) / f"{name}.json"
    if not path.is_file():
        raise HyperGSError(f"no model weights at {path}: train one with `hypergs train` and `hypergs export`")
    return json.loads(path.read_text())


def load_model(directory=WEIGHTS_DIR, name: str = BUNDLED_NAME):
    from safetensors.torch import load_file

    from .model import build_model
    card = read_card(directory, name)
    model = build_model(card["config"])
    model.load_state_dict(load_file(str(Path(directory) / f"{name}.safetensors")))
    return model.eval()


def torch_encoder(model, device="cpu") -> NetworkEncoder:
    import torch
    model = model.to(device).eval()

    def forward(frames: np.ndarray) -> np.ndarray:
        with torch.inference_mode():
            return model(torch.from_numpy(frames).to(device)).float().cpu().numpy()

    cfg = model.cfg
    return NetworkEncoder(forward, cfg.stride, cfg.multiple, cfg.reach, "network-torch")


def onnx_encoder(onnx_path, card: dict, providers: list[str] | None = None, threads: int = 0) -> NetworkEncoder:
    """providers: onnxruntime execution providers, best first (default: the CPU's); threads: the CPU
    provider's intra-op threads (0: onnxruntime's default, one per core)."""
    import onnxruntime as ort
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.intra_op_num_threads = threads
    session = ort.InferenceSession(str(onnx_path), options, providers=providers or ["CPUExecutionProvider"])

    def forward(frames: np.ndarray) -> np.ndarray:
        return session.run(["params"], {"frames": frames})[0]

    geometry = card["geometry"]  # written by training.export from the model's config
    return NetworkEncoder(forward, geometry["stride"], geometry["multiple"], geometry["reach"], "network-onnx",
                          session=session)


def resolve_encoder(kind: str = "network", backend: str = "auto", weights=None, device=None,
                    providers: list[str] | None = None, threads: int = 0):
    """The encoder to use. kind: "network" (the trained network in `weights`, default the bundled one)
    or "floor" (the no-learning grid floor). backend for the network: "torch" (needs torch and the
    .safetensors weights), "onnx" (needs onnxruntime and the .onnx model), or "auto": torch where both
    are there, else onnx. providers, threads: onnxruntime's execution providers and CPU threads (see
    onnx_encoder). What cannot load raises HyperGSError saying why; nothing falls back to another kind
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
        has_weights = (directory / f"{BUNDLED_NAME}.safetensors").is_file()
        backend = "torch" if optional.torch_available() and has_weights else "onnx"
    try:
        if backend == "torch":
            import torch
            device = device or ("cuda" if torch.cuda.is_available() else "cpu")
            return torch_encoder(load_model(directory), device)
        onnx_path = directory / f"{BUNDLED_NAME}.onnx"
        if not onnx_path.is_file():
            raise HyperGSError(f"no ONNX model at {onnx_path}: run `hypergs export-onnx`")
        return onnx_encoder(onnx_path, read_card(directory), providers, threads)
    except HyperGSError:
        raise
    except Exception as e:  # a missing package or a broken weights file, said plainly
        raise HyperGSError(f"the trained network could not be loaded with {backend} "
                           f"({type(e).__name__}: {e})") from e

