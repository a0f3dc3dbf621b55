"""Load and save GaussianVideo clips, choosing the format by file suffix:
  .hgs              compressed (codec.py / hgs.py); options: bits (8, 6, 4 or 8 values), group_size, mode
  .npz              uncompressed float32 (npz.py); options are ignored
  .usd/.usda/.usdc  UsdGeomPoints with a time sample per frame (usd.py); option: start_frame
"""
from __future__ import annotations

from pathlib import Path

from ..errors import HyperGSError
from ..gaussians import GaussianVideo, param_problem

CLIP_SUFFIXES = (".hgs", ".npz", ".usd", ".usda", ".usdc")
_SAVE_OPTIONS = {".hgs": {"bits", "group_size", "mode", "quantizer"}, ".npz": {"bits"},
                 ".usd": {"start_frame", "bits"}}


def _suffix(path: Path) -> str:
    suffix = path.suffix.lower()
    if suffix in (".usda", ".usdc"):
        return ".usd"
    if suffix not in CLIP_SUFFIXES:
        raise HyperGSError(f"{path}: unknown Gaussian video format {path.suffix!r} (use {', '.join(CLIP_SUFFIXES)})")
    return suffix


def save_clip(video: GaussianVideo, path, **options) -> None:
    """Write `video` to `path` in the format its suffix names. `bits` only matters for .hgs."""
    path = Path(path)
    suffix = _suffix(path)
    unknown = set(options) - _SAVE_OPTIONS[suffix]
    if unknown:
        raise HyperGSError(f"{path}: option(s) {', '.join(sorted(unknown))} do not apply to {suffix} files")
    problem = param_problem(video.params)
    if problem:  # a file that no reader would accept
        raise HyperGSError(f"{path}: {problem}")
    if suffix == ".hgs":
        from .hgs import save_hgs
        save_hgs(video, path, **options)
    elif suffix == ".npz":
        from .npz import save_npz
        save_npz(video, path)
    else:
        from .usd import export_usd
        export_usd(video, path, start_frame=options.get("start_frame", 1))


def load_clip(path) -> GaussianVideo:
    path = Path(path)
    suffix = _suffix(path)
    if not path.is_file():
        raise HyperGSError(f"{path}: no such file")
    if suffix == ".hgs":
        from .hgs import load_hgs
        return load_hgs(path)
    if suffix == ".usd":
        from .usd import import_usd
        return import_usd(path)
    from .npz import load_npz
    return load_npz(path)
