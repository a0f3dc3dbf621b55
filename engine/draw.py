"""Viewport drawing for the engine's Rendered mode: the frame is rasterized on the CPU (as F12 does)
and drawn as a texture through the display-space shader (view transform and display device apply).
Only called where Blender has a GPU context (never in background mode)."""
from __future__ import annotations

import numpy as np

from .geometry import evaluated_clips, render_clips


def frame_rect(context, scene) -> tuple[float, float, float, float]:
    """Where the render frame lies in the region: (x, y, width, height) in region pixels. In camera
    view, the camera border; otherwise the largest rectangle of the output's aspect that fits."""
    region, rv3d = context.region, context.region_data
    if rv3d is not None and rv3d.view_perspective == "CAMERA" and scene.camera is not None:
        from bpy_extras.view3d_utils import location_3d_to_region_2d
        cam = scene.camera
        corners = [cam.matrix_world @ v for v in cam.data.view_frame(scene=scene)]
        points = [location_3d_to_region_2d(region, rv3d, c) for c in corners]
        if all(p is not None for p in points):
            xs, ys = [p.x for p in points], [p.y for p in points]
            return min(xs), min(ys), max(xs) - min(xs), max(ys) - min(ys)
    r = scene.render
    aspect = (r.resolution_x * r.pixel_aspect_x) / max(1, r.resolution_y * r.pixel_aspect_y)
    w, h = region.width, region.height
    if w / h > aspect:
        fw, fh = h * aspect, h
    else:
        fw, fh = w, w / aspect
    return (w - fw) / 2, (h - fh) / 2, fw, fh


def raster_size(rect_w: float, rect_h: float, max_size: int) -> tuple[int, int]:
    scale = min(1.0, max_size / max(rect_w, rect_h, 1))
    return max(1, round(rect_w * scale)), max(1, round(rect_h * scale))


def make_texture(rgba: np.ndarray):
    import gpu
    h, w = rgba.shape[:2]
    buffer = gpu.types.Buffer("FLOAT", w * h * 4, np.ascontiguousarray(rgba, np.float32).ravel())
    return gpu.types.GPUTexture((w, h), format="RGBA16F", data=buffer)


def view_draw(engine, context, depsgraph, cache, max_size: int):
    """Draw the current frame; returns the cache to keep ((key, texture) or None)."""
    import gpu
    from gpu_extras.presets import draw_texture_2d

    scene = depsgraph.scene
    x, y, w, h = frame_rect(context, scene)
    size = raster_size(w, h, max_size)
    key = (scene.frame_current, size)
    if cache is None or cache[0] != key:
        view_layer = depsgraph.view_layer

        def visible(ob):
            try:
                return ob.original.visible_get(view_layer=view_layer)
            except (TypeError, RuntimeError, ReferenceError):
                return True

        rgba = render_clips(evaluated_clips(depsgraph, visible), size[0], size[1])
        cache = (key, make_texture(rgba))
    gpu.state.blend_set("ALPHA_PREMULT")
    engine.bind_display_space_shader(scene)
    draw_texture_2d(cache[1], (x, y), w, h)
    engine.unbind_display_space_shader()
    gpu.state.blend_set("NONE")
    return cache
