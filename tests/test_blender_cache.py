"""Frame caches in the real bpy wheel (issue 17): a conversion streams every frame into a cache file and the
clip's mesh holds one frame at a time; edits are kept as overrides through undo, save and reopen; the cache
moves beside the .blend on its first save, packs into it and unpacks again (also through Blender's File >
External Data); a command-line render in a fresh process finds it, and stops without it; cancelled, failed
and disk-full conversions leave neither files nor datablocks; File > Import sets the scene's frame rate and
range; Re-encode keeps or drops the edits; clips of earlier versions (embedded in their mesh, linked) still
render and copy into a cache.

One Blender session in a subprocess (tests/blender_session.py), as in test_blender_addon.py; the farm
renders are a further process each (tools/blender_headless.py render).
"""
import errno
import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from blender_headless import install_extension, read_png
from blender_session import (addon_module, attempt_unchanged, cache_error, display_points, files_under,
                             mesh_frames, run_blender_session, session_main, snapshot, start_session, step)
from conftest import make_pan_clip

from hypergs_blender.encode import QUALITY, FloorEncoder, plan_layout

ROOT = Path(__file__).resolve().parents[1]
ENCODER = "floor"  # the network's quality does not matter here
FRAMES = 24  # the test movie: a 432 x 240 pan at 24 fps
N = plan_layout(432, 240, FloorEncoder.stride, cell=QUALITY["draft"]["cell"]).count  # Gaussians per frame, Draft
LEGACY = ROOT / "tests" / "data" / "legacy_4.2.blend"  # tools/make_legacy_blend.py: the add-on before caches
SESSION_TIMEOUT = 600


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    work = tmp_path_factory.mktemp("blender_cache")
    make_pan_clip(work / "pan.mp4", frames=FRAMES)
    return run_blender_session(__file__, work, ENCODER, SESSION_TIMEOUT)


def test_import_streams_into_a_temporary_cache_and_shows_one_frame(session):
    r = step(session, "import")
    assert r["result"] == ["FINISHED"]
    assert r["cache_in_temp"] and r["cache_name"] == ".pan.hgs" and r["cache_exists"]
    assert r["vertices"] == N and r["shown"] == 0 and r["modifiers"] == ["HyperGS Points"]
    assert r["display_points"] in (None, N)  # Solid mode shows the frame's points
    assert r["num_frames"] == FRAMES and r["gaussians_per_frame"] == N


def test_import_sets_the_scene_frame_rate_and_range(session):
    r = step(session, "import")
    assert r["scene"] == dict(fps=24, fps_base=1.0, frame_start=1, frame_end=FRAMES)  # was 30 fps, 1-250
    assert "frame rate to 24 fps" in session["console"] and f"frame range to 1-{FRAMES}" in session["console"]
    assert r["lock_interface"]


def test_every_frame_change_loads_that_frame_from_the_cache(session):
    r = step(session, "round_trip")
    assert r["frames_checked"] == FRAMES
    assert r["mesh_vs_cache"] < 1e-6  # the mesh holds the cache's frame (up to float32 rounding to points and back)
    assert r["cache_vs_core_means"] == 0.0  # means stored float32
    assert r["cache_vs_core"] <= 1  # the rest float16
    assert r["f12_vs_core"] > 45  # F12 renders the frame shown


def test_memory_holds_one_frame(session):
    r = step(session, "one_frame")
    assert r["vertices_after_scrubbing"] == N
    assert r["decoded_bytes"] <= r["decoded_limit"]
    assert r["blend_growth"] < N * 40 + 100_000  # one frame's points and a node group


def test_edits_become_overrides_that_undo_keeps_and_takes_back(session):
    r = step(session, "edits")
    assert r["override_frames"] == [4, 7]
    assert r["edit_back_on_return"] and r["other_frame_unchanged"]
    assert r["f12_vs_core_edited"] > 45
    assert r["after_undo"] == dict(overrides=[4], frame_5_edited=True, frame_8_edited=False)
    assert r["after_redo"] == dict(overrides=[4, 7], frame_5_edited=True, frame_8_edited=True)


def test_first_save_moves_the_cache_beside_the_blend_and_reopen_keeps_the_edits(session):
    r = step(session, "save")
    assert r["path"] == "//project_hypergs/pan.hgs" and r["moved"] and not r["temp_left"]
    # Undo past the save keeps reading the moved file (undo leaves Image datablocks' paths alone).
    assert r["undone_reads"] and r["saved_again"] == ["pan.hgs"]
    assert r["reopened"] == dict(overrides=[4, 7], frame_5_edited=True, frame_8_edited=True, vertices=N)
    # The .blend grew by the frame shown and the two edited ones (40 bytes a point), not by every frame.
    assert r["blend_growth"] < 3 * N * 40 + 100_000 < FRAMES * N * 40


def test_pack_and_unpack(session):
    r = step(session, "pack")
    assert r["packed_bytes"] == r["cache_bytes"] and r["blend_mb"] > r["cache_bytes"] / 1e6
    assert r["reads_packed_without_the_file"] and r["panel_says_packed"]
    assert r["unpacked"] == dict(packed=False, path="//project_hypergs/pan.hgs", exists=True, same_bytes=True)


def test_blenders_external_data_tools_handle_the_cache(session):
    r = step(session, "external_data")
    assert r["pack_all_packs_it"] and r["unpack_all"]["reads"] and not r["unpack_all"]["packed"]
    assert r["purge_keeps_it"]
    assert r["report_missing"] == ["FINISHED"]  # File > External Data > Report Missing Files names it:
    assert any("pan.hgs" in line and "not found" in line for line in session["console"].splitlines())


def test_a_command_line_render_finds_the_cache(session):
    r = step(session, "farm")
    ok = r["with_cache"]
    assert ok["error"] is None and len(ok["written"]) == 3, ok
    assert r["farm_vs_session"] == 0.0  # the farm's frame is the session's


def test_a_command_line_render_without_the_cache_stops(session):
    r = step(session, "farm")
    missing = r["without_cache"]
    assert missing["error"] and "Render Missing Clips Black" in missing["error"] and "pan.hgs" in missing["error"]
    assert missing["written"] == []
    allowed = r["black_allowed"]
    assert allowed["error"] is None and len(allowed["written"]) == 3 and r["black_frames"]


@pytest.mark.parametrize("case", ["cancelled", "corrupt_video", "apply_fails", "disk_full", "disk_full_saved"])
def test_failed_conversions_leave_no_files_and_no_datablocks(session, case):
    r = step(session, "failures")[case]
    assert r["raised"] or r.get("cancelled"), r
    assert "Traceback" not in r["message"] and "\n" not in r["message"].strip()
    assert r["expect"].lower() in r["message"].lower(), r["message"]
    assert r["unchanged"], r["diff"]
    assert r["files_before"] == r["files_after"]


def test_reencode_keeps_or_discards_the_edits(session):
    r = step(session, "reencode")
    assert r["keep"] == dict(result=["FINISHED"], overrides=[4, 7], frame_5_edited=True, new_cache=True)
    assert r["discard"] == dict(result=["FINISHED"], overrides=[], frame_5_edited=False, new_cache=True)
    assert r["old_caches_kept"]  # undo goes back to them
    assert r["undo_restores_the_cache"]


def test_export_of_a_cache_clip_has_the_edits(session):
    r = step(session, "export")
    assert r["result"] == ["FINISHED"] and r["frames"] == FRAMES
    assert r["edited_frame_matches"] < 1e-4 and r["other_frame_matches"] < 1e-4


@pytest.mark.skipif(not LEGACY.is_file(), reason="no legacy .blend")
def test_clips_of_earlier_versions_still_render_and_copy_into_a_cache(session):
    r = step(session, "legacy")
    assert r["embedded"]["renders"] and r["linked"]["renders"]
    assert r["embedded"]["frames_match_the_mesh"]
    assert r["copied"]["cache"] and r["copied"]["vertices_frame_1"] == r["embedded"]["frame_1_points"]
    assert r["copied"]["render_same"] and r["copied"]["edit_kept"]
    assert r["linked_copied"]["cache"] and r["linked_copied"]["render_same"]


# ----------------------------------------------------------------------------------------------------
# Blender side (run as a script: python test_blender_cache.py ZIP WORKDIR OUT.json)

def run_session(zip_path, work, out_path):
    bpy, record, results = start_session(work, out_path)
    addon = install_extension(bpy, zip_path)
    cache = addon_module(addon, "com.cache")
    from hypergs_blender.encode import EncodeSettings, encode_video
    from hypergs_blender.io.hgs import HgsReader
    from hypergs_blender.metrics import psnr
    from hypergs_blender.render import render_params

    movie = work / "pan.mp4"
    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base, scene.frame_start, scene.frame_end = 30, 1.0, 1, 250
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 216, 120, 100
    scene.render.dither_intensity = 0.0
    temp = Path(cache.temp_folder())
    ctx = {}

    def clip():
        return bpy.data.objects["pan"]

    def f12(frame, name):
        sc = bpy.context.scene
        sc.frame_set(frame)
        sc.render.image_settings.file_format = "PNG"
        sc.render.filepath = str(work / f"{name}.png")
        bpy.ops.render.render(write_still=True)
        return read_png(bpy, work / f"{name}.png")

    def core_f12(params):
        return np.clip(render_params(params, 432, 240, 216, 120), 0, 1)

    def params_now(obj):
        return mesh_frames(bpy, obj, [bpy.context.scene.frame_current - obj.hypergs.frame_start])[0]

    @record("import")
    def _():
        before = files_under(temp)
        bpy.ops.wm.save_as_mainfile(filepath=str(work / "baseline.blend"), copy=True)  # what the .blend grows from
        result = bpy.ops.hypergs.import_video(filepath=str(movie), quality="DRAFT")
        obj = clip()
        s = obj.hypergs
        path = Path(cache.clip_file(obj))
        ctx["cache"] = path
        return dict(result=sorted(result), cache_in_temp=path.parent == temp and files_under(temp) != before,
                    cache_name=s.cache.name, cache_exists=path.is_file(), vertices=len(obj.data.vertices),
                    shown=obj.data.get("hypergs_frame"), modifiers=[m.name for m in obj.modifiers],
                    display_points=display_points(bpy, obj), num_frames=s.num_frames,
                    gaussians_per_frame=s.gaussians_per_frame,
                    scene=dict(fps=scene.render.fps, fps_base=scene.render.fps_base, frame_start=scene.frame_start,
                               frame_end=scene.frame_end),
                    lock_interface=scene.render.use_lock_interface)

    encoder = addon_module(addon, "hypergs_blender.runtime").make_encoder()
    reference = encode_video(str(movie), encoder, EncodeSettings.choose("draft"))

    @record("round_trip")
    def _():
        obj = clip()
        with HgsReader(ctx["cache"]) as reader:
            stored = reader.read_frames()
        shown = mesh_frames(bpy, obj, range(FRAMES))
        mesh_vs_cache = max(float(np.abs(a - b).max()) for a, b in zip(shown, stored))
        image = f12(9, "round_trip")
        return dict(frames_checked=len(shown), mesh_vs_cache=mesh_vs_cache,
                    cache_vs_core_means=float(np.abs(stored[..., :2] - reference.params[..., :2]).max()),
                    cache_vs_core=cache_error(stored, reference.params),
                    f12_vs_core=float(psnr(image, core_f12(reference.params[8]))))

    @record("one_frame")
    def _():
        obj = clip()
        rng = np.random.default_rng(0)
        for frame in [*range(1, FRAMES + 1), *rng.integers(1, FRAMES + 1, 30)]:
            scene.frame_set(int(frame))
        from hypergs_blender.io.cache import MAX_FRAME_BYTES
        bpy.ops.wm.save_as_mainfile(filepath=str(work / "size.blend"), copy=True)
        return dict(vertices_after_scrubbing=len(obj.data.vertices), decoded_bytes=cache.FRAMES.frame_bytes,
                    decoded_limit=MAX_FRAME_BYTES,
                    blend_growth=(work / "size.blend").stat().st_size - (work / "baseline.blend").stat().st_size)

    def edit(frame, vertex, dx):
        """Move a point in Edit Mode at a scene frame, then back to Object Mode (an undo step after)."""
        import bmesh
        obj = clip()
        bpy.context.view_layer.objects.active = obj
        bpy.context.scene.frame_set(frame)
        bpy.ops.hypergs.edit_frame()
        bm = bmesh.from_edit_mesh(obj.data)
        bm.verts.ensure_lookup_table()
        bm.verts[vertex].co.x += dx
        bmesh.update_edit_mesh(obj.data)
        bpy.ops.object.mode_set(mode="OBJECT")
        bpy.ops.ed.undo_push(message=f"edit frame {frame}")

    original = {f: reference.params[f - 1] for f in (5, 8)}

    def state():
        obj = clip()
        got = {f: mesh_frames(bpy, obj, [f - 1])[0] for f in (5, 8)}
        edited = {f: not np.allclose(got[f][:, :2], original[f][:, :2], atol=1e-5) for f in (5, 8)}
        return dict(overrides=sorted(o.frame for o in obj.hypergs.overrides), frame_5_edited=edited[5],
                    frame_8_edited=edited[8])

    @record("edits")
    def _():
        bpy.ops.ed.undo_push(message="before the edits")
        edit(5, 7, 0.3)
        bpy.context.scene.frame_set(6)
        other = params_now(clip())
        edit(8, 11, -0.2)
        back = mesh_frames(bpy, clip(), [4])[0]
        image = f12(5, "edited")
        out = dict(override_frames=sorted(o.frame for o in clip().hypergs.overrides),
                   edit_back_on_return=bool(abs(back[7, 0] - original[5][7, 0] - 0.3 / (432 / 240)) < 1e-4),
                   other_frame_unchanged=bool(np.abs(other - reference.params[5]).max() < 1e-2),
                   f12_vs_core_edited=float(psnr(image, core_f12(back))))
        bpy.ops.ed.undo()
        out["after_undo"] = state()
        bpy.ops.ed.redo()
        out["after_redo"] = state()
        return out

    @record("save")
    def _():
        project = work / "project"
        project.mkdir()
        temp_file = Path(cache.clip_file(clip()))
        bpy.ops.wm.save_as_mainfile(filepath=str(project / "project.blend"))
        obj = clip()
        moved = Path(cache.clip_file(obj))
        out = dict(path=obj.hypergs.cache.filepath, moved=moved == project / "project_hypergs" / "pan.hgs"
                   and moved.is_file(), temp_left=temp_file.exists(),
                   blend_growth=(project / "project.blend").stat().st_size - (work / "baseline.blend").stat().st_size)
        bpy.ops.ed.undo()
        got = mesh_frames(bpy, clip(), [2])[0]
        out["undone_reads"] = cache.clip_file(clip()) == str(moved) and bool(
            np.abs(got[:, :2] - reference.params[2][:, :2]).max() < 1e-5)
        bpy.ops.ed.redo()
        bpy.ops.wm.save_mainfile()
        out["saved_again"] = files_under(project / "project_hypergs")
        bpy.ops.wm.open_mainfile(filepath=str(project / "project.blend"))
        out["reopened"] = dict(state(), vertices=len(clip().data.vertices))
        return out

    project = work / "project"

    @record("pack")
    def _():
        obj = clip()
        bpy.context.view_layer.objects.active = obj
        size = (project / "project_hypergs" / "pan.hgs").stat().st_size
        bpy.ops.hypergs.pack_cache()
        packed = obj.hypergs.cache.packed_file.size
        bpy.ops.wm.save_as_mainfile(filepath=str(project / "packed.blend"), copy=True)
        out = dict(packed_bytes=packed, cache_bytes=size, blend_mb=(project / "packed.blend").stat().st_size / 1e6)
        shutil.move(project / "project_hypergs", work / "away")  # the packed .blend needs no file
        bpy.ops.wm.open_mainfile(filepath=str(project / "packed.blend"))
        obj = clip()
        expect = reference.params[12]
        got = mesh_frames(bpy, obj, [12])[0]
        out["reads_packed_without_the_file"] = bool(np.abs(got[:, :2] - expect[:, :2]).max() < 1e-5)
        panel = _panel_labels(bpy, addon, obj)
        out["panel_says_packed"] = any("Packed in the .blend" in text for text in panel)
        bpy.context.view_layer.objects.active = obj
        bpy.ops.hypergs.unpack_cache()
        path = Path(cache.clip_file(obj))
        out["unpacked"] = dict(packed=obj.hypergs.cache.packed_file is not None, path=obj.hypergs.cache.filepath,
                               exists=path.is_file(),
                               same_bytes=path.read_bytes() == (work / "away" / "pan.hgs").read_bytes())
        bpy.ops.wm.save_mainfile()
        return out

    @record("external_data")
    def _():
        obj = clip()
        bpy.ops.file.pack_all()
        packed = obj.hypergs.cache.packed_file is not None
        bpy.ops.file.unpack_all(method="WRITE_LOCAL")
        obj = clip()
        unpack = dict(packed=obj.hypergs.cache.packed_file is not None, path=obj.hypergs.cache.filepath)
        got = mesh_frames(bpy, obj, [3])[0]
        unpack["reads"] = bool(np.abs(got[:, :2] - reference.params[3][:, :2]).max() < 1e-5)
        bpy.data.orphans_purge(do_recursive=True)
        kept = clip().hypergs.cache is not None
        bpy.ops.wm.open_mainfile(filepath=str(project / "project.blend"))  # the saved state, path back
        path = Path(cache.clip_file(clip()))
        path.rename(path.with_suffix(".away"))
        missing = bpy.ops.file.report_missing_files()
        path.with_suffix(".away").rename(path)
        return dict(pack_all_packs_it=packed, unpack_all=unpack, purge_keeps_it=kept, report_missing=sorted(missing))

    def farm(blend, frames="2-4"):
        out = work / "farm_out"
        shutil.rmtree(out, ignore_errors=True)
        proc = subprocess.run([sys.executable, str(ROOT / "tools" / "blender_headless.py"), "render", str(blend),
                               "--user", str(work / "user"), "--frames", frames],
                              capture_output=True, text=True, timeout=300)
        import json
        lines = [line for line in proc.stdout.splitlines() if line.startswith("{")]
        if not lines:
            return dict(error=f"no report (rc {proc.returncode}): {proc.stderr[-2000:]}", written=[])
        return json.loads(lines[-1])

    @record("farm")
    def _():
        bpy.ops.wm.open_mainfile(filepath=str(project / "project.blend"))
        sc = bpy.context.scene
        sc.render.filepath = "//../farm_out/f_####"
        sc.render.image_settings.file_format = "PNG"
        bpy.ops.wm.save_mainfile()
        session_image = f12(3, "farm_reference")
        with_cache = farm(project / "project.blend")
        farm_image = read_png(bpy, work / "farm_out" / "f_0003.png") if not with_cache["error"] else None
        folder = project / "project_hypergs"
        folder.rename(project / "elsewhere")
        without = farm(project / "project.blend")
        bpy.context.scene.hypergs.allow_missing_clips = True
        bpy.ops.wm.save_mainfile()
        allowed = farm(project / "project.blend")
        black = all(read_png(bpy, Path(p)).max() == 0 for p in allowed["written"])
        (project / "elsewhere").rename(folder)
        bpy.ops.wm.open_mainfile(filepath=str(project / "project.blend"))
        bpy.context.scene.hypergs.allow_missing_clips = False
        bpy.ops.wm.save_mainfile()
        return dict(with_cache=with_cache, without_cache=without, black_allowed=allowed, black_frames=black,
                    farm_vs_session=float(np.abs(farm_image - session_image).max()) if farm_image is not None else 1.0)

    def watched(expect, call, folders):
        """attempt_unchanged, and the files in `folders` before and after."""
        before = [files_under(f) for f in folders]
        out = attempt_unchanged(bpy, expect, call)
        return dict(out, files_before=before, files_after=[files_under(f) for f in folders])

    @record("failures")
    def _():
        out = {}
        folders = [temp, project]
        encode = addon_module(addon, "hypergs_blender.encode")
        original = encode.EncodePlan.chunks

        def cancelling(self, progress=None, *args, **kwargs):  # what Esc does: progress returns False
            return original(self, lambda done, total: progress(done, total) and done < 5, *args, **kwargs)
        encode.EncodePlan.chunks = cancelling
        try:
            before = snapshot(bpy)
            files = [files_under(f) for f in folders]
            result = bpy.ops.hypergs.import_video(filepath=str(movie), quality="DRAFT")
            after = snapshot(bpy)
            out["cancelled"] = dict(raised=False, cancelled=result == {"CANCELLED"}, message="", expect="",
                                    unchanged=before == after, diff=str(before != after),
                                    files_before=files, files_after=[files_under(f) for f in folders])
        finally:
            encode.EncodePlan.chunks = original
        data = movie.read_bytes()
        corrupt = work / "corrupt.mp4"  # frame data zeroed past the first frames: decoding fails mid-way
        start, stop = data.find(b"mdat") + 12000, data.find(b"moov") - 4
        corrupt.write_bytes(data[:start] + bytes(stop - start) + data[stop:])
        out["corrupt_video"] = watched("corrupt.mp4", lambda: bpy.ops.hypergs.import_video(filepath=str(corrupt)),
                                       folders)
        scene_module = addon_module(addon, "ops.scene")
        made = scene_module.create_clip_object

        def failing(*args, **kwargs):
            raise RuntimeError("the scene refused the clip")
        scene_module.create_clip_object = failing
        try:
            out["apply_fails"] = watched("refused", lambda: bpy.ops.hypergs.import_video(filepath=str(movie)), folders)
        finally:
            scene_module.create_clip_object = made
        files = addon_module(addon, "hypergs_blender.io.files")
        opened = files.AtomicOutput.open

        def disk_full(self):  # a file system with 20 kB left
            return _FullDisk(opened(self), 20_000)
        files.AtomicOutput.open = disk_full
        try:
            bpy.ops.wm.read_homefile(use_empty=True)  # an unsaved file: the cache would go to the temporary folder
            out["disk_full"] = watched("No space left on device",
                                       lambda: bpy.ops.hypergs.import_video(filepath=str(movie)), folders)
            bpy.ops.wm.open_mainfile(filepath=str(project / "project.blend"))
            out["disk_full_saved"] = watched("No space left on device",
                                             lambda: bpy.ops.hypergs.import_video(filepath=str(movie)), folders)
        finally:
            files.AtomicOutput.open = opened
        return out

    @record("reencode")
    def _():
        bpy.ops.wm.open_mainfile(filepath=str(project / "project.blend"))
        out = {}
        caches = []
        for case, keep in (("keep", True), ("discard", False)):
            obj = clip()
            bpy.context.view_layer.objects.active = obj
            before = cache.clip_file(obj)
            caches.append(before)
            bpy.ops.ed.undo_push(message=f"before re-encode ({case})")
            result = bpy.ops.hypergs.reencode(keep_edits=keep)
            bpy.ops.ed.undo_push(message="Re-encode")  # what the UI does after an operator
            obj = clip()
            s = state()
            out[case] = dict(result=sorted(result), overrides=s["overrides"], frame_5_edited=s["frame_5_edited"],
                             new_cache=cache.clip_file(obj) != before and Path(cache.clip_file(obj)).is_file())
        out["old_caches_kept"] = all(Path(p).is_file() for p in caches)
        bpy.ops.ed.undo()
        out["undo_restores_the_cache"] = cache.clip_file(clip()) == caches[1] and state()["overrides"] == [4, 7]
        return out

    @record("export")
    def _():
        from hypergs_blender.io.clips import load_clip
        obj = clip()
        bpy.context.view_layer.objects.active = obj
        result = bpy.ops.hypergs.export_clip(filepath=str(work / "exported.npz"))
        video = load_clip(work / "exported.npz")
        edited, other = mesh_frames(bpy, obj, [4, 2])
        return dict(result=sorted(result), frames=video.num_frames,
                    edited_frame_matches=float(np.abs(video.params[4][:len(edited)] - edited).max()),
                    other_frame_matches=float(np.abs(video.params[2][:len(other)] - other).max()))

    @record("legacy")
    def _():
        if not LEGACY.is_file():
            return {}
        folder = work / "legacy"
        folder.mkdir()
        for path in LEGACY.parent.glob("legacy*"):
            shutil.copy(path, folder / path.name)
        bpy.ops.wm.open_mainfile(filepath=str(folder / LEGACY.name))
        sc = bpy.context.scene
        sc.render.resolution_x, sc.render.resolution_y, sc.render.dither_intensity = 96, 64, 0.0
        embedded, linked = bpy.data.objects["embedded"], bpy.data.objects["linked"]

        def only(obj):
            for o in bpy.data.objects:
                if o.type == "MESH":
                    o.hide_render = o is not obj
        only(embedded)
        before = f12(2, "legacy_embedded")
        ev = embedded.evaluated_get(bpy.context.evaluated_depsgraph_get())
        ev_points = len(ev.data.vertices)
        frame_attribute = np.empty(len(embedded.data.vertices), np.int32)
        embedded.data.attributes["frame"].data.foreach_get("value", frame_attribute)
        only(linked)
        linked_before = f12(2, "legacy_linked")
        out = dict(embedded=dict(renders=bool(before.max() > 0.05), frame_1_points=ev_points,
                                 frames_match_the_mesh=ev_points == int((frame_attribute == 1).sum())),
                   linked=dict(renders=bool(linked_before.max() > 0.05)))
        bpy.context.view_layer.objects.active = embedded
        bpy.ops.hypergs.embed_clip()  # Copy to Frame Cache
        embedded = bpy.data.objects["embedded"]
        only(embedded)
        bpy.context.scene.frame_set(2)
        after = f12(2, "legacy_copied")
        out["copied"] = dict(cache=embedded.hypergs.cache is not None, vertices_frame_1=len(embedded.data.vertices),
                             render_same=bool(np.abs(after - before).max() < 2 / 255),
                             edit_kept=len(embedded.data.vertices) == ev_points)
        bpy.context.view_layer.objects.active = linked
        bpy.ops.hypergs.embed_clip()
        linked = bpy.data.objects["linked"]
        only(linked)
        linked_after = f12(2, "legacy_linked_copied")
        out["linked_copied"] = dict(cache=linked.hypergs.cache is not None,
                                    render_same=bool(np.abs(linked_after - linked_before).max() < 2 / 255))
        return out

    return results


class _FullDisk:
    """A file that takes `room` bytes, then fails as a full disk does (ENOSPC)."""

    def __init__(self, file, room: int):
        self._file, self._room = file, room

    def write(self, data):
        if len(data) > self._room:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        self._room -= len(data)
        return self._file.write(data)

    def __getattr__(self, name):
        return getattr(self._file, name)


def _panel_labels(bpy, addon, obj):
    from blender_session import Recorder, types_namespace
    panel = addon_module(addon, "ui").HYPERGS_PT_clip
    bpy.context.view_layer.objects.active = obj
    layout = Recorder()
    panel.draw(types_namespace(layout=layout, draw_linked=panel.draw_linked, draw_cache=panel.draw_cache),
               bpy.context)
    return [c[1] for c in layout.calls if c[0] == "label"]


if __name__ == "__main__":
    session_main(run_session)
