"""The encoder the operators use: `network.resolve_encoder` (the one policy: the bundled network,
onnxruntime in a Blender without torch; what cannot load is reported, never replaced by another
encoder), loaded once per Blender session. `HYPERGS_ENCODER=floor` picks the no-learning
`FloorEncoder` instead (tests use it where the network's quality does not matter).
"""
from __future__ import annotations

import os

from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.network import resolve_encoder

ENCODER_ENV = "HYPERGS_ENCODER"
_cache: dict = {}


def make_encoder():
    choice = os.environ.get(ENCODER_ENV, "bundled").strip().lower()
    if choice not in ("bundled", "floor"):
        raise HyperGSError(f"{ENCODER_ENV}={choice!r}: use 'bundled' or 'floor'")
    if choice not in _cache:  # loading the network is slow: once per Blender session
        _cache[choice] = resolve_encoder("floor" if choice == "floor" else "network")
    return _cache[choice]
