"""`hypergs bench raster`: rasterizer throughput of every path (numba kernels, the pure-torch patch
renderer, the numpy-only path Blender runs, the dense reference)."""
from __future__ import annotations

import math
import os

from ..errors import HyperGSError
from .common import timed


def _timeit(fn, repeats: int, sync=None) -> float:
    """Median seconds of fn() over `repeats` runs after one warm-up run."""
    return timed(fn, repeats, warmup=True, sync=sync)[0]


def realistic_gaussians(frames: int, n: int, width: int, height: int, seed: int = 0):
    """Rasterizer inputs (means, chol, colors) of `realistic_params` at their own size: float32 numpy arrays,
    and sigma."""
    import numpy as np

    from ..gaussians import render_inputs

    params, sigma = realistic_params(frames, n, width, height, seed)
    means, chol, colors = render_inputs(params, width, height, width, height)
    return [np.ascontiguousarray(x, np.float32) for x in (means, chol, colors)], sigma


def realistic_params(frames: int, n: int, width: int, height: int, seed: int = 0):
    """Parameters [frames, n, 8] (float32) on a width x height canvas like a trained model's: means uniform
    over the frame, sigma ~ 0.8 * sqrt(W H / N) px so the Gaussians tile the frame, anisotropy exp(+-a) with
    a ~ N(0, 0.35) and uniform rotation, small additive colours; and sigma."""
    import numpy as np

    from ..gaussians import NUM_PARAMS

    rng = np.random.default_rng(seed)
    sigma = 0.8 * math.sqrt(width * height / n)
    a = rng.normal(0, 0.35, (frames, n))
    params = np.empty((frames, n, NUM_PARAMS), np.float32)
    params[..., 0:2] = rng.uniform(-1, 1, (frames, n, 2))
    params[..., 2] = sigma * np.exp(a)
    params[..., 3] = sigma * np.exp(-a)
    params[..., 4] = rng.uniform(0, 2 * math.pi, (frames, n))
    params[..., 5:8] = rng.uniform(0, 0.25, (frames, n, 3))
    return params, sigma


def bench_raster(device: str = "cpu", batch: int = 32, sizes=(250, 1000, 3000), repeats: int = 5) -> dict:
    """Rasterizer throughput: `rasterize` forward and forward+backward frames/s at 256 x 256 (batched),
    one 1920 x 1080 frame with 25,000 Gaussians (seconds), the numpy-only path on that frame, and the
    dense reference at a small size for scale. Medians of `repeats` runs after a warm-up."""
    import torch

    from ..raster import (
        numba_available,
        rasterize,
        rasterize_numpy,
        rasterize_reference,
    )

    if device == "cuda" and not torch.cuda.is_available():
        raise HyperGSError("bench raster --device cuda: CUDA is not available to torch")
    dev = torch.device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else None
    report = {
        "device": torch.cuda.get_device_name(dev) if dev.type == "cuda" else "cpu",
        "rasterize_backend": "numba" if dev.type == "cpu" and numba_available() else "torch",
        "torch_version": torch.__version__,
        "torch_threads": torch.get_num_threads(),
        "cpu_count": os.cpu_count(),
    }
    if numba_available():
        import numba

        report["numba_version"] = numba.__version__
        report["numba_threads"] = numba.get_num_threads()

    def tensors(arrays, grad=False):
        return [torch.from_numpy(a).to(dev).requires_grad_(grad) for a in arrays]

    def forward_fn(arrays, width, height, fn=rasterize):
        m, c, col = tensors(arrays)

        def run():
            with torch.no_grad():
                fn(m, c, col, width, height)
        return run

    def forward_backward_fn(arrays, width, height, fn=rasterize):
        leaves = tensors(arrays, grad=True)
        grad_out = torch.randn(arrays[0].shape[:-2] + (height, width, arrays[2].shape[-1]), device=dev)

        def run():
            fn(*leaves, width, height).backward(grad_out)
        return run

    rows = {}
    for n in sizes:
        arrays, sigma = realistic_gaussians(batch, n, 256, 256, seed=n)
        fwd = _timeit(forward_fn(arrays, 256, 256), repeats, sync)
        fwd_bwd = _timeit(forward_backward_fn(arrays, 256, 256), repeats, sync)
        rows[f"N={n}"] = {"batch": batch, "sigma_px": round(sigma, 2), "forward_fps": round(batch / fwd, 1),
                          "forward_backward_fps": round(batch / fwd_bwd, 1)}
    report["256x256"] = rows

    arrays, sigma = realistic_gaussians(1, 25_000, 1920, 1080, seed=1)
    hd = {"gaussians": 25_000, "sigma_px": round(sigma, 2),
          "forward_s": round(_timeit(forward_fn(arrays, 1920, 1080), repeats, sync), 4),
          "forward_backward_s": round(_timeit(forward_backward_fn(arrays, 1920, 1080), repeats, sync), 4)}
    if numba_available():
        hd["rasterize_numpy_numba_s"] = round(
            _timeit(lambda: rasterize_numpy(*arrays, 1920, 1080), repeats), 4)
    hd["rasterize_numpy_pure_numpy_s"] = round(
        _timeit(lambda: rasterize_numpy(*arrays, 1920, 1080, backend="numpy"), 2), 3)
    report["1920x1080"] = hd

    # For scale: the pure-torch patch renderer (what runs on CUDA or without numba) on CPU, and the dense
    # reference (every Gaussian at every pixel), both on few frames.
    if dev.type == "cpu":
        arrays, _ = realistic_gaussians(4, 1000, 256, 256, seed=7)

        def patch(*a):
            return rasterize(*a, backend="torch")
        report["torch_patch_cpu_256x256_N=1000"] = {
            "batch": 4,
            "forward_fps": round(4 / _timeit(forward_fn(arrays, 256, 256, patch), 2), 2),
            "forward_backward_fps": round(4 / _timeit(forward_backward_fn(arrays, 256, 256, patch), 2), 2)}
    arrays, _ = realistic_gaussians(1, 250, 256, 256, seed=8)
    report["reference_256x256_N=250"] = {
        "batch": 1,
        "forward_fps": round(1 / _timeit(forward_fn(arrays, 256, 256, rasterize_reference), 3, sync), 2),
        "forward_backward_fps": round(
            1 / _timeit(forward_backward_fn(arrays, 256, 256, rasterize_reference), 3, sync), 2)}
    return report
