"""The paper's transformer as a model users run: per-clip anchors, the patch grid's windows
(network.TransformerEncoder), its layout (encode.TileLayout), export to ONNX and loading by card."""
import json
from dataclasses import replace

import numpy as np
import pytest
import torch

from hypergs_blender.commands.cli import main
from hypergs_blender.encode import (EncodePlan, EncodeSettings, TileLayout, encode_video, frames_layout,
                                    plan_tile_layout)
from hypergs_blender.errors import HyperGSError
from hypergs_blender import network
from hypergs_blender.gaussians import covariance, grid_anchors, lattice_anchors
from hypergs_blender.model import PRESETS, HyperGS, TransformerConfig
from hypergs_blender.network import (TransformerEncoder, onnx_encoder, resolve_encoder, tiles, torch_encoder,
                                     transformer_geometry)
from hypergs_blender.training.export import card_of, export_onnx, save_weights
from tiny_transformer import TINY



def random_transformer(parametrization="local", seed=0) -> HyperGS:
    """A tiny transformer away from its grid-floor initialisation."""
    torch.manual_seed(seed)
    model = HyperGS(TransformerConfig(**TINY, parametrization=parametrization, max_gaussians=64))
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn_like(p) * 0.05)
    return model.eval()


def test_lattice_anchors_are_windows_of_one_lattice():
    np.testing.assert_array_equal(lattice_anchors(6, [(0.5, 0.5)])[0], grid_anchors(36))
    # a window cut from a lattice of spacing s at any offset holds k x k of its points, at its phase
    k, canvas, offset = 5, 40.0, 13.0
    s = canvas / k
    points = (np.arange(40) + 0.5) * s
    inside = points[(points >= offset) & (points < offset + canvas)]
    phase = (inside[0] - offset) / s
    window = lattice_anchors(k, [(phase, 0.5)])[0]
    np.testing.assert_allclose((window[:k, 0] + 1) / 2 * canvas + offset, inside, rtol=1e-5)


def test_anchors_per_clip_match_one_clip_at_a_time():
    model = random_transformer()
    frames = torch.rand(3, 4, 32, 32, 3)
    anchors = torch.from_numpy(lattice_anchors(5, np.random.default_rng(0).random((3, 2))))
    cell = torch.tensor([2.0 / 5])
    with torch.no_grad():
        together = model(frames, anchors, cell)
        apart = torch.cat([model(frames[i:i + 1], anchors[i], cell) for i in range(3)])
    torch.testing.assert_close(together, apart, atol=1e-5, rtol=1e-5)


def probe_encoder(canvas=32, clip_frames=4, margin=4) -> TransformerEncoder:
    """A transformer stand-in whose Gaussians sit on their anchors, coloured by the pixel under them and
    scaled by the phase it was given: what the windows hand it shows in the frame's Gaussians."""
    calls = []

    def forward(frames, anchors, cell):
        calls.append(frames.shape[0])
        b, t, c = frames.shape[:3]
        n = anchors.shape[1]
        out = np.zeros((b, t, n, 8), np.float32)
        out[..., 0:2] = anchors[:, None]
        pix = np.clip(((anchors + 1) / 2 * c + 1e-3).astype(int), 0, c - 1)  # the pixel under each anchor
        for i in range(b):
            out[i, :, :, 5:8] = frames[i][:, pix[i, :, 1], pix[i, :, 0]]
        out[..., 2:4] = cell[0] * c / 2
        return out

    encoder = TransformerEncoder(forward, canvas, clip_frames, 8, "probe", margin, (1, 4096))
    encoder.calls = calls
    return encoder


@pytest.mark.parametrize("tiles, k, margin", [((1, 1), 4, 4), ((3, 2), 5, 4), ((2, 2), 7, 8), ((3, 1), 6, 0)])
def test_windows_give_every_lattice_point_once(tiles, k, margin):
    """Over any patch grid, the windows' cores hand back the whole frame's k-per-tile lattice, each point
    once, row-major, with the pixels under it: the windows are cut and placed right."""
    c = 32
    encoder = probe_encoder(c, margin=margin)
    w, h = tiles[0] * c, tiles[1] * c
    frames = np.random.default_rng(1).random((6, h, w, 3), dtype=np.float32)
    cols, rows = tiles[0] * k, tiles[1] * k
    out = encoder.predict(frames, (cols, rows))
    assert out.shape == (6, rows * cols, 8)
    xs, ys = (np.arange(cols) + 0.5) / cols * 2 - 1, (np.arange(rows) + 0.5) / rows * 2 - 1
    np.testing.assert_allclose(out[0, :, 0].reshape(rows, cols), np.broadcast_to(xs, (rows, cols)), atol=1e-5)
    np.testing.assert_allclose(out[0, :, 1].reshape(rows, cols), np.broadcast_to(ys[:, None], (rows, cols)), atol=1e-5)
    px = np.clip(((xs + 1) / 2 * w + 1e-3).astype(int), 0, w - 1)  # (off exact pixel borders, as the probe)
    py = np.clip(((ys + 1) / 2 * h + 1e-3).astype(int), 0, h - 1)
    # (the windows that share a point near a border see the same pixel under it: their blend is that pixel)
    np.testing.assert_allclose(out[:, :, 5:8].reshape(6, rows, cols, 3), frames[:, py][:, :, px], atol=1e-6)
    # 6 frames are 2 clips of 4 (the second padded), every window of both in the forward passes
    windows = len(encoder.tile_borders(w, h)[0]) + 1, len(encoder.tile_borders(w, h)[1]) + 1
    assert sum(encoder.calls) == 2 * windows[0] * windows[1]
    if margin and tiles[0] > 1:
        assert windows[0] > tiles[0]  # overlapping windows, each core with context beyond it


@pytest.mark.parametrize("band", [0.0, 12.0])
def test_windows_cross_fade_across_their_borders(monkeypatch, band):
    """Each window says where it starts (its colour and rotation follow its top-left pixel); a Gaussian
    within band / 2 working pixels of a border between cores is the linear blend of the two windows'
    (the owner's weight 1/2 + its distance into the core / band), means and colours averaged and the
    covariance the weighted mean of theirs; elsewhere, and everywhere with band 0, its core's own."""
    monkeypatch.setattr(network, "SEAM_BLEND", band)
    c, k, margin, tiles_x, tiles_y = 32, 8, 8, 3, 2
    w, h = tiles_x * c, tiles_y * c

    def forward(frames, anchors, cell):
        out = np.zeros((frames.shape[0], frames.shape[1], anchors.shape[1], 8), np.float32)
        out[..., 0:2] = anchors[:, None]
        corner = frames[:, :, 0, 0]  # [B, T, 3]: the window's start, x / w and y / h
        out[..., 2], out[..., 3] = 2.0, 0.5
        out[..., 4] = np.pi * (corner[..., 0] + 2 * corner[..., 1])[..., None]
        out[..., 5:7] = corner[:, :, None, :2]
        return out

    ramp = np.zeros((2, h, w, 3), np.float32)
    ramp[..., 0], ramp[..., 1] = np.arange(w) / w, (np.arange(h) / h)[:, None]
    out = TransformerEncoder(forward, c, 2, 8, "probe", margin, (1, 64)).predict(ramp, (tiles_x * k, tiles_y * k))
    out = out[0].reshape(tiles_y * k, tiles_x * k, 8)

    def weights(size):  # [points, windows]: each window's share of each lattice point along an axis
        points = (np.arange(size * k // c) + 0.5) * c / k
        cores = [(c0, c1) for _, _, c0, c1 in tiles(size, margin, 1, c)]
        share = np.stack([(points >= c0) & (points < c1) for c0, c1 in cores], 1).astype(float)
        for i, (c0, c1) in enumerate(cores):
            inside = (points >= c0) & (points < c1)
            for border, into, neighbour in ((c0, points - c0, i - 1), (c1, c1 - points, i + 1)):
                if not band or border in (0, size):  # the frame's own edge: no neighbour
                    continue
                near = inside & (np.abs(points - border) < band / 2)
                share[near, i] = 0.5 + into[near] / band
                share[near, neighbour] = 0.5 - into[near] / band
        return share

    starts_x, starts_y = ([s for s, _, _, _ in tiles(n, margin, 1, c)] for n in (w, h))
    wx, wy = weights(w), weights(h)
    assert ((wx > 0) & (wx < 1)).any() == (band > 0)  # the probe's frame has blended points
    np.testing.assert_allclose(out[..., 5], np.broadcast_to(wx @ np.array(starts_x) / w, out.shape[:2]), atol=1e-5)
    np.testing.assert_allclose(out[..., 6], np.broadcast_to((wy @ np.array(starts_y) / h)[:, None], out.shape[:2]),
                               atol=1e-5)
    rotation = np.pi * (np.array(starts_x)[None, :] / w + 2 * np.array(starts_y)[:, None] / h)  # [windows y, x]
    windows_cov = covariance(np.array([2.0, 0.5]), rotation)
    expected = np.einsum("ya,xb,abij->yxij", wy, wx, windows_cov)
    blended = covariance(out[..., 2:4].astype(np.float64), out[..., 4].astype(np.float64))
    np.testing.assert_allclose(blended, expected, atol=1e-5)
    cols, rows = tiles_x * k, tiles_y * k  # the means stay on the lattice
    np.testing.assert_allclose(out[..., 0], np.broadcast_to((np.arange(cols) + 0.5) / cols * 2 - 1, (rows, cols)),
                               atol=1e-5)


def test_last_clip_is_padded_with_its_last_frame():
    model = random_transformer()
    encoder = torch_encoder(model)
    frames = np.random.default_rng(2).random((6, 32, 32, 3), dtype=np.float32)
    padded = np.concatenate([frames, frames[-1:], frames[-1:]])
    np.testing.assert_allclose(encoder.predict(frames, (5, 5)), encoder.predict(padded, (5, 5))[:6], atol=1e-6)
    with pytest.raises(ValueError, match="cannot hold"):
        encoder.predict(frames, (5, 6))


def test_tile_layout():
    layout = plan_tile_layout(256, 256, 128, gaussians=1000, grid=(2, 2))
    assert isinstance(layout, TileLayout) and layout.per_tile == 32 * 32 and layout.count == 4 * 1024
    assert (layout.cols, layout.rows, layout.work_width, layout.work_height) == (64, 64, 256, 256)
    # default grid: tiles of about the canvas at the frame's resolution; a cell size sets k per tile
    hd = plan_tile_layout(1280, 720, 128, cell=8)
    assert hd.tiles == (10, 6) and hd.per_tile == 15 ** 2 and not hd.note  # tiles of 128 x 120 px: 15 cells of 8.3
    assert plan_tile_layout(100, 60, 128, gaussians=50).tiles == (1, 1)
    # more Gaussians per tile, or more tiles, is more Gaussians
    counts = [plan_tile_layout(432, 240, 128, gaussians=n, grid=(1, 1)).count for n in (250, 1000, 3000)]
    assert counts == sorted(counts) and counts[-1] == 55 * 55
    clamped = plan_tile_layout(256, 256, 128, gaussians=10_000, grid=(1, 1), trained=(200, 3600))
    assert clamped.per_tile == 3600 and "outside the trained range" in clamped.note
    with pytest.raises(HyperGSError, match="not both"):
        plan_tile_layout(64, 64, 32, gaussians=10, cell=8)


def test_conv_and_floor_refuse_a_patch_grid():
    from hypergs_blender.encode import FloorEncoder
    frames = np.zeros((1, 64, 64, 3), np.uint8)
    assert frames_layout(frames, FloorEncoder(), gaussians=64, grid=(1, 1)).count == 64
    with pytest.raises(HyperGSError, match="patch grid is the transformer's"):
        frames_layout(frames, FloorEncoder(), gaussians=64, grid=(2, 2))


@pytest.mark.parametrize("parametrization", ["local", "paper"])
def test_onnx_matches_torch(tmp_path, parametrization):
    """One exported graph, dynamic batch and Gaussian count, gives torch's Gaussians on any patch grid."""
    model = random_transformer(parametrization)
    export_onnx(model, tmp_path / "m.onnx")
    card = card_of(model)
    assert card["arch"] == "transformer"
    onnx, torch_ = onnx_encoder(tmp_path / "m.onnx", card), torch_encoder(model)
    assert onnx.name == "transformer-onnx" and torch_.name == "transformer-torch"
    rng = np.random.default_rng(0)
    for shape, k in (((5, 32, 32, 3), 4), ((4, 64, 96, 3), 6), ((2, 64, 64, 3), 8)):
        frames = rng.random(shape, dtype=np.float32)
        cells = (k * shape[2] // 32, k * shape[1] // 32)
        a, b = onnx.predict(frames, cells), torch_.predict(frames, cells)
        assert a.shape == (shape[0], cells[0] * cells[1], 8)
        np.testing.assert_allclose(a, b, atol=1e-4, rtol=1e-4)


@pytest.fixture
def exported(tmp_path):
    """A tiny transformer exported as `hypergs export` writes it."""
    folder = tmp_path / "weights"
    model = random_transformer()
    save_weights(model, folder, "tiny", info={"train_args": {"gaussians": "4:400"}})
    export_onnx(model, folder / "tiny.onnx")
    return folder


def test_loaded_by_card_on_both_backends(exported, moving_video):
    card = json.loads((exported / "tiny.json").read_text())
    assert card["arch"] == "transformer" and card["geometry"]["gaussians"] == [4, 400]
    torch_, onnx = resolve_encoder(weights=exported, backend="torch"), resolve_encoder(weights=exported, backend="onnx")
    assert (torch_.name, onnx.name) == ("transformer-torch", "transformer-onnx")
    # the encode loop: clips of clip_frames (7 frames: the last clip padded), the lattice as the clip's grid
    videos = [encode_video(moving_video, e, EncodeSettings(gaussians=16, grid=(2, 1)), stop=7,
                           chunk_frames=3) for e in (torch_, onnx)]
    assert videos[0].params.shape == (7, 2 * 16, 8) and videos[0].grid == (8, 4)
    np.testing.assert_allclose(videos[0].params, videos[1].params, atol=1e-4)
    assert EncodePlan(moving_video, torch_, EncodeSettings(gaussians=16)).layout.tiles == (2, 2)  # 64 x 48 in tiles of about 32


def test_a_folder_of_several_models_needs_a_name(exported, tmp_path):
    import shutil
    for suffix in ("json", "safetensors", "onnx"):
        shutil.copy(exported / f"tiny.{suffix}", exported / f"other.{suffix}")
    with pytest.raises(HyperGSError, match="several models"):
        resolve_encoder(weights=exported)
    assert resolve_encoder(weights=exported / "other.json", backend="onnx").name == "transformer-onnx"
    with pytest.raises(HyperGSError, match="no model 'missing' in .*: its models are other, tiny"):
        resolve_encoder(weights=exported / "missing.json")  # the name mistyped: what the folder holds
    with pytest.raises(HyperGSError, match="no model weights at"):
        resolve_encoder(weights=tmp_path / "missing.json")  # a folder without models


def test_eval_command_with_a_patch_grid(exported, moving_video, capsys):
    main(["eval", str(moving_video), "--weights", str(exported), "--gaussians", "16", "--grid", "2", "--frames", "4",
          "--backend", "onnx", "--json"])
    report = json.loads(capsys.readouterr().out)
    row = report["videos"][0]
    assert report["encoder"] == "transformer-onnx" and report["density"]["grid"] == [2, 2]
    assert row["grid"] == [2, 2] and row["per_tile"] == 16 and row["gaussians"] == 64
    assert row["seam_ratio"] is not None and np.isfinite(row["psnr"])
    with pytest.raises(SystemExit):
        main(["eval", str(moving_video), "--encoder", "floor", "--grid", "2"])
    assert "patch grid is the transformer's" in capsys.readouterr().err


def test_delta_psnr_sees_flicker_not_a_steady_error():
    from hypergs_blender.bench.designs import delta_psnr
    frames = np.full((4, 8, 8, 3), 100, np.uint8)
    steady = np.full((4, 8, 8, 3), 100 / 255 + 0.1, np.float32)
    flicker = steady.copy()
    flicker[1::2] -= 0.2  # +0.1, -0.1, +0.1, -0.1: every difference is off by 0.2
    assert delta_psnr(steady, frames) > 100
    assert delta_psnr(flicker, frames) == pytest.approx(-10 * np.log10(0.04), abs=1e-3)


def test_bench_designs_compares_at_equal_count_and_time(exported, moving_video):
    from hypergs_blender.bench.designs import bench_designs
    from hypergs_blender.encode import FloorEncoder
    transformer = resolve_encoder(weights=exported, backend="onnx")
    report = bench_designs([moving_video], FloorEncoder(), transformer, gaussians=(16, 64), grids=(1, 2),
                           refine_steps=(1, 3), size=32, frames=4, device="cpu",
                           training=dict(step=2, cpu_hours=0.01, train_args=dict(steps=10, init_from=dict(
                               path="w.safetensors", info=dict(step=1500, cpu_hours=1.25, train_args=dict(steps=1500))))))
    first = report["summary"][0]
    assert [e["n"] for e in report["summary"]] == [16, 64] and first["videos"] == 1
    assert first["conv"]["gaussians"] == 16 and first["transformer"]["1"]["gaussians"] == 16
    assert [r["k"] for r in first["refine"]] == [1, 3]
    assert "| transformer, grid 2x2 |" in report["table"] and "30.3 dB" in report["table"]
    assert "step 2 of the 10 its run planned, 0.01 CPU hours of training: undertrained" in report["table"]
    assert "2 runs, 1,502 steps and 1.26 CPU hours in all" in report["table"]


def test_bench_designs_names_the_chain_only_where_there_is_one():
    from hypergs_blender.bench.designs import training_summary
    single = training_summary(dict(step=5, cpu_hours=0.5, train_args=dict(steps=5)))
    assert single["chain"] == dict(runs=1, steps=5, cpu_hours=0.5)
    three = training_summary(dict(step=5, cpu_hours=0.5, train_args=dict(init_from=dict(info=dict(
        step=7, cpu_hours=0.25, train_args=dict(init_from=dict(info=dict(step=11, cpu_hours=1.0))))))))
    assert three["chain"] == dict(runs=3, steps=23, cpu_hours=1.75) and three["step"] == 5


def test_train_then_export_a_transformer_run(tmp_path, monkeypatch, capsys):
    """`hypergs train --preset small` (tiny here) then `hypergs export` (no --out: into the run's export
    folder, never the bundled model's): the design's own file name, a card with its arch and trained
    Gaussian range."""
    from hypergs_blender.training import train
    monkeypatch.setitem(train.PRESETS, "small", TransformerConfig(**TINY))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    run = tmp_path / "run"
    main(["train", "--out", str(run), "--preset", "small", "--data", "procedural:1", "--steps", "2", "--batch", "1",
          "--gaussians", "9:100", "--warmup", "1", "--threads", "1"])
    main(["export", str(run)])
    assert f"{run / 'export'}/hypergs_transformer.{{safetensors,json,onnx}}" in capsys.readouterr().out
    card = json.loads((run / "export" / "hypergs_transformer.json").read_text())
    assert card["arch"] == "transformer" and card["geometry"]["gaussians"] == [9, 100]
    assert card["info"]["step"] == 2 and "regularizer" in card["info"]["train_args"]
    encoder = resolve_encoder(weights=run / "export", backend="onnx")
    assert encoder.gaussians == (9, 100) and encoder.canvas == 32


def test_a_warm_started_transformer_goes_on_from_the_thresholds_its_card_recorded(tmp_path, monkeypatch):
    """`hypergs train --init-from` exported transformer weights: the adaptive regularizer starts from the
    thresholds the weights' card recorded (their run had adapted them), not from the paper's initial ones."""
    from hypergs_blender.training import train
    monkeypatch.setitem(train.PRESETS, "small", TransformerConfig(**TINY))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    common = ["--preset", "small", "--data", "procedural:1", "--steps", "1", "--batch", "1", "--gaussians", "9:100",
              "--warmup", "1", "--threads", "1"]
    first, second = tmp_path / "first", tmp_path / "second"
    main(["train", "--out", str(first), *common])
    main(["export", str(first)])
    card_path = first / "export" / "hypergs_transformer.json"
    card = json.loads(card_path.read_text())
    card["info"]["train_args"]["regularizer"] = {"erank_ema": 1.3, "scale_ema": 7.0}  # the initial: 1.05 / 4.0
    card_path.write_text(json.dumps(card))
    main(["train", "--out", str(second), "--init-from", str(card_path.with_suffix(".safetensors")), *common])
    state = torch.load(second / "checkpoint.pt", weights_only=True)["regularizer"]
    # its one step moved each EMA 1 % of the way (momentum 0.99) to that batch's percentile
    assert abs(float(state["erank_ema"]) - 1.3) < 0.01 and abs(float(state["scale_ema"]) - 7.0) < 0.1


@pytest.mark.parametrize("preset", ["small", "paper"])
def test_window_margins_are_whole_patches_beyond_a_quarter_of_the_canvas(preset):
    """Windows whose starts are not whole patches apart tokenize a border differently on its two sides
    (a 36 px margin on the 128 px canvas: seam ratio 1.27 against 1.01 with 40, network.transformer_geometry)."""
    cfg = PRESETS[preset]
    local = transformer_geometry(replace(cfg, parametrization="local"))
    assert local["margin"] % cfg.patch == 0 and cfg.canvas // 4 < local["margin"] < cfg.canvas // 2
    assert transformer_geometry(replace(cfg, parametrization="paper"))["margin"] == 0


def test_model_takes_a_designs_name_as_blender_does(tmp_path):
    """--model conv / transformer (Blender's names for the designs) stand for the names `hypergs export` gives
    them, unless the folder holds a model of that very name."""
    import argparse

    from hypergs_blender.commands.options import weights_from_args
    from hypergs_blender.network import WEIGHTS_DIR

    def weights(model, folder=None):
        return weights_from_args(argparse.Namespace(model=model, weights=folder))
    assert weights("transformer") == WEIGHTS_DIR / "hypergs_transformer.json"
    assert weights("conv") == WEIGHTS_DIR / "hypergs.json"
    assert weights("hypergs_transformer") == WEIGHTS_DIR / "hypergs_transformer.json"
    (tmp_path / "transformer.json").write_text("{}")
    assert weights("transformer", tmp_path) == tmp_path / "transformer.json"  # the folder's own model wins
    assert weights("conv", tmp_path) == tmp_path / "hypergs.json"  # and a missing one is reported by that name
    assert resolve_encoder(weights=weights("transformer"), backend="onnx").name == "transformer-onnx"
