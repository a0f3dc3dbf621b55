"""Menus and the clip panel (Properties > Object > HyperGS Clip)."""
from __future__ import annotations

import os
import textwrap

import bpy

from ..com import frames, linked
from ..com.mesh import linked_file
from ..ops import preferences, quality
from ..ops.clip_files import HYPERGS_OT_embed_clip, HYPERGS_OT_export_clip, HYPERGS_OT_import_clip
from ..ops.context import active_clip
from ..ops.edit_frame import HYPERGS_OT_edit_frame
from ..ops.encode import HYPERGS_OT_convert_strip, HYPERGS_OT_import_video, HYPERGS_OT_reencode
from ..ops.frame_cache import HYPERGS_OT_pack_cache, HYPERGS_OT_unpack_cache
from ..ops.sources import reencode_source


class HYPERGS_PT_clip(bpy.types.Panel):
    bl_label = "HyperGS Clip"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        return active_clip(context) is not None

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        obj = active_clip(context)
        s = obj.hypergs
        col = layout.column(align=True)
        col.label(text=f"Source: {os.path.basename(s.source) or '-'}", icon="FILE_MOVIE")
        if s.linked:
            self.draw_linked(obj, layout.box())
        elif frames.is_cached_clip(obj):
            self.draw_cache(obj, layout.box())
        else:
            box = layout.box()
            box.label(text="Every frame is in this object's mesh (an earlier version's clip)", icon="MESH_DATA")
            box.operator(HYPERGS_OT_embed_clip.bl_idname, icon="FILE_CACHE")
        info = layout.column(align=True)
        cell = (s.canvas_width * s.canvas_height / s.gaussians_per_frame) ** 0.5 if s.gaussians_per_frame else 0
        for label, value in (("Frames", f"{s.num_frames}  ({s.canvas_width} x {s.canvas_height}, {s.fps:.3g} fps)"),
                             ("Gaussians per Frame", f"{s.gaussians_per_frame:,}  ({s.grid[0]} x {s.grid[1]} "
                                                     f"cells of {cell:.1f} px)"),
                             ("PSNR", f"{s.psnr:.2f} dB"),
                             ("Encoder", f"{s.encoder}, {s.encode_seconds:.1f} s")):
            row = info.row()
            row.label(text=label)
            row.label(text=value)
        if context.scene.render.engine != "HYPERGS":
            layout.label(text="Set the render engine to HyperGS to render clips", icon="INFO")
        timing = layout.column(align=True)
        timing.prop(s, "frame_start")
        timing.prop(s, "speed")
        layout.operator(HYPERGS_OT_export_clip.bl_idname, text="Export Gaussian Video...", icon="EXPORT")
        if s.linked:
            return
        layout.operator(HYPERGS_OT_edit_frame.bl_idname, icon="EDITMODE_HLT")
        box = layout.box()
        quality.draw(box, s, lambda: [reencode_source(obj)], preferences.runtime(context))
        box.operator(HYPERGS_OT_reencode.bl_idname, icon="FILE_REFRESH")

    @staticmethod
    def draw_cache(obj, box):
        """Where the clip's frames are (its frame cache: a file, or packed), what is wrong with it, and
        the frames edited in Blender."""
        s = obj.hypergs
        image = s.cache
        box.label(text="Frame Cache", icon="FILE_CACHE")
        row = box.row(align=True)
        if image.packed_file is not None:
            row.label(text=f"Packed in the .blend ({image.packed_file.size / 1e6:.1f} MB)", icon="PACKAGE")
            row.operator(HYPERGS_OT_unpack_cache.bl_idname, icon="UGLYPACKAGE")
        else:
            row.prop(image, "filepath", text="")
            row.operator(HYPERGS_OT_pack_cache.bl_idname, text="", icon="PACKAGE")
        _draw_problem(box, frames.cache_problem(obj), "The clip shows nothing until the cache is found")
        if s.overrides:
            count = len(s.overrides)
            box.label(text=f"{count} frame{'s' if count > 1 else ''} edited in Blender (kept in the .blend)",
                      icon="EDITMODE_HLT")

    @staticmethod
    def draw_linked(obj, box):
        """The linked file: its path (editable), and what is wrong with it, if anything."""
        box.label(text="Linked: Gaussians are read from this file at render time", icon="LINKED")
        box.prop(obj.hypergs, "linked_path")
        _draw_problem(box, linked.problem(linked_file(obj)), "The clip renders nothing until the file is fixed")
        box.operator(HYPERGS_OT_embed_clip.bl_idname, icon="IMPORT")


def _draw_problem(layout, problem: str | None, consequence: str) -> None:
    """A file's problem (if any) in red, wrapped, and what it means for the clip."""
    if not problem:
        return
    col = layout.column(align=True)
    col.alert = True
    lines = textwrap.wrap(problem, 60) or [problem]
    col.label(text=lines[0], icon="ERROR")
    for line in lines[1:4]:
        col.label(text=line, icon="BLANK1")
    col.label(text=consequence, icon="BLANK1")


class HYPERGS_PT_render(bpy.types.Panel):
    """Properties > Render > HyperGS: the scene's render settings."""
    bl_label = "HyperGS"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "render"

    @classmethod
    def poll(cls, context):
        return context.scene.render.engine == "HYPERGS"

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        layout.prop(context.scene.hypergs, "allow_missing_clips")


def menu_import(self, context):
    self.layout.operator(HYPERGS_OT_import_video.bl_idname, text="Video as Gaussians (.mp4, .mov, ...)")
    self.layout.operator(HYPERGS_OT_import_clip.bl_idname, text="Gaussian Video (.hgs/.usd/.npz)")


def menu_export(self, context):
    self.layout.operator(HYPERGS_OT_export_clip.bl_idname, text="Gaussian Video (.hgs/.usd)")


def menu_strip(self, context):
    """Strip menu and the strip's context menu: convert the selected movie / image strips."""
    self.layout.separator()
    self.layout.operator_context = "INVOKE_DEFAULT"  # the options dialog
    self.layout.operator(HYPERGS_OT_convert_strip.bl_idname, text="Convert to Gaussians...", icon="MOD_PARTICLES")


MENUS = [("TOPBAR_MT_file_import", menu_import), ("TOPBAR_MT_file_export", menu_export),
         ("SEQUENCER_MT_strip", menu_strip), ("SEQUENCER_MT_context_menu", menu_strip)]


def register():
    for menu, fn in MENUS:
        getattr(bpy.types, menu).append(fn)


def unregister():
    for menu, fn in MENUS:
        getattr(bpy.types, menu).remove(fn)


CLASSES = [HYPERGS_PT_clip, HYPERGS_PT_render]
