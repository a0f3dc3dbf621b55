"""Viewport drawing for the engine's Rendered mode: the part of the render frame that shows in the region is
splatted on the GPU (engine/splat.py) at one image pixel per region pixel and drawn through the display-space
shader (view transform and display device apply). Only called where Blender has a GPU context."""
from __future__ import annotations

import math

from . import splat
from .geometry import evaluated_clips
from ..hypergs_blender.splat import splat_rows


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


def visible_window(rect, region_width: int, region_height: int):
    """The frame rect (x, y, w, h) (region pixels, y up) rendered at one image pixel per region pixel:
    the image size (W, H) and the window of it inside the region, (x, y, w, h) in image pixels from its
    top-left corner; the window is None when no part of the frame shows."""
    x, y, w, h = rect
    size = (max(1, round(w)), max(1, round(h)))
    sx, sy = size[0] / max(w, 1e-9), size[1] / max(h, 1e-9)  # image pixels per region pixel
    j0, j1 = max(0, math.floor(-x * sx)), min(size[0], math.ceil((region_width - x) * sx))
    i0, i1 = max(0, math.floor((y + h - region_height) * sy)), min(size[1], math.ceil((y + h) * sy))
    if j1 <= j0 or i1 <= i0:
        return size, None
    return size, (j0, i0, j1 - j0, i1 - i0)


class ViewCache:
    """What the viewport shows: the drawn window's key and its splat image (kept between frames: playback
    redraws into the same offscreens)."""

    def __init__(self):
        self.key = None
        self.image = None

    def invalidate(self):
        self.key = None

    def image_of_size(self, width: int, height: int):
        if self.image is None or self.image.size != (width, height):
            if self.image is not None:
                self.image.free()
            self.image = splat.SplatImage(width, height)
        return self.image


def view_draw(engine, context, depsgraph, cache: ViewCache) -> None:
    """Draw the current frame into the region."""
    import gpu
    from gpu_extras.presets import draw_texture_2d

    scene = depsgraph.scene
    rect = frame_rect(context, scene)
    size, window = visible_window(rect, context.region.width, context.region.height)
    if window is None:
        return
    key = (scene.frame_current + scene.frame_subframe, size, window)
    if cache.key != key:
        view_layer = depsgraph.view_layer

        def visible(ob):
            try:
                return ob.original.visible_get(view_layer=view_layer)
            except (TypeError, RuntimeError, ReferenceError):
                return True

        clips = [(params, cw, ch) for _, params, cw, ch in evaluated_clips(depsgraph, visible)]
        cache.image_of_size(window[2], window[3]).draw(splat_rows(clips, *size, window), window[:2])
        cache.key = key
    x, y, w, h = rect
    j, i, ww, wh = window
    sx, sy = w / size[0], h / size[1]  # region pixels per image pixel
    gpu.state.blend_set("ALPHA_PREMULT")
    engine.bind_display_space_shader(scene)
    draw_texture_2d(cache.image.texture, (x + j * sx, y + h - (i + wh) * sy), ww * sx, wh * sy)
    engine.unbind_display_space_shader()
    gpu.state.blend_set("NONE")
