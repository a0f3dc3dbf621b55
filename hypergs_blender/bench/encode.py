"""`hypergs bench encode`: encode throughput of the bundled network through the whole encode path."""
from __future__ import annotations

from ..encode import encode_frames, frames_layout
from ..network import resolve_encoder
from .common import timed


def bench_encode(backends=("torch", "onnx"), counts=(250, 1000, 3000), frames: int = 8, size: int = 256,
                 repeats: int = 3, weights=None) -> dict:
    """Encode throughput of the bundled network: `frames` size x size frames per call, through the
    whole encode path (resize to the working size, forward in tiles, stretch back), per Gaussian count."""
    import numpy as np
    import torch

    clip = np.random.default_rng(0).integers(0, 256, (frames, size, size, 3), dtype=np.uint8)
    report = {"frames_per_call": frames, "size": size, "torch_threads": torch.get_num_threads(),
              "device": "cpu"}
    for backend in backends:
        encoder = resolve_encoder("network", backend, weights, device="cpu")
        for n in counts:
            layout = frames_layout(clip, encoder, gaussians=n)
            seconds = timed(lambda: encode_frames(clip, encoder, layout), repeats, warmup=True)[0]
            report[f"{backend}_N={n}"] = {"clips_per_s": round(1 / seconds, 3), "frames_per_s": round(frames / seconds, 2)}
    return report
