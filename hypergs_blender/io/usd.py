"""GaussianVideo <-> USD (usd-core): one UsdGeomPoints prim with a time sample per frame.

Layout written by `export_usd`:
  /GaussianVideo               Xform, the stage's default prim
  /GaussianVideo/Gaussians     Points, customData["hypergs"] = {version, canvas_width, canvas_height,
                               grid, source (JSON text)}
    points                     per frame: (x * W/2, -y * H/2, 0): canvas pixels, origin at the canvas
                               centre, Y up (the stage is Y up, metersPerUnit 0.01)
    widths                     per frame: 2 * sqrt(scale_x * scale_y), the diameter of the circle with the
                               Gaussian's 1-sigma area, in the same pixel units
    primvars:scale             float2, vertex: scale x, y in canvas pixels (exact)
    primvars:rotation          float, vertex: rotation in radians in the image convention (y down); in
                               the Y-up stage the ellipse's angle is -rotation
    primvars:displayColor      color3f, vertex: the additive r, g, b (sRGB-encoded, may leave [0, 1])
    ids                        0..N-1: Gaussian i is the same Gaussian in every frame
  stage: timeCodesPerSecond = framesPerSecond = fps, frames start_frame .. start_frame + T - 1

`import_usd` reads that prim back into a GaussianVideo (float32: exact up to float rounding of the
position mapping). The suffix picks the file format: .usd / .usdc binary, .usda text.
Reading checks the file size, the frame and point counts against limits.py before it reads the
frames, and every value after (GaussianVideo.checked: no NaN, scales > 0). Payloads are not loaded.
usd-core's binary (crate) reader trusts the file: a damaged .usdc can make it allocate tens of GB or
crash the process (SIGSEGV: 5 of 16,000 damaged files in tests/test_input_fuzz.py's runs), which in
Blender would take the user's session with it. So a crate file (`.usdc`, or any file that starts like
one) is read in a child process (`_read_in_child`: this module run by the same Python), where a crash
is an error message naming the file; text files (.usda) are read here. Either way the read runs with
its process' address space capped at its size plus a headroom (`_address_space_headroom`, Linux),
where such an allocation fails and USD reports an error instead.
"""
from __future__ import annotations

import builtins
import json
import os
import pickle
import signal
import subprocess
import sys
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from .. import limits, optional
from ..errors import HyperGSError, LimitError, reason
from ..gaussians import NUM_PARAMS, GaussianVideo
from .files import AtomicOutput, StreamingWriter

ROOT_PATH = "/GaussianVideo"
PRIM_PATH = "/GaussianVideo/Gaussians"
METADATA_KEY = "hypergs"
USD_VERSION = 1
USD_SUFFIXES = (".usd", ".usda", ".usdc")
CRATE_MAGIC = b"PXR-USDC"  # the first bytes of a binary (crate) USD file


class UsdError(HyperGSError):
    """A USD file that cannot be written or read as a Gaussian video."""


SAVE_EVERY = 32  # frames a binary (crate) USD writer holds in memory between saves


class UsdWriter(StreamingWriter):
    """Streaming USD writer: `write(params)` frames [T, N, 8] or one [N, 8], in order; `close()` finishes
    the file (use it as a context manager). Only a complete file appears at `path` (files.AtomicOutput):
    on an exception inside `with`, or `abort()`, the file there stays as it was.

    A binary (crate) file (.usd, .usdc) is saved every SAVE_EVERY frames and its layer reloaded: a crate
    layer reads time samples from the file on demand, so the samples written leave memory, which holds
    SAVE_EVERY frames whatever the clip's length (1,200 frames of 57,600 points: a peak of 155 MB instead
    of 1.3 GB). A text file (.usda) is written whole at the end."""

    def __init__(self, path, canvas_width: int, canvas_height: int, num_gaussians: int, fps: float = 24.0,
                 grid=(1, 1), source: dict | None = None, start_frame: int = 1, prim_path: str = PRIM_PATH):
        optional.require("pxr")
        from pxr import Sdf, Usd, UsdGeom, Vt

        self.path = Path(path)
        if self.path.suffix.lower() not in USD_SUFFIXES:
            raise UsdError(f"{self.path}: a USD file must end in {', '.join(USD_SUFFIXES)}")
        self.canvas_width, self.canvas_height = int(canvas_width), int(canvas_height)
        self.num_gaussians, self.start_frame, self.prim_path = int(num_gaussians), int(start_frame), prim_path
        self.num_frames = 0
        self._crate = self.path.suffix.lower() != ".usda"
        self._output = AtomicOutput(self.path, streamed=True)
        try:
            self._stage = Usd.Stage.CreateNew(str(self._output.temp))
            if self._stage is None:
                raise UsdError(f"{self.path}: cannot write USD")
            stage = self._stage
            UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
            UsdGeom.SetStageMetersPerUnit(stage, 0.01)
            stage.SetTimeCodesPerSecond(fps)
            stage.SetFramesPerSecond(fps)
            stage.SetStartTimeCode(self.start_frame)
            root_path = str(Sdf.Path(prim_path).GetParentPath())
            if root_path not in ("", "/"):
                stage.SetDefaultPrim(UsdGeom.Xform.Define(stage, root_path).GetPrim())
            points = UsdGeom.Points.Define(stage, prim_path)
            prim = points.GetPrim()
            prim.SetCustomDataByKey(METADATA_KEY, {
                "version": USD_VERSION, "canvas_width": self.canvas_width, "canvas_height": self.canvas_height,
                "grid": Vt.IntArray([int(g) for g in grid]), "source": json.dumps(source or {}, default=str)})
            primvars = UsdGeom.PrimvarsAPI(prim)
            primvars.CreatePrimvar("scale", Sdf.ValueTypeNames.Float2Array, UsdGeom.Tokens.vertex)
            primvars.CreatePrimvar("rotation", Sdf.ValueTypeNames.FloatArray, UsdGeom.Tokens.vertex)
            points.CreateDisplayColorPrimvar(UsdGeom.Tokens.vertex)
            points.CreateIdsAttr(Vt.Int64Array.FromNumpy(np.arange(self.num_gaussians, dtype=np.int64)))
        except UsdError:
            self.abort()
            raise
        except Exception as e:  # pxr raises Tf.ErrorException
            self.abort()
            raise UsdError(f"{self.path}: cannot write USD ({e})") from None

    def _attributes(self):
        from pxr import UsdGeom
        points = UsdGeom.Points(self._stage.GetPrimAtPath(self.prim_path))
        primvars = UsdGeom.PrimvarsAPI(points.GetPrim())
        return (points.GetPointsAttr(), points.GetWidthsAttr(), points.GetExtentAttr(),
                primvars.GetPrimvar("scale").GetAttr(), primvars.GetPrimvar("rotation").GetAttr(),
                points.GetDisplayColorPrimvar().GetAttr())

    def write(self, params: np.ndarray) -> None:
        from pxr import Vt

        if self._stage is None:
            raise UsdError("writer is closed")
        params = np.asarray(params, np.float32)
        params = params[None] if params.ndim == 2 else params
        if params.ndim != 3 or params.shape[1:] != (self.num_gaussians, NUM_PARAMS):
            raise UsdError(f"expected frames of [{self.num_gaussians}, {NUM_PARAMS}] parameters, got {params.shape}")
        half = np.array([self.canvas_width / 2, -self.canvas_height / 2])
        try:
            for frame in params:
                points, widths_attr, extent, scale, rotation, color = self._attributes()
                time = float(self.start_frame + self.num_frames)
                pos = np.zeros((self.num_gaussians, 3), np.float32)
                pos[:, :2] = frame[:, :2].astype(np.float64) * half
                widths = (2 * np.sqrt(frame[:, 2].astype(np.float64) * frame[:, 3])).astype(np.float32)
                points.Set(Vt.Vec3fArray.FromNumpy(pos), time)
                widths_attr.Set(Vt.FloatArray.FromNumpy(widths), time)
                if self.num_gaussians:
                    r = widths[:, None] / 2
                    extent.Set(Vt.Vec3fArray.FromNumpy(np.stack([(pos - r).min(0), (pos + r).max(0)])), time)
                scale.Set(Vt.Vec2fArray.FromNumpy(np.ascontiguousarray(frame[:, 2:4])), time)
                rotation.Set(Vt.FloatArray.FromNumpy(np.ascontiguousarray(frame[:, 4])), time)
                color.Set(Vt.Vec3fArray.FromNumpy(np.ascontiguousarray(frame[:, 5:8])), time)
                self.num_frames += 1
                if self._crate and self.num_frames % SAVE_EVERY == 0:
                    self._save()
                    self._stage.GetRootLayer().Reload()  # the saved samples leave memory
        except UsdError:
            raise
        except Exception as e:  # pxr raises Tf.ErrorException (e.g. a full disk while saving)
            raise UsdError(f"{self.path}: cannot write USD ({e})") from None

    def _save(self) -> None:
        if not self._stage.GetRootLayer().Save():
            raise UsdError(f"{self.path}: cannot write USD")

    def close(self) -> None:
        """Write what is left and move the file into place."""
        if self._stage is None:
            return
        try:
            if self.num_frames == 0:
                raise UsdError("cannot export an empty clip (no frames)")
            self._stage.SetEndTimeCode(self.start_frame + self.num_frames - 1)
            self._save()
        except UsdError:
            self.abort()
            raise
        except Exception as e:
            self.abort()
            raise UsdError(f"{self.path}: cannot write USD ({e})") from None
        self._stage = None  # closes the layer (its file must not be open when renamed, on Windows)
        self._output.commit()

    def abort(self) -> None:
        self._stage = None
        self._output.discard()


def export_usd(video: GaussianVideo, path, start_frame: int = 1, prim_path: str = PRIM_PATH) -> None:
    """Write the clip as a UsdGeomPoints prim with one time sample per frame."""
    if video.num_frames == 0:
        raise UsdError("cannot export an empty clip (no frames)")
    with UsdWriter(path, video.canvas_width, video.canvas_height, video.num_gaussians, video.fps, video.grid,
                   video.source, start_frame, prim_path) as writer:
        writer.write(video.params)


def find_gaussian_prim(stage, prim_path: str | None = None):
    """The Points prim written by export_usd (or the one at prim_path)."""
    from pxr import UsdGeom

    if prim_path is not None:
        prim = stage.GetPrimAtPath(prim_path)
        if not prim or not prim.IsA(UsdGeom.Points):
            raise UsdError(f"no UsdGeomPoints prim at {prim_path}")
        return prim
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Points) and prim.GetCustomDataByKey(METADATA_KEY) is not None:
            return prim
    raise UsdError("no Gaussian video in this USD file (no UsdGeomPoints prim with HyperGS metadata)")


def import_usd(path, prim_path: str | None = None) -> GaussianVideo:
    """Read a Gaussian video written by export_usd back (frames in time-sample order); a crate file in a
    child process (see the module's doc)."""
    path = Path(path)
    if not path.is_file():
        raise UsdError(f"{path}: no such file")
    limits.BYTES.check(path.stat().st_size, str(path))
    optional.require("pxr")  # here, not in the child, which would only name the missing module
    if path.suffix.lower() == ".usdc" or _starts_like_a_crate(path):
        return _read_in_child(path, prim_path)
    return _read_usd(path, prim_path)


def _starts_like_a_crate(path: Path) -> bool:
    try:
        with open(path, "rb") as f:
            return f.read(len(CRATE_MAGIC)) == CRATE_MAGIC
    except OSError as e:
        raise UsdError(f"{path}: cannot read it ({e.strerror or e})") from None


# Exceptions a child's read may end in that the parent raises again as they were (by name): ours, and
# Python's own (a missing pxr is a ModuleNotFoundError, as in one process); anything else is a RuntimeError.
_CHILD_ERRORS = {cls.__name__: cls for cls in (UsdError, LimitError, HyperGSError)}


def _read_in_child(path: Path, prim_path: str | None) -> GaussianVideo:
    """_read_usd in a child process, run by this Python with this process' module path (where pxr and
    numpy are) and this package first on it, so a crash there (usd-core on a damaged file) is a UsdError
    naming the file. The child sends back plain values (pickled; it is our own code), never our classes:
    the package may have another name here (bl_ext.user_default.hypergs.hypergs_blender in Blender)."""
    package_parent = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([package_parent, *(p for p in sys.path if p)]))
    code = "from hypergs_blender.io.usd import _child_main; _child_main()"
    proc = subprocess.run([sys.executable, "-c", code, str(path), prim_path or ""], env=env, capture_output=True,
                          cwd=package_parent, creationflags=getattr(subprocess, "CREATE_NO_WINDOW", 0))
    if proc.returncode < 0:
        try:
            name = signal.Signals(-proc.returncode).name
        except ValueError:
            name = f"signal {-proc.returncode}"
        raise UsdError(f"{path}: damaged USD data (usd-core crashed reading it: {name})")
    try:
        ok, value = pickle.loads(proc.stdout)
    except Exception:
        lines = [line for line in proc.stderr.decode(errors="replace").splitlines() if line.strip()]
        raise UsdError(f"{path}: cannot read it (the reading process ended with status {proc.returncode}"
                       + (f": {lines[-1].strip()})" if lines else ")")) from None
    if ok:
        params, width, height, fps, grid, source = value
        return GaussianVideo(params, width, height, fps, grid, source)
    name, message = value
    error = _CHILD_ERRORS.get(name) or getattr(builtins, name, None)
    if not (isinstance(error, type) and issubclass(error, Exception)):
        error, message = RuntimeError, f"{name}: {message}"
    raise error(message)


def _child_main() -> None:
    """The child's side of _read_in_child: argv [path, prim path or ""] -> pickled (True, clip values) or
    (False, (exception type name, message)) on stdout."""
    path, prim_path = Path(sys.argv[1]), sys.argv[2] or None
    try:
        video = _read_usd(path, prim_path)
        result = (True, (video.params, video.canvas_width, video.canvas_height, video.fps, video.grid, video.source))
    except Exception as e:
        result = (False, (type(e).__name__, str(e)))
    sys.stdout.buffer.write(pickle.dumps(result, protocol=pickle.HIGHEST_PROTOCOL))
    sys.stdout.flush()


def _read_usd(path: Path, prim_path: str | None) -> GaussianVideo:
    """The read itself, in this process."""
    from pxr import Tf, Usd

    with _address_space_headroom(4 * limits.BYTES.value + (1 << 30)):
        try:
            stage = Usd.Stage.Open(str(path), Usd.Stage.LoadNone)
        except Tf.ErrorException as e:
            raise UsdError(f"{path}: not a readable USD file ({reason(e)})") from None
        if stage is None:
            raise UsdError(f"{path}: not a readable USD file")
        try:
            return _read_clip(stage, path, prim_path)
        except (Tf.ErrorException, TypeError, ValueError) as e:  # damaged data: USD errors, unconvertible values
            raise UsdError(f"{path}: damaged USD data ({reason(e)})") from None
        except MemoryError:
            raise UsdError(f"{path}: damaged USD data (declares arrays too large to read)") from None


@contextmanager
def _address_space_headroom(nbytes: int):
    """While inside, the process may grow by at most `nbytes` of address space (RLIMIT_AS, where
    /proc/self/statm tells the current size: Linux; elsewhere no cap)."""
    try:
        import resource
        with open("/proc/self/statm") as f:
            used = int(f.read().split()[0]) * os.sysconf("SC_PAGE_SIZE")
    except (ImportError, OSError, ValueError):
        yield
        return
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = used + nbytes
    if soft != resource.RLIM_INFINITY:
        cap = min(cap, soft)
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    try:
        yield
    finally:
        resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def _read_clip(stage, path: Path, prim_path: str | None) -> GaussianVideo:
    from pxr import Usd, UsdGeom

    try:
        prim = find_gaussian_prim(stage, prim_path)
    except UsdError as e:
        raise UsdError(f"{path}: {e}") from None
    meta = prim.GetCustomDataByKey(METADATA_KEY) or {}
    try:
        width, height = int(meta["canvas_width"]), int(meta["canvas_height"])
        grid = tuple(int(g) for g in meta.get("grid", (1, 1)))
        source = json.loads(meta.get("source", "{}"))
    except (KeyError, TypeError, ValueError, OverflowError, RecursionError) as e:
        raise UsdError(f"{path}: damaged HyperGS metadata on {prim.GetPath()} ({type(e).__name__}: {e})") from None
    if width <= 0 or height <= 0 or len(grid) != 2:
        raise UsdError(f"{path}: damaged HyperGS metadata on {prim.GetPath()}")
    points = UsdGeom.Points(prim)
    primvars = UsdGeom.PrimvarsAPI(prim)
    attrs = {"points": points.GetPointsAttr(), "scale": primvars.GetPrimvar("scale").GetAttr(),
             "rotation": primvars.GetPrimvar("rotation").GetAttr(),
             "color": points.GetDisplayColorPrimvar().GetAttr()}
    missing = [name for name, attr in attrs.items() if not attr]
    if missing:
        raise UsdError(f"{path}: {prim.GetPath()} lacks {', '.join(missing)}")
    times = attrs["points"].GetTimeSamples() or [Usd.TimeCode.Default()]
    limits.FRAMES.check(len(times), str(path))
    frames = []
    half = np.array([width / 2, -height / 2])
    for time in times:
        values = {name: attr.Get(time) for name, attr in attrs.items()}
        if any(v is None for v in values.values()):
            raise UsdError(f"{path}: frame at time {time} lacks some of {', '.join(attrs)}")
        try:
            pos = np.asarray(values["points"], np.float64).reshape(-1, 3)
            n = len(pos)
            if not frames:
                limits.check_clip_size(len(times), n, str(path))
            frame = np.empty((n, NUM_PARAMS), np.float32)
            with np.errstate(over="ignore", invalid="ignore"):  # GaussianVideo.checked reports them
                frame[:, 0:2] = pos[:, :2] / half
            frame[:, 2:4] = np.asarray(values["scale"], np.float32).reshape(n, 2)
            frame[:, 4] = np.asarray(values["rotation"], np.float32).reshape(n)
            frame[:, 5:8] = np.asarray(values["color"], np.float32).reshape(n, 3)
        except (TypeError, ValueError):
            raise UsdError(f"{path}: frame at time {time}: points and primvars are not {NUM_PARAMS} numbers "
                           "per point") from None
        if frames and n != frames[0].shape[0]:
            raise UsdError(f"{path}: the number of points changes over time ({frames[0].shape[0]} then {n})")
        frames.append(frame)
    fps = stage.GetTimeCodesPerSecond() or 24.0
    return GaussianVideo.checked(path, np.stack(frames), width, height, fps, grid, source)
