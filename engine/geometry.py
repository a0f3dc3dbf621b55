"""Reading clips from depsgraph-evaluated geometry (embedded clips) or their .hgs file (linked clips)
and rendering them (no GPU needed)."""
from __future__ import annotations

import numpy as np

from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.points import (clip_frame_index, points_to_params, render_params_srgb,
                                      srgb_image_to_linear_rgba)

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


def evaluated_clips(depsgraph, visible=None, problems: list | None = None):
    """(name, params [M, 8], canvas width, canvas height) for every HyperGS clip in the depsgraph.
    visible: optional predicate on the evaluated object (the viewport's visibility).
    A linked clip whose file is missing or damaged is left out; `problems` gets a message for it."""
    scene = depsgraph.scene
    scene_frame = scene.frame_current + scene.frame_subframe
    for ob in depsgraph.objects:
        if ob.type != "MESH" or not ob.hypergs.is_clip or (visible is not None and not visible(ob)):
            continue
        s = ob.hypergs
        if s.linked:
            clip = _linked_clip(ob, scene_frame, problems)
            if clip is not None:
                yield clip
            continue
        points = read_points(ob.data)
        if points is None or s.canvas_width <= 0 or s.canvas_height <= 0:
            continue
        params = points_to_params(points["position"], points["scale"], points["rotation"], points["color"],
                                  s.canvas_width, s.canvas_height)
        yield ob.name, params, s.canvas_width, s.canvas_height


def _linked_clip(ob, scene_frame: float, problems: list | None):
    """The frame of a linked clip for the scene frame, read from its file; None when the clip shows
    nothing then (outside its frames) or its file cannot be read (told to `problems`)."""
    from ..ops import linked
    from ..ops.scene import linked_file
    s = ob.hypergs
    frame = clip_frame_index(scene_frame, s.frame_start, s.speed)
    try:
        path = linked_file(ob.original)
        reader = linked.reader(path)
        if not 0 <= frame < reader.num_frames:
            return None
        params, width, height = linked.read_frame(path, frame)
    except HyperGSError as e:
        if problems is not None:
            problems.append(f"'{ob.name}': {e}")
        return None
    return ob.name, params, width, height


def render_clips(clips, width: int, height: int, keep_going=lambda done, total: True) -> np.ndarray | None:
    """Sum of the clips' renders at width x height as a scene-linear RGBA pass (rows bottom-up),
    or None when keep_going(done, total) says stop."""
    clips = list(clips)
    image = np.zeros((height, width, 3), np.float32)
    for i, (_, params, cw, ch) in enumerate(clips):
        if not keep_going(i, len(clips)):
            return None
        image += render_params_srgb(params, cw, ch, width, height)
    keep_going(len(clips), len(clips))
    return srgb_image_to_linear_rgba(image)
