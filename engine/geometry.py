"""Reading clips for a render: from depsgraph-evaluated geometry (embedded clips) or their .hgs file
(linked clips), and rendering them on the CPU (no GPU needed)."""
from __future__ import annotations

import numpy as np

from ..com import linked
from ..com.mesh import is_clip, linked_file, read_points
from ..hypergs_blender.colour import srgb_image_to_linear_rgba
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.points import clip_frame_index, points_to_params
from ..hypergs_blender.render import render_params


def evaluated_clips(depsgraph, visible=None, problems: list | None = None):
    """(name, params [M, 8], canvas width, canvas height) for every HyperGS clip in the depsgraph.
    visible: optional predicate on the evaluated object (the viewport's visibility).
    A linked clip whose file is missing or damaged is left out; `problems` gets a message for it."""
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
        points = read_points(ob.data)
        if points is None or s.canvas_width <= 0 or s.canvas_height <= 0:
            continue
        params = points_to_params(points["position"], points["scale"], points["rotation"], points["color"],
                                  s.canvas_width, s.canvas_height)
        yield ob.name, params, s.canvas_width, s.canvas_height


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

