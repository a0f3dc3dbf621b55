"""Operators (public interface): hypergs.import_video, hypergs.convert_strip, hypergs.reencode,
hypergs.edit_frame, hypergs.import_clip, hypergs.export_clip, hypergs.embed_clip.

The encoding operators share one pattern: validate on the main thread, encode on a worker thread
(EncodeJob) while a modal operator shows progress and listens for Esc, then write the result into
bpy in one go on the main thread. Nothing is written before that, so a cancel or a failure leaves
the scene as it was, and a finished run is one undo step. Invoked from the UI they run modally;
executed from a script or in background mode (no window: timers do not tick there) they run
synchronously and return when done.
"""
import os
import re
import traceback

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..com import linked
from ..com.compat import all_strips, strip_range, strip_source_first
from ..com.mesh import clip_problem, linked_file, read_clip_points
from ..hypergs_blender.encode import Cancelled
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io import image_sequence
from ..hypergs_blender.io.images import IMAGE_EXTENSIONS, VIDEO_EXTENSIONS
from ..hypergs_blender.points import clip_frame_index
from . import preferences
from . import scene as clip_scene
from .jobs import EncodeJob, Source, describe
from . import quality
from .quality import EncodeOptions


class _EncodeOperator:
    """Mixin: subclasses define make_requests(context) -> ([Source], EncodeSettings) and apply(context,
    results) -> message; apply gets a result for every source (one job encodes them in turn, all or
    nothing)."""

    bl_options = {"REGISTER", "UNDO"}

    use_modal: BoolProperty(default=False, options={"HIDDEN", "SKIP_SAVE"})

    _job = None
    _timer = None

    def _begin(self, context):
        try:
            sources, settings = self.make_requests(context)
        except HyperGSError as e:
            self.report({"ERROR"}, str(e))
            return {"CANCELLED"}
        job = EncodeJob(sources, settings, preferences.runtime(context))
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
            if not isinstance(job.error, HyperGSError):
                traceback.print_exception(job.error)  # to the console, for bug reports
            self.report({"ERROR"}, describe(job.error))
            return {"CANCELLED"}
        try:
            message = self.apply(context, job.results)
        except Exception as e:  # what apply() made is removed again (scene.Undo)
            if not isinstance(e, HyperGSError):
                traceback.print_exc()
            self.report({"ERROR"}, describe(e))
            return {"CANCELLED"}
        self.report({"INFO"}, message)
        return {"FINISHED"}


def _summary(obj, result, changed) -> str:
    s = obj.hypergs
    text = (f"HyperGS: '{obj.name}': {s.num_frames} frames x {s.gaussians_per_frame} Gaussians, "
            f"PSNR {result.psnr:.2f} dB, {result.seconds:.1f} s with {result.encoder}")
    if changed:
        text += "; changed: " + ", ".join(changed)
    return text


def _check_file(path: str) -> str:
    """An absolute path to a video file or an image sequence (a file of it, a frame-number pattern
    such as `shot_####.png`, or its folder); raises HyperGSError naming what is wrong."""
    if not path:
        raise HyperGSError("No video file given")
    path = bpy.path.abspath(path)
    if image_sequence.is_image_sequence(path):
        image_sequence.list_frames(path)  # VideoError: no such file / no matching files / ...
        return path
    if not os.path.isfile(path):
        raise HyperGSError(f"{path}: no such video file")
    return path


_FRAME_FIELD = re.compile(r"(#+|%0?\d*d|\{frame(:0?\d*d)?\}|\d+)$")


def _clip_name(path: str) -> str:
    """Object name for a source: the file's stem; for an image sequence without its frame number."""
    p = os.path.normpath(path)
    if not image_sequence.is_image_sequence(p):
        return os.path.splitext(os.path.basename(p))[0]
    stem = os.path.basename(p) if os.path.isdir(p) else os.path.splitext(os.path.basename(p))[0]
    name = _FRAME_FIELD.sub("", stem).rstrip("._- ")
    return name or os.path.basename(os.path.dirname(p)) or "sequence"


def _scene_fps(scene) -> float:
    return scene.render.fps / scene.render.fps_base


class HYPERGS_OT_import_video(_EncodeOperator, EncodeOptions, bpy.types.Operator, ImportHelper):
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
        path = _check_file(self.filepath)
        if self.last_frame and self.last_frame < self.first_frame:
            raise HyperGSError(f"Last Frame {self.last_frame} comes before First Frame {self.first_frame}")
        return Source(os.path.basename(path), path, self.first_frame - 1, self.last_frame or None)

    def make_requests(self, context):
        source = self._source()
        self._path = source.path
        return [source], quality.settings(self)

    def apply(self, context, results):
        (result,) = results
        name = _clip_name(self._path)
        if image_sequence.is_image_sequence(self._path):  # image files have no frame rate: the scene's
            result.video.fps = _scene_fps(context.scene)
        with clip_scene.Undo() as undo:
            obj = clip_scene.create_clip_object(
                context.view_layer.active_layer_collection.collection, name, result.video,
                frame_start=context.scene.frame_start, speed=1.0, psnr=result.psnr, seconds=result.seconds,
                encoder=result.encoder, source=self._path, source_start=int(result.video.source["frames"][0]),
                undo=undo)
            changed = clip_scene.prepare_scene(context.scene, undo)
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


def _sequencer_scene(context):
    return getattr(context, "sequencer_scene", None) or context.scene


def strips_to_convert(editor) -> list:
    """The movie and image strips to convert: the selected ones, or the active one when none is
    selected. Raises HyperGSError when there is none."""
    chosen = [s for s in all_strips(editor) if s.select] if editor is not None else []
    if not chosen and editor is not None and editor.active_strip is not None:
        chosen = [editor.active_strip]
    if not chosen:
        raise HyperGSError("No strip selected: select movie or image-sequence strips in the Sequencer")
    strips = [s for s in chosen if s.type in ("MOVIE", "IMAGE")]
    if not strips:
        names = ", ".join(f"'{s.name}'" for s in chosen[:3]) + (", ..." if len(chosen) > 3 else "")
        raise HyperGSError(f"{names}: not a movie strip or an image sequence")
    return strips


class HYPERGS_OT_convert_strip(_EncodeOperator, EncodeOptions, bpy.types.Operator):
    """Convert the selected movie and image-sequence strips to 2D Gaussians. Each clip gets a scene
    rendered by HyperGS, played by a scene strip with the original timing above the (muted) original"""

    bl_idname = "hypergs.convert_strip"
    bl_label = "Convert to Gaussians"

    @classmethod
    def poll(cls, context):
        return _sequencer_scene(context) is not None  # no strip to convert: execute says so

    def invoke(self, context, event):
        self.use_modal = True
        return context.window_manager.invoke_props_dialog(self)  # the options; OK runs execute()

    def draw(self, context):
        editor = _sequencer_scene(context).sequence_editor
        quality.draw(self.layout, self, lambda: [strip_source(s) for s in strips_to_convert(editor)],
                     preferences.runtime(context))

    def execute(self, context):
        return self._begin(context)

    def make_requests(self, context):
        scene = _sequencer_scene(context)
        sources = [strip_source(strip) for strip in strips_to_convert(scene.sequence_editor)]
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
                if strip.type == "IMAGE":  # image files have no frame rate: the scene's
                    result.video.fps = _scene_fps(scene)
                obj, scene_strip = clip_scene.add_strip_scene(
                    scene, strip, result.video, undo=undo, psnr=result.psnr, seconds=result.seconds,
                    encoder=result.encoder, source=path, source_start=int(result.video.source["frames"][0]))
                quality.copy_options(self, obj.hypergs)  # what Re-encode starts from
                made.append((obj, scene_strip, result))
            changed = clip_scene.sequencer_preview_rendered(scene, undo)
        for strip in strips:
            strip.select = False
        for _, scene_strip, _ in made:
            scene_strip.select = True
        editor.active_strip = made[-1][1]
        text = "; ".join(_summary(obj, result, []).removeprefix("HyperGS: ") + f", played by the scene strip "
                         f"'{scene_strip.name}' (channel {scene_strip.channel})"
                         for obj, scene_strip, result in made)
        return "HyperGS: " + text + ("; changed: " + ", ".join(changed) if changed else "")


def strip_source(strip) -> Source:
    """What a movie or image strip shows: its source's frames from the strip's first shown one on, as
    many as the strip is long. Raises HyperGSError (a missing file, images that are not a sequence)."""
    library = getattr(strip.id_data, "library", None)
    first = strip_source_first(strip)  # index of the strip's first shown frame in its source
    start, end = strip_range(strip)
    count = end - start
    if strip.type == "IMAGE":
        path, first = _image_strip_source(strip, library, first, count)
    else:
        path = _check_file(bpy.path.abspath(strip.filepath, library=library))
    return Source(strip.name, path, first, first + count)


def _image_strip_source(strip, library, first: int, count: int) -> tuple[str, int]:
    """(the sequence's first file, index of the strip's first shown image among the sequence's files)
    for an image strip. The strip's images from `first` on must be consecutive files of one
    numbered sequence (what Add > Image/Sequence makes): the encoder reads that sequence."""
    names = [element.filename for element in strip.elements]
    used = names[first:first + count]
    if len(names) < 2 or len(used) < count or not used:
        raise HyperGSError(f"The strip '{strip.name}' shows a single image, not an image sequence")
    directory = bpy.path.abspath(strip.directory, library=library)
    path = _check_file(os.path.join(directory, used[0]))
    frames = image_sequence.list_frames(path)
    position = {os.path.normcase(f.name): i for i, (_, f) in enumerate(frames)}
    start = position.get(os.path.normcase(used[0]))
    if start is None or [position.get(os.path.normcase(n)) for n in used] != list(range(start, start + count)):
        raise HyperGSError(f"The images of the strip '{strip.name}' are not consecutive files of one numbered "
                           f"sequence in {directory} (such as {used[0]} and the files numbered after it)")
    return str(frames[0][1]), start  # the sequence's first file: `start` counts from it (as re-encode does)


class HYPERGS_OT_reencode(_EncodeOperator, bpy.types.Operator):
    """Encode the clip's source again with the panel's quality (replaces its points)"""

    bl_idname = "hypergs.reencode"
    bl_label = "Re-encode"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return (obj is not None and obj.type == "MESH" and obj.hypergs.is_clip and not obj.hypergs.linked
                and context.mode == "OBJECT")

    def invoke(self, context, event):
        self.use_modal = True
        return self.execute(context)

    def execute(self, context):
        return self._begin(context)

    def make_requests(self, context):
        obj = context.object
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
        clip_scene.replace_clip_mesh(obj, result.video, psnr=result.psnr, seconds=result.seconds,
                                     encoder=result.encoder, source=obj.hypergs.source,
                                     source_start=obj.hypergs.source_start)
        return _summary(obj, result, [])


def reencode_source(obj) -> Source:
    """The frames a clip was encoded from (what Re-encode encodes again)."""
    s = obj.hypergs
    return Source(obj.name, _check_file(s.source), s.source_start, s.source_start + s.num_frames)


def clip_frame(obj, scene_frame: int) -> int:
    s = obj.hypergs
    return clip_frame_index(scene_frame, s.frame_start, s.speed)


class HYPERGS_OT_edit_frame(bpy.types.Operator):
    """Edit the points of the frame shown now: Edit Mode with the other frames' points hidden"""

    bl_idname = "hypergs.edit_frame"
    bl_label = "Edit Current Frame"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = context.object
        return (obj is not None and obj.type == "MESH" and obj.hypergs.is_clip and not obj.hypergs.linked
                and context.mode in {"OBJECT", "EDIT_MESH"})

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


# ----------------------------------------------------------------------------------------------------
# Gaussian video files: .hgs (compressed), .usd/.usda/.usdc, .npz (float32)

CLIP_GLOB = "*.hgs;*.usd;*.usda;*.usdc;*.npz"
USD_SUFFIXES = (".usd", ".usda", ".usdc")


def _active_clip(context):
    obj = getattr(context, "active_object", None) or getattr(context, "object", None)
    return obj if obj is not None and obj.type == "MESH" and obj.hypergs.is_clip else None


def _settings_from_source(source) -> dict:
    """create_clip_object settings from a clip file's free-form `source` metadata (best effort)."""
    source = source if isinstance(source, dict) else {}

    def number(key, kind, default):
        try:
            return kind(source.get(key) or default)
        except (TypeError, ValueError):
            return default
    frames = source.get("frames")
    try:
        start = max(0, int(frames[0])) if frames else 0
    except (TypeError, ValueError, IndexError, KeyError):
        start = 0
    return dict(psnr=number("psnr", float, 0.0), seconds=number("encode_seconds", float, 0.0),
                encoder=str(source.get("encoder") or ""), source=str(source.get("path") or ""), source_start=start)


class HYPERGS_OT_import_clip(bpy.types.Operator, ImportHelper):
    """Import a Gaussian video (.hgs, .usd, .npz) as a clip object: embedded in the .blend, or linked
    to its .hgs file"""

    bl_idname = "hypergs.import_clip"
    bl_label = "Import Gaussian Video"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".hgs"
    filter_glob: StringProperty(default=CLIP_GLOB, options={"HIDDEN"})
    link: BoolProperty(name="Link", default=False,
                       description="Read the Gaussians from the .hgs file at render time instead of copying "
                                   "them into the .blend (smaller .blend; the points cannot be edited)")

    def invoke(self, context, event):
        if self.filepath:  # dropped on the 3D Viewport
            return self.execute(context)
        return ImportHelper.invoke(self, context, event)

    def execute(self, context):
        try:
            message = self._import(context)
        except Exception as e:  # what it made is removed again (scene.Undo)
            if not isinstance(e, HyperGSError):
                traceback.print_exc()
            self.report({"ERROR"}, describe(e))
            return {"CANCELLED"}
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def _import(self, context) -> str:
        from ..hypergs_blender.io.clips import load_clip
        if not self.filepath:
            raise HyperGSError("No Gaussian video file given")
        path = bpy.path.abspath(self.filepath)
        name = os.path.basename(path)
        if self.link and os.path.splitext(path)[1].lower() != ".hgs":
            raise HyperGSError(f"{name}: only .hgs files can be linked (import .usd and .npz clips embedded)")
        try:  # everything is read and checked before anything is made
            video = linked.verify(path) if self.link else load_clip(path)
        except HyperGSError:
            raise  # the readers' messages name the file and the reason
        except Exception as e:  # still one line, naming the file
            traceback.print_exc()
            raise HyperGSError(f"{name}: cannot read it as a Gaussian video ({type(e).__name__}: {e})") from e
        problem = clip_problem(video)
        if problem:
            raise HyperGSError(f"{name}: {problem}")
        with clip_scene.Undo() as undo:
            obj = clip_scene.create_clip_object(
                context.view_layer.active_layer_collection.collection, os.path.splitext(os.path.basename(path))[0],
                video, frame_start=context.scene.frame_start, speed=1.0, linked_path=path if self.link else None,
                undo=undo, **_settings_from_source(video.source))
            changed = clip_scene.prepare_scene(context.scene, undo)
        clip_scene.select_only(context, obj)
        s = obj.hypergs
        text = (f"HyperGS: '{obj.name}': {s.num_frames} frames x {s.gaussians_per_frame} Gaussians "
                f"{'linked to' if self.link else 'from'} {os.path.basename(path)}")
        return text + ("; changed: " + ", ".join(changed) if changed else "")


class HYPERGS_FH_clip(bpy.types.FileHandler):
    """Drop a .hgs file on the 3D Viewport to import it."""

    bl_idname = "HYPERGS_FH_clip"
    bl_label = "Gaussian Video"
    bl_import_operator = HYPERGS_OT_import_clip.bl_idname
    bl_file_extensions = ".hgs"

    @classmethod
    def poll_drop(cls, context):
        return context.area is not None and context.area.type == "VIEW_3D"


FORMATS = {"HGS": ".hgs", "USD": ".usd", "USDA": ".usda", "NPZ": ".npz"}


class HYPERGS_OT_export_clip(bpy.types.Operator, ExportHelper):
    """Export the active clip's Gaussians, as edited in Blender, to a Gaussian video file"""

    bl_idname = "hypergs.export_clip"
    bl_label = "Export Gaussian Video"
    bl_options = {"REGISTER", "UNDO", "PRESET"}

    filename_ext = ".hgs"
    filter_glob: StringProperty(default=CLIP_GLOB, options={"HIDDEN"})
    file_format: EnumProperty(
        name="Format", default="HGS",
        items=[("HGS", ".hgs", "Compressed HyperGS video (quantized to Bits per value)"),
               ("USD", ".usd", "USD points with a time sample per frame (binary crate file)"),
               ("USDA", ".usda", "USD points with a time sample per frame (text)"),
               ("NPZ", ".npz", "Uncompressed float32 parameters (NumPy)")])
    bits: IntProperty(name="Bits", default=8, min=1, max=16,
                      description="Bits per value in a .hgs file (more: larger file, smaller error)")
    link: BoolProperty(name="Link to File", default=False,
                       description="Afterwards read the clip's Gaussians from the exported .hgs file: they leave "
                                   "the .blend (and can no longer be edited there)")

    @classmethod
    def poll(cls, context):
        return _active_clip(context) is not None

    def invoke(self, context, event):
        self.filename_ext = FORMATS[self.file_format]
        if not self.filepath:  # the clip's name, next to the .blend (ExportHelper would use the .blend's name)
            obj = _active_clip(context)
            folder = os.path.dirname(bpy.data.filepath) if bpy.data.filepath else ""
            self.filepath = os.path.join(folder, bpy.path.clean_name(obj.name) + self.filename_ext)
        return ExportHelper.invoke(self, context, event)

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(self, "file_format")
        if self.file_format == "HGS":
            layout.prop(self, "bits")
            layout.prop(self, "link")

    def check(self, context):
        # The Format menu picks the suffix (a typed .usd etc. is replaced), as Blender's glTF exporter does.
        self.filename_ext = FORMATS[self.file_format]
        return ExportHelper.check(self, context)

    def execute(self, context):
        obj = _active_clip(context)
        if obj is None:
            self.report({"ERROR"}, "No active HyperGS clip to export")
            return {"CANCELLED"}
        try:
            message = self._export(context, obj)
        except Exception as e:
            if not isinstance(e, HyperGSError):
                traceback.print_exc()
            self.report({"ERROR"}, describe(e))
            return {"CANCELLED"}
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def _target(self) -> str:
        """The path to write: a script's filepath keeps any clip suffix; otherwise the format's is added."""
        if not self.filepath:
            raise HyperGSError("No file name given")
        path = bpy.path.abspath(self.filepath)
        if os.path.splitext(path)[1].lower() in (*FORMATS.values(), ".usdc"):
            return path
        return path + FORMATS[self.file_format]

    def _export(self, context, obj) -> str:
        from ..hypergs_blender.io.clips import save_clip
        path = self._target()
        suffix = os.path.splitext(path)[1].lower()
        if self.link and suffix != ".hgs":
            raise HyperGSError("Link to File needs a .hgs file")
        if self.link and obj.mode != "OBJECT":
            raise HyperGSError(f"'{obj.name}' is in {obj.mode.title()} Mode: leave it to link the clip to a file")
        if not os.path.isdir(os.path.dirname(path) or "."):
            raise HyperGSError(f"{os.path.dirname(path)}: no such folder")
        video, dropped = clip_video(obj)
        options = {"bits": self.bits}
        if suffix in USD_SUFFIXES:
            options["start_frame"] = obj.hypergs.frame_start
        save_clip(video, path, **options)
        linked.forget(path)  # a linked clip reading this file sees the new version
        if self.link:
            clip_scene.link_clip(obj, path)
        text = (f"HyperGS: '{obj.name}': {video.num_frames} frames exported to {os.path.basename(path)} "
                f"({os.path.getsize(path) / 1e6:.2f} MB)")
        if dropped:
            text += f"; {dropped} point(s) with a zero scale or invalid values left out"
        return text + ("; the clip is now linked to it" if self.link else "")


def clip_video(obj):
    """(GaussianVideo, points left out) of a clip as it is now: an embedded clip's mesh with the
    user's edits (Edit Mode included; modifiers other than the frame filter are not applied), or a
    linked clip's file."""
    from ..hypergs_blender.io.clips import load_clip
    from ..hypergs_blender.points import frame_counts, points_to_video
    s = obj.hypergs
    if s.linked:
        return load_clip(linked_file(obj)), 0
    if s.canvas_width <= 0 or s.canvas_height <= 0:
        raise HyperGSError(f"'{obj.name}' has no canvas size")
    if obj.mode == "EDIT":
        # In Edit Mode the mesh's attributes are the edit mesh's layers (no `position`): read a copy
        # of the mesh synced from the edit mesh instead.
        obj.update_from_editmode()
        mesh = obj.data.copy()
        try:
            points = read_clip_points(mesh)
        finally:
            bpy.data.meshes.remove(mesh)
    else:
        points = read_clip_points(obj.data)
    count = s.num_frames
    source = dict(path=s.source, frames=list(range(s.source_start, s.source_start + count)), encoder=s.encoder,
                  encode_seconds=s.encode_seconds, psnr=s.psnr)
    video = points_to_video(points, s.canvas_width, s.canvas_height, s.fps, num_frames=count,
                            grid=tuple(s.grid), source=source)
    if video.num_frames != count:
        video.source["frames"] = list(range(s.source_start, s.source_start + video.num_frames))
    return video, len(points["frame"]) - int(frame_counts(video).sum())


class HYPERGS_OT_embed_clip(bpy.types.Operator):
    """Copy a linked clip's Gaussians from its .hgs file into the .blend, so its points can be edited"""

    bl_idname = "hypergs.embed_clip"
    bl_label = "Embed in .blend"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = _active_clip(context)
        return obj is not None and obj.hypergs.linked and obj.mode == "OBJECT"

    def execute(self, context):
        from ..hypergs_blender.io.clips import load_clip
        obj = _active_clip(context)
        try:
            video = load_clip(linked_file(obj))
            name = os.path.basename(obj.hypergs.linked_path)
            clip_scene.embed_clip(obj, video)
        except Exception as e:  # load_clip fails before anything changes
            if not isinstance(e, HyperGSError):
                traceback.print_exc()
            self.report({"ERROR"}, describe(e))
            return {"CANCELLED"}
        self.report({"INFO"}, f"HyperGS: '{obj.name}': {video.num_frames} frames embedded from {name}")
        return {"FINISHED"}


CLASSES = [HYPERGS_OT_import_video, HYPERGS_FH_video, HYPERGS_OT_convert_strip, HYPERGS_OT_reencode,
           HYPERGS_OT_edit_frame, HYPERGS_OT_import_clip, HYPERGS_FH_clip, HYPERGS_OT_export_clip,
           HYPERGS_OT_embed_clip]
