"""Reading clips for a render: from depsgraph-evaluated geometry (the frame com/frames.py put into a
clip's mesh, or a clip embedded whole in its mesh), from the frame cache when the mesh holds another
frame, or from a linked clip's .hgs file; and rendering them on the CPU (no GPU needed)."""
from __future__ import annotations

import numpy as np

from ..com import frames, linked
from ..com.mesh import NOTHING, SHOWN, is_clip, linked_file, read_points
from ..hypergs_blender.colour import srgb_image_to_linear_rgba
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.points import clip_frame_index, points_to_params
from ..hypergs_blender.render import render_params


def evaluated_clips(depsgraph, visible=None, problems: list | None = None):
    """(name, params [M, 8], canvas width, canvas height) for every HyperGS clip in the depsgraph.
    visible: optional predicate on the evaluated object (the viewport's visibility).
    A clip whose frame cache or linked file is missing or damaged is left out; `problems` gets a
    message for it."""
    scene = depsgraph.scene
    scene_frame = scene.frame_current + scene.frame_subframe
    for ob in depsgraph.objects:
        if not is_clip(ob) or (visible is not None and not visible(ob)):
            continue
        s = ob.hypergs
        if s.linked:
            clip = _linked_clip(ob, scene_frame, problems)
            if clip is not None:
                yield clip
            continue
        if s.canvas_width <= 0 or s.canvas_height <= 0:
            continue
        if frames.is_cached_clip(ob.original):
            frame = frames.wanted_frame(ob.original, scene_frame)
            if frame == NOTHING:
                continue
            problem = frames.cache_problem(ob.original)  # also when the mesh holds the frame: a farm
            if problem is not None:  # render stops at its first frame, not its second
                if problems is not None:
                    problems.append(f"'{ob.name}': {problem}")
                continue
            if ob.original.data.get(SHOWN) != frame:  # Edit Mode on another frame, a missing cache, a
                try:  # mesh not brought here: read the frame itself (without the object's modifiers)
                    points = frames.frame_points(ob.original, frame)
                except HyperGSError as e:
                    if problems is not None:
                        problems.append(f"'{ob.name}': {e}")
                    continue
                yield ob.name, _params(points, s), s.canvas_width, s.canvas_height
                continue
        points = read_points(ob.data)
        if points is not None:
            yield ob.name, _params(points, s), s.canvas_width, s.canvas_height


def _params(points: dict, settings):
    return points_to_params(points["position"], points["scale"], points["rotation"], points["color"],
                            settings.canvas_width, settings.canvas_height)


def _linked_clip(ob, scene_frame: float, problems: list | None):
    """The frame of a linked clip for the scene frame, read from its file; None when the clip shows
    nothing then (outside its frames) or its file cannot be read (told to `problems`)."""
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
        image += render_params(params, cw, ch, width, height)
    keep_going(len(clips), len(clips))
    return srgb_image_to_linear_rgba(image)

