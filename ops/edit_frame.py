"""hypergs.edit_frame: Edit Mode on the points of the frame the scene shows. A cache clip's mesh holds
just that frame (com/frames.py keeps the edits as the frame's override); a clip embedded whole in its
mesh (an earlier version's) gets the other frames' points hidden."""
import bpy

from ..com import frames
from ..com.mesh import make_color_active
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.points import clip_frame_index
from .context import active_clip, report_error


def clip_frame(obj, scene_frame: int) -> int:
    s = obj.hypergs
    return clip_frame_index(scene_frame, s.frame_start, s.speed)


class HYPERGS_OT_edit_frame(bpy.types.Operator):
    """Edit the points of the frame shown now (Edit Mode)"""

    bl_idname = "hypergs.edit_frame"
    bl_label = "Edit Current Frame"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = active_clip(context)
        return obj is not None and not obj.hypergs.linked and context.mode in {"OBJECT", "EDIT_MESH"}

    def execute(self, context):
        obj = active_clip(context)
        if obj.mode == "EDIT":
            bpy.ops.object.mode_set(mode="OBJECT")
        scene = context.scene
        if frames.is_cached_clip(obj):
            if frames.wanted_frame(obj, scene.frame_current + scene.frame_subframe) == frames.NOTHING:
                return report_error(self, HyperGSError(f"Frame {scene.frame_current} shows no frame of '{obj.name}'"))
            try:
                frames.sync(obj, scene.frame_current + scene.frame_subframe)
            except HyperGSError as e:
                return report_error(self, e)
        elif not show_only_frame(obj.data, clip_frame(obj, scene.frame_current)):
            self.report({"ERROR"}, f"'{obj.name}' has no `frame` attribute")
            return {"CANCELLED"}
        bpy.ops.object.mode_set(mode="EDIT")
        make_color_active(obj.data)  # Blender 5.1 loses the active attribute on entering Edit Mode (5.0 and 5.2 keep it)
        return {"FINISHED"}


def show_only_frame(mesh, frame: int) -> bool:
    """Hide (and deselect) the vertices of other frames, show this frame's (Object Mode mesh)."""
    import numpy as np

    attribute = mesh.attributes.get("frame")
    if attribute is None:
        return False
    frames = np.empty(len(mesh.vertices), np.int32)
    attribute.data.foreach_get("value", frames)
    hide = frames != frame
    mesh.vertices.foreach_set("hide", hide)
    mesh.vertices.foreach_set("select", np.zeros_like(hide))
    mesh.update()
    return True


CLASSES = [HYPERGS_OT_edit_frame]
