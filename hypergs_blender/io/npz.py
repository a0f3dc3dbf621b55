"""GaussianVideo as an uncompressed .npz (float32 parameters and a JSON header; no pickle). The .hgs
codec is the compact format; this one keeps every bit."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from ..errors import HyperGSError
from ..gaussians import GaussianVideo

FORMAT_VERSION = 1


def save_npz(video: GaussianVideo, path) -> None:
    meta = dict(version=FORMAT_VERSION, canvas=[video.canvas_width, video.canvas_height], fps=video.fps,
                grid=list(video.grid), source=video.source)
    with open(path, "wb") as f:
        np.savez(f, params=video.params, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))


def load_npz(path) -> GaussianVideo:
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            params = z["params"]
            meta = json.loads(z["meta"].tobytes().decode())
    except (OSError, ValueError, KeyError) as e:
        raise HyperGSError(f"{path}: not a Gaussian video file ({e})") from e
    if meta.get("version") != FORMAT_VERSION:
        raise HyperGSError(f"{path}: unsupported Gaussian video version {meta.get('version')}")
    w, h = meta["canvas"]
    return GaussianVideo(params, w, h, meta["fps"], tuple(meta["grid"]), meta.get("source", {}))
