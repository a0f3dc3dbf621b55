"""The paper's transformer in the real bpy wheel: the Model choice is offered only where transformer
weights are (bundled, or the add-on preferences' folder: the tiny model here), the dialog shows its tiles,
Gaussians per tile and per frame and an estimate, File > Import with it converts a short clip with
tiles x N Gaussians per frame (what the core's encode gives), and weights that are not a transformer's
are refused with the scene as it was.

The weights: a tiny transformer at its initialisation (tools/tiny_transformer.py), exported as
`hypergs export` writes one; its picture is the floor's, its path the transformer's. One Blender
session in a subprocess (tests/blender_session.py).
"""
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
from blender_headless import SAMPLE, install_extension
from blender_session import (Recorder, addon_module, attempt_unchanged, cache_error, mesh_frames, operator_defaults,
                             run_blender_session, session_main, start_session, step, types_namespace)

from hypergs_blender.encode import QUALITY, plan_tile_layout

PER_TILE = 64  # Gaussians per tile: an 8 x 8 lattice
GRID = (2, 1)  # the patch grid asked for
FRAMES = 6  # of the sample (256 x 144): one clip of 4 and one padded
SESSION_TIMEOUT = 300
WEIGHTS_ENV = "HYPERGS_TEST_TRANSFORMER"


@pytest.fixture(scope="module")
def session(tmp_path_factory):
    from tiny_transformer import export_tiny_transformer
    work = tmp_path_factory.mktemp("blender_transformer")
    card = export_tiny_transformer(work / "weights")
    return run_blender_session(__file__, work, "bundled", SESSION_TIMEOUT,
                               env={"HYPERGS_ENCODER": "bundled", WEIGHTS_ENV: str(card.parent)})


def labels(drawn):
    return [c[1] for c in drawn if c[0] == "label"]


def test_the_model_is_offered_only_where_transformer_weights_are(session):
    r = step(session, "dialog")
    assert ["prop", "model", None] not in r["without_weights"]
    assert ["prop", "patch_grid", None] not in r["without_weights"]
    assert ["prop", "model", None] in r["with_weights"] and ["prop", "model", None] in r["bundled"]
    assert any("HyperGS transformer:" in line for line in r["preferences"]), r["preferences"]


def test_dialog_shows_tiles_gaussians_per_tile_and_an_estimate(session):
    drawn = step(session, "dialog")["custom"]
    assert ["prop", "patch_grid", None] in drawn and ["prop", "gaussian_count", None] in drawn
    count = GRID[0] * GRID[1] * PER_TILE
    assert any(line.startswith(f"{count:,} Gaussians per frame ({GRID[0]} x {GRID[1]} tiles of {PER_TILE},")
               and "at 256 x 144" in line for line in labels(drawn)), labels(drawn)
    assert any(line.startswith(f"{FRAMES} frames: about") and "CPU thread" in line for line in labels(drawn))


def test_a_preset_with_the_default_patch_grid(session):
    drawn = step(session, "dialog")["standard"]
    layout = plan_tile_layout(256, 144, 32, cell=QUALITY["standard"]["cell"])  # the tiny model's canvas: 32
    columns, rows = layout.tiles
    assert any(line.startswith(f"{layout.count:,} Gaussians per frame ({columns} x {rows} tiles of "
                               f"{layout.per_tile},") for line in labels(drawn)), labels(drawn)


def test_import_with_the_transformer_gives_tiles_times_n_gaussians(session):
    r = step(session, "convert")
    assert r["result"] == ["FINISHED"]
    assert r["gaussians"] == GRID[0] * GRID[1] * PER_TILE  # tiles x N
    assert r["grid"] == [GRID[0] * 8, GRID[1] * 8] and r["frames"] == FRAMES  # the lattice: 8 per tile side
    assert r["encoder"].startswith("transformer-onnx on CPU") and r["model"] == "TRANSFORMER"
    assert r["cache_error"] <= 1, r  # the frames are the core's encode with the same weights and settings
    assert r["psnr"] > 15, r


def test_weights_that_are_not_a_transformer_are_refused(session):
    r = step(session, "wrong_weights")
    assert r["raised"] and "Traceback" not in r["message"]
    assert r["expect"] in r["message"], r["message"]
    assert r["unchanged"], r["diff"]


# ----------------------------------------------------------------------------------------------------
# Blender side (run as a script: python test_blender_transformer.py ZIP WORKDIR OUT.json)

def run_session(zip_path, work, out_path):
    bpy, record, results = start_session(work, out_path)
    addon = install_extension(bpy, zip_path)
    quality = addon_module(addon, "ops.quality")
    preferences = addon_module(addon, "ops.preferences")
    jobs = addon_module(addon, "ops.jobs")
    prefs = bpy.context.preferences.addons[preferences.ADDON].preferences
    weights = os.environ[WEIGHTS_ENV]
    op = bpy.types.HYPERGS_OT_import_video
    custom = dict(model="TRANSFORMER", quality="CUSTOM", gaussian_count=PER_TILE, patch_grid=GRID)

    def dialog(**options):
        layout = Recorder()
        values = {**operator_defaults(bpy, op), "patch_grid": (0, 0), **options}
        quality.draw(layout, types_namespace(**values), [jobs.Source("sample", str(SAMPLE), 0, FRAMES)],
                     preferences.runtime(bpy.context))
        return [list(c) for c in layout.calls]

    @record("dialog")
    def _():
        out = dict(bundled=dialog())  # no folder set: the bundled transformer
        core_runtime = addon_module(addon, "hypergs_blender.runtime")
        bundled_dir, core_runtime.WEIGHTS_DIR = core_runtime.WEIGHTS_DIR, Path(work) / "bundles_none"
        try:
            out.update(without_weights=dialog())  # a build that bundles none
        finally:
            core_runtime.WEIGHTS_DIR = bundled_dir
        prefs.transformer_weights = weights
        layout = Recorder()
        type(prefs).draw(types_namespace(layout=layout, **{k: getattr(prefs, k) for k in
                                                           ("device", "threads", "transformer_weights")}),
                         bpy.context)
        out.update(preferences=labels(layout.calls), with_weights=dialog(), custom=dialog(**custom),
                   standard=dialog(model="TRANSFORMER"))
        return out

    @record("convert")
    def _():
        from hypergs_blender.encode import EncodeSettings, encode_video
        from hypergs_blender.network import resolve_encoder
        result = bpy.ops.hypergs.import_video(filepath=str(SAMPLE), last_frame=FRAMES, **custom)
        obj = bpy.context.active_object
        s = obj.hypergs
        params = np.stack(mesh_frames(bpy, obj, range(s.num_frames)))
        reference = encode_video(str(SAMPLE), resolve_encoder(weights=weights, backend="onnx"),
                                 EncodeSettings(gaussians=PER_TILE, grid=GRID), stop=FRAMES)
        return dict(result=sorted(result), gaussians=s.gaussians_per_frame, grid=list(s.grid), frames=s.num_frames,
                    encoder=s.encoder, model=s.model, psnr=s.psnr, cache_error=cache_error(params, reference.params))

    @record("wrong_weights")
    def _():
        conv = Path(work) / "conv_only"  # a folder of the conv network alone
        conv.mkdir()
        shutil.copy(Path(addon.__file__).parent / "hypergs_blender" / "weights" / "hypergs.json", conv)
        prefs.transformer_weights = str(conv)
        return attempt_unchanged(bpy, "not a transformer's", lambda: bpy.ops.hypergs.import_video(
            filepath=str(SAMPLE), last_frame=2, model="TRANSFORMER"))


if __name__ == "__main__":
    session_main(run_session)
