"""One frame in memory: a clip object's mesh holds the points of the clip frame the scene shows, loaded
from the clip's frame cache (cache.py) when the frame changes, so users edit that frame as geometry
(Edit Mode, Geometry Nodes, scripts) and the render engine renders what the depsgraph evaluated.

When the mesh is written: `frame_change_pre` (playback, scrubbing, `frame_set`, every frame of an
animation or command-line render: Blender calls it before the depsgraph evaluates the new frame, and
documents it as the place to change data for that frame), and after undo / redo, a file load, or a
change of the clip's timing (`sync`). A frame costs a cache read (a few ms, or nothing when the LRU has
it), the points (3 ms for 57,600) and foreach_set (0.4 ms): not the clip's length.

Why this is safe where com/linked.py once refused it:
- Undo: writing mesh data from a handler pushes no undo step. An undo step stores the mesh with the
  frame it held then and the SHOWN property saying which (they are restored together, so they always
  agree); after undo / redo (`_after_undo`) the mesh is brought to the scene's frame again. Edits made
  before the step are in the mesh it restores, and are kept as an override again if they were lost.
- Edits are never lost: before the mesh leaves a frame, its points are compared with what that frame
  holds (the override, or the cache); when they differ they become the frame's override, a mesh
  datablock in the .blend (`settings.overrides`), so undo, save and reopen keep them like any mesh. They
  are also kept as soon as the depsgraph reports the mesh changed (`_after_depsgraph_update`), so the
  mesh holds no unkept edit when a render starts. In Edit Mode the mesh holds its frame (an edit mesh
  cannot be swapped under the user): the engine then reads other frames itself (engine/geometry.py).
- The render thread: during F12 / Ctrl-F12 Blender calls frame_change_pre on the render thread; the
  mesh is then only written (never an override made), and the scenes get Render > Lock Interface
  (ops/scene.prepare_scene), which Blender's handler documentation asks for when a handler changes data
  the viewport draws. A frame whose mesh cannot be brought to the render's frame is read from the
  cache by the engine instead (never a stale frame).
- A file saved mid-clip reopens with the mesh and SHOWN of that frame, and the render of any other
  frame on a farm (`blender -b file.blend -a`, the extension enabled) goes through frame_change_pre.
"""
from __future__ import annotations

import threading

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io.clips import ClipFrames
from ..hypergs_blender.points import (FRAME_COUNTS, clip_frame_index, padding, params_to_points, points_to_params,
                                      source_frame_counts)
from . import add_handlers, cache, remove_handlers
from .mesh import NOTHING, SHOWN, read_points, write_frame

_loaded: dict = {}  # mesh session uid -> (frame, points): what the mesh was given, to tell edits cheaply


def is_cached_clip(obj) -> bool:
    """A clip whose frames are in a frame cache (not one embedded whole in its mesh)."""
    s = getattr(obj, "hypergs", None)
    return obj.type == "MESH" and s is not None and s.is_clip and s.cache is not None


def wanted_frame(obj, scene_frame: float) -> int:
    """The clip frame shown at a scene frame, or NOTHING outside the clip."""
    s = obj.hypergs
    frame = clip_frame_index(scene_frame, s.frame_start, s.speed)
    return frame if 0 <= frame < s.num_frames else NOTHING


def cache_problem(obj) -> str | None:
    """What is wrong with a cache clip's frame cache now (missing, damaged, a packed one that cannot be
    written out), or None."""
    try:
        return cache.FRAMES.problem(cache.clip_file(obj))
    except HyperGSError as e:
        return str(e)


def override(obj, frame: int):
    """The mesh holding frame `frame`'s edits, or None."""
    for item in obj.hypergs.overrides:
        if item.frame == frame and item.mesh is not None:
            return item.mesh
    return None


def _cache_params(obj, frame: int) -> np.ndarray:
    """float32 [M, 8] parameters of a frame in the clip's cache, without the padding of a clip whose
    frames hold fewer Gaussians than N (points.points_to_video: a clip embedded whole, copied in)."""
    path = cache.clip_file(obj)
    params = cache.FRAMES.read_frame(path, frame)
    source = cache.FRAMES.reader(path).source
    if FRAME_COUNTS in source:
        params = params[:source_frame_counts(source, obj.hypergs.num_frames, len(params))[frame]]
    return params


def frame_points(obj, frame: int) -> dict:
    """What frame `frame` of a clip holds: its override's points or the cache's, as position, scale,
    rotation, color [M, 4] float32 (empty outside the clip). Raises HyperGSError (a missing or
    damaged cache, an override without the clip's attributes)."""
    if frame == NOTHING:
        return params_to_points(np.zeros((0, 8), np.float32), 1, 1)
    mesh = override(obj, frame)
    if mesh is not None:
        points = _override_points(obj, mesh, frame)
        color = np.ones((len(points["color"]), 4), np.float32)
        color[:, :3] = points["color"]
        return dict(points, color=color)
    s = obj.hypergs
    return params_to_points(_cache_params(obj, frame), s.canvas_width, s.canvas_height)


def _override_points(obj, mesh, frame: int) -> dict:
    points = read_points(mesh)
    if points is None:
        raise HyperGSError(f"'{mesh.name}' (frame {frame + 1} of '{obj.name}') lacks the clip's point attributes")
    return points


def _valid_params(points: dict, s) -> np.ndarray:
    """Canvas parameters of points (a mesh's), without those that cannot be a Gaussian (a zero scale,
    values that are not finite), as points.points_to_video leaves them out."""
    params = points_to_params(points["position"], np.abs(points["scale"]), points["rotation"], points["color"],
                              s.canvas_width, s.canvas_height)
    return params[np.all(np.isfinite(params), axis=1) & np.all(params[:, 2:4] > 0, axis=1)]


def clip_frames(obj, shown: dict | None = None) -> tuple[ClipFrames, int]:
    """(every frame of a cache clip as edited in Blender, read a frame at a time; the points left out
    because they cannot be a Gaussian). shown: the points the mesh holds now for the frame it shows
    (Edit Mode: the edit mesh's), taken for that frame. Frames are padded to the largest count
    (points.points_to_video), which `source["frame_counts"]` records. Raises HyperGSError."""
    s = obj.hypergs
    edited, dropped = {}, 0  # frame -> params of the frames whose points are the user's
    for item in s.overrides:
        if item.mesh is not None and 0 <= item.frame < s.num_frames:
            edited[item.frame] = _override_points(obj, item.mesh, item.frame)
    frame = obj.data.get(SHOWN, NOTHING)
    if shown is not None and 0 <= frame < s.num_frames:
        edited[frame] = shown
    for frame, points in edited.items():
        edited[frame] = _valid_params(points, s)
        dropped += len(points["position"]) - len(edited[frame])
    path = cache.clip_file(obj)
    reader = cache.FRAMES.reader(path)
    counts = source_frame_counts(reader.source, s.num_frames, reader.num_gaussians)
    for frame, params in edited.items():
        counts[frame] = len(params)
    n = max(1, int(counts.max()))
    pad = padding(cache.FRAMES.read_frame(path, 0))

    def frames():
        for frame in range(s.num_frames):
            params = edited[frame] if frame in edited else _cache_params(obj, frame)
            out = np.broadcast_to(pad, (n, 8)).copy()
            out[:len(params)] = params
            yield out

    source = dict(path=s.source, frames=list(range(s.source_start, s.source_start + s.num_frames)),
                  encoder=s.encoder, encode_seconds=s.encode_seconds, psnr=s.psnr)
    if np.any(counts != n):
        source[FRAME_COUNTS] = counts.tolist()
    return ClipFrames(frames, s.num_frames, n, s.canvas_width, s.canvas_height, s.fps, tuple(s.grid), source), dropped


def _same(mesh, points: dict) -> bool:
    now = read_points(mesh)
    return now is not None and len(now["position"]) == len(points["position"]) and all(
        np.array_equal(now[name], points[name][:, :3] if name == "color" else points[name])
        for name in ("position", "scale", "rotation", "color"))


def holds_edits(obj) -> bool:
    """Whether the clip's mesh differs from what the frame it shows holds (its override or the cache)."""
    mesh = obj.data
    frame = mesh.get(SHOWN, NOTHING)
    if frame == NOTHING:
        return False
    loaded = _loaded.get(mesh.session_uid)
    return not _same(mesh, loaded[1] if loaded is not None and loaded[0] == frame else frame_points(obj, frame))


def keep_edits(obj) -> bool:
    """If the clip's mesh holds edits, make its points the override of the frame it shows (a copy of
    the mesh). Main thread, Object Mode. Returns whether it made one."""
    mesh = obj.data
    frame = mesh.get(SHOWN, NOTHING)
    if obj.mode == "EDIT" or not holds_edits(obj):
        return False
    copy = mesh.copy()
    copy.name = f"{obj.name} frame {frame + 1}"
    old = override(obj, frame)
    items = obj.hypergs.overrides
    item = next((i for i in items if i.frame == frame), None) or items.add()
    item.frame, item.mesh = frame, copy
    if old is not None and old.users == 0:
        bpy.data.meshes.remove(old)
    _loaded[mesh.session_uid] = (frame, frame_points(obj, frame))
    return True


def forget_frame(obj) -> None:
    """The clip's frames changed (a new cache): its mesh holds no known frame, and sync loads one."""
    obj.data.pop(SHOWN, None)
    _loaded.pop(obj.data.session_uid, None)


def sync(obj, scene_frame: float, on_main_thread: bool = True) -> bool:
    """Bring a clip's mesh to the frame shown at `scene_frame`, keeping edits first (on the main
    thread). A mesh in Edit Mode keeps its frame. Returns whether the mesh holds the wanted frame."""
    mesh = obj.data
    frame = wanted_frame(obj, scene_frame)
    if mesh.get(SHOWN) == frame:
        return True
    if obj.mode == "EDIT":
        return False
    if on_main_thread:
        keep_edits(obj)
    elif holds_edits(obj):  # the render thread makes no datablock: never lose an edit not kept yet
        return False  # (edits are kept as they are made, so this does not happen from the UI)
    points = frame_points(obj, frame)
    write_frame(mesh, points, frame)
    _loaded[mesh.session_uid] = (frame, points)
    return True


def sync_scene(scene, on_main_thread: bool = True) -> None:
    """sync every cached clip of a scene to its frame; a clip whose cache cannot be read keeps its
    mesh (the panel and the engine report the problem)."""
    scene_frame = scene.frame_current + scene.frame_subframe
    for obj in scene.objects:
        if obj.library is None and is_cached_clip(obj):
            try:
                sync(obj, scene_frame, on_main_thread)
            except HyperGSError:
                pass


@persistent
def _frame_change_pre(scene, *args):
    sync_scene(scene, threading.current_thread() is threading.main_thread())


@persistent
def _after_undo(scene, *args):
    _loaded.clear()  # the meshes (and overrides) are those of the restored step
    for each in bpy.data.scenes:
        sync_scene(each)


@persistent
def _after_load(*args):
    _loaded.clear()
    for each in bpy.data.scenes:
        sync_scene(each)


@persistent
def _after_depsgraph_update(scene, depsgraph):
    """Keep edits as soon as they are made (leaving Edit Mode, a script, an operator), and bring back
    to the scene's frame a mesh that left Edit Mode on another one."""
    if threading.current_thread() is not threading.main_thread():
        return
    meshes = {update.id.original for update in depsgraph.updates
              if isinstance(update.id, bpy.types.Mesh) and update.is_updated_geometry}
    if not meshes:
        return
    scene_frame = scene.frame_current + scene.frame_subframe
    for obj in scene.objects:
        if obj.library is None and obj.data in meshes and is_cached_clip(obj) and obj.mode != "EDIT":
            try:
                keep_edits(obj)
                sync(obj, scene_frame)
            except HyperGSError:
                pass


HANDLERS = (("frame_change_pre", _frame_change_pre), ("undo_post", _after_undo), ("redo_post", _after_undo),
            ("load_post", _after_load), ("depsgraph_update_post", _after_depsgraph_update))


def register():
    add_handlers(HANDLERS)


def unregister():
    remove_handlers(HANDLERS)
