"""Blender from Python, headless, with the `bpy` wheel: a session in this process (`start_blender`, then
`install_extension` of a built zip into a throw-away user directory), and what the main job, the splat
bench and the Blender tests do in one: a movie strip, F12 to a PNG and back, a render with a GPU context,
the source frames to compare with, steps recorded to JSON as they finish.

bpy imports once per process: every user runs its session in a fresh Python (a subprocess).

Run as a script it is a render farm's command line, `blender -b FILE.blend -a`, with the wheel: a fresh
process with the extension installed in USER_DIR (enabled, as a farm's preferences have it) opens the
.blend and renders its animation, printing one JSON line: the files written, or the error that stopped it.

    python tools/blender_headless.py render FILE.blend --user USER_DIR [--frames 1-3]
"""
from __future__ import annotations

import importlib
import json
import os
import sys
import time
import traceback
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]  # the repository root = the extension root
SAMPLE = ROOT / "hypergs_blender" / "samples" / "sample.mp4"
EXTENSION_ID = "hypergs"
# Environment for a Blender without a GPU context on a machine that has Mesa's EGL: glvnd's libEGL then finds
# no driver, as on a machine without libegl-mesa0 (the engine must take its numpy path, not abort).
NO_EGL = {"__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent/no_egl_vendor.json"}


def step_recorder(results: dict, out_path):
    """Decorator factory for sessions: `@record(name)` runs the step at once and stores its result (or
    its traceback) under `name`, rewriting `out_path` as JSON after every step, so a session that dies
    still reports the steps it finished."""
    def record(name):
        def wrap(fn):
            try:
                results[name] = fn()
            except BaseException:
                results[name] = {"error": traceback.format_exc()}
            Path(out_path).write_text(json.dumps(results, indent=1, default=str))
            return fn
        return wrap
    return record


def start_blender(user_dir, block=("torch", "numba")):
    """Import bpy with HOME, caches and Blender's user resources in `user_dir` (must run before any
    other bpy import in the process). Modules in `block` are made unimportable first, as in a plain
    Blender (its Python has neither torch nor numba)."""
    user_dir = str(user_dir)
    for key in ("HOME", "XDG_CACHE_HOME", "XDG_CONFIG_HOME", "BLENDER_USER_RESOURCES"):
        os.environ[key] = user_dir
    for name in block:
        sys.modules[name] = None
    import bpy
    add_bundled_modules(bpy)
    return bpy


def add_bundled_modules(bpy) -> None:
    """Put the modules Blender bundles (OpenImageIO, pxr, ...: the bpy wheels from 4.4 on) on this Python's path, as
    Blender's own Python has them; the bpy module keeps them inside its package, off the path."""
    bundled = (Path(bpy.utils.resource_path("LOCAL")) / "python" / "lib" /
               f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages")
    if bundled.is_dir() and str(bundled) not in sys.path:
        sys.path.append(str(bundled))


def install_extension(bpy, zip_path):
    """Install and enable the zip in the user_default repository; returns the add-on module."""
    result = bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo="user_default",
                                                      enable_on_install=True)
    if result != {"FINISHED"}:
        raise RuntimeError(f"installing {zip_path} failed: {result}")
    return importlib.import_module(f"bl_ext.user_default.{EXTENSION_ID}")


def addon_module(addon, name: str):
    """A module of the installed extension (`addon`), e.g. "com.compat": reached at run time, so the
    sessions work with whichever Blender's glue the zip installed."""
    return importlib.import_module(f"{addon.__name__}.{name}")


def add_movie_strip(bpy, scene, path, frame_start=1, name="clip"):
    """A movie strip stretched to the scene's output size (set it first), as `source_frames` resizes the
    frames it is compared with (Add > Movie's default, Scale to Fit, would letterbox another aspect)."""
    editor = scene.sequence_editor_create()
    strips = editor.strips if hasattr(editor, "strips") else editor.sequences
    strip = strips.new_movie(name=name, filepath=str(path), channel=1, frame_start=frame_start,
                             fit_method="STRETCH")
    editor.active_strip = strip
    return strip


def in_gpu_context(bpy, work) -> dict:
    """Run `work(depsgraph) -> dict` inside a render whose engine has a GPU context (bl_use_gpu_context:
    Blender has no window in background mode, so this is where the gpu module draws offscreen), with a
    throw-away 4 x 4 frame; the scene's engine and size are put back. An exception in `work` comes back as
    {"error": "Type: message"} (it cannot cross Blender's render call)."""
    found = {}

    class Probe(bpy.types.RenderEngine):
        bl_idname = "HYPERGS_GPU_PROBE"
        bl_label = "probe"
        bl_use_gpu_context = True

        def render(self, depsgraph):
            try:
                found.update(work(depsgraph))
            except Exception as e:
                found["error"] = f"{type(e).__name__}: {e}"
            self.end_result(self.begin_result(0, 0, 4, 4))

    r = bpy.context.scene.render
    saved = r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage
    bpy.utils.register_class(Probe)
    r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage = Probe.bl_idname, 4, 4, 100
    try:
        bpy.ops.render.render()
    finally:
        r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage = saved
        bpy.utils.unregister_class(Probe)
    return found


def set_strip_range(strip, first: int, end: int) -> None:
    """Move a strip's handles: it shows timeline frames [first, end)."""
    if hasattr(strip, "left_handle"):  # Blender 5.2+
        strip.left_handle, strip.right_handle = first, end
    else:
        strip.frame_final_start, strip.frame_final_end = first, end


def render_png(bpy, scene, frame: int, path) -> float:
    """F12 of one frame, saved as an 8-bit PNG with the scene's colour management; returns seconds."""
    scene.frame_set(frame)
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_depth = "8"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.filepath = str(path)
    started = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - started


def read_png(bpy, path) -> np.ndarray:
    """An 8-bit PNG as float32 [H, W, 3] in [0, 1] (stored bytes / 255), rows top to bottom."""
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        w, h = image.size
        pixels = np.empty(w * h * image.channels, np.float32)
        image.pixels.foreach_get(pixels)
        return pixels.reshape(h, w, image.channels)[::-1, :, :3].copy()
    finally:
        bpy.data.images.remove(image)


def source_frames(path, indices, width, height) -> dict:
    """{index: float32 [H, W, 3] in [0, 1]} source frames, resized (stretched) to width x height."""
    from hypergs_blender.io.frames import iter_frames
    from hypergs_blender.io.images import resize_exact
    return {i: resize_exact(f, width, height).astype(np.float32) / 255 for i, f in iter_frames(path, indices)}


def exit_session(status: int = 0) -> None:
    """End a session's process without bpy's teardown (slow; bpy 4.2 segfaults at exit once a render
    engine is registered, 4.5 can hang), removing the session's temporary folder as Blender's exit would
    (frame caches of unsaved files are there)."""
    bpy = sys.modules.get("bpy")
    if bpy is not None and bpy.app.tempdir:
        import shutil
        shutil.rmtree(bpy.app.tempdir, ignore_errors=True)
    sys.stdout.flush()
    sys.stderr.flush()
    os._exit(status)


def render_animation_main(argv=None) -> int:
    """The script's `render` command (see the module doc); exit status 1 when the render failed."""
    import argparse
    parser = argparse.ArgumentParser(description="blender -b FILE.blend -a, with the bpy wheel")
    parser.add_argument("command", choices=["render"])
    parser.add_argument("blend")
    parser.add_argument("--user", required=True, help="Blender's user folder, the extension installed there")
    parser.add_argument("--frames", help="FIRST-LAST instead of the scene's frame range")
    args = parser.parse_args(argv)
    bpy = start_blender(args.user)
    import addon_utils
    addon_utils.enable(f"bl_ext.user_default.{EXTENSION_ID}", default_set=True)
    bpy.ops.wm.open_mainfile(filepath=str(Path(args.blend).resolve()))
    scene = bpy.context.scene
    if args.frames:
        scene.frame_start, scene.frame_end = map(int, args.frames.split("-"))
    before = set(Path(bpy.path.abspath(scene.render.filepath)).parent.glob("*"))
    report = {"frames": [scene.frame_start, scene.frame_end]}
    started = time.perf_counter()
    try:
        bpy.ops.render.render(animation=True)
        report["error"] = None
    except RuntimeError as e:  # an ERROR report stops the animation (as `blender -a` does)
        report["error"] = str(e)
    report["seconds"] = time.perf_counter() - started
    written = set(Path(bpy.path.abspath(scene.render.filepath)).parent.glob("*")) - before
    report["written"] = sorted(str(p) for p in written)
    print(json.dumps(report), flush=True)
    return 1 if report["error"] else 0


if __name__ == "__main__":
    exit_session(render_animation_main())
