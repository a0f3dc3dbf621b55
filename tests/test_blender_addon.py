"""The extension in the real bpy 5.0.1 wheel: install the built zip into a throw-away user directory,
import a movie as Gaussians, render with F12, edit points, Geometry Nodes, save/reload, errors, cancel.
(The Sequencer's conversion: test_blender_sequencer.py.)

bpy can be imported once per process, so one Blender session runs in a subprocess (this file run as
a script, with torch and numba made unimportable, as in Blender's own Python: tests/blender_session.py)
and writes what it measured to JSON; the tests below check it. Encoder: $HYPERGS_ENCODER, else ENCODER below.
$HYPERGS_BLENDER_PYTHON runs the session with another Python that has bpy (e.g. bpy 4.2 LTS).
"""
import os
from pathlib import Path

import numpy as np
import pytest
from blender_session import (Recorder, addon_module, attempt_unchanged, diff, display_points, mesh_frames,
                             operator_defaults, run_blender_session, session_main, snapshot, start_session, step,
                             types_namespace)
from blender_headless import SAMPLE, install_extension, read_png, render_png
from conftest import make_pan_clip

from hypergs_blender.encode import QUALITY, FloorEncoder, plan_layout
from hypergs_blender.raster import SIGMA_CUTOFF

ROOT = Path(__file__).resolve().parents[1]
CLIP_NAME = "pan"  # the session's movie: a 432 x 240, 70-frame pan that conftest.make_pan_clip writes
# The encoder the session converts with: the bundled network (HYPERGS_ENCODER=floor for the no-learning floor).
ENCODER = "bundled"
REQUESTED = 1000  # Gaussians per frame asked for (Quality: Custom) ...
GAUSSIANS = plan_layout(432, 240, FloorEncoder.stride, gaussians=REQUESTED).count  # ... what that gives at 432 x 240
REENCODED = plan_layout(432, 240, FloorEncoder.stride, gaussians=500).count
SAMPLE_DRAFT = plan_layout(256, 144, FloorEncoder.stride, cell=QUALITY["draft"]["cell"]).count
RENDER_FRAMES = (1, 35, 70)  # scene frames; the clip starts at frame 1, so source index = frame - 1
SIZES = ((256, 256), (864, 480))
PSNR_MARGIN = 0.3  # dB the F12 render may lose to the core's own encode -> render (8-bit PNG, dither)
SESSION_TIMEOUT = 600


# ----------------------------------------------------------------------------------------------------
# pytest side

@pytest.fixture(scope="module")
def session(tmp_path_factory):
    work = tmp_path_factory.mktemp("blender")
    make_pan_clip(work / f"{CLIP_NAME}.mp4")
    return run_blender_session(__file__, work, ENCODER, SESSION_TIMEOUT)


def test_install_and_enable(session):
    r = step(session, "install")
    assert r["module"].startswith("bl_ext.user_default.hypergs")
    assert "/extensions/user_default/hypergs/" in r["file"]
    assert r["operators"] == ["convert_strip", "edit_frame", "embed_clip", "export_clip", "import_clip",
                              "import_video", "pack_cache", "reencode", "unpack_cache"]
    assert r["engine"] and not r["torch_importable"]


@pytest.mark.parametrize("case", ["corrupt_video", "truncated_video", "text_as_mp4", "missing_file", "no_room",
                                  "no_strip", "not_a_movie_strip"])
def test_errors_are_reported_and_change_nothing(session, case):
    r = step(session, "errors")[case]
    assert r["raised"], "the error must reach the user (a RuntimeError from bpy.ops in background mode)"
    assert "Traceback" not in r["message"]
    assert r["expect"].lower() in r["message"].lower(), r["message"]
    assert r["unchanged"], r["diff"]


def test_bundled_network_loads_without_torch_or_says_why(session):
    r = step(session, "bundled_encoder")
    if r["has_onnx"]:  # the packaged ONNX model runs on onnxruntime (torch is not importable here)
        assert r["problem"] is None and r["encoder"] == "network-onnx", r["problem"]
    else:
        assert r["problem"].startswith("HyperGSError") and r["raised"] and r["unchanged"], r


def test_preferences_choose_the_execution_provider_and_threads(session):
    r = step(session, "providers")
    assert r["defaults"] == ["AUTO", 0] and "CPUExecutionProvider" in r["available"]
    # Asked for CUDA (absent from the bundled onnxruntime here): the CPU runs it, with the threads asked for.
    assert r["asked_cuda"] == dict(provider="CPUExecutionProvider", threads=1, described="network-onnx on CPU (1 thread)")
    # (The policy itself, providers_for, is tested without Blender: test_runtime.py.)
    assert ["prop", "transformer_weights", None] in r["preferences_drawn"]
    # None set: the preferences name the bundled transformer (test_blender_transformer.py sets a folder).
    assert any(c[1].startswith("HyperGS transformer: ") and c[1].endswith("hypergs_transformer.json")
               for c in r["preferences_drawn"] if c[0] == "label"), r["preferences_drawn"]


def test_import_dialog_gaussians_follow_the_resolution(session):
    r = step(session, "import_dialog")
    standard = QUALITY["standard"]["cell"]
    for name, (w, h) in (("pan", (432, 240)), ("sample", (256, 144))):
        count = plan_layout(w, h, FloorEncoder.stride, cell=standard).count
        assert any(line.startswith(f"{count:,} Gaussians per frame") and f"at {w} x {h}" in line
                   for line in r[name]["labels"]), r[name]
    assert any(line.startswith("30 frames") for line in r["sample"]["labels"])  # frames 11-40
    assert r["reversed_range"] == ["Last Frame 5 comes before First Frame 10"]


def test_cancelled_import_changes_nothing(session):
    r = step(session, "cancel")
    assert r["result"] == ["CANCELLED"]
    assert r["progress_calls"] >= 1 and r["unchanged"], r["diff"]
    assert r["thread_job_cancelled"] and r["thread_job_left"] == []  # no cache file, nor the folder it made


def test_import_video(session):
    r = step(session, "import_video")
    assert r["result"] == ["FINISHED"]
    # Quality Draft, source frames 11-40: the Gaussians per frame follow the video's 256 x 144.
    assert (r["num_frames"], r["source_start"], r["gaussians_per_frame"]) == (30, 10, SAMPLE_DRAFT)
    assert r["quality"] == "DRAFT"  # the clip's Re-encode starts from the options used
    assert r["frame_start"] == r["scene_frame_start"] and r["active"] == "sample"
    assert r["camera"] == "HyperGS Camera"  # F12 needs one; the scene had none
    assert r["display_points"] in (None, SAMPLE_DRAFT)


def test_imported_clip_shows_one_frame_at_a_time(session):
    r = step(session, "clip")
    assert r["result"] == ["FINISHED"]
    # The mesh holds the scene frame's Gaussians (the rest are in the clip's frame cache).
    assert r["num_frames"] == 70 and r["gaussians_per_frame"] == GAUSSIANS and r["vertices"] == GAUSSIANS
    assert r["frame_start"] == 1 and r["canvas"] == [432, 240] and r["fps"] == pytest.approx(24)
    assert r["evaluated_vertices"] == GAUSSIANS and r["cache"]
    assert r["engine"] == "HYPERGS" and r["view_transform"] == "Standard"
    assert r["attributes"] == {"color": "FLOAT_COLOR", "rotation": "FLOAT", "scale": "FLOAT2"}
    assert r["psnr"] > 10 and abs(r["psnr"] - r["reference_psnr"]) < 1.0
    # What ran, shown in the panel and the report.
    assert r["encoder"] == ("floor" if os.environ.get("HYPERGS_ENCODER") == "floor" else "network-onnx on CPU (all cores)")
    assert r["display_points"] in (None, GAUSSIANS)  # a point cloud shows the frame in Solid mode


def test_ctrl_f12_renders_the_animation(session):
    r = step(session, "animation")
    assert r["files"] == ["f_0001.png", "f_0002.png", "f_0003.png"]
    assert r["first_vs_last_psnr"] < 60  # the frames follow the clip


@pytest.mark.parametrize("size", [f"{w}x{h}" for w, h in SIZES])
def test_f12_matches_the_source(session, size):
    r = step(session, "render")[size]
    for frame in map(str, RENDER_FRAMES):
        f = r[frame]
        assert f["size"] == [int(v) for v in size.split("x")][::-1]
        # What the core's encode -> render reaches with the same encoder, minus a small margin.
        assert f["psnr_source"] > f["psnr_reference"] - PSNR_MARGIN, f
        # The F12 PNG is the core's render (exact stretched covariance), up to 8-bit output.
        assert f["psnr_vs_core"] > 40, f


def test_moving_a_point_in_edit_mode_changes_the_render_there(session):
    r = step(session, "move_point")
    assert r["changed_near_old"] > 0.01 and r["changed_near_new"] > 0.01
    assert r["max_change_far"] < 2 / 255
    assert r["psnr_vs_core_edited"] > 40
    assert r["other_frame_unchanged"]
    # `color` is active in Edit Mode (Blender 5.1 made `rotation` active: com/compat.py), and stays the user's pick
    assert r["active_in_edit_mode"] == ["color", "scale"]


def test_delete_and_recolour_in_edit_mode_show_in_render(session):
    r = step(session, "delete_recolour")
    assert r["points_in_frame"] == GAUSSIANS - 1 and r["points_in_other_frame"] == GAUSSIANS
    assert r["recoloured"] == [1.0, 0.0, 0.0, 1.0]
    assert r["psnr_vs_core_edited"] > 40


def test_geometry_nodes_set_position_shows_in_render(session):
    r = step(session, "geometry_nodes")
    assert r["psnr_vs_unmodified"] < 30  # it moved
    assert r["psnr_vs_core_shifted"] > 40  # exactly as the core renders the shifted Gaussians


def test_save_and_reload_keeps_every_frame(session):
    r = step(session, "save_reload")
    assert r["frames_equal"] and r["settings_equal"]
    assert r["edited_frames"] == [34, 49] and r["vertices_at_50"] == GAUSSIANS - 1
    assert r["render_psnr_vs_before"] > 50


def test_edit_current_frame_shows_only_that_frame(session):
    r = step(session, "edit_frame")
    assert r["mode"] == "EDIT"
    assert r["visible"] == GAUSSIANS and r["shown"] == r["clip_frame"]


def test_reencode_replaces_points_and_keeps_modifiers(session):
    r = step(session, "reencode")
    assert r["result"] == ["FINISHED"]
    assert (r["vertices"], r["gaussians_per_frame"]) == (REENCODED, REENCODED)
    assert r["modifiers"] == ["HyperGS Points", "Shift"] and r["display_points"] in (None, REENCODED)
    assert r["psnr"] != r["psnr_before"]
    assert r["mesh"] == CLIP_NAME and r["meshes"] == 1  # the edited frames' meshes are gone (discarded)


# ----------------------------------------------------------------------------------------------------
# Blender side (run as a script: python test_blender_addon.py ZIP WORKDIR OUT.json)

def run_session(zip_path, work, out_path):
    CLIP = work / f"{CLIP_NAME}.mp4"
    bpy, record, results = start_session(work, out_path)
    ctx = {}

    @record("install")
    def _():
        addon = install_extension(bpy, zip_path)
        ctx["addon"] = addon
        return dict(module=addon.__name__, file=addon.__file__,
                    operators=sorted(n for n in dir(bpy.ops.hypergs) if not n.startswith("_")),
                    engine="HYPERGS" in {getattr(e, "bl_idname", None)
                                         for e in bpy.types.RenderEngine.__subclasses__()},
                    torch_importable=_importable("torch"))

    addon = ctx["addon"]
    from hypergs_blender.encode import EncodeSettings, encode_video
    from hypergs_blender.io.frames import iter_frames
    from hypergs_blender.io.images import resize_exact
    from hypergs_blender.metrics import psnr
    from hypergs_blender.render import render_frames, render_params
    encoder = addon_module(addon, "hypergs_blender.runtime").make_encoder()
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = 24, 1.0

    @record("errors")
    def _():
        data = CLIP.read_bytes()
        corrupt = Path(work) / "corrupt.mp4"  # container intact, frame data zeroed after the first frames
        start, stop = data.find(b"mdat") + 20000, data.find(b"moov") - 4
        assert 0 < start < stop, "expected mdat before moov"
        corrupt.write_bytes(data[:start] + bytes(stop - start) + data[stop:])
        truncated = Path(work) / "truncated.mp4"
        truncated.write_bytes(data[:len(data) // 2])
        text = Path(work) / "notes.mp4"
        text.write_text("this is not a video\n" * 100)
        cases = {}

        def attempt(name, expect, call):
            cases[name] = attempt_unchanged(bpy, expect, call)

        attempt("corrupt_video", "corrupt.mp4: cannot decode",
                lambda: bpy.ops.hypergs.import_video(filepath=str(corrupt)))
        attempt("truncated_video", "truncated.mp4",
                lambda: bpy.ops.hypergs.import_video(filepath=str(truncated)))
        attempt("text_as_mp4", "notes.mp4", lambda: bpy.ops.hypergs.import_video(filepath=str(text)))
        attempt("missing_file", "no such video file",
                lambda: bpy.ops.hypergs.import_video(filepath=str(Path(work) / "nothing.mp4")))
        import shutil
        disk_usage = shutil.disk_usage
        shutil.disk_usage = lambda folder: type(disk_usage(work))(10**9, 10**9 - 1000, 1000)  # 1,000 bytes free
        try:
            attempt("no_room", "which has 1,000 bytes", lambda: bpy.ops.hypergs.import_video(filepath=str(CLIP)))
        finally:
            shutil.disk_usage = disk_usage
        attempt("no_strip", "no strip selected", lambda: bpy.ops.hypergs.convert_strip())
        editor = scene.sequence_editor_create()
        strips = editor.strips if hasattr(editor, "strips") else editor.sequences
        length = dict(length=10) if bpy.app.version >= (5, 0, 0) else dict(frame_end=11)
        color = strips.new_effect(name="colour", type="COLOR", channel=3, frame_start=1, **length)
        editor.active_strip = color
        attempt("not_a_movie_strip", "not a movie strip", lambda: bpy.ops.hypergs.convert_strip())
        strips.remove(color)
        return cases

    @record("bundled_encoder")
    def _():
        encoder_module = addon_module(addon, "hypergs_blender.runtime")
        weights = Path(addon.__file__).parent / "hypergs_blender" / "weights"
        has_onnx = any(weights.glob("*.onnx"))
        saved = os.environ.get("HYPERGS_ENCODER")
        os.environ["HYPERGS_ENCODER"] = "bundled"
        try:
            try:
                name, error = encoder_module.make_encoder().name, None
            except Exception as e:
                name, error = None, f"{type(e).__name__}: {e}"
            before = snapshot(bpy)
            raised = False
            if error is not None:  # the operator reports it and changes nothing
                try:
                    bpy.ops.hypergs.import_video(filepath=str(SAMPLE))
                except RuntimeError:
                    raised = True
            unchanged = snapshot(bpy) == before
        finally:
            os.environ["HYPERGS_ENCODER"] = saved or ""
            encoder_module._cache.clear()
        return dict(has_onnx=has_onnx, encoder=name, problem=error, raised=raised, unchanged=unchanged)

    @record("providers")
    def _():
        encoder_module, prefs_module = addon_module(addon, "hypergs_blender.runtime"), addon_module(addon, "ops.preferences")
        prefs = bpy.context.preferences.addons[prefs_module.ADDON].preferences
        defaults = [prefs.device, prefs.threads]
        prefs.device, prefs.threads = "CUDAExecutionProvider", 1
        runtime = prefs_module.runtime(bpy.context)
        saved = os.environ.get("HYPERGS_ENCODER")
        os.environ["HYPERGS_ENCODER"] = "bundled"
        try:
            encoder = encoder_module.make_encoder(runtime)
            asked = dict(provider=encoder.provider, threads=encoder.session.get_session_options().intra_op_num_threads,
                         described=encoder_module.describe_encoder(encoder, runtime))
        finally:
            os.environ["HYPERGS_ENCODER"] = saved or ""
            prefs.device, prefs.threads = defaults
            encoder_module._cache.clear()
        layout = Recorder()
        type(prefs).draw(types_namespace(layout=layout, device=prefs.device, threads=prefs.threads,
                                         transformer_weights=prefs.transformer_weights), bpy.context)
        return dict(defaults=defaults, available=encoder_module.available_providers(), asked_cuda=asked,
                    preferences_drawn=[list(c) for c in layout.calls])

    @record("import_dialog")
    def _():
        op = bpy.types.HYPERGS_OT_import_video
        out = {}
        for name, path, frames in (("pan", CLIP, {}), ("sample", SAMPLE, dict(first_frame=11, last_frame=40)),
                                   ("reversed", SAMPLE, dict(first_frame=10, last_frame=5))):
            layout = Recorder()
            options = dict(operator_defaults(bpy, op), filepath=str(path), **frames)
            namespace = types_namespace(layout=layout, **options)
            namespace._source = lambda ns=namespace: op._source(ns)
            op.draw(namespace, bpy.context)
            out[name] = dict(labels=[c[1] for c in layout.calls if c[0] == "label"])
        out["reversed_range"] = [c for c in out.pop("reversed")["labels"] if "comes before" in c]
        return out

    @record("cancel")
    def _():
        plan = addon_module(addon, "hypergs_blender.encode").EncodePlan
        original = plan.chunks
        calls = []

        def cancelling(self, progress=None, *args, **kwargs):  # what Esc does: progress returns False
            def progress_then_cancel(done, total):
                calls.append(done)
                progress(done, total)
                return done == 0
            return original(self, progress_then_cancel, *args, **kwargs)

        before = snapshot(bpy)
        plan.chunks = cancelling
        try:
            result = bpy.ops.hypergs.import_video(filepath=str(CLIP))
        finally:
            plan.chunks = original
        after = snapshot(bpy)
        jobs = addon_module(addon, "ops.jobs")
        chosen = addon_module(addon, "hypergs_blender.encode").EncodeSettings(gaussians=500)
        target = Path(work) / "cancelled" / "clip.hgs"
        threaded = jobs.EncodeJob([jobs.Source(CLIP_NAME, str(CLIP))], [str(target)], chosen).start()
        threaded.cancel()
        threaded.join(60)
        return dict(result=sorted(result), progress_calls=len(calls), unchanged=before == after,
                    diff=diff(before, after), thread_job_cancelled=type(threaded.error).__name__ == "Cancelled",
                    thread_job_left=[str(p) for p in target.parent.parent.glob("cancelled*")])

    @record("import_video")
    def _():
        for o in list(bpy.data.objects):  # an empty scene, as in a Video Editing file: no camera either
            bpy.data.objects.remove(o)
        result = bpy.ops.hypergs.import_video(filepath=str(SAMPLE), quality="DRAFT", first_frame=11, last_frame=40)
        obj = bpy.data.objects["sample"]
        s = obj.hypergs
        out = dict(result=sorted(result), num_frames=s.num_frames, gaussians_per_frame=s.gaussians_per_frame,
                   source_start=s.source_start, quality=s.quality, frame_start=s.frame_start,
                   scene_frame_start=scene.frame_start,
                   camera=scene.camera.name if scene.camera else None,
                   active=bpy.context.view_layer.objects.active.name,
                   display_points=display_points(bpy, obj))
        bpy.data.meshes.remove(obj.data)  # the renders below show the pan clip alone
        return out

    reference = encode_video(str(CLIP), encoder, EncodeSettings(gaussians=REQUESTED))  # what Quality: Custom asks for
    truth = {i: f for i, f in iter_frames(str(CLIP), [f - 1 for f in RENDER_FRAMES])}

    @record("clip")
    def _():
        scene.frame_start = 1
        result = bpy.ops.hypergs.import_video(filepath=str(CLIP), quality="CUSTOM", gaussian_count=REQUESTED)
        obj = bpy.data.objects[CLIP_NAME]
        ctx["obj"] = obj
        s = obj.hypergs
        scene.frame_set(10)
        ev = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
        ref_psnr = float(np.mean([psnr(render_frames(reference, 432, 240, [i])[0], f / np.float32(255))
                                  for i, f in truth.items()]))
        return dict(result=sorted(result), num_frames=s.num_frames, gaussians_per_frame=s.gaussians_per_frame,
                    vertices=len(obj.data.vertices), frame_start=s.frame_start, cache=s.cache is not None,
                    canvas=[s.canvas_width, s.canvas_height],
                    fps=s.fps, evaluated_vertices=len(ev.data.vertices),
                    engine=scene.render.engine, view_transform=scene.view_settings.view_transform,
                    attributes={a.name: a.data_type for a in obj.data.attributes
                                if a.name in ("scale", "rotation", "color", "frame")},
                    psnr=s.psnr, reference_psnr=ref_psnr, seconds=s.encode_seconds, encoder=s.encoder,
                    display_points=display_points(bpy, obj))

    obj = ctx["obj"]

    def f12(frame, width, height, name):
        scene.render.resolution_x, scene.render.resolution_y = width, height
        scene.render.resolution_percentage = 100
        png = Path(work) / f"{name}.png"
        seconds = render_png(bpy, scene, frame, png)
        return read_png(bpy, png), seconds

    def core_render(params, width, height):
        return np.clip(render_params(params, 432, 240, width, height), 0, 1)

    @record("render")
    def _():
        out = {}
        for w, h in SIZES:
            row = {}
            for frame in RENDER_FRAMES:
                image, seconds = f12(frame, w, h, f"f{frame}_{w}x{h}")
                src = resize_exact(truth[frame - 1], w, h) / np.float32(255)
                ref = render_frames(reference, w, h, [frame - 1])[0]
                row[str(frame)] = dict(size=list(image.shape[:2]), seconds=seconds,
                                       psnr_source=float(psnr(image, src)), psnr_reference=float(psnr(ref, src)),
                                       psnr_vs_core=float(psnr(image, np.clip(ref, 0, 1))))
            out[f"{w}x{h}"] = row
        return out

    @record("animation")
    def _():
        scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 216, 120, 100
        scene.frame_start, scene.frame_end = 1, 3
        scene.render.image_settings.file_format = "PNG"
        scene.render.filepath = str(Path(work) / "anim" / "f_####")
        bpy.ops.render.render(animation=True)
        files = sorted(p.name for p in (Path(work) / "anim").glob("f_*.png"))
        first, last = (read_png(bpy, Path(work) / "anim" / name) for name in (files[0], files[-1]))
        scene.frame_start, scene.frame_end = 1, 70
        return dict(files=files, first_vs_last_psnr=float(psnr(last, first)))

    def frame_params(clip_frame):
        """The clip frame's parameters as the mesh holds them there (the scene goes to it), and the
        vertex index of each."""
        params = mesh_frames(bpy, obj, [clip_frame])[0]
        return params, np.arange(len(params))

    W, H = 864, 480

    @record("move_point")
    def _():
        import bmesh
        frame, clip_frame = 35, 34
        before, _ = f12(frame, W, H, "move_before")
        other_before, _ = f12(1, W, H, "move_other_before")
        params, index = frame_params(clip_frame)
        k = int(np.argmax(params[:, 5:8].sum(1) * (np.abs(params[:, 0]) < 0.6) * (np.abs(params[:, 1]) < 0.6)))
        vertex = int(index[k])
        delta = np.array([0.35, 0.25, 0.0])  # plane units (canvas height = 2)
        bpy.context.view_layer.objects.active = obj
        bpy.ops.object.mode_set(mode="EDIT")  # as Tab does: the clip's first time in Edit Mode
        attributes = obj.data.attributes
        bpy.context.view_layer.update()  # as the UI updates the depsgraph after an operator
        active = [attributes.active.name]
        attributes.active = attributes["scale"]  # the user picks another attribute in Edit Mode
        bpy.context.view_layer.update()
        active.append(attributes.active.name)
        bm = bmesh.from_edit_mesh(obj.data)
        bm.verts.ensure_lookup_table()
        bm.verts[vertex].co += _vec(delta)
        bmesh.update_edit_mesh(obj.data)
        bpy.ops.object.mode_set(mode="OBJECT")
        after, _ = f12(frame, W, H, "move_after")
        other_after, _ = f12(1, W, H, "move_other_after")
        edited, _ = frame_params(clip_frame)
        change = np.abs(after - before).max(-1)
        old = ((params[k, 0] + 1) * W / 2, (params[k, 1] + 1) * H / 2)
        new = ((edited[k, 0] + 1) * W / 2, (edited[k, 1] + 1) * H / 2)
        # the Gaussian's box (raster.box_radii: axis-aligned) reaches SIGMA_CUTOFF hypot(sx, sy) at its corners
        reach = SIGMA_CUTOFF * np.hypot(params[k, 2], params[k, 3]) * W / 432 + 2
        yy, xx = np.mgrid[0:H, 0:W] + 0.5
        near_old = np.hypot(xx - old[0], yy - old[1]) < 2
        near_new = np.hypot(xx - new[0], yy - new[1]) < 2
        far = (np.hypot(xx - old[0], yy - old[1]) > reach) & (np.hypot(xx - new[0], yy - new[1]) > reach)
        return dict(vertex=vertex, changed_near_old=float(change[near_old].max()),
                    changed_near_new=float(change[near_new].max()), max_change_far=float(change[far].max()),
                    psnr_vs_core_edited=float(psnr(after, core_render(edited, W, H))),
                    other_frame_unchanged=bool(np.abs(other_after - other_before).max() < 1e-6),
                    active_in_edit_mode=active)

    @record("delete_recolour")
    def _():
        import bmesh
        frame, clip_frame = 50, 49
        bpy.context.view_layer.objects.active = obj
        params, index = frame_params(clip_frame)  # (the scene goes to `frame`)
        order = np.argsort(-params[:, 5:8].sum(1))
        recolour, delete = int(index[order[0]]), int(index[order[1]])
        bpy.ops.hypergs.edit_frame()

        def select(vertex):
            bm = bmesh.from_edit_mesh(obj.data)
            bm.verts.ensure_lookup_table()
            for v in bm.verts:
                v.select_set(False)
            bm.verts[vertex].select_set(True)
            bmesh.update_edit_mesh(obj.data)

        select(recolour)
        bpy.ops.mesh.attribute_set(value_color=(1.0, 0.0, 0.0, 1.0))  # Mesh > Set Attribute
        select(delete)
        bpy.ops.mesh.delete(type="VERT")
        bpy.ops.object.mode_set(mode="OBJECT")
        in_frame = len(obj.data.vertices)
        recoloured = list(obj.data.attributes["color"].data[recolour - (delete < recolour)].color)
        after, _ = f12(frame, W, H, "recolour_after")
        edited, _ = frame_params(clip_frame)
        return dict(points_in_frame=in_frame, points_in_other_frame=len(frame_params(clip_frame + 1)[0]),
                    recoloured=recoloured, psnr_vs_core_edited=float(psnr(after, core_render(edited, W, H))))

    @record("geometry_nodes")
    def _():
        frame = 1
        plain, _ = f12(frame, W, H, "gn_before")
        mod = obj.modifiers.new("Shift", "NODES")
        mod.node_group = set_position_group(bpy, (0.25, 0.0, 0.0))
        shifted, _ = f12(frame, W, H, "gn_after")
        params, _ = frame_params(frame - 1)
        params[:, 0] += 0.25 / (432 / 240)  # plane x -> canvas x
        return dict(psnr_vs_unmodified=float(psnr(shifted, plain)),
                    psnr_vs_core_shifted=float(psnr(shifted, core_render(params, W, H))))

    @record("save_reload")
    def _():
        checked = (9, 34, 49)  # clip frames: one as encoded, two edited (override meshes)
        before_frames = mesh_frames(bpy, obj, checked)
        before_settings = settings(obj)
        before_render, _ = f12(35, W, H, "reload_before")
        path = Path(work) / "clip.blend"
        bpy.ops.wm.save_as_mainfile(filepath=str(path))
        bpy.ops.wm.open_mainfile(filepath=str(path))
        again = bpy.data.objects[CLIP_NAME]
        after_frames = mesh_frames(bpy, again, checked)
        sc = bpy.context.scene
        png = Path(work) / "reload_after.png"
        render_png(bpy, sc, 35, png)
        after_render = read_png(bpy, png)
        ctx["obj"] = again
        return dict(frames_equal=all(np.array_equal(a, b) for a, b in zip(before_frames, after_frames)),
                    settings_equal=settings(again) == before_settings,
                    edited_frames=sorted(o.frame for o in again.hypergs.overrides),
                    vertices_at_50=len(after_frames[2]),
                    render_psnr_vs_before=float(psnr(after_render, before_render)))

    @record("edit_frame")
    def _():
        again = ctx["obj"]
        sc = bpy.context.scene
        bpy.context.view_layer.objects.active = again
        sc.frame_set(20)
        bpy.ops.hypergs.edit_frame()
        mode = again.mode
        bpy.ops.object.mode_set(mode="OBJECT")
        hidden = np.empty(len(again.data.vertices), bool)
        again.data.vertices.foreach_get("hide", hidden)
        return dict(mode=mode, clip_frame=19, visible=int((~hidden).sum()), shown=again.data.get("hypergs_frame"))

    @record("reencode")
    def _():
        again = ctx["obj"]
        psnr_before = again.hypergs.psnr
        again.hypergs.quality, again.hypergs.gaussian_count = "CUSTOM", 500
        result = bpy.ops.hypergs.reencode(keep_edits=False)
        s = again.hypergs
        return dict(result=sorted(result), vertices=len(again.data.vertices), gaussians_per_frame=s.gaussians_per_frame,
                    psnr_before=psnr_before, psnr=s.psnr,
                    modifiers=[m.name for m in again.modifiers], display_points=display_points(bpy, again),
                    mesh=again.data.name, meshes=len(bpy.data.meshes))

    return results


def _vec(values):
    from mathutils import Vector
    return Vector(values)


def _importable(name):
    try:
        __import__(name)
        return True
    except ImportError:
        return False


def settings(obj):
    s = obj.hypergs
    values = {k: getattr(s, k) for k in ("is_clip", "source", "num_frames", "gaussians_per_frame", "psnr",
                                         "canvas_width", "canvas_height", "fps", "frame_start", "speed")}
    return dict(values, grid=list(s.grid))


def set_position_group(bpy, offset):
    group = bpy.data.node_groups.new("Shift", "GeometryNodeTree")
    group.interface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    group.interface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    gin, gout = group.nodes.new("NodeGroupInput"), group.nodes.new("NodeGroupOutput")
    setp = group.nodes.new("GeometryNodeSetPosition")
    setp.inputs["Offset"].default_value = offset
    group.links.new(gin.outputs[0], setp.inputs["Geometry"])
    group.links.new(setp.outputs[0], gout.inputs[0])
    return group


if __name__ == "__main__":
    session_main(run_session)
