"""Optional dependencies, probed once: torch is there on the command line and absent from Blender's own
Python (the bundled network then runs on onnxruntime, and refining is skipped); pxr (USD) and OpenImageIO
come with Blender's Python and with our requirements, but not with every Python the extension may run in (the
bpy 4.2 and 4.3 wheels have neither), so what needs them says so in one clear error (`require`)."""
from __future__ import annotations

import functools
import importlib

from .errors import HyperGSError

# module -> (what needs it, the PyPI package that provides it)
MODULES = {"pxr": ("USD files", "usd-core"), "OpenImageIO": ("Image files", "OpenImageIO")}


@functools.cache
def torch_available() -> bool:
    """Whether torch imports here."""
    try:
        import torch  # noqa: F401
    except ImportError:
        return False
    return True


def require(module: str):
    """The module `module` (a key of MODULES). Raises HyperGSError saying what needs it and where it comes from
    when this Python cannot import it."""
    try:
        return importlib.import_module(module)
    except ImportError as e:
        purpose, package = MODULES[module]
        raise HyperGSError(f"{purpose} need the Python module '{module}' (PyPI package {package}), which this "
                           f"Python cannot import ({e})") from None
