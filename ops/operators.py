"""Operators (public interface): hypergs.import_video, hypergs.convert_strip, hypergs.reencode,
hypergs.edit_frame.

The encoding operators share one pattern: validate on the main thread, encode on a worker thread
(EncodeJob) while a modal operator shows progress and listens for Esc, then write the result into
bpy in one go on the main thread. Nothing is written before that, so a cancel or a failure leaves
the scene as it was, and a finished run is one undo step. Invoked from the UI they run modally;
executed from a script or in background mode (no window: timers do not tick there) they run
synchronously and return when done.
"""
import math
import os
import traceback

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from ..hypergs_blender.encode import Cancelled
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.video import VIDEO_EXTENSIONS
from . import scene as clip_scene
from .jobs import EncodeJob, EncodeRequest, describe
from .props import GAUSSIAN_COUNT, PATCH_GRID


class _EncodeOperator:
    """Mixin: subclasses define make_request(context) -> EncodeRequest and apply(context, result)."""

    bl_options = {"REGISTER", "UNDO"}

    use_modal: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    _job = None
    _timer = None

    def _begin(self, context):
        try:
            request = self.make_request(context)
        except HyperGSError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        job = EncodeJob(request)
        if self.use_modal and context.window is not None and not bpy.app.background:
            self._job = job.start()
            wm = context.window_manager
            self._timer = wm.event_timer_add(0.1, window=context.window)
            wm.progress_begin(0, 100)
            wm.modal_handler_add(self)
            self._status(context, "HyperGS: starting (Esc to cancel)")
            return {"RUNNING_MODAL"}
        return self._end(context, job.run())

    def modal(self, context, event):
        job = self._job
        if event.type == "ESC" and event.value == "PRESS":
            job.cancel()
            self._status(context, "HyperGS: cancelling...")
            return {"RUNNING_MODAL"}
        if event.type == "TIMER":
            if job.finished:
                self._cleanup(context)
                return self._end(context, job)
            context.window_manager.progress_update(int(100 * job.fraction))
            if job.total:
                self._status(context, f"HyperGS: encoding frame {job.done} of {job.total} (Esc to cancel)")
            return {"RUNNING_MODAL"}
        if event.type in {"MOUSEMOVE", "INBETWEEN_MOUSEMOVE", "TIMER_REPORT", "WINDOW_DEACTIVATE"}:
            return {"PASS_THROUGH"}
        return {"RUNNING_MODAL"}  # the scene stays untouched while the job runs

    def cancel(self, context):  # Blender ends the modal (window closed, file loaded)
        if self._job is not None:
            self._job.cancel()
        self._cleanup(context)

    def _cleanup(self, context):
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
            wm.progress_end()
        self._status(context, None)

    @staticmethod
    def _status(context, text):
        workspace = getattr(context, "workspace", None)
        if workspace is not None:
            workspace.status_text_set(text)

    def _end(self, context, job):
        if isinstance(job.error, Cancelled):
            self.report({"WARNING"}, "HyperGS: cancelled, nothing was changed")
            return {"CANCELLED"}
        if job.error is not None:
            if not isinstance(job.error, HyperGSError):
                traceback.print_exception(job.error)  # to the console, for bug reports
            self.report({"ERROR"}, describe(job.error))
            return {"CANCELLED"}
        try:
            message = self.apply(context, job.result)
        except Exception as e:  # what apply() made is removed again (see scene.create_clip_object)
            if not isinstance(e, HyperGSError):
                traceback.print_exc()
            self.report({"ERROR"}, describe(e))
            return {"CANCELLED"}
        self.report({"INFO"}, message)
        return {"FINISHED"}


def _summary(obj, result, changed) -> str:
    s = obj.hypergs
    text = (f"HyperGS: '{obj.name}': {s.num_frames} frames x {s.gaussians_per_frame} Gaussians, "
            f"PSNR {result.psnr:.2f} dB, {result.seconds:.1f} s")
    if changed:
        text += "; changed: " + ", ".join(changed)
    return text


def _check_file(path: str) -> str:
    if not path:
        raise HyperGSError("No video file given")
    path = bpy.path.abspath(path)
    if not os.path.isfile(path):
        raise HyperGSError(f"{path}: no such video file")
    return path


class HYPERGS_OT_import_video(_EncodeOperator, bpy.types.Operator, ImportHelper):
    """Encode a video as 2D Gaussians: one object whose points follow the scene frame"""

    bl_idname = "hypergs.import_video"
    bl_label = "Import Video as Gaussians"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".mp4"
    filter_glob: StringProperty(default=";".join("*" + e for e in VIDEO_EXTENSIONS), options={"HIDDEN"})
    gaussian_count: IntProperty(**GAUSSIAN_COUNT)
    patch_grid: IntProperty(**PATCH_GRID)

    def invoke(self, context, event):
        self.use_modal = True
        if self.filepath:  # dropped on the 3D Viewport, or invoked by a script with a file
            return self.execute(context)
        return ImportHelper.invoke(self, context, event)

    def execute(self, context):
        return self._begin(context)

    def make_request(self, context):
        self._path = _check_file(self.filepath)
        return EncodeRequest(self._path, self.gaussian_count, self.patch_grid)

    def apply(self, context, result):
        name = os.path.splitext(os.path.basename(self._path))[0]
        obj = clip_scene.create_clip_object(
            context.view_layer.active_layer_collection.collection, name, result.video,
            frame_start=context.scene.frame_start, speed=1.0, psnr=result.psnr, seconds=result.seconds,
            encoder=result.encoder, source=self._path, source_start=0)
        changed = clip_scene.prepare_scene(context.scene)
        clip_scene.select_only(context, obj)
        return _summary(obj, result, changed)


class HYPERGS_FH_video(bpy.types.FileHandler):
    """Drop a video on the 3D Viewport to import it as Gaussians."""

    bl_idname = "HYPERGS_FH_video"
    bl_label = "Video as Gaussians"
    bl_import_operator = HYPERGS_OT_import_video.bl_idname
    bl_file_extensions = ";".join(VIDEO_EXTENSIONS)

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type == "VIEW_3D"


def all_strips(editor):
    """Every strip, meta strips' contents included (`strips_all` since 5.0, `sequences_all` before)."""
    return editor.strips_all if hasattr(editor, "strips_all") else editor.sequences_all


def _sequencer_scene(context):
    return getattr(context, "sequencer_scene", None) or context.scene


class HYPERGS_OT_convert_strip(_EncodeOperator, bpy.types.Operator):
    """Convert the active movie strip to 2D Gaussians (keeps its timing; mutes the strip)"""

    bl_idname = "hypergs.convert_strip"
    bl_label = "Convert Strip to Gaussians"

    gaussian_count: IntProperty(**GAUSSIAN_COUNT)
    patch_grid: IntProperty(**PATCH_GRID)

    @classmethod
    def poll(cls, context):
        return _sequencer_scene(context) is not None

    def invoke(self, context, event):
        self.use_modal = True
        return self.execute(context)

    def execute(self, context):
        return self._begin(context)

    def _strip(self, context):
        scene = _sequencer_scene(context)
        editor = scene.sequence_editor
        strip = editor.active_strip if editor is not None else None
        if strip is None:
            raise HyperGSError("No active strip: select a movie strip in the Sequencer")
        if strip.type != "MOVIE":
            raise HyperGSError(f"The active strip '{strip.name}' is not a movie strip")
        return scene, strip

    def make_request(self, context):
        scene, strip = self._strip(context)
        path = _check_file(bpy.path.abspath(strip.filepath, library=getattr(strip.id_data, "library", None)))
        first = int(round(strip.frame_final_start - strip.frame_start + strip.animation_offset_start))
        count = int(strip.frame_final_duration)
        self._target = (scene.name, strip.name, int(strip.frame_final_start))
        return EncodeRequest(path, self.gaussian_count, self.patch_grid, start=max(0, first),
                             stop=max(0, first) + count)

    def apply(self, context, result):
        scene_name, strip_name, frame_start = self._target
        scene = bpy.data.scenes.get(scene_name)
        strip = all_strips(scene.sequence_editor).get(strip_name) if scene and scene.sequence_editor else None
        if strip is None:
            raise HyperGSError(f"The strip '{strip_name}' is gone")
        collection = (context.view_layer.active_layer_collection.collection if scene == context.scene
                      else scene.collection)
        obj = clip_scene.create_clip_object(
            collection, strip.name, result.video, frame_start=frame_start, speed=1.0,
            psnr=result.psnr, seconds=result.seconds, encoder=result.encoder,
            source=bpy.path.abspath(strip.filepath), source_start=int(result.video.source["frames"][0]))
        strip.mute = True  # the sequencer's output would replace the render otherwise
        changed = ["strip muted"]
        if scene.render.use_sequencer and not any(
                not s.mute and s.type not in {"SOUND", "META"} for s in all_strips(scene.sequence_editor)):
            # Blender 4.2 renders the sequencer (black) even when all its strips are muted.
            scene.render.use_sequencer = False
            changed.append("Output > Post Processing > Sequencer off (it would render the muted strip)")
        changed += clip_scene.prepare_scene(scene)
        if scene == context.scene:
            clip_scene.select_only(context, obj)
        return _summary(obj, result, changed)


class HYPERGS_OT_reencode(_EncodeOperator, bpy.types.Operator):
    """Encode the clip's source again with the panel's Gaussian count and patch grid (replaces its points)"""

    bl_idname = "hypergs.reencode"
    bl_label = "Re-encode"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == "MESH" and obj.hypergs.is_clip and context.mode == "OBJECT"

    def invoke(self, context, event):
        self.use_modal = True
        return self.execute(context)

    def execute(self, context):
        return self._begin(context)

    def make_request(self, context):
        obj = context.object
        s = obj.hypergs
        self._name = obj.name
        return EncodeRequest(_check_file(s.source), s.gaussian_count, s.patch_grid, start=s.source_start,
                             stop=s.source_start + s.num_frames)

    def apply(self, context, result):
        obj = bpy.data.objects.get(self._name)
        if obj is None or not obj.hypergs.is_clip:
            raise HyperGSError(f"The object '{self._name}' is gone")
        if obj.mode != "OBJECT":
            raise HyperGSError(f"'{obj.name}' is in {obj.mode.title()} Mode: leave it and re-encode again")
        clip_scene.replace_clip_mesh(obj, result.video, psnr=result.psnr, seconds=result.seconds,
                                     encoder=result.encoder, source=obj.hypergs.source,
                                     source_start=obj.hypergs.source_start)
        return _summary(obj, result, [])


def clip_frame(obj, scene_frame: int) -> int:
    s = obj.hypergs
    return math.floor((scene_frame - s.frame_start) * s.speed + 1e-4)


class HYPERGS_OT_edit_frame(bpy.types.Operator):
    """Edit the points of the frame shown now: Edit Mode with the other frames' points hidden"""

    bl_idname = "hypergs.edit_frame"
    bl_label = "Edit Current Frame"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == "MESH" and obj.hypergs.is_clip and context.mode in {
            "OBJECT", "EDIT_MESH"}

    def execute(self, context):
        obj = context.object
        if obj.mode == "EDIT":
            bpy.ops.object.mode_set(mode="OBJECT")
        if not show_only_frame(obj.data, clip_frame(obj, context.scene.frame_current)):
            self.report({"ERROR"}, f"'{obj.name}' has no `frame` attribute")
            return {"CANCELLED"}
        bpy.ops.object.mode_set(mode="EDIT")
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


CLASSES = [HYPERGS_OT_import_video, HYPERGS_FH_video, HYPERGS_OT_convert_strip, HYPERGS_OT_reencode,
           HYPERGS_OT_edit_frame]
