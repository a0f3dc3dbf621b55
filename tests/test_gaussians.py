import math

import numpy as np
import pytest
import torch

from hypergs_blender.encode import EncodeSettings, FloorEncoder
from hypergs_blender.errors import HyperGSError
from hypergs_blender.gaussians import (GaussianVideo, covariance, grid_anchors, inverse_covariance,
                                       render_inputs, stretch_params)
from hypergs_blender.io.hgs import load_hgs, save_hgs
from hypergs_blender.io.npz import load_npz, save_npz
from hypergs_blender.raster import rasterize_reference


def random_params(t, n, seed=0, canvas=64):
    rng = np.random.default_rng(seed)
    p = np.empty((t, n, 8), np.float32)
    p[..., 0:2] = rng.uniform(-0.9, 0.9, (t, n, 2))
    p[..., 2:4] = rng.uniform(0.5, 6, (t, n, 2))
    p[..., 4] = rng.uniform(0, 2 * math.pi, (t, n))
    p[..., 5:8] = rng.uniform(-0.2, 1, (t, n, 3))
    return p


def test_save_load_round_trip(tmp_path):
    video = GaussianVideo(random_params(3, 10), 64, 48, fps=25.0, grid=(2, 2), source={"path": "x.mp4"})
    save_npz(video, tmp_path / "clip.npz")
    back = load_npz(tmp_path / "clip.npz")
    np.testing.assert_array_equal(back.params, video.params)
    assert (back.canvas_width, back.canvas_height, back.fps, back.grid, back.source) == (64, 48, 25.0, (2, 2), {"path": "x.mp4"})


def test_a_panorama_lattice_round_trips(tmp_path):
    """An 8192 x 1024 panorama at Standard (cells of 6 px) is a 1365 x 170 lattice: wider than 1024
    cells, which the grid field once refused after the encode had started."""
    layout = EncodeSettings.choose(quality="standard").layout(8192, 1024, FloorEncoder())
    assert layout.cols > 1024
    video = GaussianVideo(random_params(1, 4), 8192, 1024, grid=(layout.cols, layout.rows))
    save_hgs(video, tmp_path / "wide.hgs")
    save_npz(video, tmp_path / "wide.npz")
    assert load_hgs(tmp_path / "wide.hgs").grid == load_npz(tmp_path / "wide.npz").grid == (layout.cols, layout.rows)


def test_load_rejects_other_files(tmp_path):
    (tmp_path / "bad.npz").write_text("not a zip")
    with pytest.raises(HyperGSError, match="bad.npz"):
        load_npz(tmp_path / "bad.npz")


def test_bad_shape_is_refused():
    with pytest.raises(ValueError, match=r"\[T, N, 8\]"):
        GaussianVideo(np.zeros((2, 3, 7)), 8, 8)


def test_covariance_and_inverse():
    p = random_params(1, 20)[0]
    cov = covariance(p[:, 2:4].astype(np.float64), p[:, 4].astype(np.float64), (1.5, 0.5))
    inv = inverse_covariance(p[:, 2:4].astype(np.float64), p[:, 4].astype(np.float64), (1.5, 0.5))
    np.testing.assert_allclose(cov @ inv, np.broadcast_to(np.eye(2), cov.shape), atol=1e-9)
    # determinant = (sx sy tx ty)^2 and eigenvalues are the stretched squared scales when axis-aligned
    det = np.linalg.det(cov)
    np.testing.assert_allclose(det, (p[:, 2] * p[:, 3] * 1.5 * 0.5) ** 2, rtol=1e-5)


def test_render_inputs_cholesky_matches_numpy():
    p = random_params(2, 30).astype(np.float64)
    means, chol, _ = render_inputs(p, 64, 32, 200, 50)
    cov = covariance(p[..., 2:4], p[..., 4], (200 / 64, 50 / 32))
    expected = np.linalg.cholesky(cov)
    np.testing.assert_allclose(chol[..., 0], expected[..., 0, 0], rtol=1e-9)
    np.testing.assert_allclose(chol[..., 1], expected[..., 1, 0], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(chol[..., 2], expected[..., 1, 1], rtol=1e-9)
    np.testing.assert_allclose(means[..., 0], (p[..., 0] + 1) * 100)
    # torch gives the same numbers
    t_means, t_chol, _ = render_inputs(torch.from_numpy(p), 64, 32, 200, 50)
    np.testing.assert_allclose(t_chol.numpy(), chol, rtol=1e-9)


def test_needle_cholesky_is_exact():
    p = np.array([[0, 0, 40.0, 1e-3, 0.7, 1, 1, 1]])
    _, chol, _ = render_inputs(p, 64, 64, 64, 64)
    l11, l21, l22 = chol[0]
    assert l11 * l22 == pytest.approx(40.0 * 1e-3, rel=1e-9)


def test_stretch_params_renders_like_a_stretch():
    p = random_params(1, 12, canvas=32)
    stretched = stretch_params(p, 2.0, 1.25)  # larger than the canvas, where render_inputs adds no pixel filter
    a = render_inputs(torch.from_numpy(p).double(), 32, 32, 64, 40)
    b = render_inputs(torch.from_numpy(stretched).double(), 64, 40, 64, 40)
    img_a = rasterize_reference(*a, 64, 40)
    img_b = rasterize_reference(*b, 64, 40)
    np.testing.assert_allclose(img_a.numpy(), img_b.numpy(), atol=2e-5)


def image_moments(image):
    """Sum, mean (x, y) and covariance [2, 2] of a one-channel image [H, W] over its pixel centres."""
    h, w = image.shape
    y, x = np.mgrid[0:h, 0:w] + 0.5
    mass = image.sum()
    mx, my = (image * x).sum() / mass, (image * y).sum() / mass
    dx, dy = x - mx, y - my
    cov = np.array([[(image * dx * dx).sum(), (image * dx * dy).sum()],
                    [(image * dx * dy).sum(), (image * dy * dy).sum()]]) / mass
    return mass, (mx, my), cov


@pytest.mark.parametrize("width, height", [(32, 48), (64, 64), (128, 96)])
def test_a_render_smaller_than_the_canvas_adds_the_pixel_filter_and_keeps_each_gaussians_sum(width, height):
    from hypergs_blender.gaussians import PIXEL_VARIANCE
    p = np.array([[[0.1, -0.05, 3.0, 1.4, 0.4, 0.8, 0.8, 0.8]]])
    image = rasterize_reference(*render_inputs(torch.from_numpy(p), 64, 64, width, height), width, height)
    mass, mean, cov = image_moments(image[0, ..., 0].numpy())
    t = np.array([width / 64, height / 64])
    stretched = covariance(p[0, :, 2:4], p[0, :, 4], t)[0]
    expected = stretched + np.diag(PIXEL_VARIANCE * np.maximum(0, 1 - t * t))  # nothing added at 64 x 64 or larger
    np.testing.assert_allclose(cov, expected, rtol=5e-3)  # the 4-sigma box cuts 0.2-0.4 % of the second moments
    np.testing.assert_allclose(mean, (p[0, 0, :2] + 1) / 2 * [width, height], atol=2e-3)
    # the filtered Gaussian's sum is the unfiltered one's, c 2 pi sqrt(det T Sigma T) (less the 4-sigma box's cut)
    np.testing.assert_allclose(mass, 0.8 * 2 * math.pi * math.sqrt(np.linalg.det(stretched)), rtol=2e-3)


def test_a_smaller_render_is_nearer_the_canvas_render_averaged_over_its_pixels():
    # The pixel filter stands in for what an area resize of the canvas-sized render gives: a render at half
    # the canvas, against the canvas render averaged over 2 x 2 pixels, is nearer with it than without it.
    p = random_params(1, 40, canvas=64)
    p[..., 2:4] /= 4  # small Gaussians, which a smaller render would otherwise sample sparsely
    full = rasterize_reference(*render_inputs(torch.from_numpy(p).double(), 64, 64, 64, 64), 64, 64)[0].numpy()
    averaged = full.reshape(32, 2, 32, 2, 3).mean((1, 3))
    means, chol, colors = render_inputs(torch.from_numpy(p).double(), 64, 64, 32, 32)
    filtered = rasterize_reference(means, chol, colors, 32, 32)[0].numpy()
    unfiltered = rasterize_reference(*render_inputs(torch.from_numpy(stretch_params(p, 0.5, 0.5)).double(),
                                                    32, 32, 32, 32), 32, 32)[0].numpy()
    error, before = np.abs(filtered - averaged).mean(), np.abs(unfiltered - averaged).mean()
    assert error < 0.6 * before, (error, before)


@pytest.mark.parametrize("n, aspect", [(1, 1.0), (250, 1.0), (1000, 1.0), (3000, 1.0), (1000, 16 / 9)])
def test_grid_anchors(n, aspect):
    a = grid_anchors(n, aspect)
    assert a.shape == (n, 2) and np.all(np.abs(a) < 1)
    assert len(np.unique(a, axis=0)) == n
