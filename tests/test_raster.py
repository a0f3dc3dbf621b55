"""Fast rasterizers against the dense reference (raster.rasterize_reference).

Inputs are float32-representable (rounded through float32), so every implementation sees the same
numbers. Tolerances, relative to the largest magnitude of the compared tensor (scale = max|ref|):
- rasterize(backend="numba"), float32 I/O with float64 internals, vs the float64 reference:
  forward 2e-6 * scale, gradients 1e-6 * scale.
- rasterize(backend="torch"), evaluated in float64 like the reference: 1e-9 * scale.
- rasterize_numpy: numba path as above; the pure-numpy path repeats the reference's float32 arithmetic,
  so it is compared with the float32 reference: 2e-6 * scale.
"""
from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from hypergs_blender.gaussians import render_inputs
from hypergs_blender.raster import box_pixels, box_radii, numba_available, rasterize, rasterize_numpy, rasterize_reference

TORCH_BACKENDS = ["numba", "torch"] if numba_available() else ["torch"]
NUMPY_BACKENDS = ["numba", "numpy"] if numba_available() else ["numpy"]
FWD_TOL = {"numba": 2e-6, "torch": 1e-9}
GRAD_TOL = {"numba": 1e-6, "torch": 1e-9}


def f32(*arrays):
    """float64 tensors holding float32-representable values."""
    return [torch.as_tensor(np.asarray(a, np.float32), dtype=torch.float64) for a in arrays]


def random_gaussians(b, n, width, height, c=3, seed=0, sigma=(0.5, 6.0)):
    rng = np.random.default_rng(seed)
    means = rng.uniform(-0.1, 1.1, (b, n, 2)) * [width, height]
    l11 = rng.uniform(*sigma, (b, n)) * rng.choice([-1, 1], (b, n))
    l22 = rng.uniform(*sigma, (b, n))
    l21 = rng.normal(0, sigma[1] / 2, (b, n))
    colors = rng.normal(0.2, 0.5, (b, n, c))
    return f32(means, np.stack([l11, l21, l22], -1), colors)


def close(actual, expected, tol, what):
    actual = torch.as_tensor(actual, dtype=torch.float64)
    expected = torch.as_tensor(expected, dtype=torch.float64)
    scale = max(float(expected.abs().max()), 1e-30) if expected.numel() else 1.0
    err = float((actual - expected).abs().max()) if expected.numel() else 0.0
    assert actual.shape == expected.shape, f"{what}: shape {tuple(actual.shape)} != {tuple(expected.shape)}"
    assert err <= tol * max(scale, 1e-3), f"{what}: max error {err:.3g} (scale {scale:.3g}, tol {tol:g})"


def reference_with_grads(means, chol, colors, width, height, grad_out):
    leaves = [t.clone().requires_grad_(True) for t in (means, chol, colors)]
    lead = means.shape[:-2]  # the reference takes [B, N, k]: flatten any leading dims
    ref = rasterize_reference(*(t.reshape((-1,) + t.shape[-2:]) for t in leaves), width, height)
    ref = ref.reshape(lead + ref.shape[1:])
    grads = torch.autograd.grad((ref * grad_out).sum(), leaves)
    return ref.detach(), grads


def check_all(means, chol, colors, width, height, seed=1, grads=True):
    """rasterize (each backend, forward and gradients) and rasterize_numpy (each backend) vs reference."""
    shape = means.shape[:-2] + (height, width, colors.shape[-1])
    grad_out = f32(np.random.default_rng(seed).normal(size=shape))[0]
    ref, ref_grads = reference_with_grads(means, chol, colors, width, height, grad_out)
    for backend in TORCH_BACKENDS:
        leaves = [t.clone().requires_grad_(grads) for t in (means, chol, colors)]
        out = rasterize(*leaves, width, height, backend=backend)
        assert out.dtype == torch.float64
        close(out.detach(), ref, FWD_TOL[backend], f"rasterize[{backend}] forward")
        if grads:
            got = torch.autograd.grad((out * grad_out).sum(), leaves)
            for name, g, r in zip(("means", "chol", "colors"), got, ref_grads):
                close(g, r, GRAD_TOL[backend], f"rasterize[{backend}] d/d{name}")
    np_in = [t.numpy().astype(np.float32) for t in (means, chol, colors)]
    ref32 = rasterize_reference(*[torch.from_numpy(a.reshape((-1,) + a.shape[-2:])) for a in np_in], width,
                                height).reshape(ref.shape)
    for backend in NUMPY_BACKENDS:
        out = rasterize_numpy(*np_in, width, height, backend=backend)
        assert out.dtype == np.float32
        close(out, ref if backend == "numba" else ref32, 2e-6, f"rasterize_numpy[{backend}]")
    return ref


def test_random_gaussians():
    scene = random_gaussians(2, 60, 48, 40)
    ref = check_all(*scene, 48, 40)
    assert float(ref.abs().max()) > 0.5  # the scene is not empty
    if numba_available():  # the scene exercises both row paths of the numba kernels
        from hypergs_blender import _raster_numba as rn

        boxes, consts = rn._prepare(scene[0].float().numpy(), scene[1].float().numpy(), 48, 40)
        full = consts[..., rn._FULL][boxes[..., 0] <= boxes[..., 1]]
        assert 0.2 < full.mean() < 0.8


@pytest.mark.parametrize("channels", [1, 4])
def test_other_channel_counts(channels):
    check_all(*random_gaussians(2, 30, 20, 17, c=channels, seed=2), 20, 17)


def test_anisotropic_stretched_render_inputs():
    """Canvas 64 x 64 rendered at 96 x 40: a non-uniform stretch of rotated anisotropic Gaussians."""
    rng = np.random.default_rng(3)
    n = 40
    params = np.concatenate([rng.uniform(-1, 1, (2, n, 2)), rng.uniform(0.5, 6, (2, n, 2)),
                             rng.uniform(0, 2 * math.pi, (2, n, 1)), rng.uniform(0, 1, (2, n, 3))], -1)
    means, chol, colors = render_inputs(np.asarray(params, np.float32).astype(np.float64), 64, 64, 96, 40)
    assert np.abs(chol[..., 1]).max() > 1.0  # really sheared
    check_all(*f32(means, chol, colors), 96, 40)


@pytest.mark.parametrize("rotation", [0.0, 0.3, math.pi / 4, 1.2, math.pi / 2, 2.5])
def test_needles(rotation):
    """sigma 0.05 px across, 30 px along: ~1 pixel per row or column where it is rotated."""
    n = 5
    rng = np.random.default_rng(4)
    params = np.zeros((1, n, 8))
    params[..., 0:2] = rng.uniform(-0.4, 0.4, (1, n, 2))
    params[..., 2], params[..., 3] = 30.0, 0.05
    params[..., 4] = rotation + rng.uniform(-0.01, 0.01, (1, n))
    params[..., 5:8] = rng.uniform(0.2, 1, (1, n, 3))
    means, chol, colors = render_inputs(params, 64, 56, 64, 56)
    ref = check_all(*f32(means, chol, colors), 64, 56)
    assert float(ref.abs().max()) > 0.1  # some pixel centre lies close to a needle


def test_frame_filling_and_off_screen():
    W, H = 32, 24
    means = [[16.3, 11.8], [5.0, -40.0], [-3.0, 10.0], [34.0, 30.0], [-60.0, -60.0], [200.0, 12.0],
             [10.0, 70.0]]
    chol = [[60.0, 10.0, 45.0],  # frame-filling: sigma > image size
            [30.0, -20.0, 25.0],  # mean far above, box still covers the frame
            [2.0, 0.5, 1.5],  # partly off the left edge
            [3.0, 1.0, 2.0],  # partly off the bottom-right corner
            [2.0, 0.0, 2.0],  # fully off-screen
            [3.0, 1.0, 2.0],  # fully off to the right
            [1.0, 0.0, 2.0]]  # fully off below
    colors = np.random.default_rng(5).uniform(0.1, 1, (1, 7, 3))
    m, c, col = f32([means], [chol], colors)
    check_all(m, c, col, W, H)
    for backend in TORCH_BACKENDS:  # off-screen Gaussians get exactly zero gradients
        leaves = [t.clone().requires_grad_(True) for t in (m, c, col)]
        rasterize(*leaves, W, H, backend=backend).square().sum().backward()
        for t in leaves:
            assert torch.all(t.grad[0, 4:] == 0), backend
            assert torch.all(t.grad[0, :4].abs().sum(-1) > 0), backend


@pytest.mark.parametrize("size", [(1, 1), (7, 5)])
def test_tiny_images(size):
    W, H = size
    means, chol, colors = random_gaussians(3, 12, W, H, seed=6, sigma=(0.2, 3.0))
    check_all(means, chol, colors, W, H)


def test_batch_and_leading_dims():
    means, chol, colors = random_gaussians(6, 25, 30, 22, seed=7)
    lead = (2, 3)
    m, c, col = (t.reshape(lead + t.shape[1:]) for t in (means, chol, colors))
    ref = check_all(m, c, col, 30, 22)
    assert ref.shape == (2, 3, 22, 30, 3)
    # frames are independent: each frame equals the frame rendered alone
    for backend in TORCH_BACKENDS:
        full = rasterize(m, c, col, 30, 22, backend=backend)
        alone = rasterize(m[1, 2], c[1, 2], col[1, 2], 30, 22, backend=backend)
        assert torch.equal(full[1, 2], alone)
    unbatched = rasterize_numpy(m[0, 1].numpy(), c[0, 1].numpy(), col[0, 1].numpy(), 30, 22)
    close(unbatched, ref[0, 1], 2e-6, "unbatched rasterize_numpy")


def test_large_odd_frame():
    """1921 x 1079 with a few Gaussians, incl. ones on the edges and corners. Memory stays small: the
    reference renders each Gaussian alone on a crop around its box (it is zero outside the box),
    with the means shifted by the crop's origin; images and gradients add up over the Gaussians."""
    W, H = 1921, 1079
    rng = np.random.default_rng(8)
    pts = np.array([[0.2, 0.3], [W - 0.7, 5.0], [3.0, H - 1.2], [W / 2, H / 2], [W - 2.0, H - 2.0],
                    [960.4, 63.9], [100.0, 540.0], [1500.0, 900.0]])
    n = len(pts)
    chol = np.stack([rng.uniform(1, 25, n), rng.normal(0, 8, n), rng.uniform(1, 25, n)], -1)
    m, c, col = f32(pts[None], chol[None], rng.uniform(0.1, 1, (1, n, 3)))
    grad_out = f32(rng.normal(size=(1, H, W, 3)))[0]
    ref = torch.zeros(1, H, W, 3, dtype=torch.float64)
    ref_grads = [torch.zeros_like(t) for t in (m, c, col)]
    for k in range(n):
        rx, ry = box_radii(c[0, k].numpy()) + 2
        x0, y0 = max(0, int(m[0, k, 0] - rx)), max(0, int(m[0, k, 1] - ry))
        x1, y1 = min(W, int(m[0, k, 0] + rx) + 1), min(H, int(m[0, k, 1] + ry) + 1)
        shifted = m[:, k:k + 1] - torch.tensor([x0, y0], dtype=torch.float64)
        crop, grads = reference_with_grads(shifted, c[:, k:k + 1], col[:, k:k + 1], x1 - x0, y1 - y0,
                                           grad_out[:, y0:y1, x0:x1])
        ref[:, y0:y1, x0:x1] += crop
        for acc, g in zip(ref_grads, grads):
            acc[:, k:k + 1] += g
    for backend in TORCH_BACKENDS:
        leaves = [t.clone().requires_grad_(True) for t in (m, c, col)]
        out = rasterize(*leaves, W, H, backend=backend)
        close(out.detach(), ref, FWD_TOL[backend], f"1921x1079 rasterize[{backend}]")
        got = torch.autograd.grad((out * grad_out).sum(), leaves)
        for name, g, r in zip(("means", "chol", "colors"), got, ref_grads):
            close(g, r, GRAD_TOL[backend], f"1921x1079 rasterize[{backend}] d/d{name}")
    for backend in NUMPY_BACKENDS:
        out = rasterize_numpy(m.numpy(), c.numpy(), col.numpy(), W, H, backend=backend)
        close(out, ref, 2e-6, f"1921x1079 rasterize_numpy[{backend}]")
    assert float(ref[0, 0, 0].abs().sum()) > 0 and float(ref[0, H - 1, W - 1].abs().sum()) > 0


def test_invalid_gaussians_contribute_nothing():
    means, chol, colors = random_gaussians(1, 6, 16, 12, seed=9)
    bad_m, bad_c = means.clone(), chol.clone()
    bad_m[0, 1, 0] = float("nan")
    bad_c[0, 2, 0] = 0.0
    bad_c[0, 3, 2] = 0.0
    bad_c[0, 4, 1] = float("inf")
    keep = [0, 5]
    expected = rasterize_reference(means[:, keep], chol[:, keep], colors[:, keep], 16, 12)
    for backend in TORCH_BACKENDS:
        out = rasterize(bad_m, bad_c, colors, 16, 12, backend=backend)
        close(out, expected, FWD_TOL[backend], f"invalid rasterize[{backend}]")
    for backend in NUMPY_BACKENDS:
        out = rasterize_numpy(bad_m.numpy(), bad_c.numpy(), colors.numpy(), 16, 12, backend=backend)
        close(out, expected, 2e-6, f"invalid rasterize_numpy[{backend}]")


@pytest.mark.skipif(not numba_available(), reason="numba is not installed")
def test_set_threads_caps_the_numba_kernels_in_its_thread():
    """`hypergs train --threads 1` must leave the other core free: torch's setting does not reach numba.
    Run in a thread of its own, as numba's setting is per thread (the test's own thread keeps its)."""
    import threading

    import numba

    from hypergs_blender import raster

    means, chol, colors = random_gaussians(1, 300, 40, 30, seed=3)
    expected = rasterize(means, chol, colors, 40, 30, backend="numba")
    seen = {}

    def capped():
        raster.set_threads(1)
        seen["threads"] = numba.get_num_threads()
        seen["image"] = rasterize(means, chol, colors, 40, 30, backend="numba")

    worker = threading.Thread(target=capped)
    worker.start()
    worker.join()
    assert seen["threads"] == 1
    close(seen["image"], expected, 1e-6, "one numba thread")


@pytest.mark.skipif(not numba_available(), reason="numba is not installed")
def test_numba_survives_extreme_values():
    """Magnitudes from 1e-38 to 1e38 (thin, absurdly sheared, far away), zeros, denormals, inf and NaN:
    the kernels index only inside the image and return finite images and gradients (invalid Gaussians
    add nothing), without crashing (they run without bounds checks)."""
    rng = np.random.default_rng(11)
    b, n = 4, 400
    mag = lambda *shape: np.exp(rng.uniform(-87, 87, shape)) * rng.choice([-1, 1], shape)  # noqa: E731
    special = np.array([0.0, -0.0, np.inf, -np.inf, np.nan, 1e-45, -1e-45, 3e38, -3e38])
    pick = lambda *shape: np.where(rng.random(shape) < 0.1, rng.choice(special, shape), mag(*shape))  # noqa
    means = np.where(rng.random((b, n, 2)) < 0.5, rng.uniform(-5, 25, (b, n, 2)), pick(b, n, 2))
    chol = np.where(rng.random((b, n, 3)) < 0.5, rng.uniform(-5, 5, (b, n, 3)), pick(b, n, 3))
    m, c, col = (torch.from_numpy(np.asarray(a, np.float32)) for a in (means, chol, rng.random((b, n, 3))))
    leaves = [t.clone().requires_grad_(True) for t in (m, c, col)]
    out = rasterize(*leaves, 20, 15, backend="numba")
    out.square().sum().backward()
    assert torch.isfinite(out).all()
    for t in leaves:
        assert torch.isfinite(t.grad).all()
    assert float(out.detach().abs().max()) > 0


def test_float32_inputs_give_float32_and_empty_inputs():
    means, chol, colors = (t.float() for t in random_gaussians(2, 10, 9, 8, seed=10))
    for backend in TORCH_BACKENDS:
        assert rasterize(means, chol, colors, 9, 8, backend=backend).dtype == torch.float32
        empty = rasterize(means[:, :0], chol[:, :0], colors[:, :0], 9, 8, backend=backend)
        assert empty.shape == (2, 8, 9, 3) and not empty.any()
    for backend in NUMPY_BACKENDS:
        empty = rasterize_numpy(means[:, :0].numpy(), chol[:, :0].numpy(), colors[:, :0].numpy(), 9, 8,
                                backend=backend)
        assert empty.shape == (2, 8, 9, 3) and not empty.any()
    with pytest.raises(ValueError):
        rasterize(means, chol[..., :2], colors, 9, 8)


def test_numpy_path_without_torch_or_numba():
    """raster.py must import and render with numpy alone (the Blender render engine's situation)."""
    root = Path(__file__).resolve().parents[1]
    code = (
        "import sys; sys.modules['torch'] = None; sys.modules['numba'] = None\n"
        "import numpy as np\n"
        "from hypergs_blender.raster import rasterize_numpy, numba_available\n"
        "assert not numba_available()\n"
        "img = rasterize_numpy(np.array([[4.0, 3.0]]), np.array([[1.0, 0.2, 1.5]]), np.ones((1, 3)), 8, 6)\n"
        "assert img.shape == (6, 8, 3) and abs(img[2, 3, 0] - 0.9) < 0.1, img[..., 0]\n"
        "assert 'torch' not in sys.modules or sys.modules['torch'] is None\n"
        "print('ok')\n")
    res = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr


def test_box_pixels_decide_the_edges_as_the_float32_test():
    """Box edges on pixel centres, give or take a float32 ulp (where float64 and float32 arithmetic disagree),
    also off the window's sides: box_pixels picks exactly the pixels the rasterizers' float32 test picks."""
    rng = np.random.default_rng(3)
    n = 4000
    chol = np.stack([rng.choice([1 / 3, 0.5, 1.1, 7 / 3, 40.0], n), rng.uniform(-2, 2, n),
                     rng.choice([1 / 3, 0.25, 2.0], n)], 1).astype(np.float32)
    radii = box_radii(chol).astype(np.float64)
    centre = rng.integers(-5, 45, (n, 2)) + 0.5 + rng.choice([-1, 1], (n, 2)) * radii
    means = (centre + rng.integers(-2, 3, (n, 2)) * 1e-6 * np.abs(centre)).astype(np.float32)
    means[::5] = np.nextafter(means[::5], np.float32(np.inf))
    means[2::5] = np.nextafter(means[2::5], np.float32(-np.inf))
    columns, rows = (3, 37), (0, 29)
    ok, (x0, x1, y0, y1) = box_pixels(means, chol, columns, rows)
    r = box_radii(chol)
    in_x = np.abs((np.arange(*columns, dtype=np.float32) + np.float32(0.5)) - means[:, :1]) <= r[:, :1]
    in_y = np.abs((np.arange(*rows, dtype=np.float32) + np.float32(0.5)) - means[:, 1:]) <= r[:, 1:]
    expect_ok = in_x.any(1) & in_y.any(1)
    np.testing.assert_array_equal(ok, expect_ok)
    assert 0.3 < ok.mean() < 1
    np.testing.assert_array_equal(x0[ok], columns[0] + in_x[ok].argmax(1))
    np.testing.assert_array_equal(x1[ok], columns[1] - 1 - in_x[ok, ::-1].argmax(1))
    np.testing.assert_array_equal(y0[ok], rows[0] + in_y[ok].argmax(1))
    np.testing.assert_array_equal(y1[ok], rows[1] - 1 - in_y[ok, ::-1].argmax(1))
