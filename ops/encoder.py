"""The one place that chooses the encoder the operators use.

Default: the bundled network (`encode.default_encoder()`: torch with CUDA when importable, else
onnxruntime; the ONNX model also where torch imports but its backend does not load). Where the
network cannot load, the operators report that; they never fall back to another encoder silently.
`HYPERGS_ENCODER=floor` picks the no-learning `FloorEncoder` instead (tests and the main job set it
until the bundled network's weights land).
"""
from __future__ import annotations

import os

from ..hypergs_blender.errors import HyperGSError

ENCODER_ENV = "HYPERGS_ENCODER"
_cache: dict = {}


def make_encoder():
    choice = os.environ.get(ENCODER_ENV, "bundled").strip().lower()
    if choice == "floor":
        from ..hypergs_blender.encode import FloorEncoder
        return FloorEncoder()
    if choice != "bundled":
        raise HyperGSError(f"{ENCODER_ENV}={choice!r}: use 'bundled' or 'floor'")
    if "bundled" not in _cache:  # loading the network is slow: once per Blender session
        from ..hypergs_blender.encode import default_encoder
        try:
            _cache["bundled"] = default_encoder()  # torch (CUDA) when importable, else onnxruntime
        except Exception as first:
            try:  # a Blender with torch but not the rest of its stack (safetensors): the bundled ONNX model
                _cache["bundled"] = default_encoder("onnx")
            except Exception:
                if isinstance(first, HyperGSError):
                    raise first
                raise HyperGSError(f"The bundled HyperGS network could not be loaded "
                                   f"({type(first).__name__}: {first})") from first
    return _cache["bundled"]


def encoder_name(encoder) -> str:
    return getattr(encoder, "name", type(encoder).__name__)
