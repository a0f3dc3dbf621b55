"""The HYPERGS render engine: F12 / Ctrl-F12 render every visible clip additively from the evaluated
geometry at the scene's resolution x percentage; the viewport's Rendered mode shows the same frame."""
from __future__ import annotations

import bpy

from . import draw, splat
from .geometry import evaluated_clips, render_clips


class HyperGSRenderEngine(bpy.types.RenderEngine):
    bl_idname = "HYPERGS"
    bl_label = "HyperGS"
    bl_use_preview = False
    bl_use_postprocess = True
    bl_use_gpu_context = splat.gpu_context_possible()  # F12 splats on the GPU where it can (engine/splat.py)

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        self._view = draw.ViewCache()

    def render(self, depsgraph):
        width, height = self.resolution_x, self.resolution_y
        self.update_stats("", "HyperGS: reading clips")

        def keep_going(done, total):
            self.update_progress(done / total if total else 1.0)
            if done < total:
                self.update_stats("", f"HyperGS: clip {done + 1} of {total}")
            return not self.test_break()

        problems = []
        clips = list(evaluated_clips(depsgraph, problems=problems))
        if problems and missing_clips_stop(self.is_animation, bpy.app.background,
                                           depsgraph.scene.hypergs.allow_missing_clips):
            # Blender treats an ERROR report as a failed frame: no image is written, Ctrl-F12 and a
            # command-line render stop, bpy.ops.render.render raises.
            for problem in problems:
                self.report({"ERROR"}, f"HyperGS: {problem}; the render stops (to render the clip black "
                                       "instead: Render Properties > HyperGS > Render Missing Clips Black)")
            return
        rgba = splat.render_clips(clips, width, height) if self.bl_use_gpu_context else None
        if rgba is None:  # no GPU context, or an image too large for the GPU: the numpy path
            rgba = render_clips(clips, width, height, keep_going)
        for problem in problems:  # the other clips still render
            self.report({"WARNING"}, f"HyperGS: {problem}; the clip renders nothing")
        if rgba is None:
            return
        result = self.begin_result(0, 0, width, height)
        result.layers[0].passes["Combined"].rect.foreach_set(rgba.ravel())
        self.end_result(result)

    def view_update(self, context, depsgraph):
        self._view.invalidate()

    def view_draw(self, context, depsgraph):
        draw.view_draw(self, context, depsgraph, self._view)


def missing_clips_stop(is_animation: bool, background: bool, allow_black: bool) -> bool:
    """Whether a linked clip whose file is missing or damaged stops the render: in an animation
    (Ctrl-F12) or command-line render (nobody watches: black frames would pass unnoticed, e.g. on a
    render farm) unless the scene allows black frames; never in an interactive single-frame F12, which
    shows the warning."""
    return (is_animation or background) and not allow_black


# Built-in panels (output size, frame range, colour management, mesh data, ...) show only for the
# engines they list; add ours to the generic ones, as Blender's custom-engine example does.
_EXCLUDE_PANELS = {"VIEWLAYER_PT_filter", "VIEWLAYER_PT_layer_passes"}


def _panels():
    for panel in bpy.types.Panel.__subclasses__():
        engines = getattr(panel, "COMPAT_ENGINES", None)
        if engines is not None and "BLENDER_RENDER" in engines and panel.__name__ not in _EXCLUDE_PANELS:
            yield panel


def register():
    for panel in _panels():
        panel.COMPAT_ENGINES.add(HyperGSRenderEngine.bl_idname)


def unregister():
    for panel in _panels():
        panel.COMPAT_ENGINES.discard(HyperGSRenderEngine.bl_idname)


CLASSES = [HyperGSRenderEngine]
