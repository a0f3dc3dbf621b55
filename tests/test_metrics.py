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
