"""The GPU splats (engine/splat.py) in the real bpy 5.0.1 wheel against the numpy rasterizer they replace:
F12 and Ctrl-F12 through the engine's GPU path (bl_use_gpu_context; on a machine without a GPU, Mesa's
software OpenGL through EGL) of two clips with hard Gaussians (needles, off-image, huge) at a
non-square size, the windowed drawing of the viewport, and F12 in a Blender without a GPU context, which
must take the numpy path (bpy 5.0.1 aborts the process when a bl_use_gpu_context engine renders there).

Two Blender sessions in subprocesses (this file run as a script), as in test_blender_addon.py: one as the
machine is, one with EGL hidden (tools/blender_headless.NO_EGL). The GPU tests skip only where the machine has no
EGL display at all (Debian packages libegl1 libegl-mesa0 libgl1-mesa-dri, which .ci/run installs).
"""
import os

import numpy as np
import pytest
from blender_headless import NO_EGL, in_gpu_context, install_extension
from blender_session import addon_module, run_blender_session, session_main, start_session, step
from conftest import hard_params

ENCODER = "floor"  # nothing is encoded here
SIZE = (333, 201)  # the render size: non-square, odd
CLIPS = {"needles": ((96, 64), 2500), "tall": ((50, 80), 1500)}  # name: (canvas, Gaussians per frame)
FRAMES = 2
MEAN_ERROR = 1 / 255  # mean absolute difference GPU vs numpy, scene-linear RGB
SESSION_TIMEOUT = 400


# ----------------------------------------------------------------------------------------------------
# pytest side

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    return run_blender_session(__file__, tmp_path_factory.mktemp("splat"), ENCODER, SESSION_TIMEOUT)


@pytest.fixture(scope="module")
def no_egl_session(tmp_path_factory):
    return run_blender_session(__file__, tmp_path_factory.mktemp("splat_no_egl"), ENCODER, SESSION_TIMEOUT,
                               env=NO_EGL)


def gpu_or_skip(session):
    r = step(session, "install")
    if not r["gpu_context_possible"]:
        pytest.skip("no GPU context on this machine (no EGL display: install libegl1 libegl-mesa0 libgl1-mesa-dri)")
    assert r["bl_use_gpu_context"]


def test_f12_on_the_gpu_matches_numpy(session):
    gpu_or_skip(session)
    r = step(session, "f12")
    assert r["gpu_images"] == 1 and r["size"] == [SIZE[1], SIZE[0], 4]
    assert r["mean_error"] <= MEAN_ERROR and r["max_error"] < 1e-3, r
    assert 0.1 < r["brightness"] < 1 and r["alpha"] == [1.0, 1.0]


def test_ctrl_f12_on_the_gpu_matches_numpy_on_every_frame(session):
    gpu_or_skip(session)
    r = step(session, "ctrl_f12")
    assert r["result"] == ["FINISHED"] and r["gpu_images"] == FRAMES
    for frame in r["frames"]:
        assert frame["mean_error"] <= MEAN_ERROR and frame["max_error"] < 1e-3, r
    assert r["frames_differ"] > 0.02


def test_viewport_window_matches_numpy(session):
    gpu_or_skip(session)
    r = step(session, "viewport_window")
    assert r["windows"] == r["expected_windows"]
    for name, case in r["cases"].items():
        assert case["mean_error"] <= MEAN_ERROR and case["max_error"] < 1e-3, (name, case)


def test_without_egl_f12_takes_the_numpy_path(no_egl_session):
    r = step(no_egl_session, "install")
    if r["egl_still_found"]:
        pytest.skip("hiding EGL through glvnd's __EGL_VENDOR_LIBRARY_FILENAMES has no effect on this machine")
    assert not r["gpu_context_possible"] and not r["bl_use_gpu_context"]
    r = step(no_egl_session, "f12")
    assert r["gpu_images"] == 0 and r["size"] == [SIZE[1], SIZE[0], 4]
    assert r["max_error"] < 1e-5 and r["brightness"] > 0.05


# ----------------------------------------------------------------------------------------------------
# Blender side (run as a script: python test_blender_splat.py ZIP WORKDIR OUT.json)

def run_session(zip_path, work, out_path):
    bpy, record, results = start_session(work, out_path)
    ctx = {}

    @record("install")
    def _():
        addon = install_extension(bpy, zip_path)
        ctx["addon"] = addon
        splat = addon_module(addon, "engine.splat")
        engine = addon_module(addon, "engine").HyperGSRenderEngine
        possible = splat.gpu_context_possible()
        return dict(gpu_context_possible=possible, bl_use_gpu_context=engine.bl_use_gpu_context,
                    egl_still_found=possible and NO_EGL.items() <= os.environ.items())

    addon = ctx["addon"]
    splat = addon_module(addon, "engine.splat")
    geometry = addon_module(addon, "engine.geometry")
    from hypergs_blender.gaussians import GaussianVideo
    from hypergs_blender.io.npz import save_npz

    scene = bpy.context.scene
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    for k, (name, (canvas, n)) in enumerate(CLIPS.items()):
        params = np.stack([hard_params(n, seed=10 * k + t, invalid=False) for t in range(FRAMES)])  # files refuse NaN
        params[..., 5:8] *= 0.3  # a frame of mid-grey brightness, not a white-out
        save_npz(GaussianVideo(params, *canvas), work / f"{name}.npz")
        bpy.ops.hypergs.import_clip(filepath=str(work / f"{name}.npz"))
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = *SIZE, 100
    scene.frame_start, scene.frame_end = 1, FRAMES
    settings = scene.render.image_settings
    settings.file_format, settings.color_mode, settings.color_depth, settings.exr_codec = "OPEN_EXR", "RGBA", "32", "ZIP"

    # Count the images the GPU path makes (engine.render calls splat.render_clips through the module).
    gpu_images = []
    drawn = splat.render_clips

    def counting(*args, **kwargs):
        rgba = drawn(*args, **kwargs)
        gpu_images.extend([] if rgba is None else [rgba.shape])
        return rgba
    splat.render_clips = counting

    def numpy_reference():
        """The engine's numpy path (the fallback) on the evaluated clips of the current frame."""
        return geometry.render_clips(geometry.evaluated_clips(bpy.context.evaluated_depsgraph_get()), *SIZE)

    def compare(path, reference):
        image = bpy.data.images.load(str(path), check_existing=False)
        try:
            pixels = np.empty(len(image.pixels), np.float32)
            image.pixels.foreach_get(pixels)
            pixels = pixels.reshape(image.size[1], image.size[0], 4)
        finally:
            bpy.data.images.remove(image)
        d = np.abs(pixels[..., :3] - reference[..., :3])
        return dict(size=list(pixels.shape), mean_error=float(d.mean()), max_error=float(d.max()),
                    brightness=float(reference[..., :3].mean()),
                    alpha=[float(pixels[..., 3].min()), float(pixels[..., 3].max())]), pixels

    @record("f12")
    def _():
        del gpu_images[:]
        scene.frame_set(1)
        scene.render.filepath = str(work / "f12.exr")
        bpy.ops.render.render(write_still=True)
        found, _ = compare(work / "f12.exr", numpy_reference())
        return dict(found, gpu_images=len(gpu_images))

    @record("ctrl_f12")
    def _():
        del gpu_images[:]
        scene.render.filepath = str(work / "anim_")
        result = bpy.ops.render.render(animation=True)
        frames, images = [], []
        for frame in range(1, FRAMES + 1):
            scene.frame_set(frame)
            found, pixels = compare(work / f"anim_{frame:04d}.exr", numpy_reference())
            frames.append(found)
            images.append(pixels)
        return dict(result=sorted(result), frames=frames, gpu_images=len(gpu_images),
                    frames_differ=float(np.abs(images[0] - images[-1]).mean()))

    if results["install"].get("gpu_context_possible"):
        @record("viewport_window")
        def _():
            return viewport_window_check(bpy, addon, numpy_reference)
    return results


def viewport_window_check(bpy, addon, numpy_reference):
    """What view_draw does, short of the window Blender has none of here: the part of the frame inside the
    region (draw.visible_window), splatted into a SplatImage of that size (inside a render with a GPU context)
    and compared with the same part of the numpy render."""
    draw = addon_module(addon, "engine.draw")
    splat = addon_module(addon, "engine.splat")
    from hypergs_blender.splat import splat_rows

    scene = bpy.context.scene
    scene.frame_set(1)
    clips = [(p, cw, ch) for _, p, cw, ch in addon_module(addon, "engine.geometry").evaluated_clips(
        bpy.context.evaluated_depsgraph_get())]
    reference = numpy_reference()[::-1]  # rows top-down, as the windows count them
    # frame rects (x, y, w, h) in a 400 x 300 region, each rendering SIZE, and the windows they must give
    cases = {"inside": ((30.0, 40.0, *SIZE), (0, 0, *SIZE)),
             "out at the bottom left": ((-100.0, -50.0, *SIZE), (100, 0, 233, 151)),
             "out at the top right": ((200.0, 200.0, *SIZE), (0, 101, 200, 100)),
             "between pixels": ((-10.5, 120.25, *SIZE), (10, 21, 323, 180))}
    windows = {name: list(draw.visible_window(rect, 400, 300)[1]) for name, (rect, _) in cases.items()}

    def work(depsgraph) -> dict:
        found = {}
        for name, window in windows.items():
            x, y, w, h = window
            image = splat.SplatImage(w, h)
            try:
                image.draw(splat_rows(clips, *SIZE, window), (x, y))
                pixels = image.read()[::-1]
            finally:
                image.free()
            d = np.abs(pixels[..., :3] - reference[y:y + h, x:x + w, :3])
            found[name] = dict(mean_error=float(d.mean()), max_error=float(d.max()))
        return found

    found = in_gpu_context(bpy, work)
    if "error" in found:
        raise RuntimeError(found["error"])
    return dict(windows=windows, expected_windows={name: list(w) for name, (_, w) in cases.items()}, cases=found)


if __name__ == "__main__":
    session_main(run_session)
