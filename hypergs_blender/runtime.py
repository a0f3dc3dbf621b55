"""The encoder an application keeps for its session (Blender's operators): `network.resolve_encoder`
(the one policy: the bundled network, onnxruntime where torch is missing; what cannot load is reported,
never replaced by another encoder), loaded once per session, `Runtime` and model (encode.MODELS: the
conv network, or the paper's transformer when its weights are there: bundled, or the folder or card
the user set, `Runtime.transformer_weights`). `HYPERGS_ENCODER=floor` picks the no-learning
`FloorEncoder` instead (tests use it where the network's quality does not matter).

Where the network runs is a `Runtime` (in Blender the add-on preferences' choice, ops/preferences.py),
turned into onnxruntime's execution providers here: a GPU provider when the user's onnxruntime has one
(the bundled wheels have CoreML on macOS; CUDA and DirectML come with the onnxruntime-gpu /
onnxruntime-directml packages), the CPU otherwise, with the preferred thread count.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

from .encode import MODELS
from .errors import HyperGSError
from .network import DEFAULT_NAMES, WEIGHTS_DIR, read_card, resolve_encoder, weights_name

ENCODER_ENV = "HYPERGS_ENCODER"
CPU = "CPUExecutionProvider"
# onnxruntime's providers that we ask for -> what the user sees; "Best Available" tries the GPU ones in
# this order, and the CPU always comes last (it runs what the others cannot).
PROVIDERS = {"CUDAExecutionProvider": "CUDA", "DmlExecutionProvider": "DirectML",
             "CoreMLExecutionProvider": "CoreML", CPU: "CPU"}
AUTO = "AUTO"
_cache: dict = {}


@dataclass(frozen=True)
class Runtime:
    """Where the network runs: `device` is AUTO (the best provider this onnxruntime has) or a key of
    PROVIDERS; `threads` the CPU's (0: one per core); `transformer_weights` the transformer's weights
    (a folder or a model's card; "": the bundled ones)."""
    device: str = AUTO
    threads: int = 0
    transformer_weights: str = ""

    @property
    def cpu_threads(self) -> int:
        """The CPU threads the network runs on (for the time estimate)."""
        return self.threads or os.cpu_count() or 1


def available_providers() -> list[str]:
    """The PROVIDERS the installed onnxruntime has, best first (none without onnxruntime)."""
    try:
        import onnxruntime
    except ImportError:
        return []
    have = set(onnxruntime.get_available_providers())
    return [p for p in PROVIDERS if p in have]


def providers_for(device: str, available: list[str]) -> list[str]:
    """The execution providers to ask onnxruntime for, best first: the chosen GPU provider (every
    available one for AUTO) if this onnxruntime has it, then the CPU."""
    wanted = [p for p in available if p != CPU] if device == AUTO else [device]
    return [p for p in wanted if p in available and p != CPU] + [CPU]


def model_weights(runtime: Runtime, model: str) -> Path | None:
    """The weights `model` loads (resolve_encoder's `weights`): None for the bundled conv network; the
    transformer's card, from `runtime.transformer_weights` or the bundled one. Raises HyperGSError when
    there is none, saying where to set it."""
    if model not in MODELS:
        raise HyperGSError(f"unknown model {model!r} ({', '.join(MODELS)})")
    if model == "conv":
        return None
    if runtime.transformer_weights:
        path = Path(runtime.transformer_weights).expanduser()
        if path.is_dir():  # its transformer (a folder may hold the conv network too), else its only model
            named = path / f"{DEFAULT_NAMES['transformer']}.json"
            path = named if named.is_file() else path / f"{weights_name(path)}.json"
    else:
        path = WEIGHTS_DIR / f"{DEFAULT_NAMES['transformer']}.json"
        if not path.is_file():
            raise HyperGSError("no HyperGS transformer weights: this build bundles none; train and export one "
                               "(`hypergs train --preset small`, `hypergs export`) and set its folder in the "
                               "add-on's preferences")
    try:
        arch = read_card(path.parent, path.stem).get("arch", "conv")
    except (OSError, ValueError, AttributeError) as e:  # unreadable, not JSON, not a card
        raise HyperGSError(f"{path} is not a model's card ({type(e).__name__}: {e})") from None
    if arch != "transformer":
        raise HyperGSError(f"{path} holds the {arch} network's weights, not a transformer's")
    return path


def transformer_available(runtime: Runtime) -> bool:
    """Whether the transformer can be offered: its weights are there (model_weights finds them)."""
    try:
        model_weights(runtime, "transformer")
    except HyperGSError:
        return False
    return True


def make_encoder(runtime: Runtime = Runtime(), model: str = MODELS[0]):
    """The session's encoder for `runtime` and `model` (loaded on first use; one network in memory at a
    time)."""
    choice = os.environ.get(ENCODER_ENV, "bundled").strip().lower()
    if choice not in ("bundled", "floor"):
        raise HyperGSError(f"{ENCODER_ENV}={choice!r}: use 'bundled' or 'floor'")
    weights = model_weights(runtime, model) if choice == "bundled" else None
    key = (choice, runtime, weights) if choice == "bundled" else (choice,)
    if key not in _cache:  # loading the network is slow: once per session, runtime and model
        _cache.clear()  # one network in memory
        _cache[key] = (resolve_encoder("floor") if choice == "floor" else
                       resolve_encoder("network", weights=weights,
                                       providers=providers_for(runtime.device, available_providers()),
                                       threads=runtime.threads))
    return _cache[key]


def describe_encoder(encoder, runtime: Runtime) -> str:
    """What encoded, for Blender's clip panel and the operator's report: e.g. "network-onnx on CUDA",
    "network-onnx on CPU (4 threads)", "floor"."""
    provider = getattr(encoder, "provider", None)
    if provider is None:
        return encoder.name
    text = f"{encoder.name} on {PROVIDERS.get(provider, provider)}"
    if provider == CPU:
        text += f" ({runtime.threads} thread{'s' if runtime.threads > 1 else ''})" if runtime.threads else " (all cores)"
    return text
