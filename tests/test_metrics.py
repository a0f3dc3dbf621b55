"""The artefact checks of `hypergs eval` (seams at tile borders, a lattice in flat regions, dark frame
edges) on synthetic frames: each sees its artefact, and the encoders' output passes them."""
import numpy as np
import pytest
import torch

from hypergs_blender import metrics
from hypergs_blender.encode import EncodeSettings, FloorEncoder
from hypergs_blender.evaluate import evaluate_frames
from hypergs_blender.model import ConvConfig, ConvGS
from hypergs_blender.network import torch_encoder


def smooth_frames(t=2, h=96, w=128, seed=0):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w] / np.float32(max(h, w))
    out = np.empty((t, h, w, 3), np.float32)
    for i in range(t):
        for c in range(3):
            a, b, p = rng.uniform(1, 4, 3)
            out[i, ..., c] = 0.5 + 0.3 * np.sin(a * x + b * y + p)
    return out


def test_seam_ratio_sees_a_seam():
    target = smooth_frames()
    noisy = target + np.random.default_rng(1).normal(0, 0.01, target.shape).astype(np.float32)
    assert metrics.seam_ratio(noisy, target, xs=[64], ys=[48]) == pytest.approx(1.0, abs=0.15)
    seamed = noisy.copy()
    seamed[:, :, 63:65] += 0.05  # a bright seam down the middle
    assert metrics.seam_ratio(seamed, target, xs=[64]) > 5
    assert metrics.seam_ratio(noisy, target) is None  # no borders, no figure


def test_flat_ripple_sees_a_lattice():
    flat = np.full((1, 64, 64, 3), 0.4, np.float32)
    y, x = np.mgrid[0:64, 0:64]
    lattice = flat + (0.02 * np.cos(2 * np.pi * x / 8) * np.cos(2 * np.pi * y / 8))[None, ..., None]
    ripple = metrics.flat_ripple(lattice, flat, window=16)
    assert ripple["blocks"] == 4 and ripple["source_std"] == pytest.approx(0.0, abs=1e-3)  # the inner 2 x 2
    assert ripple["render_std"] > 2.0  # about 0.01 x 255 / ... well above a code value
    assert metrics.flat_ripple(flat, flat, window=16)["render_std"] == pytest.approx(0.0, abs=1e-3)


def test_flat_blocks_keep_away_from_the_frame_edge_and_from_detail():
    frame = np.full((1, 96, 96, 3), 0.4, np.float32)
    frame[:, :, 72:] = 0.9  # an edge inside the fifth column of 16-px blocks
    keep = metrics.flat_blocks(frame, 16)
    expected = np.zeros((1, 6, 6), bool)
    expected[:, 1:5, 1:3] = True  # not the frame's border blocks, not the edge's block nor its neighbours
    np.testing.assert_array_equal(keep, expected)


def test_flat_ripple_means_over_the_videos_blocks():
    from hypergs_blender.commands.evaluate import mean_flat_ripple
    one = {"blocks": 1, "source_std": 0.4, "render_std": 3.0}  # a video with a single flat block
    many = {"blocks": 99, "source_std": 0.2, "render_std": 0.5}
    none = {"blocks": 0, "source_std": None, "render_std": None}
    mean = mean_flat_ripple([one, many, none])
    assert mean["flat_ripple_blocks"] == 100
    assert mean["flat_ripple_render_std"] == pytest.approx((3.0 + 99 * 0.5) / 100)  # not (3.0 + 0.5) / 2
    assert mean["flat_ripple_source_std"] == pytest.approx((0.4 + 99 * 0.2) / 100)
    assert mean_flat_ripple([none]) == {"flat_ripple_render_std": None, "flat_ripple_source_std": None,
                                        "flat_ripple_blocks": 0}


def test_edge_bias_sees_dark_edges():
    target = smooth_frames()
    dark = target.copy()
    for edge in (np.s_[:, :6], np.s_[:, -6:], np.s_[:, :, :6], np.s_[:, :, -6:]):
        dark[edge] = target[edge] * 0.9  # 10 % darker: about -13 code values at 0.5
    assert -15 < metrics.edge_bias(dark, target) < -8
    assert metrics.edge_bias(target, target) == pytest.approx(0.0, abs=1e-4)


def test_floor_has_no_lattice_in_flat_regions():
    """Grey frames with a bright square: the grid floor keeps the flat parts flat (std within half a
    code value of the source's), and the frame's edges dark by the missing neighbours only."""
    frames = np.full((2, 96, 128, 3), 120, np.uint8)
    frames[:, 30:60, 40:80] = (230, 200, 60)
    result = evaluate_frames(frames, FloorEncoder(), EncodeSettings(cell=6))
    ripple = result["flat_ripple"]
    assert ripple["blocks"] > 10 and ripple["render_std"] - ripple["source_std"] < 0.5
    assert result["seam_ratio"] is None and result["tiles"] == [1, 1]


def test_tiled_network_has_no_seams():
    """The conv network encodes large frames in tiles: the error at the tiles' borders is the error
    elsewhere (test_seam_ratio_sees_a_seam shows the check sees a seam)."""
    torch.manual_seed(0)
    model = ConvGS(ConvConfig(width=8, stem=4, blocks=(2,))).eval()
    with torch.no_grad():
        model.head.weight.normal_(0, 0.02)
    encoder = torch_encoder(model)
    encoder.tile = 2 * model.cfg.reach + 32
    frames = (smooth_frames(2, 120, 320) * 255).astype(np.uint8)
    result = evaluate_frames(frames, encoder, EncodeSettings(cell=4))
    assert result["tiles"][0] > 2 and result["seam_ratio"] == pytest.approx(1.0, abs=0.2)


# ---- temporal figures -------------------------------------------------------------------------------

def test_delta_psnr_matches_a_loop_over_frame_pairs():
    rng = np.random.default_rng(2)
    target = smooth_frames(t=4).astype(np.float64)
    pred = np.clip(target + rng.normal(0, 0.03, target.shape), 0, 1)
    expected = np.mean([10 * np.log10(1 / np.mean(((pred[i + 1] - pred[i]) - (target[i + 1] - target[i])) ** 2))
                        for i in range(3)])
    assert metrics.delta_psnr(pred, target) == pytest.approx(expected, abs=1e-9)


def test_delta_psnr_forgives_a_steady_error_and_sees_flicker():
    target = smooth_frames(t=4)
    steady = target + 0.05  # the same error in every frame: the changes are exact (to float32 round-off)
    assert metrics.delta_psnr(steady, target) > 120
    flicker = target + 0.01 * np.array([1, -1, 1, -1], np.float32)[:, None, None, None]
    assert metrics.delta_psnr(flicker, target) == pytest.approx(-20 * np.log10(0.02), abs=1e-3)  # |change| 0.02


def test_still_change_measures_flicker_where_the_source_is_still():
    target = np.zeros((3, 32, 32, 3), np.float32) + 0.5
    target[1:, :, 16:] = 0.9  # the right half changes after the first frame; the left half never does
    pred = target.copy()
    pred[1, :, :16] += 3 / 255  # the still left half flickers by 3 code values in frame 1 (so in both pairs)
    change = metrics.still_change(pred, target)
    # still: the left half in both pairs, the right half in the second pair -> 3/4 of the pixels
    assert change["fraction"] == pytest.approx(0.75)
    assert change["source"] == pytest.approx(0.0, abs=1e-6)
    assert change["render"] == pytest.approx(3 * 2 / 3, abs=1e-4)  # 3/255 on two of the three still halves
    assert metrics.still_change(pred, target * 0 + np.arange(3)[:, None, None, None] / 2)["render"] is None


def test_eval_reports_temporal_figures(moving_video):
    from hypergs_blender.evaluate import evaluate_video
    result = evaluate_video(moving_video, FloorEncoder(), EncodeSettings(cell=4), size=None, frames=4, temporal_frames=5)
    temporal = result["temporal"]
    assert temporal["frames"] == 5
    assert 15 < temporal["delta_psnr"] < 60 and 15 < temporal["psnr"] < 60
    assert temporal["still_change"]["fraction"] > 0.5 and temporal["still_change"]["render"] > 0  # near the square
    assert "temporal" not in evaluate_video(moving_video, FloorEncoder(), EncodeSettings(cell=4), size=None, frames=2, temporal_frames=0)


def test_a_still_clip_renders_still():
    from hypergs_blender.evaluate import evaluate_temporal
    frames = np.repeat((smooth_frames(t=1) * 255).astype(np.uint8), 3, axis=0)
    temporal = evaluate_temporal(frames, FloorEncoder(), EncodeSettings(cell=4))
    assert temporal["delta_psnr"] == np.inf
    assert temporal["still_change"] == {"fraction": 1.0, "source": 0.0, "render": 0.0}


def test_eval_command_reports_the_temporal_means(moving_video, capsys):
    import json
    from hypergs_blender.commands.cli import main
    main(["eval", str(moving_video), str(moving_video), "--encoder", "floor", "--full", "--cell", "4", "--frames", "2",
          "--temporal-frames", "4", "--json"])
    report = json.loads(capsys.readouterr().out)
    video = report["videos"][0]["temporal"]
    assert report["temporal_frames"] == 4 and video["frames"] == 4
    mean = report["mean"]["temporal"]
    assert mean["delta_psnr"] == pytest.approx(video["delta_psnr"])
    assert mean["still_change"] == pytest.approx(video["still_change"])


def test_cell_phase_means_match_a_loop_over_pixels():
    rng = np.random.default_rng(3)
    h, w, cell, bins = 13, 17, 4.3, 3  # no pixel centre on a bin's edge
    values = rng.normal(size=(h, w, 2))
    phase, means = metrics.cell_phase_means(values.reshape(-1, 2), np.arange(h)[:, None], np.arange(w)[None, :],
                                            cell, bins)
    sums, counts, expected_phase = np.zeros((bins * bins, 2)), np.zeros(bins * bins), []
    for row in range(h):
        for col in range(w):
            k = int((row + 0.5) % cell / cell * bins) * bins + int((col + 0.5) % cell / cell * bins)  # centre's bin
            expected_phase.append(k)
            sums[k] += values[row, col]
            counts[k] += 1
    np.testing.assert_array_equal(phase, expected_phase)
    np.testing.assert_allclose(means, sums / np.maximum(counts, 1)[:, None])
    assert counts.min() > 0  # every phase seen: the means are not the empty-phase zeros
