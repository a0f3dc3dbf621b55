"""Optional dependencies, probed once: torch is there on the command line and absent from Blender's own
Python (the bundled network then runs on onnxruntime, and refining is skipped)."""
from __future__ import annotations

import functools


@functools.cache
def torch_available() -> bool:
    """Whether torch imports here."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True
