"""Gaussian video files: hypergs.import_clip (File > Import: .hgs, .usd/.usda/.usdc, .npz; copied into a
frame cache, or linked to its .hgs file), hypergs.export_clip (File > Export: the clip as edited, streamed
a frame at a time) and hypergs.embed_clip (Copy to Frame Cache: a linked clip's file, or a clip embedded
whole in its mesh by an earlier version, copied into a frame cache, so its points can be edited)."""
import contextlib
import os
import traceback

import bpy
from bpy.props import BoolProperty, EnumProperty, IntProperty, StringProperty
from bpy_extras.io_utils import ExportHelper, ImportHelper

from ..com import cache as clip_cache
from ..com import frames, linked
from ..com.mesh import clip_problem, linked_file, read_clip_points, read_points
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io.cache import write_clip
from ..hypergs_blender.io.clips import ClipFrames
from ..hypergs_blender.io.files import make_folders, remove_folders
from . import scene as clip_scene
from .context import active_clip, report_error, reported

CLIP_GLOB = "*.hgs;*.usd;*.usda;*.usdc;*.npz"
USD_SUFFIXES = (".usd", ".usda", ".usdc")


def copy_to_cache(context, clip: ClipFrames, name: str, undo: "clip_scene.Undo"):
    """Write `clip` a frame at a time into a new frame cache for the clip `name` (progress in the
    window's cursor); returns (its path, its header). The file goes again if `undo` takes back."""
    path = clip_cache.new_cache_path(name)
    folders = make_folders(os.path.dirname(path))
    wm = context.window_manager
    wm.progress_begin(0, max(1, clip.num_frames))
    try:
        header = write_clip(clip, path, lambda done, total: wm.progress_update(done) or True)
    except BaseException:
        remove_folders(folders)
        raise
    finally:
        wm.progress_end()

    def remove():
        try:
            os.remove(path)
        except OSError:
            pass
        remove_folders(folders)
    undo.call(remove)
    return path, header


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
        return reported(self, lambda: self._import(context))  # _import undoes itself (scene.Undo)

    def _import(self, context) -> str:
        from ..hypergs_blender.io.clips import load_clip
        from ..hypergs_blender.io.hgs import HgsReader
        if not self.filepath:
            raise HyperGSError("No Gaussian video file given")
        path = bpy.path.abspath(self.filepath)
        name = os.path.basename(path)
        hgs = os.path.splitext(path)[1].lower() == ".hgs"
        if self.link and not hgs:
            raise HyperGSError(f"{name}: only .hgs files can be linked (import .usd and .npz clips into a frame cache)")
        try:  # read and checked before anything is made (a .hgs file's frames: as they are copied)
            clip = linked.verify(path) if self.link else HgsReader(path) if hgs else load_clip(path)
        except HyperGSError:
            raise  # the readers' messages name the file and the reason
        except Exception as e:  # still one line, naming the file
            traceback.print_exc()
            raise HyperGSError(f"{name}: cannot read it as a Gaussian video ({type(e).__name__}: {e})") from e
        try:
            problem = clip_problem(clip)
            if problem:
                raise HyperGSError(f"{name}: {problem}")
            scene, stem = context.scene, os.path.splitext(name)[0]
            with clip_scene.Undo() as undo:
                cache_path, header = None, clip
                if not self.link:
                    cache_path, header = copy_to_cache(context, ClipFrames.of(clip), stem, undo)
                obj = clip_scene.create_clip_object(
                    context.view_layer.active_layer_collection.collection, stem, header, scene=scene,
                    frame_start=scene.frame_start, speed=1.0, cache_path=cache_path,
                    linked_path=path if self.link else None, undo=undo, **_settings_from_source(clip.source))
                changed = clip_scene.match_scene_timing(scene, obj, undo) + clip_scene.prepare_scene(scene, undo)
        finally:
            if isinstance(clip, HgsReader) and not self.link:
                clip.close()
        clip_scene.select_only(context, obj)
        s = obj.hypergs
        text = (f"HyperGS: '{obj.name}': {s.num_frames} frames x {s.gaussians_per_frame} Gaussians "
                f"{'linked to' if self.link else 'from'} {name}")
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
                      description="Bits per value in a .hgs file (more: larger file, smaller error); the "
                                  "positions get what the Gaussians' spacing needs")
    link: BoolProperty(name="Link to File", default=False,
                       description="Afterwards read the clip's Gaussians from the exported .hgs file: they leave "
                                   "the .blend (and can no longer be edited there)")

    @classmethod
    def poll(cls, context):
        return active_clip(context) is not None

    def invoke(self, context, event):
        self.filename_ext = FORMATS[self.file_format]
        if not self.filepath:  # the clip's name, next to the .blend (ExportHelper would use the .blend's name)
            obj = active_clip(context)
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
        obj = active_clip(context)
        if obj is None:
            return report_error(self, HyperGSError("No active HyperGS clip to export"))
        return reported(self, lambda: self._export(context, obj))

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
        options = {"bits": self.bits}
        if suffix in USD_SUFFIXES:
            options["start_frame"] = obj.hypergs.frame_start
        with clip_frames(obj) as (clip, dropped):
            save_clip(clip, path, **options)
        linked.forget(path)  # a linked clip reading this file sees the new version
        if self.link:
            clip_scene.link_clip(obj, path)
        text = (f"HyperGS: '{obj.name}': {clip.num_frames} frames exported to {os.path.basename(path)} "
                f"({os.path.getsize(path) / 1e6:.2f} MB)")
        if dropped:
            text += f"; {dropped} point(s) with a zero scale or invalid values left out"
        return text + ("; the clip is now linked to it" if self.link else "")


@contextlib.contextmanager
def clip_frames(obj):
    """(clips.ClipFrames, points left out) of a clip as it is now, read a frame at a time: a cache
    clip's frames with the user's edits (Edit Mode included), a linked clip's file, or a clip embedded
    whole in its mesh (in memory already) with the user's edits. The object's modifiers other than the
    frame filter are not applied."""
    from ..hypergs_blender.io.hgs import HgsReader
    from ..hypergs_blender.points import frame_counts, points_to_video
    s = obj.hypergs
    if s.linked:
        with HgsReader(linked_file(obj)) as reader:
            yield ClipFrames.of(reader), 0
        return
    if s.canvas_width <= 0 or s.canvas_height <= 0:
        raise HyperGSError(f"'{obj.name}' has no canvas size")
    if obj.mode == "EDIT":
        # In Edit Mode the mesh's attributes are the edit mesh's layers (no `position`): read a copy
        # of the mesh synced from the edit mesh instead.
        obj.update_from_editmode()
        mesh = obj.data.copy()
        try:
            points = (read_points if frames.is_cached_clip(obj) else read_clip_points)(mesh)
        finally:
            bpy.data.meshes.remove(mesh)
    else:
        points = (read_points if frames.is_cached_clip(obj) else read_clip_points)(obj.data)
    if frames.is_cached_clip(obj):
        yield frames.clip_frames(obj, points)
        return
    count = s.num_frames
    source = dict(path=s.source, frames=list(range(s.source_start, s.source_start + count)), encoder=s.encoder,
                  encode_seconds=s.encode_seconds, psnr=s.psnr)
    video = points_to_video(points, s.canvas_width, s.canvas_height, s.fps, num_frames=count,
                            grid=tuple(s.grid), source=source)
    if video.num_frames != count:
        video.source["frames"] = list(range(s.source_start, s.source_start + video.num_frames))
    yield ClipFrames.of(video), len(points["frame"]) - int(frame_counts(video).sum())


class HYPERGS_OT_embed_clip(bpy.types.Operator):
    """Copy the clip's Gaussians into a frame cache of the .blend's, so its points can be edited: a
    linked clip's .hgs file, or every frame of a clip embedded in its mesh by an earlier version (its
    edits kept)"""

    bl_idname = "hypergs.embed_clip"
    bl_label = "Copy to Frame Cache"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = active_clip(context)
        return obj is not None and not frames.is_cached_clip(obj) and obj.mode == "OBJECT"

    def execute(self, context):
        return reported(self, lambda: self._copy(context, active_clip(context)))

    @staticmethod
    def _copy(context, obj) -> str:
        s = obj.hypergs
        what = os.path.basename(s.linked_path) if s.linked else "its mesh"
        settings = dict(psnr=s.psnr, seconds=s.encode_seconds, encoder=s.encoder, source=s.source,
                        source_start=s.source_start)
        with clip_scene.Undo() as undo, clip_frames(obj) as (clip, _):
            path, header = copy_to_cache(context, clip, obj.name, undo)  # fails before anything changes
            clip_scene.set_cache(obj, path, header, scene=context.scene, keep_edits=False, **settings)
        return f"HyperGS: '{obj.name}': {header.num_frames} frames copied from {what} into its frame cache"


CLASSES = [HYPERGS_OT_import_clip, HYPERGS_FH_clip, HYPERGS_OT_export_clip, HYPERGS_OT_embed_clip]
