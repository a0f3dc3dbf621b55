"""A clip's mesh data, shared by the operators (ops/) and the render engine (engine/): writing and
reading its points' attributes (see hypergs_blender/points.py for what they mean), the frame a cache
clip's mesh holds (SHOWN, com/frames.py), the outline mesh of a linked clip, and the path of a clip's
linked file. Clips embedded whole (made before frame caches) also have a `frame` attribute
(`read_clip_points`). Where Blender loses the active attribute on entering Edit Mode (compat.py), a handler
makes a clip's `color` active again.
"""
from __future__ import annotations

import threading

import bpy
import numpy as np
from bpy.app.handlers import persistent

from ..hypergs_blender.errors import HyperGSError
from . import add_handlers, remove_handlers
from .compat import EDIT_MODE_KEEPS_ACTIVE_ATTRIBUTE


def is_clip(obj) -> bool:
    """Whether `obj` (an object, evaluated or not, or None) is a HyperGS clip."""
    return obj is not None and obj.type == "MESH" and obj.hypergs.is_clip


# attribute -> (components wanted, {data_type: (foreach key, components stored)})
_ATTRIBUTES = {
    "scale": (2, {"FLOAT2": ("vector", 2), "FLOAT_VECTOR": ("vector", 3)}),
    "rotation": (1, {"FLOAT": ("value", 1)}),
    "color": (3, {"FLOAT_COLOR": ("color", 4), "BYTE_COLOR": ("color", 4), "FLOAT_VECTOR": ("vector", 3)}),
}


def _read(attribute, n: int, key: str, stored: int) -> np.ndarray:
    out = np.empty(n * stored, np.float32)
    attribute.data.foreach_get(key, out)
    return out.reshape(n, stored)


def read_points(mesh) -> dict | None:
    """position [M, 3], scale [M, 2], rotation [M], color [M, 3] float32 of a mesh's points, or None
    when an attribute is missing or of a kind we cannot read (e.g. a modifier removed it)."""
    n = len(mesh.vertices)
    out = {"position": _read(mesh.attributes["position"], n, "vector", 3)} if n else {
        "position": np.zeros((0, 3), np.float32)}
    for name, (wanted, kinds) in _ATTRIBUTES.items():
        attribute = mesh.attributes.get(name)
        if attribute is None or attribute.domain != "POINT" or attribute.data_type not in kinds:
            return None
        key, stored = kinds[attribute.data_type]
        values = _read(attribute, n, key, stored)[:, :wanted] if n else np.zeros((0, wanted), np.float32)
        out[name] = values[:, 0] if wanted == 1 else values
    return out


# The point attributes written (position aside): name -> (data type, foreach key)
POINT_ATTRIBUTES = {"scale": ("FLOAT2", "vector"), "rotation": ("FLOAT", "value"), "color": ("FLOAT_COLOR", "color")}
SHOWN = "hypergs_frame"  # ID property of a clip's mesh: the clip frame it holds (NOTHING: none)
NOTHING = -1


def make_color_active(mesh) -> None:
    """Make `color` the attribute that Mesh > Set Attribute and the colour display act on (where the mesh has it)."""
    try:
        mesh.attributes.active_color = mesh.attributes["color"]
        mesh.attributes.active = mesh.attributes["color"]
    except (AttributeError, TypeError, KeyError):
        pass


def write_frame(mesh, points: dict, frame: int) -> None:
    """Make the (Object Mode) mesh hold one frame's points: position, scale, rotation, color [M, 4]
    (float32), and SHOWN = frame. Its vertices are made again only when their count changes (or an
    attribute is missing or of another type): then edges, faces and attributes of the user's go too.
    About 0.4 ms for 57,600 points (foreach_set of float32 and the depsgraph update)."""
    n = len(points["position"])
    if len(mesh.vertices) != n or mesh.edges or mesh.polygons or any(
            (a := mesh.attributes.get(name)) is None or a.data_type != kind or a.domain != "POINT"
            for name, (kind, _) in POINT_ATTRIBUTES.items()):
        mesh.clear_geometry()  # also removes the custom attributes
        mesh.vertices.add(n)
        for name, (kind, _) in POINT_ATTRIBUTES.items():
            mesh.attributes.new(name, kind, "POINT")
        make_color_active(mesh)
    if n:
        for name, key in (("position", "vector"), *((n, k) for n, (_, k) in POINT_ATTRIBUTES.items())):
            mesh.attributes[name].data.foreach_set(key, np.ascontiguousarray(points[name], np.float32).ravel())
    mesh[SHOWN] = int(frame)
    mesh.update()


def clip_problem(video) -> str | None:
    """Why a clip read from a file (a GaussianVideo, or an HgsReader) cannot become a clip object, or
    None: its canvas must be at least one pixel, and it must have a frame of at least one Gaussian."""
    if video.canvas_width < 1 or video.canvas_height < 1:
        return f"its canvas of {video.canvas_width} x {video.canvas_height} pixels is empty"
    if video.num_frames < 1 or video.num_gaussians < 1:
        return f"an empty clip ({video.num_frames} frames of {video.num_gaussians} Gaussians)"
    return None


def outline(canvas_width: int, canvas_height: int) -> np.ndarray:
    aspect = canvas_width / max(1, canvas_height)
    return np.array([[-aspect, -1, 0], [aspect, -1, 0], [aspect, 1, 0], [-aspect, 1, 0]], np.float32)


def new_linked_mesh(name: str, canvas_width: int, canvas_height: int):
    """A linked clip's mesh: the image plane's outline (4 vertices, 4 edges), no Gaussians."""
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(outline(canvas_width, canvas_height).tolist(), [(0, 1), (1, 2), (2, 3), (3, 0)], [])
    mesh.update()
    return mesh


def read_clip_points(mesh) -> dict:
    """Every frame's points of an embedded clip's (original, Object Mode) mesh: position, scale,
    rotation, color (RGB), frame. Raises HyperGSError when an attribute is missing or unreadable."""
    points = read_points(mesh)
    frame = mesh.attributes.get("frame")
    if points is None or frame is None or frame.domain != "POINT" or frame.data_type not in ("INT", "FLOAT"):
        raise HyperGSError(f"'{mesh.name}' lacks the clip's point attributes (scale, rotation, color, frame)")
    values = np.empty(len(mesh.vertices), np.int32 if frame.data_type == "INT" else np.float32)
    frame.data.foreach_get("value", values)
    points["frame"] = np.floor(values + 0.5).astype(np.int64) if values.dtype != np.int32 else values
    return points


def linked_file(obj) -> str:
    """Absolute path of a linked clip's file ('' when none is set)."""
    path = obj.hypergs.linked_path
    return bpy.path.abspath(path, library=obj.library) if path else ""


_in_edit_mode: set[int] = set()  # session_uid of the clips last seen in Edit Mode


@persistent
def _after_depsgraph_update(scene, depsgraph):
    """A clip that has just entered Edit Mode (Tab included) gets `color` active again; once per entry, so an
    attribute the user picks in Edit Mode stays active."""
    if threading.current_thread() is not threading.main_thread():
        return
    for update in depsgraph.updates:
        obj = update.id.original
        if not isinstance(obj, bpy.types.Object) or not is_clip(obj):
            continue
        if obj.mode != "EDIT":
            _in_edit_mode.discard(obj.session_uid)
        elif obj.session_uid not in _in_edit_mode:
            _in_edit_mode.add(obj.session_uid)
            make_color_active(obj.data)


HANDLERS = () if EDIT_MODE_KEEPS_ACTIVE_ATTRIBUTE else (("depsgraph_update_post", _after_depsgraph_update),)


def register():
    add_handlers(HANDLERS)


def unregister():
    remove_handlers(HANDLERS)
