"""GaussianVideo as an uncompressed .npz (float32 parameters and a JSON header; no pickle). The .hgs
codec is the compact format; this one keeps every bit.

Reading trusts nothing in the file: the sizes in the zip directory and in each array's .npy header are
checked against each other and against the limits (limits.py) before anything is decompressed or
allocated, so a zip bomb or a header declaring a huge shape is refused in milliseconds; then the
values are checked (GaussianVideo.checked)."""
from __future__ import annotations

import json
import tokenize
import zipfile
import zlib
from pathlib import Path

import numpy as np

from .. import limits
from ..errors import HyperGSError
from ..gaussians import GaussianVideo
from .files import AtomicOutput

FORMAT_VERSION = 1


def save_npz(video: GaussianVideo, path) -> None:
    meta = dict(version=FORMAT_VERSION, canvas=[video.canvas_width, video.canvas_height], fps=video.fps,
                grid=list(video.grid), source=video.source)
    arrays = {"params": video.params, "meta": np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8)}
    # As np.savez writes it, but closed in order when a write fails (np.savez leaves that to the GC).
    with AtomicOutput(path) as temp, zipfile.ZipFile(temp, "w") as z:
        for name, array in arrays.items():
            with z.open(f"{name}.npy", "w", force_zip64=True) as f:
                np.lib.format.write_array(f, array, allow_pickle=False)


def load_npz(path) -> GaussianVideo:
    path = Path(path)
    try:
        with zipfile.ZipFile(path) as z:
            members = {info.filename: info for info in z.infolist()}
            for name in ("params.npy", "meta.npy"):
                if name not in members:
                    raise HyperGSError(f"{path}: not a Gaussian video file (no {name[:-4]} array)")
            limits.BYTES.check(members["params.npy"].file_size, f"{path}: params")
            limits.METADATA.check(members["meta.npy"].file_size, f"{path}: meta")
            meta = _metadata(_read_array(z, members["meta.npy"], path), path)
            params = _read_array(z, members["params.npy"], path)
    except (zipfile.BadZipFile, zlib.error, EOFError, OSError, ValueError, NotImplementedError, RuntimeError,
            SyntaxError, RecursionError, tokenize.TokenError) as e:  # (the last three from numpy's header parser)
        raise HyperGSError(f"{path}: not a readable Gaussian video file ({type(e).__name__}: {e})") from None
    return GaussianVideo.checked(path, params, *meta["canvas"], meta["fps"], tuple(meta["grid"]),
                                 meta.get("source", {}))


def _read_array(z: zipfile.ZipFile, info: zipfile.ZipInfo, path) -> np.ndarray:
    """One .npy member, its header checked before its data is read: a known numeric dtype, and a shape
    whose size is what the zip directory says the member holds (itself within the limits)."""
    name = info.filename[:-4]
    with z.open(info) as f:
        version = np.lib.format.read_magic(f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
        elif version == (2, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
        else:
            raise HyperGSError(f"{path}: {name}: unsupported .npy version {version}")
        if dtype.hasobject or dtype.kind not in "biufc" or dtype.fields is not None:
            raise HyperGSError(f"{path}: {name}: arrays of {dtype} are not Gaussian video data")
        count = int(np.prod(shape, dtype=object))
        nbytes = count * dtype.itemsize
        if nbytes != info.file_size - f.tell():
            raise HyperGSError(f"{path}: {name}: shape {shape} does not match the {info.file_size} bytes stored")
        data = f.read(nbytes)
        if len(data) != nbytes:
            raise HyperGSError(f"{path}: {name}: truncated")
    return np.frombuffer(data, dtype).reshape(shape, order="F" if fortran else "C")


def _metadata(raw: np.ndarray, path) -> dict:
    if raw.dtype != np.uint8 or raw.ndim != 1:
        raise HyperGSError(f"{path}: damaged metadata (not JSON bytes)")
    try:
        meta = json.loads(raw.tobytes().decode("utf-8"))
    except (ValueError, RecursionError) as e:
        raise HyperGSError(f"{path}: damaged metadata ({type(e).__name__})") from None
    if not isinstance(meta, dict):
        raise HyperGSError(f"{path}: damaged metadata (not a JSON object)")
    if meta.get("version") != FORMAT_VERSION:
        raise HyperGSError(f"{path}: unsupported Gaussian video version {meta.get('version')!r}")
    pairs_ok = all(isinstance(meta.get(k), list) and len(meta[k]) == 2 for k in ("canvas", "grid"))
    if not pairs_ok or "fps" not in meta:
        raise HyperGSError(f"{path}: damaged metadata (canvas, fps or grid missing or malformed)")
    return meta
