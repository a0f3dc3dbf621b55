"""The Blender test sessions' one harness. bpy imports once per process, so each test_blender_*.py file
runs its Blender session in a subprocess: the file run as a script (`python test_x.py ZIP WORK OUT.json`)
starts Blender (`start_session`), records each step's result to JSON as it finishes, and ends with
`session_main`; its pytest side (`run_blender_session`, `step`) builds the zip, runs that script and
checks the steps. Blender's side is tools/blender_headless.py (shared with the main job and the splat
bench); what the sessions check with is here: mesh attributes, the operators' dialogs drawn into a
recorder, whether a failed operator left the file as it was.
"""
import importlib
import json
import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from blender_headless import addon_module, exit_session, start_blender, step_recorder  # noqa: F401 (re-exported)

ROOT = Path(__file__).resolve().parents[1]


# ----------------------------------------------------------------------------------------------------
# pytest side

def run_blender_session(script, work: Path, encoder: str, timeout: float, env: dict | None = None) -> dict:
    """Build the extension zip, then run `script ZIP WORK OUT.json` in a fresh Python (bpy can be
    imported once per process) with $HYPERGS_ENCODER defaulting to `encoder` and the variables `env`
    added. Returns the steps' results, with the session's console output under "console" (Blender prints
    render reports there)."""
    from build_extension import build_zip
    zip_path = build_zip(work / "dist")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(ROOT), str(ROOT / "tools")]),
           "HYPERGS_ENCODER": os.environ.get("HYPERGS_ENCODER", encoder), **(env or {})}  # `env` wins
    out = work / "session.json"
    python = os.environ.get("HYPERGS_BLENDER_PYTHON", sys.executable)  # e.g. a venv with bpy 4.2
    proc = subprocess.run([python, str(script), str(zip_path), str(work), str(out)], env=env,
                          capture_output=True, text=True, timeout=timeout)
    if not out.is_file():
        pytest.fail(f"the Blender session died (rc {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return dict(json.loads(out.read_text()), console=proc.stdout + proc.stderr)


def step(session, name):
    """One recorded step of a Blender session; fails with its traceback if it raised."""
    result = session.get(name)
    assert result is not None, f"step {name} did not run"
    assert "error" not in result, result["error"]
    return result


# ----------------------------------------------------------------------------------------------------
# Blender side

def start_session(work: Path, out_path):
    """(bpy, record, results) for a session script: Blender started with its user files in WORK/user
    (torch and numba unimportable, as in Blender's own Python); `@record(name)` runs a step and writes
    `results` to out_path."""
    results = {}
    record = step_recorder(results, out_path)
    return start_blender(Path(work) / "user"), record, results


def session_main(run_session) -> None:
    """A session script's __main__: run_session(zip, work, out_path) with the command line's values,
    then end the process without bpy's teardown."""
    zip_arg, work_arg, out_arg = sys.argv[1:4]
    run_session(zip_arg, Path(work_arg), out_arg)
    exit_session()


def mesh_frames(bpy, obj, frames) -> list:
    """Canvas parameters [M, 8] of a cache clip's frames (clip frame indices) as its mesh holds them after
    its scene goes to each (the frame-change handler loads them); the scene is left at the last one."""
    from hypergs_blender.points import points_to_params
    s = obj.hypergs
    scene = obj.users_scene[0] if obj.users_scene else bpy.context.scene
    out = []
    for frame in frames:
        scene.frame_set(s.frame_start + int(frame))
        mesh = obj.data
        n = len(mesh.vertices)
        values = {}
        for name, key, size in (("position", "vector", 3), ("scale", "vector", 2), ("rotation", "value", 1),
                                ("color", "color", 4)):
            values[name] = np.empty(n * size, np.float32)
            mesh.attributes[name].data.foreach_get(key, values[name])
        out.append(points_to_params(values["position"].reshape(n, 3), values["scale"].reshape(n, 2),
                                    values["rotation"], values["color"].reshape(n, 4),
                                    s.canvas_width, s.canvas_height))
    return out


def cache_error(a, b) -> float:
    """How far Gaussian parameters read back from a frame cache (`a`, [..., 8]) are from the float32 ones
    written (`b`), as a fraction of what the cache's float16 codec allows: the means kept to float32
    rounding (1e-6), the rest to float16 (a relative 2^-11, taken as 2^-10; the rotation modulo pi, as
    stored). At most 1 when the cache keeps what it claims."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.shape != b.shape:
        return float("inf")
    means = np.abs(a[..., :2] - b[..., :2]).max(initial=0) / 1e-6
    others = [2, 3, 5, 6, 7]
    rest = np.abs(a[..., others] - b[..., others]) / np.maximum(np.abs(b[..., others]), 2 ** -14)
    turn = np.mod(a[..., 4] - b[..., 4], np.pi)
    rotation = np.minimum(turn, np.pi - turn) / np.pi
    return float(max(means, rest.max(initial=0) / 2 ** -10, rotation.max(initial=0) / 2 ** -10))


def display_points(bpy, obj):
    """Points of the evaluated point cloud that shows the clip in Solid mode (None: no API to look)."""
    ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    if not hasattr(bpy.types, "GeometrySet"):
        return None
    geometry = bpy.types.GeometrySet.from_evaluated_object(ev)  # keep it alive while reading
    cloud = geometry.pointcloud
    return len(cloud.points) if cloud is not None else 0


def files_under(folder) -> list[str]:
    """Every file and folder under `folder` (relative paths, sorted; [] when it does not exist)."""
    folder = Path(folder)
    return sorted(str(p.relative_to(folder)) for p in folder.rglob("*")) if folder.is_dir() else []


def attempt_unchanged(bpy, expect, call) -> dict:
    """Run an operator call expected to fail: did it raise, with what message, and is the scene
    (snapshot) exactly as before?"""
    before = snapshot(bpy)
    message, raised = "", False
    try:
        call()
    except RuntimeError as e:
        message, raised = str(e), True
    after = snapshot(bpy)
    return dict(raised=raised, message=message, expect=expect, unchanged=before == after, diff=diff(before, after))


def snapshot(bpy):
    """What an operator must not change when it fails or is cancelled: every datablock collection of
    bpy.data (names), the scene's settings the add-on touches, its strips, the selection."""
    data = {}
    for kind in dir(bpy.data):
        collection = getattr(bpy.data, kind, None)
        if isinstance(collection, bpy.types.bpy_prop_collection) and kind not in ("window_managers", "screens"):
            data[kind] = sorted(x.name_full for x in collection if isinstance(x, bpy.types.ID))
    sc = bpy.context.scene
    editor = sc.sequence_editor
    strips = []
    if editor is not None:
        compat = importlib.import_module("bl_ext.user_default.hypergs.com.compat")
        strips = sorted((s.name, s.type, s.mute, s.select, s.channel, compat.strip_range(s))
                        for s in compat.all_strips(editor))
    vs = sc.view_settings
    data["scene"] = dict(engine=sc.render.engine, view=vs.view_transform, look=vs.look, exposure=vs.exposure,
                         gamma=vs.gamma, camera=sc.camera.name if sc.camera else None,
                         frames=[sc.frame_start, sc.frame_end, sc.frame_current], strips=strips,
                         preview=sc.render.sequencer_gl_preview, use_sequencer=sc.render.use_sequencer,
                         lock=sc.render.use_lock_interface, fps=[sc.render.fps, sc.render.fps_base],
                         active=bpy.context.view_layer.objects.active.name
                         if bpy.context.view_layer.objects.active else None,
                         selected=sorted(o.name for o in bpy.context.view_layer.objects if o.select_get()))
    return data


def diff(a, b):
    return {k: (a.get(k), b.get(k)) for k in set(a) | set(b) if a.get(k) != b.get(k)}


class Recorder:
    """A stand-in for bpy's UILayout that records label / prop / operator calls."""

    def __init__(self, calls=None, attributes=None):
        self.__dict__["calls"] = [] if calls is None else calls
        self.__dict__["attributes"] = {} if attributes is None else attributes

    def __setattr__(self, name, value):  # alert, use_property_split, operator_context, ...
        self.attributes[name] = value

    def __getattr__(self, name):
        def call(*args, **kwargs):
            if name in ("label", "operator"):
                self.calls.append((name, kwargs.get("text") or (args[0] if args else ""), kwargs.get("icon")))
            elif name == "prop":
                self.calls.append((name, args[1], None))
            return Recorder(self.calls, self.attributes)
        return call


def types_namespace(**kwargs):
    return SimpleNamespace(**kwargs)


def operator_defaults(bpy, operator_class) -> dict:
    """{property: default} of an operator class (what its dialog starts from)."""
    module, name = operator_class.bl_idname.split(".")
    properties = getattr(getattr(bpy.ops, module), name).get_rna_type().properties
    return {p.identifier: p.default for p in properties
            if p.identifier != "rna_type" and hasattr(p, "default") and not getattr(p, "is_array", False)}
