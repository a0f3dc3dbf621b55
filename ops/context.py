"""What the operators and the clip panel share: the clip object they act on (`active_clip`, which their
polls start from) and how an outcome reaches the user (`report_error`, `reported`): one line, never a
traceback (that goes to the console, for bug reports, when the error is not the user's input)."""
from __future__ import annotations

import traceback

from ..com.mesh import is_clip
from ..hypergs_blender.errors import HyperGSError


def active_clip(context):
    """The clip the context shows (the Properties editor's object, else the active object), or None."""
    obj = getattr(context, "object", None) or getattr(context, "active_object", None)
    return obj if is_clip(obj) else None


def describe(error: BaseException) -> str:
    """The message the user sees for an error (no traceback)."""
    if isinstance(error, HyperGSError):
        return str(error)
    return f"{type(error).__name__}: {error}"


def report_error(operator, error: BaseException) -> set[str]:
    """Report `error` to the user (an unexpected one's traceback to the console too); {"CANCELLED"}."""
    if not isinstance(error, HyperGSError):
        traceback.print_exception(error)
    operator.report({"ERROR"}, describe(error))
    return {"CANCELLED"}


def reported(operator, work) -> set[str]:
    """Run work() -> message: reported as INFO, {"FINISHED"}; or its error reported, {"CANCELLED"}. What
    work() made before it failed is its own to remove (scene.Undo)."""
    try:
        message = work()
    except Exception as e:
        return report_error(operator, e)
    operator.report({"INFO"}, message)
    return {"FINISHED"}
