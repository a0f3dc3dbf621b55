"""Gaussian video files in the real bpy wheel: File > Export / Import (.hgs, .usd, .npz; an import is copied
into a frame cache) with edits, clips linked to an external .hgs file (render, missing and damaged files,
copied into a frame cache), image sequences.

One Blender session in a subprocess (tests/blender_session.py): this file run as a script writes what
it measured to JSON; the tests below check it.
"""
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from blender_headless import install_extension, read_png
from blender_session import (Recorder, addon_module, attempt_unchanged, cache_error, diff, files_under, mesh_frames,
                             run_blender_session, session_main, snapshot, start_session, step, types_namespace)

ENCODER = "floor"
T, N, CANVAS = 10, 200, (96, 64)  # the test clip: frames, Gaussians per frame, canvas
SEQUENCE = 6  # PNG frames written for the image-sequence tests
# Gaussian video files an import must refuse with a one-line message naming the file, changing nothing.
BAD_FILES = ("negative_canvas.npz", "zero_gaussians.npz", "no_canvas.npz", "not_a_zip.npz", "truncated.npz",
             "garbage.hgs", "garbage.usda", "damaged_frame.hgs")  # the last fails while its frames are copied
SESSION_TIMEOUT = 300


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    work = tmp_path_factory.mktemp("blender_io")
    return run_blender_session(__file__, work, ENCODER, SESSION_TIMEOUT)


def test_import_npz_builds_a_clip_object(session):
    r = step(session, "import_npz")
    assert r["result"] == ["FINISHED"]
    assert (r["num_frames"], r["gaussians_per_frame"], r["canvas"], r["fps"]) == (T, N, list(CANVAS), 30.0)
    assert r["vertices"] == N and r["modifiers"] == ["HyperGS Points"] and not r["linked"] and r["cached"]
    assert r["cache_error"] <= 1  # the frame cache keeps the clip (float16 where it may)
    assert r["source"] == "/videos/orig.mp4" and r["source_start"] == 5 and r["psnr"] == pytest.approx(31.5)


@pytest.mark.parametrize("suffix", [".hgs", ".usd", ".usda", ".npz"])
def test_export_and_reimport_gives_the_same_gaussians(session, suffix):
    r = step(session, "round_trip")[suffix]
    assert r["export"] == ["FINISHED"] and r["import"] == ["FINISHED"]
    assert r["vertices"] == N and r["num_frames"] == T and r["canvas"] == list(CANVAS)
    assert r["fps"] == pytest.approx(30.0) and r["psnr"] == pytest.approx(31.5)
    if suffix == ".hgs":  # quantized: every value within half a quantization step (8 bits), and float16
        assert all(e <= b for e, b in zip(r["errors"], r["bounds"])), r
        assert r["error_vs_file"] <= 1  # and the clip holds what the file decodes to
    else:
        assert r["error_vs_file"] <= 1, r


@pytest.mark.parametrize("suffix", [".hgs", ".usd"])
def test_edits_survive_export_and_import(session, suffix):
    r = step(session, "edits")[suffix]
    assert r["export"] == ["FINISHED"] and r["import"] == ["FINISHED"]
    # the deleted point stays deleted (padded in the file, dropped again)
    assert r["frame_counts"] == [N] * 5 + [N - 1] + [N] * (T - 6)
    assert r["moved_error"] < r["moved_bound"]  # the moved point is where it was moved to
    assert r["moved_distance"] > 0.29
    assert r["max_error"] < r["bound"]  # everything else as edited


def test_linked_clip_renders_like_the_embedded_one(session):
    r = step(session, "linked")
    assert r["result"] == ["FINISHED"]
    assert r["linked"] and r["path_shown"] and r["mesh_vertices"] == 4 and r["modifiers"] == []
    assert (r["num_frames"], r["gaussians_per_frame"]) == (T, N)
    for frame, f in r["frames"].items():
        assert f["max_diff_linked_vs_embedded"] <= 1 / 255 + 1e-6, (frame, f)
        assert f["brightness"] > 0.01, (frame, f)
    assert r["frames_differ"]  # the linked clip follows the scene frame
    assert r["outside_clip_black"]
    assert r["problem_when_fine"] is None
    assert r["edit_frame_poll"] is False and r["reencode_poll"] is False


def test_panel_shows_the_linked_file(session):
    r = step(session, "broken")
    fine, embedded = r["panel_fine"], r["panel_embedded"]
    assert ["prop", "linked_path", None] in fine and ["operator", "hypergs.embed_clip", "IMPORT"] in fine
    assert ["prop", "filepath", None] in embedded  # the frame cache's file
    assert not any(c[2] == "ERROR" for c in fine)
    assert ["operator", "hypergs.edit_frame", "EDITMODE_HLT"] not in fine
    assert ["operator", "hypergs.edit_frame", "EDITMODE_HLT"] in embedded
    assert not any(c[1] == "linked_path" for c in embedded)


@pytest.mark.parametrize("case", ["deleted", "corrupted", "truncated"])
def test_broken_linked_file_stops_a_command_line_render(session, case):
    r = step(session, "broken")[case]
    assert r["expect"] in r["problem"], r["problem"]
    # Background mode is a command-line render: nobody would see black frames, so the render stops.
    assert r["strict"]["raised"] and r["problem"] in r["strict"]["message"], r["strict"]
    assert "Render Missing Clips Black" in r["strict"]["message"] and not r["strict"]["written"]
    assert r["panel_error"] and r["panel_error"] in r["problem"]  # the panel shows it
    assert r["unchanged"], r["diff"]
    assert r["restored_matches"]  # the file back: it renders again, the scene is fine


@pytest.mark.parametrize("case", ["deleted", "corrupted", "truncated"])
def test_broken_linked_file_renders_black_when_the_scene_allows_it(session, case):
    r = step(session, "broken")[case]
    assert r["allowed"]["render"] == ["FINISHED"] and r["allowed"]["black"], r["allowed"]
    assert f"HyperGS: 'linked': {r['problem']}; the clip renders nothing" in session["console"]  # the warning


def test_only_unattended_renders_stop_for_a_missing_clip(session):
    # (is_animation, background, allow black) -> stops; an interactive F12 (neither) only warns.
    assert step(session, "broken")["policy"] == [[False, False, False, False], [True, False, False, True],
                                                 [False, True, False, True], [True, True, True, False]]


def test_embed_export_link_switch_storage(session):
    r = step(session, "storage")
    assert r["embed_missing"]["raised"] and "no such file" in r["embed_missing"]["message"]
    assert r["embed_missing"]["unchanged"], r["embed_missing"]["diff"]
    assert r["embedded"] == dict(linked=False, cached=True, vertices=N, modifiers=["HyperGS Points"])
    assert r["embedded_render_diff"] <= 1 / 255 + 1e-6
    assert r["relinked"] == dict(linked=True, vertices=4, modifiers=[])
    assert r["relinked_render_diff"] <= 1 / 255 + 1e-6


@pytest.mark.parametrize("case", ["link_usd", "missing", "damaged", "export_no_folder", "link_export_usd"])
def test_io_errors_are_reported_and_change_nothing(session, case):
    r = step(session, "errors")[case]
    assert r["raised"] and "Traceback" not in r["message"]
    assert r["expect"].lower() in r["message"].lower(), r["message"]
    assert r["unchanged"], r["diff"]


@pytest.mark.parametrize("case", sorted(BAD_FILES))
def test_failed_import_names_the_file_and_leaves_every_datablock(session, case):
    r = step(session, "bad_files")[case]
    assert r["raised"], r
    message = r["message"].removeprefix("Error: ").strip()
    assert r["expect"] in message and not message.startswith(("KeyError", "ValueError", "BadZipFile")), message
    assert "Traceback" not in message and "\n" not in message  # one line
    assert r["unchanged"], r["diff"]  # every collection of bpy.data (and the scene) exactly as before
    assert r["cache_files_before"] == r["cache_files_after"]  # no frame cache (or part of one) left


def test_linked_file_is_read_lazily(session):
    r = step(session, "lazy")
    assert r["panel_read"] < 0.05 * r["file_bytes"], r  # drawing the panel: header and frame index only
    assert r["frame_read"] < 0.25 * r["file_bytes"], r  # one frame: its group of frames only
    assert r["frame_matches"] and r["handles_open"] == 0
    assert r["panel_read_again"] == 0  # unchanged file: a stat, no read


def test_linked_paths_are_relative_to_the_blend(session):
    r = step(session, "paths")
    assert r["supports_relative"] == r["blender_has_the_option"]  # 4.5+: no red `//` warning in the panel
    assert r["linked_when_saved"] == "//clip.hgs"  # linking in a saved .blend stores it relative
    assert r["absolute_after_save"] == "//../linked.hgs"  # a save makes an absolute path relative
    assert r["moved"] == dict(path="//clip.hgs", problem=None, matches=True)  # the project folder moved
    assert r["save_as_subfolder"] == dict(path="//../clip.hgs", problem=None, matches=True)
    assert r["save_copy_keeps_open_file"] == "//../clip.hgs" and r["copy_stored"] == "//../moved/clip.hgs"
    assert r["typed"] == dict(path="//../clip.hgs", problem=None)


def test_import_video_reads_an_image_sequence(session):
    r = step(session, "import_sequence")
    for case in ("file", "pattern"):
        c = r[case]
        assert c["result"] == ["FINISHED"] and c["name"] == "frame"
        assert c["num_frames"] == SEQUENCE and c["fps"] == pytest.approx(25.0)
        assert c["error_vs_core"] <= 1  # the same frames the core encodes (float16 where the cache may)


def test_image_strip_converts_keeping_its_timing(session):
    r = step(session, "image_strip")
    assert r["result"] == ["FINISHED"] and r["muted"]
    assert r["num_frames"] == SEQUENCE - 1 and r["frame_start"] == 1  # the clip's scene counts from 1
    assert r["scene_strip"] == ["SCENE", 11, 11 + SEQUENCE - 1]  # trimmed by one at the start
    assert r["source"].endswith("frame_0001.png") and r["source_start"] == 1  # re-encode reads the same
    assert r["error_vs_core"] <= 1  # its clip frame 0 is the sequence's second image
    assert r["still_image"]["raised"] and "single image" in r["still_image"]["message"]


# ----------------------------------------------------------------------------------------------------
# Blender side (run as a script: python test_blender_io.py ZIP WORKDIR OUT.json)

def run_session(zip_path, work, out_path):
    bpy, record, results = start_session(work, out_path)
    addon = install_extension(bpy, zip_path)
    linked = addon_module(addon, "com.linked")
    from hypergs_blender.io.codec import Quantizer
    from hypergs_blender.encode import EncodeSettings, encode_video
    from hypergs_blender.gaussians import GaussianVideo
    from hypergs_blender.io.hgs import load_hgs
    from hypergs_blender.io.npz import save_npz
    from hypergs_blender.io.images import write_image

    scene = bpy.context.scene
    scene.render.fps, scene.render.fps_base = 25, 1.0
    for o in list(bpy.data.objects):
        bpy.data.objects.remove(o)
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = *CANVAS, 100
    scene.render.dither_intensity = 0.0  # so that "black" is exactly 0 in the 8-bit PNG

    rng = np.random.default_rng(0)
    params = np.empty((T, N, 8), np.float32)
    params[..., 0:2] = rng.uniform(-1, 1, (T, N, 2))
    params[..., 2:4] = rng.uniform(1.0, 5.0, (T, N, 2))
    params[..., 4] = rng.uniform(0, 2 * np.pi, (T, N))
    params[..., 5:8] = rng.uniform(0.0, 0.25, (T, N, 3))
    original = GaussianVideo(params, *CANVAS, fps=30.0, grid=(1, 1),
                             source=dict(path="/videos/orig.mp4", frames=list(range(5, 5 + T)), encoder="floor",
                                         psnr=31.5))
    save_npz(original, work / "orig.npz")
    bounds = Quantizer.fit(params, 8).max_error()

    def clip_params(obj):
        """Every frame of a cache clip, as its mesh holds them on frame change: [T, N, 8]."""
        return np.stack(mesh_frames(bpy, obj, range(obj.hypergs.num_frames)))

    def errors(a, b):
        """Per-parameter max error in the codec's domain (log scales, rotation modulo pi)."""
        d = np.abs(a - b)
        d[..., 2:4] = np.abs(np.log(a[..., 2:4]) - np.log(b[..., 2:4]))
        r = np.mod(a[..., 4] - b[..., 4], np.pi)
        d[..., 4] = np.minimum(r, np.pi - r)
        return d.reshape(-1, 8).max(0)

    def activate(obj):
        for o in bpy.context.selected_objects:
            o.select_set(False)
        obj.select_set(True)
        bpy.context.view_layer.objects.active = obj

    def render(frame, name, show):
        """F12 at `frame` with only the objects in `show` rendered."""
        for o in bpy.data.objects:
            if o.type == "MESH":
                o.hide_render = o not in show
        png = work / f"{name}.png"
        sc = bpy.context.scene  # (not `scene`: the paths step opens other .blend files)
        sc.frame_set(frame)
        sc.render.image_settings.file_format = "PNG"
        sc.render.image_settings.color_depth = "8"
        sc.render.image_settings.color_mode = "RGB"
        sc.render.filepath = str(png)
        result = bpy.ops.render.render(write_still=True)
        return read_png(bpy, png), sorted(result)

    def attempt(expect, call):
        return attempt_unchanged(bpy, expect, call)

    @record("import_npz")
    def _():
        result = bpy.ops.hypergs.import_clip(filepath=str(work / "orig.npz"))
        obj = bpy.data.objects["orig"]
        s = obj.hypergs
        return dict(result=sorted(result), num_frames=s.num_frames, gaussians_per_frame=s.gaussians_per_frame,
                    canvas=[s.canvas_width, s.canvas_height], fps=s.fps, vertices=len(obj.data.vertices),
                    modifiers=[m.name for m in obj.modifiers], linked=s.linked, cached=s.cache is not None,
                    cache_error=cache_error(clip_params(obj), params), source=s.source,
                    source_start=s.source_start, psnr=s.psnr)

    clip = bpy.data.objects["orig"]

    @record("round_trip")
    def _():
        out = {}
        held = clip_params(clip)
        for suffix in (".hgs", ".usd", ".usda", ".npz"):
            path = work / f"rt{suffix}"
            activate(clip)
            exported = bpy.ops.hypergs.export_clip(filepath=str(path), bits=8)
            imported = bpy.ops.hypergs.import_clip(filepath=str(path))
            obj = bpy.context.view_layer.objects.active
            s = obj.hypergs
            p = clip_params(obj)
            row = {"export": sorted(exported), "import": sorted(imported), "vertices": len(obj.data.vertices),
                   "num_frames": s.num_frames, "canvas": [s.canvas_width, s.canvas_height], "fps": s.fps,
                   "psnr": s.psnr}
            if suffix == ".hgs":  # the file's quantization of what the clip held, then the cache's float16
                row.update(errors=errors(load_hgs(path).params, held).tolist(), bounds=(bounds + 1e-5).tolist(),
                           error_vs_file=cache_error(p, load_hgs(path).params))
            else:
                row["error_vs_file"] = cache_error(p, held)
            out[suffix] = row
            bpy.data.meshes.remove(obj.data)
        return out

    @record("edits")
    def _():
        import bmesh
        activate(clip)

        def edit(frame, change):
            """Edit Mode on clip frame `frame`: change(edit mesh's vertices)."""
            bpy.context.scene.frame_set(clip.hypergs.frame_start + frame)
            bpy.ops.object.mode_set(mode="EDIT")
            bm = bmesh.from_edit_mesh(clip.data)
            bm.verts.ensure_lookup_table()
            change(bm.verts)
            bmesh.update_edit_mesh(clip.data)

        moved = {}

        def move(verts):
            moved["before"] = tuple(verts[17].co)
            verts[17].co.x += 0.3
            verts[17].co.y -= 0.2
            moved["target"] = tuple(verts[17].co)
        edit(3, move)
        bpy.ops.object.mode_set(mode="OBJECT")
        edit(5, lambda verts: verts.remove(verts[40]))
        exported = {}
        for suffix in (".hgs", ".usd"):  # straight from Edit Mode
            exported[suffix] = sorted(bpy.ops.hypergs.export_clip(filepath=str(work / f"edited{suffix}")))
        bpy.ops.object.mode_set(mode="OBJECT")
        edited = mesh_frames(bpy, clip, range(T))
        out = {}
        for suffix in (".hgs", ".usd"):
            imported = bpy.ops.hypergs.import_clip(filepath=str(work / f"edited{suffix}"))
            obj = bpy.context.view_layer.objects.active
            again = mesh_frames(bpy, obj, range(T))
            bpy.context.scene.frame_set(obj.hypergs.frame_start + 3)
            moved_now = tuple(obj.data.vertices[17].co)
            bpy.data.meshes.remove(obj.data)
            same = [len(a) for a in again] == [len(e) for e in edited]
            # quantization error bound in plane units (x: canvas x * aspect), doubled: the edit moved the ranges
            tol = 1e-4 if suffix == ".usd" else 2 * max(bounds[0] * CANVAS[0] / CANVAS[1], bounds[1]) + 1e-4
            out[suffix] = {
                "export": exported[suffix], "import": sorted(imported), "frame_counts": [len(a) for a in again],
                "moved_error": float(np.abs(np.subtract(moved_now, moved["target"])).max()), "moved_bound": tol,
                "moved_distance": float(np.abs(np.subtract(moved["target"], moved["before"])).max()),
                "max_error": max(float(np.abs(a[:, :2] - e[:, :2]).max()) for a, e in zip(again, edited))
                if same else 1e9, "bound": tol}
        activate(clip)
        return out

    # The clip as edited, in a .hgs file: linked and embedded copies of it render the same.
    activate(clip)
    bpy.ops.hypergs.export_clip(filepath=str(work / "linked.hgs"))
    hgs = work / "linked.hgs"
    pristine = hgs.read_bytes()

    @record("linked")
    def _():
        bpy.ops.hypergs.import_clip(filepath=str(hgs))
        embedded = bpy.context.view_layer.objects.active
        embedded.name = "embedded"
        result = bpy.ops.hypergs.import_clip(filepath=str(hgs), link=True)
        obj = bpy.context.view_layer.objects.active
        obj.name = "linked"
        s = obj.hypergs
        frames, images = {}, {}
        for frame in (1, 4, 6):  # clip frames 0, 3 (the moved point), 5 (the deleted one)
            a, _ = render(frame, f"linked_{frame}", [obj])
            b, _ = render(frame, f"embedded_{frame}", [embedded])
            images[frame] = a
            frames[str(frame)] = dict(max_diff_linked_vs_embedded=float(np.abs(a - b).max()),
                                      brightness=float(a.mean()))
        outside, _ = render(T + 5, "linked_outside", [obj])
        poll = {}
        for name in ("edit_frame", "reencode"):
            activate(obj)
            poll[name] = getattr(bpy.ops.hypergs, name).poll()
        return dict(result=sorted(result), linked=s.linked, path_shown=s.linked_path == str(hgs),
                    mesh_vertices=len(obj.data.vertices), modifiers=[m.name for m in obj.modifiers],
                    num_frames=s.num_frames, gaussians_per_frame=s.gaussians_per_frame, frames=frames,
                    frames_differ=bool(np.abs(images[1] - images[4]).max() > 0.05),
                    outside_clip_black=bool(outside.max() == 0),
                    problem_when_fine=linked.problem(str(hgs)),
                    edit_frame_poll=poll["edit_frame"], reencode_poll=poll["reencode"])

    lobj, eobj = bpy.data.objects["linked"], bpy.data.objects["embedded"]
    panel = addon_module(addon, "ui").HYPERGS_PT_clip

    def panel_draw(obj):
        """What the clip panel draws for `obj`: [(call, text or property, icon)] (a recording layout)."""
        activate(obj)
        layout = Recorder()
        panel.draw(types_namespace(layout=layout, draw_linked=panel.draw_linked, draw_cache=panel.draw_cache),
                   bpy.context)
        return layout.calls
    reference, _ = render(4, "linked_reference", [lobj])

    @record("broken")
    def _():
        out = {}
        data = bytearray(pristine)
        data[len(data) // 2:len(data) // 2 + 64] = bytes(64)  # inside a chunk: a checksum mismatch
        breakers = {"deleted": (lambda: hgs.unlink(), "no such file"),
                    "corrupted": (lambda: hgs.write_bytes(bytes(data)), "checksum mismatch"),
                    "truncated": (lambda: hgs.write_bytes(pristine[:len(pristine) * 2 // 3]), "damaged")}
        for case, (breaker, expect) in breakers.items():
            breaker()
            before = snapshot(bpy)
            png = work / f"broken_{case}.png"
            try:
                render(4, png.stem, [lobj])
                strict = dict(raised=False, message="")
            except RuntimeError as e:
                strict = dict(raised=True, message=str(e))
            strict["written"] = png.is_file()
            after = snapshot(bpy)
            scene.hypergs.allow_missing_clips = True
            image, result = render(4, f"allowed_{case}", [lobj])
            scene.hypergs.allow_missing_clips = False
            problem = linked.problem(str(hgs)) or ""
            shown = [c for c in panel_draw(lobj) if c[0] == "label" and c[2] == "ERROR"]
            hgs.write_bytes(pristine)
            again, _ = render(4, f"restored_{case}", [lobj])
            out[case] = dict(strict=strict, allowed=dict(render=result, black=bool(image.max() == 0)),
                             problem=problem, expect=expect, panel_error=shown[0][1] if shown else None,
                             unchanged=before == after, diff=diff(before, after),
                             restored_matches=bool(np.abs(again - reference).max() == 0))
        out["panel_fine"] = panel_draw(lobj)
        out["panel_embedded"] = panel_draw(eobj)
        stop = addon_module(addon, "engine").missing_clips_stop
        out["policy"] = [[*case, stop(*case)] for case in ((False, False, False), (True, False, False),
                                                             (False, True, False), (True, True, True))]
        return out

    @record("storage")
    def _():
        activate(lobj)
        hgs.rename(work / "moved.hgs")
        embed_missing = attempt("no such file", lambda: bpy.ops.hypergs.embed_clip())
        (work / "moved.hgs").rename(hgs)
        activate(lobj)
        bpy.ops.hypergs.embed_clip()
        bpy.context.scene.frame_set(4)
        embedded = dict(linked=lobj.hypergs.linked, cached=lobj.hypergs.cache is not None,
                        vertices=len(lobj.data.vertices), modifiers=[m.name for m in lobj.modifiers])
        image, _ = render(4, "embedded_now", [lobj])
        activate(lobj)
        bpy.ops.hypergs.export_clip(filepath=str(work / "relinked.hgs"), link=True)
        relinked = dict(linked=lobj.hypergs.linked, vertices=len(lobj.data.vertices),
                        modifiers=[m.name for m in lobj.modifiers])
        image2, _ = render(4, "relinked_now", [lobj])
        return dict(embed_missing=embed_missing, embedded=embedded,
                    embedded_render_diff=float(np.abs(image - reference).max()),
                    relinked=relinked, relinked_render_diff=float(np.abs(image2 - reference).max()))

    @record("errors")
    def _():
        damaged = work / "damaged.hgs"
        damaged.write_bytes(pristine[:100])
        activate(eobj)
        return {
            "link_usd": attempt("only .hgs files can be linked",
                                lambda: bpy.ops.hypergs.import_clip(filepath=str(work / "rt.usd"), link=True)),
            "missing": attempt("no such file",
                               lambda: bpy.ops.hypergs.import_clip(filepath=str(work / "nothing.hgs"))),
            "damaged": attempt("damaged.hgs",
                               lambda: bpy.ops.hypergs.import_clip(filepath=str(damaged), link=True)),
            "export_no_folder": attempt("no_folder",
                                        lambda: bpy.ops.hypergs.export_clip(
                                            filepath=str(work / "no_folder" / "x.hgs"))),
            "link_export_usd": attempt("needs a .hgs file",
                                       lambda: bpy.ops.hypergs.export_clip(filepath=str(work / "x.usd"), link=True)),
        }

    @record("bad_files")
    def _():
        import json
        good = dict(version=1, canvas=[64, 48], fps=24.0, grid=[1, 1], source={})

        def npz(name, params, meta):
            with open(work / name, "wb") as f:
                np.savez(f, params=params, meta=np.frombuffer(json.dumps(meta).encode(), dtype=np.uint8))

        npz("negative_canvas.npz", params[:3], dict(good, canvas=[-64, 48]))
        npz("zero_gaussians.npz", params[:3, :0], good)
        npz("no_canvas.npz", params[:3], {k: v for k, v in good.items() if k != "canvas"})
        (work / "not_a_zip.npz").write_text("these are not the Gaussians you are looking for\n")
        (work / "truncated.npz").write_bytes((work / "orig.npz").read_bytes()[:300])
        (work / "garbage.hgs").write_bytes(bytes(range(256)) * 8)
        (work / "garbage.usda").write_text("#usda 1.0\ndef Points \"p\" { point3f[] points = [(1, 2)] }\n")
        from hypergs_blender.io.hgs import save_hgs
        damaged = work / "damaged_frame.hgs"  # header and index fine, a frame's data not: found mid-copy
        save_hgs(original, damaged, group_size=1)
        data = bytearray(damaged.read_bytes())
        data[int(len(data) * 0.7)] ^= 0xFF
        damaged.write_bytes(bytes(data))
        caches = addon_module(addon, "com.cache").cache_folder()

        def tried(name):
            before = files_under(caches)
            out = attempt(name, lambda: bpy.ops.hypergs.import_clip(filepath=str(work / name)))
            return dict(out, cache_files_before=before, cache_files_after=files_under(caches))
        return {name: tried(name)
                for name in BAD_FILES}

    @record("lazy")
    def _():
        from hypergs_blender.io.hgs import save_hgs
        rng = np.random.default_rng(1)
        big = GaussianVideo(np.tile(params, (8, 1, 1)) + rng.normal(0, 0.01, (8 * T, N, 8)).astype(np.float32),
                            *CANVAS, 30.0)
        big.params[..., 2:4] = np.abs(big.params[..., 2:4])
        path = work / "lazy.hgs"
        save_hgs(big, path, group_size=4)  # 20 groups of frames
        bpy.ops.hypergs.import_clip(filepath=str(path), link=True)
        obj = bpy.context.view_layer.objects.active
        counting = addon_module(addon, "hypergs_blender.io.cache")._FileOnDemand  # how linked files are read
        read = counting.read
        counted = []

        def counted_read(self, size=-1):
            data = read(self, size)
            counted.append(len(data))
            return data
        counting.read = counted_read
        try:
            linked.forget()
            panel_draw(obj)  # the panel opens the file: header and index
            panel_read = sum(counted)
            counted.clear()
            panel_draw(obj)
            panel_read_again = sum(counted)
            counted.clear()
            frame, _, _ = linked.read_frame(str(path), 37)
            frame_read = sum(counted)
        finally:
            counting.read = read
        fd = Path("/proc/self/fd")
        handles = sum(1 for f in fd.iterdir() if os.path.realpath(f) == str(path)) if fd.is_dir() else 0
        bpy.data.meshes.remove(obj.data)
        return dict(file_bytes=path.stat().st_size, panel_read=panel_read, panel_read_again=panel_read_again,
                    frame_read=frame_read, frame_matches=bool(np.allclose(frame, load_hgs(path).params[37])),
                    handles_open=handles)

    for o in list(bpy.data.objects):
        if o.type == "MESH":
            bpy.data.meshes.remove(o.data)
    encoder = addon_module(addon, "hypergs_blender.runtime").make_encoder()
    folder = work / "seq"
    folder.mkdir()
    yy, xx = np.mgrid[0:48, 0:64] / np.float32(48)
    for i in range(SEQUENCE):  # a bright disc moving right over a gradient
        rgb = np.stack([xx / 1.4, yy, np.full_like(xx, 0.3)], -1)
        rgb[(xx - 0.2 - 0.15 * i) ** 2 + (yy - 0.5) ** 2 < 0.04] = (1.0, 0.9, 0.2)
        write_image(folder / f"frame_{i + 1:04d}.png", rgb)
    (folder / "notes.txt").write_text("not a frame")
    reference_video = encode_video(str(folder / "frame_####.png"), encoder, EncodeSettings(gaussians=250))

    def compare(obj, first):
        return cache_error(clip_params(obj), reference_video.params[first:first + obj.hypergs.num_frames])

    @record("import_sequence")
    def _():
        scene.render.fps = 25  # (File > Import of the .npz clip set 30): image files take the scene's rate
        out = {}
        for case, path in (("file", folder / "frame_0003.png"), ("pattern", folder / "frame_####.png")):
            result = bpy.ops.hypergs.import_video(filepath=str(path), quality="CUSTOM", gaussian_count=250)
            obj = bpy.context.view_layer.objects.active
            out[case] = dict(result=sorted(result), name=obj.name.split(".")[0], num_frames=obj.hypergs.num_frames,
                             fps=obj.hypergs.fps, error_vs_core=compare(obj, 0))
            bpy.data.meshes.remove(obj.data)
        return out

    @record("image_strip")
    def _():
        editor = scene.sequence_editor_create()
        strips = editor.strips if hasattr(editor, "strips") else editor.sequences
        strip = strips.new_image(name="seq", filepath=str(folder / "frame_0001.png"), channel=2, frame_start=10)
        for i in range(2, SEQUENCE + 1):
            strip.elements.append(f"frame_{i:04d}.png")
        compat = addon_module(addon, "com.compat")
        if hasattr(strip, "left_handle_offset"):  # trimmed: the strip starts at scene frame 11 with the second image
            strip.left_handle_offset = 1
        else:
            strip.frame_offset_start = 1

        def select(chosen):
            for s in compat.all_strips(editor):
                s.select = s == chosen
            editor.active_strip = chosen
        select(strip)
        result = bpy.ops.hypergs.convert_strip(quality="CUSTOM", gaussian_count=250)
        obj = bpy.data.objects["seq"]
        s = obj.hypergs
        scene_strip = editor.active_strip
        still = strips.new_image(name="still", filepath=str(folder / "frame_0001.png"), channel=3, frame_start=1)
        select(still)
        still_image = attempt("single image", lambda: bpy.ops.hypergs.convert_strip())
        return dict(result=sorted(result), muted=strip.mute, num_frames=s.num_frames, frame_start=s.frame_start,
                    scene_strip=[scene_strip.type, *compat.strip_range(scene_strip)],
                    source=s.source, source_start=s.source_start, error_vs_core=compare(obj, 1),
                    still_image=still_image)

    @record("paths")
    def _():
        for o in list(bpy.data.objects):
            if o.type == "MESH":
                bpy.data.meshes.remove(o.data)
        project = work / "project"
        project.mkdir()
        shutil.copy(hgs, project / "clip.hgs")
        option = "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties
        prop = bpy.types.Object.bl_rna.properties["hypergs"].fixed_type.bl_rna.properties["linked_path"]
        supports = bool(getattr(prop, "is_path_supports_blend_relative", False))
        bpy.ops.hypergs.import_clip(filepath=str(hgs), link=True)  # in an unsaved file: absolute
        bpy.context.view_layer.objects.active.name = "absolute"
        bpy.ops.wm.save_as_mainfile(filepath=str(project / "scene.blend"))
        bpy.ops.hypergs.import_clip(filepath=str(project / "clip.hgs"), link=True)
        bpy.context.view_layer.objects.active.name = "relative"
        out = dict(supports_relative=supports, blender_has_the_option=option,
                   absolute_after_save=bpy.data.objects["absolute"].hypergs.linked_path,
                   linked_when_saved=bpy.data.objects["relative"].hypergs.linked_path)
        bpy.ops.wm.save_mainfile()
        expected, _ = render(4, "paths_expected", [bpy.data.objects["relative"]])

        def state(name="relative"):
            obj = bpy.data.objects[name]
            image, _ = render(4, f"paths_{len(out)}", [obj])
            return dict(path=obj.hypergs.linked_path, problem=linked.problem(bpy.path.abspath(obj.hypergs.linked_path)),
                        matches=bool(np.abs(image - expected).max() == 0))

        moved = work / "moved"
        shutil.copytree(project, moved)
        shutil.rmtree(project)  # the old location is gone: only the relative path can find the clip
        bpy.ops.wm.open_mainfile(filepath=str(moved / "scene.blend"))
        out["moved"] = state()
        (moved / "sub").mkdir()
        bpy.ops.wm.save_as_mainfile(filepath=str(moved / "sub" / "scene.blend"))
        out["save_as_subfolder"] = state()
        (work / "copies").mkdir()
        bpy.ops.wm.save_as_mainfile(filepath=str(work / "copies" / "copy.blend"), copy=True)
        out["save_copy_keeps_open_file"] = bpy.data.objects["relative"].hypergs.linked_path
        bpy.ops.wm.open_mainfile(filepath=str(work / "copies" / "copy.blend"))
        out["copy_stored"] = bpy.data.objects["relative"].hypergs.linked_path
        bpy.ops.wm.open_mainfile(filepath=str(moved / "sub" / "scene.blend"))
        obj = bpy.data.objects["relative"]
        obj.hypergs.linked_path = "//../clip.hgs"  # typed in the panel
        out["typed"] = dict(path=obj.hypergs.linked_path, problem=linked.problem(bpy.path.abspath(obj.hypergs.linked_path)))
        return out

    shutil.rmtree(work / "user", ignore_errors=True)
    return results


if __name__ == "__main__":
    session_main(run_session)
