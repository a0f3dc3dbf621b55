"""Menus and the clip panel (Properties > Object > HyperGS Clip)."""
from __future__ import annotations

import os

import bpy

from ..ops.operators import (HYPERGS_OT_convert_strip, HYPERGS_OT_edit_frame, HYPERGS_OT_import_video,
                             HYPERGS_OT_reencode)


class HYPERGS_PT_clip(bpy.types.Panel):
    bl_label = "HyperGS Clip"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "object"

    @classmethod
    def poll(cls, context):
        obj = context.object
        return obj is not None and obj.type == "MESH" and obj.hypergs.is_clip

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        obj = context.object
        s = obj.hypergs
        col = layout.column(align=True)
        col.label(text=f"Source: {os.path.basename(s.source) or '-'}", icon="FILE_MOVIE")
        info = layout.column(align=True)
        for label, value in (("Frames", f"{s.num_frames}  ({s.canvas_width} x {s.canvas_height}, {s.fps:.3g} fps)"),
                             ("Gaussians per Frame", f"{s.gaussians_per_frame}  (grid {s.grid} x {s.grid})"),
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
        layout.operator(HYPERGS_OT_edit_frame.bl_idname, icon="EDITMODE_HLT")
        box = layout.box()
        box.prop(s, "gaussian_count")
        box.prop(s, "patch_grid")
        box.operator(HYPERGS_OT_reencode.bl_idname, icon="FILE_REFRESH")


def menu_import(self, context):
    self.layout.operator(HYPERGS_OT_import_video.bl_idname, text="Video as Gaussians (.mp4, .mov, ...)")


def menu_strip(self, context):
    self.layout.separator()
    self.layout.operator(HYPERGS_OT_convert_strip.bl_idname, icon="MOD_PARTICLES")


MENUS = [("TOPBAR_MT_file_import", menu_import), ("SEQUENCER_MT_strip", menu_strip)]


def register():
    for menu, fn in MENUS:
        getattr(bpy.types, menu).append(fn)


def unregister():
    for menu, fn in MENUS:
        getattr(bpy.types, menu).remove(fn)


CLASSES = [HYPERGS_PT_clip]
