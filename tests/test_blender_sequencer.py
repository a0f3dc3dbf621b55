"""The Sequencer in the real bpy wheel: Convert to Gaussians on the selected movie strips, each becoming a
scene rendered by HyperGS that a scene strip plays with the original timing; the round trip (convert ->
the scene strip plays -> F12 of the Sequencer's output against the source); menus, dialog; failures,
cancels and half-done conversions leave the file as it was.

One Blender session in a subprocess (tests/blender_session.py), as in test_blender_addon.py.
"""
import os

import numpy as np
import pytest
from blender_headless import SAMPLE, install_extension, read_png, render_png, set_strip_range
from blender_session import (Recorder, addon_module, attempt_unchanged, diff, files_under, operator_defaults,
                             run_blender_session, session_main, snapshot, start_session, step, types_namespace)

from hypergs_blender.encode import QUALITY, FloorEncoder, plan_layout

ENCODER = "floor"  # fast; the matrix (tools/blender_matrix.py) runs the Sequencer with the network
GAUSSIANS = plan_layout(256, 144, FloorEncoder.stride, cell=QUALITY["draft"]["cell"]).count  # Draft, the sample
# The sample (256 x 144, 60 frames) as three strips: timeline [first, end) showing source frames from
# `source` on. "a" starts where its content does; "b" is trimmed at both ends; "c" stays unselected.
STRIPS = {"a": dict(content=1, first=1, end=13, source=0, channel=1),
          "b": dict(content=21, first=31, end=41, source=10, channel=1),
          "c": dict(content=50, first=50, end=60, source=0, channel=1)}
ROUND_TRIP = {1: ("a", 0), 7: ("a", 6), 12: ("a", 11), 31: ("b", 10), 36: ("b", 15), 40: ("b", 19)}
GAP = 20  # no strip there: black
PSNR_MARGIN = 0.3  # dB the Sequencer's F12 may lose to the core's own encode -> render (8-bit PNG)
SESSION_TIMEOUT = 300


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    work = tmp_path_factory.mktemp("blender_sequencer")
    return run_blender_session(__file__, work, ENCODER, SESSION_TIMEOUT)


def test_menus_offer_the_conversion_with_a_dialog(session):
    r = step(session, "menus")
    assert r["strip_menu"] and r["context_menu"]
    assert r["drawn"] == [["operator", "Convert to Gaussians...", "MOD_PARTICLES"]]
    assert r["operator_context"] == "INVOKE_DEFAULT"  # invoke shows the options dialog


@pytest.mark.parametrize("preset", ["DRAFT", "STANDARD", "HIGH"])
def test_dialog_shows_the_gaussians_per_frame_and_an_estimate(session, preset):
    drawn = step(session, "menus")["dialog"][preset]
    labels = [c[1] for c in drawn if c[0] == "label"]
    count = plan_layout(256, 144, FloorEncoder.stride, cell=QUALITY[preset.lower()]["cell"]).count
    for name in ("a", "b"):  # each selected strip, at its source's resolution
        assert any(line.startswith(f"{name}: {count:,} Gaussians per frame") and "at 256 x 144" in line
                   for line in labels), labels
    # The time on the CPU threads it assumes (the preferences': one per core here), and the cache's size.
    threads = os.cpu_count()
    assert any(line.startswith("22 frames") and f"on {threads} CPU thread" in line and "MB of frame cache" in line
               for line in labels), labels
    assert ["prop", "quality", None] in drawn and ["prop", "cell_size", None] not in drawn
    # High refines; this Blender's Python has no PyTorch: the dialog says so before anything runs.
    assert any("refining needs PyTorch" in line for line in labels) == (QUALITY[preset.lower()]["refine"] > 0)


def test_dialog_custom_shows_the_custom_options(session):
    drawn = step(session, "menus")["dialog"]["CUSTOM"]
    assert all(["prop", name, None] in drawn for name in ("cell_size", "gaussian_count", "refine_steps"))


@pytest.mark.parametrize("case", ["missing_movie", "nothing_convertible", "apply_fails"])
def test_failed_conversions_change_nothing(session, case):
    r = step(session, "failures")[case]
    assert r["raised"] and "Traceback" not in r["message"]
    assert r["expect"].lower() in r["message"].lower(), r["message"]
    assert r["unchanged"], r["diff"]


def test_a_failure_after_the_first_clip_takes_it_back(session):
    r = step(session, "failures")["apply_fails"]
    assert r["added_before_failing"] == 2 and r["unchanged"], r["diff"]
    assert r["cache_files_before"] == r["cache_files_after"]  # both clips' frame caches removed again


def test_esc_during_the_second_clip_changes_nothing(session):
    r = step(session, "failures")["cancelled"]
    assert r["result"] == ["CANCELLED"] and r["encoded"] == 2
    assert r["unchanged"], r["diff"]
    assert r["cache_files_before"] == r["cache_files_after"]  # the first clip's frame cache removed again


def test_selected_strips_become_scene_strips(session):
    r = step(session, "convert")
    assert r["result"] == ["FINISHED"]
    assert sorted(r["converted"]) == ["a", "b"] and r["others"]["c"] == dict(mute=False, scene_strips=0)
    for name, c in r["converted"].items():
        spec = STRIPS[name]
        count = spec["end"] - spec["first"]
        assert c["movie_muted"] and c["scene_strip_range"] == [spec["first"], spec["end"]]
        assert c["scene_strip_channel"] == spec["channel"] + 1
        assert c["origin"] == ([0.25, 0.75] if name == "a" else [0.5, 0.5])  # the movie's placement, copied
        assert c["scene"] == dict(engine="HYPERGS", resolution=[256, 144, 100], frames=[1, count], fps=24.0,
                                  camera=True, view_transform="Standard")
        assert c["clip"] == dict(frame_start=1, num_frames=count, source_start=spec["source"],
                                 gaussians_per_frame=GAUSSIANS, quality="DRAFT")
    assert r["preview_shading"] == "RENDERED"  # the Sequencer's preview shows the Gaussians
    assert r["selected"] == sorted([c["scene_strip"] for c in r["converted"].values()] + ["colour"])
    report = next(line for line in session["console"].splitlines() if line.startswith("Info: HyperGS: "))
    assert all(f"played by the scene strip '{c['scene_strip']}'" in report for c in r["converted"].values())


@pytest.mark.parametrize("frame", sorted(ROUND_TRIP))
def test_f12_of_the_sequencer_shows_the_gaussians(session, frame):
    f = step(session, "round_trip")[str(frame)]
    assert f["psnr_source"] > f["psnr_reference"] - PSNR_MARGIN, f
    assert f["psnr_vs_core"] > 40, f  # the Sequencer's output is the core's render of that frame
    assert f["psnr_source"] > f["psnr_wrong_frame"] + 1, f  # and of that frame only: the timing holds


def test_gap_between_strips_is_black(session):
    assert step(session, "round_trip")["gap_max"] == 0


def test_cutting_the_scene_strip_keeps_the_timing(session):
    r = step(session, "cut")
    assert r["psnr_vs_core"] > 40 and r["psnr_source"] > r["psnr_wrong_frame"] + 1, r


def test_a_phone_video_converts_as_its_strip_shows_it(session):
    """A phone's video: landscape frames with a display rotation, at a variable rate, in HLG. The movie strip
    shows it on its nominal rate (a frame held where a slot is skipped), upright from Blender 4.4 on (4.2's and
    4.3's ignore the rotation) and colour-managed from 5.0 on (before, the coded values); the core reads the
    frames as this Blender shows them (compat.MOVIE_DISPLAY), and the converted clip shows them in the strip's
    place."""
    r = step(session, "phone")
    rotation, hdr = r["movie_display"]
    shown = [144, 256] if rotation else [256, 144]
    assert r["strip_size"] == shown, r  # this Blender's reading...
    assert r["strip_colorspace"] == ("Rec.2100-HLG" if hdr else "sRGB"), r
    assert r["psnr_decoded_vs_movie"] > 35, r  # ...is the core's: its frame 4 is what the strip shows there
    assert r["result"] == ["FINISHED"] and r["clip_resolution"] == [*shown, 100], r
    assert r["clip_frames"] == r["strip_frames"] == [70, 77], r  # 7 slots of 1/24 s
    assert r["psnr_vs_core"] > 40, r  # the Sequencer's output is the core's render of the strip's frame 4...
    assert r["psnr_source"] > r["psnr_reference"] - PSNR_MARGIN, r
    assert r["psnr_source"] > r["psnr_next_frame"] + 1, r  # ...which is the 4th frame stored, not the 5th


def test_tagged_photos_convert_as_their_image_strip_shows_them(session):
    """Phone photos tagged "rotate 90" (EXIF orientation 6): Blender's image strip shows them as stored,
    landscape, and so does the converted clip."""
    r = step(session, "tagged_images")
    assert r["strip_size"] == [256, 144], r  # this Blender ignores the tag
    assert r["result"] == ["FINISHED"] and r["clip_resolution"] == [256, 144, 100], r
    assert r["psnr_vs_core"] > 40, r  # the Sequencer's output is the core's render of the stored image 2...
    assert r["psnr_source"] > r["psnr_reference"] - PSNR_MARGIN, r  # ...as good against the strip as the core's


# ----------------------------------------------------------------------------------------------------
# Blender side (run as a script: python test_blender_sequencer.py ZIP WORKDIR OUT.json)

def run_session(zip_path, work, out_path):
    bpy, record, results = start_session(work, out_path)
    addon = install_extension(bpy, zip_path)
    compat = addon_module(addon, "com.compat")
    from hypergs_blender.encode import EncodeSettings, encode_video
    from hypergs_blender.io.frames import iter_frames
    from hypergs_blender.metrics import psnr
    from hypergs_blender.render import render_frames
    encoder = addon_module(addon, "hypergs_blender.runtime").make_encoder()

    scene = bpy.context.scene
    for o in list(bpy.data.objects):  # a Video Editing file: strips only
        bpy.data.objects.remove(o)
    scene.render.fps, scene.render.fps_base = 24, 1.0
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 256, 144, 100
    scene.view_settings.view_transform = "Standard"
    scene.render.dither_intensity = 0.0
    scene.frame_start, scene.frame_end = 1, 60
    editor = scene.sequence_editor_create()
    strips = compat.top_strips(editor)
    made = {}
    for name, spec in STRIPS.items():
        strip = strips.new_movie(name=name, filepath=str(SAMPLE), channel=spec["channel"],
                                 frame_start=spec["content"])
        set_strip_range(strip, spec["first"], spec["end"])
        made[name] = strip
    # A placement the scene strip must copy (an origin alone leaves the picture as it is at scale 1).
    made["a"].transform.origin = (0.25, 0.75)
    strips.new_effect(name="colour", type="COLOR", channel=3, frame_start=45,  # where no frame is compared
                      **(dict(length=5) if bpy.app.version >= (5, 0, 0) else dict(frame_end=50)))

    def select(*names):
        for s in compat.all_strips(editor):
            s.select = s.name in names
        editor.active_strip = compat.all_strips(editor)[names[0]] if names else None

    def attempt(expect, call):
        return attempt_unchanged(bpy, expect, call)

    @record("menus")
    def _():
        ui = addon_module(addon, "ui")
        recorder = Recorder()
        ui.menu_strip(types_namespace(layout=recorder), bpy.context)
        drawn = [list(c) for c in recorder.calls]
        recorder.calls.clear()
        op = bpy.types.HYPERGS_OT_convert_strip
        select("a", "b")
        dialog = {}
        for preset in ("DRAFT", "STANDARD", "HIGH", "CUSTOM"):
            layout = Recorder()
            op.draw(types_namespace(layout=layout, **dict(operator_defaults(bpy, op), quality=preset)), bpy.context)
            dialog[preset] = [list(c) for c in layout.calls]
        return dict(strip_menu=ui.menu_strip in bpy.types.SEQUENCER_MT_strip.draw._draw_funcs,
                    context_menu=ui.menu_strip in bpy.types.SEQUENCER_MT_context_menu.draw._draw_funcs,
                    drawn=drawn, operator_context=recorder.attributes.get("operator_context"), dialog=dialog)

    @record("failures")
    def _():
        out = {}
        gone = work / "gone.mp4"
        gone.write_bytes(SAMPLE.read_bytes())
        missing = strips.new_movie(name="missing", filepath=str(gone), channel=5, frame_start=1)
        gone.unlink()
        select("a", "missing")
        out["missing_movie"] = attempt("gone.mp4: no such video file", lambda: bpy.ops.hypergs.convert_strip())
        strips.remove(missing)
        select("colour")
        out["nothing_convertible"] = attempt("'colour': not a movie strip",
                                             lambda: bpy.ops.hypergs.convert_strip())
        select("a", "b")
        plan = addon_module(addon, "hypergs_blender.encode").EncodePlan
        original = plan.chunks
        calls = []

        def cancel_in_the_second(self, progress=None, *args, **kwargs):  # Esc while encoding strip "b"
            calls.append(self.path)
            return original(self, (lambda done, total: len(calls) < 2), *args, **kwargs)

        plan.chunks = cancel_in_the_second
        caches = addon_module(addon, "com.cache").cache_folder()  # where the conversions write their caches
        before, files_before = snapshot(bpy), files_under(caches)
        try:
            result = bpy.ops.hypergs.convert_strip()
        finally:
            plan.chunks = original
        after = snapshot(bpy)
        out["cancelled"] = dict(result=sorted(result), encoded=len(calls), unchanged=before == after,
                                diff=diff(before, after), cache_files_before=files_before,
                                cache_files_after=files_under(caches))
        scene_module = addon_module(addon, "ops.scene")
        add = scene_module.add_strip_scene
        added = []

        def second_fails(*args, **kwargs):  # the first clip is in the file already when the second fails
            added.append(add(*args, **kwargs))
            if len(added) == 2:
                raise RuntimeError("simulated failure while adding the second clip")
            return added[-1]

        scene_module.add_strip_scene = second_fails
        files_before = files_under(caches)
        try:
            out["apply_fails"] = attempt("simulated failure", lambda: bpy.ops.hypergs.convert_strip())
        finally:
            scene_module.add_strip_scene = add
        out["apply_fails"].update(added_before_failing=len(added), cache_files_before=files_before,
                                  cache_files_after=files_under(caches))
        return out

    @record("convert")
    def _():
        select("a", "b", "colour")  # the colour strip is not a movie: left alone
        before = {s.name for s in compat.all_strips(editor)}
        result = bpy.ops.hypergs.convert_strip(quality="DRAFT")
        converted = {}
        for s in compat.all_strips(editor):
            if s.name in before or s.type != "SCENE":
                continue
            sc = s.scene
            clip = next(o for o in sc.objects if o.hypergs.is_clip)
            movie = made[clip.name.split(".")[0]]
            converted[movie.name] = dict(
                scene_strip=s.name, movie_muted=movie.mute, scene_strip_range=list(compat.strip_range(s)),
                scene_strip_channel=s.channel, origin=[round(v, 4) for v in s.transform.origin],
                scene=dict(engine=sc.render.engine, resolution=[sc.render.resolution_x, sc.render.resolution_y,
                                                                sc.render.resolution_percentage],
                           frames=[sc.frame_start, sc.frame_end], fps=sc.render.fps / sc.render.fps_base,
                           camera=sc.camera is not None, view_transform=sc.view_settings.view_transform),
                clip=dict(frame_start=clip.hypergs.frame_start, num_frames=clip.hypergs.num_frames,
                          source_start=clip.hypergs.source_start,
                          gaussians_per_frame=clip.hypergs.gaussians_per_frame, quality=clip.hypergs.quality))
        return dict(result=sorted(result), converted=converted,
                    others={"c": dict(mute=made["c"].mute,
                                      scene_strips=sum(1 for s in compat.all_strips(editor) if s.type == "SCENE"
                                                       and s.name not in before and s.scene.name.startswith("c")))},
                    preview_shading=scene.render.sequencer_gl_preview,
                    selected=sorted(s.name for s in compat.all_strips(editor) if s.select))

    sources = sorted({source for _, source in ROUND_TRIP.values()} | {source + 3 for _, source in ROUND_TRIP.values()})
    truth = {i: f / np.float32(255) for i, f in iter_frames(str(SAMPLE), sources)}
    references = {name: encode_video(str(SAMPLE), encoder, EncodeSettings.choose("draft"), start=spec["source"],
                                     stop=spec["source"] + spec["end"] - spec["first"])
                  for name, spec in STRIPS.items() if name != "c"}

    def f12(frame, name):
        png = work / f"{name}.png"
        render_png(bpy, scene, frame, png)
        return read_png(bpy, png)

    def compare(image, name, source):
        ref = render_frames(references[name], 256, 144, [source - STRIPS[name]["source"]])[0]
        return dict(psnr_source=float(psnr(image, truth[source])),
                    psnr_reference=float(psnr(ref, truth[source])),
                    psnr_vs_core=float(psnr(image, np.clip(ref, 0, 1))),
                    psnr_wrong_frame=float(psnr(image, truth[source + 3])))

    @record("round_trip")
    def _():
        out = {str(frame): compare(f12(frame, f"seq_{frame}"), name, source)
               for frame, (name, source) in ROUND_TRIP.items()}
        out["gap_max"] = float(f12(GAP, "seq_gap").max())
        return out

    @record("cut")
    def _():
        scene_strip = next(s for s in compat.all_strips(editor) if s.type == "SCENE" and s.scene.name.startswith("a"))
        set_strip_range(scene_strip, 4, 13)  # the user trims the converted clip: frame 4 still shows source frame 3
        return compare(f12(4, "cut_4"), "a", 3)

    @record("phone")
    def _():
        from conftest import write_video
        # a phone's video: landscape frames turned by the container, at a variable rate (slot 3 of 1/24 s skipped,
        # so the strip's frame 4 is the 4th frame, not the 5th), HLG HDR; frames 8 apart, so neighbours differ
        stored = np.stack([f for _, f in iter_frames(str(SAMPLE), range(0, 48, 8))])
        phone = write_video(work / "phone.mp4", stored, fps=24, rotation=90, slots=[0, 1, 2, 4, 5, 6], hdr="hlg")
        for s in compat.all_strips(editor):
            s.mute = True
        width, height = (144, 256) if compat.MOVIE_DISPLAY.rotation else (256, 144)  # an edit of the video as shown
        scene.render.resolution_x, scene.render.resolution_y = width, height
        strip = strips.new_movie(name="phone", filepath=str(phone), channel=8, frame_start=70)
        select("phone")
        movie = {k: f12(70 + k, f"phone_movie_{k}") for k in (4, 5)}  # what Blender shows of the file
        decoded = dict(iter_frames(str(phone), [4], display=compat.MOVIE_DISPLAY))[4] / np.float32(255)
        result = bpy.ops.hypergs.convert_strip(quality="DRAFT")
        scene_strip = next(s for s in compat.all_strips(editor) if s.type == "SCENE" and s.scene.name.startswith("phone"))
        r = scene_strip.scene.render
        image = f12(74, "phone_scene")
        core = render_frames(encode_video(str(phone), encoder, EncodeSettings.choose("draft"), start=4, stop=5,
                                          display=compat.MOVIE_DISPLAY), width, height, [0])[0]
        return dict(blender=bpy.app.version_string, movie_display=[compat.MOVIE_DISPLAY.rotation, compat.MOVIE_DISPLAY.hdr],
                    result=sorted(result), strip_size=[strip.elements[0].orig_width, strip.elements[0].orig_height],
                    strip_colorspace=strip.colorspace_settings.name,
                    strip_frames=[strip.frame_final_start, strip.frame_final_end],
                    clip_resolution=[r.resolution_x, r.resolution_y, r.resolution_percentage],
                    clip_frames=[scene_strip.frame_final_start, scene_strip.frame_final_end],
                    psnr_decoded_vs_movie=float(psnr(decoded, movie[4])),
                    psnr_source=float(psnr(image, movie[4])), psnr_next_frame=float(psnr(image, movie[5])),
                    psnr_reference=float(psnr(core, decoded)), psnr_vs_core=float(psnr(image, np.clip(core, 0, 1))))

    @record("tagged_images")
    def _():
        from conftest import write_image_tagged
        folder = work / "tagged"
        folder.mkdir()
        stored = [f for _, f in iter_frames(str(SAMPLE), range(0, 24, 8))]
        for i, frame in enumerate(stored, 1):
            write_image_tagged(folder / f"photo_{i:04d}.png", frame, Orientation=6)
        for s in compat.all_strips(editor):
            s.mute = True
        scene.render.resolution_x, scene.render.resolution_y = 256, 144
        strip = strips.new_image(name="tagged", filepath=str(folder / "photo_0001.png"), channel=9, frame_start=90)
        for i in range(2, len(stored) + 1):
            strip.elements.append(f"photo_{i:04d}.png")
        select("tagged")
        shown = f12(91, "tagged_strip")  # what Blender shows of the second photo
        result = bpy.ops.hypergs.convert_strip(quality="DRAFT")
        scene_strip = next(s for s in compat.all_strips(editor) if s.type == "SCENE" and s.scene.name.startswith("tagged"))
        r = scene_strip.scene.render
        image = f12(91, "tagged_scene")
        core = render_frames(encode_video(str(folder / "photo_0001.png"), encoder, EncodeSettings.choose("draft"),
                                          start=1, stop=2), 256, 144, [0])[0]
        return dict(result=sorted(result), strip_size=[strip.elements[0].orig_width, strip.elements[0].orig_height],
                    clip_resolution=[r.resolution_x, r.resolution_y, r.resolution_percentage],
                    psnr_source=float(psnr(image, shown)), psnr_reference=float(psnr(core, shown)),
                    psnr_vs_core=float(psnr(image, np.clip(core, 0, 1))))

    return results


if __name__ == "__main__":
    session_main(run_session)
