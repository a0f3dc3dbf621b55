"""The operators that encode videos: hypergs.import_video (File > Import, also a video dropped on the
3D Viewport), hypergs.convert_strip (the Sequencer's selected strips) and hypergs.reencode (a clip again,
with the panel's options).

They share one pattern (EncodeOperator): validate on the main thread and pick each clip's new frame
cache file (com/cache.py), encode on a worker thread that streams the Gaussians into those files
(EncodeJob) while a modal operator shows progress and listens for Esc, then make the clip objects in
bpy in one go on the main thread. Nothing in bpy changes before that, and a cancelled or failed job
leaves no file, so a cancel or a failure leaves the scene and the disk as they were (a failure while
making the objects removes the files again), and a finished run is one undo step. Invoked from the UI
they run modally; executed from a script or in background mode (no window: timers do not tick there)
they run synchronously and return when done.
"""
import dataclasses
import os

import bpy
from bpy.props import BoolProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ImportHelper

from ..com import cache as clip_cache
from ..com.compat import MOVIE_DISPLAY, all_strips
from ..hypergs_blender.encode import Cancelled
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io import image_sequence
from ..hypergs_blender.io.images import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS
from . import preferences, quality
from . import scene as clip_scene
from .context import active_clip, report_error, reported
from .jobs import EncodeJob, Source
from .quality import EncodeOptions
from .sources import check_video_path, clip_name, reencode_source, sequencer_scene, strip_source, strips_to_convert


class EncodeOperator:
    """Mixin (the pattern in this module's doc): subclasses define what_to_encode(context) -> ([Source],
    EncodeSettings) and apply(context, results) -> message; apply gets a result for every source (one
    job encodes them in turn, all or nothing)."""

    bl_options = {"REGISTER", "UNDO"}

    use_modal: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    _job = None
    _timer = None

    def _begin(self, context):
        try:
            sources, settings = self.what_to_encode(context)
        except HyperGSError as e:
            return report_error(self, e)
        try:
            targets = []
            for source in sources:
                targets.append(clip_cache.new_cache_path(source.name, targets))
        except HyperGSError as e:
            return report_error(self, e)
        job = EncodeJob(sources, targets, settings, preferences.runtime(context))
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
            self._status(context, f"HyperGS: {job.status()} (Esc to cancel)")
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
            return report_error(self, job.error)
        outcome = reported(self, lambda: self.apply(context, job.results))  # apply() undoes itself (scene.Undo)
        if "FINISHED" not in outcome:
            job.discard()  # the caches no clip reads
        return outcome


def _with_scene_fps(source: Source, scene) -> Source:
    """An image sequence's clip takes the scene's frame rate (image files have none)."""
    if not image_sequence.is_image_sequence(source.path):
        return source
    return dataclasses.replace(source, fps=scene.render.fps / scene.render.fps_base)


def _summary(obj, result, changed) -> str:
    s = obj.hypergs
    text = (f"HyperGS: '{obj.name}': {s.num_frames} frames x {s.gaussians_per_frame} Gaussians, "
            f"PSNR {result.psnr:.2f} dB, {result.seconds:.1f} s with {result.encoder}")
    if changed:
        text += "; changed: " + ", ".join(changed)
    return text


class HYPERGS_OT_import_video(EncodeOperator, EncodeOptions, bpy.types.Operator, ImportHelper):
    """Encode a video or an image sequence (one of its files, or a pattern such as shot_####.png)
    as 2D Gaussians: one object whose points follow the scene frame"""

    bl_idname = "hypergs.import_video"
    bl_label = "Import Video as Gaussians"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".mp4"
    filter_glob: StringProperty(default=";".join("*" + e for e in VIDEO_EXTENSIONS + IMAGE_EXTENSIONS),
                                options={"HIDDEN"})
    first_frame: IntProperty(name="First Frame", default=1, min=1,
                             description="The video's first frame to encode (1: its first)")
    last_frame: IntProperty(name="Last Frame", default=0, min=0,
                            description="The video's last frame to encode (0: its last)")

    def invoke(self, context, event):
        self.use_modal = True
        if self.filepath:  # dropped on the 3D Viewport, or invoked by a script with a file: the options
            return context.window_manager.invoke_props_dialog(self)
        return ImportHelper.invoke(self, context, event)  # the file browser shows the options beside

    def draw(self, context):
        quality.draw(self.layout, self, lambda: [self._source()], preferences.runtime(context))
        col = self.layout.column(align=True)
        col.prop(self, "first_frame")
        col.prop(self, "last_frame")

    def execute(self, context):
        return self._begin(context)

    def _source(self) -> Source:
        path = check_video_path(self.filepath)
        if self.last_frame and self.last_frame < self.first_frame:
            raise HyperGSError(f"Last Frame {self.last_frame} comes before First Frame {self.first_frame}")
        return Source(os.path.basename(path), path, self.first_frame - 1, self.last_frame or None,
                      display=MOVIE_DISPLAY)  # as this Blender shows the file in the Sequencer

    def what_to_encode(self, context):
        source = _with_scene_fps(self._source(), context.scene)
        self._path = source.path
        return [dataclasses.replace(source, name=clip_name(source.path))], quality.settings(self)

    def apply(self, context, results):
        (result,) = results
        scene = context.scene
        with clip_scene.Undo() as undo:
            obj = clip_scene.create_clip_object(
                context.view_layer.active_layer_collection.collection, clip_name(self._path), result.clip,
                scene=scene, frame_start=scene.frame_start, speed=1.0, cache_path=result.cache, undo=undo,
                psnr=result.psnr, seconds=result.seconds, encoder=result.encoder, source=self._path,
                source_start=int(result.clip.source["frames"][0]))
            changed = clip_scene.match_scene_timing(scene, obj, undo) + clip_scene.prepare_scene(scene, undo)
        quality.copy_options(self, obj.hypergs)  # what Re-encode starts from
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


class HYPERGS_OT_convert_strip(EncodeOperator, EncodeOptions, bpy.types.Operator):
    """Convert the selected movie and image-sequence strips to 2D Gaussians. Each clip gets a scene
    rendered by HyperGS, played by a scene strip with the original timing above the (muted) original"""

    bl_idname = "hypergs.convert_strip"
    bl_label = "Convert to Gaussians"

    @classmethod
    def poll(cls, context):
        return sequencer_scene(context) is not None  # no strip to convert: execute says so

    def invoke(self, context, event):
        self.use_modal = True
        return context.window_manager.invoke_props_dialog(self)  # the options; OK runs execute()

    def draw(self, context):
        editor = sequencer_scene(context).sequence_editor
        quality.draw(self.layout, self, lambda: [strip_source(s) for s in strips_to_convert(editor)],
                     preferences.runtime(context))

    def execute(self, context):
        return self._begin(context)

    def what_to_encode(self, context):
        scene = sequencer_scene(context)
        sources = [_with_scene_fps(strip_source(strip), scene)
                   for strip in strips_to_convert(scene.sequence_editor)]
        self._targets = [(source.name, source.path) for source in sources]
        self._scene = scene.name
        return sources, quality.settings(self)

    def apply(self, context, results):
        scene = bpy.data.scenes.get(self._scene)
        editor = scene.sequence_editor if scene is not None else None
        strips = [all_strips(editor).get(name) if editor is not None else None for name, _ in self._targets]
        for strip, (name, _) in zip(strips, self._targets):
            if strip is None:
                raise HyperGSError(f"The strip '{name}' is gone")
        made = []
        with clip_scene.Undo() as undo:
            for strip, (_, path), result in zip(strips, self._targets, results):
                obj, scene_strip = clip_scene.add_strip_scene(
                    scene, strip, result.clip, result.cache, undo=undo, psnr=result.psnr, seconds=result.seconds,
                    encoder=result.encoder, source=path, source_start=int(result.clip.source["frames"][0]))
                quality.copy_options(self, obj.hypergs)  # what Re-encode starts from
                made.append((obj, scene_strip, result))
            changed = clip_scene.sequencer_preview_rendered(scene, undo) + clip_scene.lock_interface(scene, undo)
        for strip in strips:
            strip.select = False
        for _, scene_strip, _ in made:
            scene_strip.select = True
        editor.active_strip = made[-1][1]
        text = "; ".join(_summary(obj, result, []).removeprefix("HyperGS: ") + f", played by the scene strip "
                         f"'{scene_strip.name}' (channel {scene_strip.channel})"
                         for obj, scene_strip, result in made)
        return "HyperGS: " + text + ("; changed: " + ", ".join(changed) if changed else "")


class HYPERGS_OT_reencode(EncodeOperator, bpy.types.Operator):
    """Encode the clip's source again with the panel's quality into a new frame cache (the clip's
    edited frames are kept or discarded, as chosen)"""

    bl_idname = "hypergs.reencode"
    bl_label = "Re-encode"

    keep_edits: BoolProperty(name="Keep Edited Frames", default=True,
                             description="Keep the frames edited in Blender as they are (else they show the "
                                         "new encode like the others)")

    @classmethod
    def poll(cls, context):
        obj = active_clip(context)
        return obj is not None and not obj.hypergs.linked and context.mode == "OBJECT"

    def invoke(self, context, event):
        self.use_modal = True
        if active_clip(context).hypergs.overrides:  # ask what becomes of them
            return context.window_manager.invoke_props_dialog(self)
        return self.execute(context)

    def draw(self, context):
        count = len(active_clip(context).hypergs.overrides)
        self.layout.label(text=f"{count} frame{'s' if count > 1 else ''} of this clip {'were' if count > 1 else 'was'} "
                               f"edited in Blender", icon="INFO")
        self.layout.prop(self, "keep_edits")

    def execute(self, context):
        return self._begin(context)

    def what_to_encode(self, context):
        obj = active_clip(context)
        s = obj.hypergs
        self._name = obj.name
        return [reencode_source(obj)], quality.settings(s)

    def apply(self, context, results):
        (result,) = results
        obj = bpy.data.objects.get(self._name)
        if obj is None or not obj.hypergs.is_clip:
            raise HyperGSError(f"The object '{self._name}' is gone")
        if obj.mode != "OBJECT":
            raise HyperGSError(f"'{obj.name}' is in {obj.mode.title()} Mode: leave it and re-encode again")
        s = obj.hypergs
        clip_scene.set_cache(obj, result.cache, result.clip, scene=context.scene, keep_edits=self.keep_edits,
                             psnr=result.psnr, seconds=result.seconds, encoder=result.encoder, source=s.source,
                             source_start=s.source_start)
        kept = f"; {len(s.overrides)} edited frame(s) kept" if s.overrides else ""
        return _summary(obj, result, []) + kept


CLASSES = [HYPERGS_OT_import_video, HYPERGS_FH_video, HYPERGS_OT_convert_strip, HYPERGS_OT_reencode]
