"""Per-frame Gaussian fitting (the 2DGS / GaussianImage baseline) and warm-started refinement.

Every frame of a batch is optimised at once through the batched rasterizer: Adam on unconstrained
parameters (means in pixels, log scales, rotation, colours), each group with its own step size
(`StepSizes`); the means' step is a fraction of the cell, the mean spacing of the Gaussians, so the
same settings mean the same at any resolution and count. `fit` from scratch (FIT_STEPS) decays its
step sizes over its length (cosine); `refine_params` (REFINE_STEPS, small: the prediction is already
close) ramps them up over its first REFINE_WARMUP steps, keeps them constant, and decays them over its
last REFINE_DECAY share of the steps. Each frame is optimised as if it were alone (ADAM_EPS), and `fit`
returns each frame's best step (_keep_better).
Refinement starts from given parameters; its first and cheapest step is the least-squares colours for
the given geometry: with opacity 1 the render is linear in the colours, I = A c, so
c = argmin |A c - y|^2 is solved by conjugate gradients on the normal equations, each iteration one
rasterizer forward (A c) and one backward (A^T r).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from .render import render_torch


@dataclass(frozen=True)
class StepSizes:
    """Adam's step sizes per parameter group."""
    mean_cells: float  # means, in cells (the mean spacing of the Gaussians, in pixels: sqrt(W H / N))
    log_scale: float
    rotation: float  # radians
    colour: float


FIT_STEPS = StepSizes(mean_cells=0.25, log_scale=0.02, rotation=0.02, colour=0.02)  # from random values
REFINE_STEPS = StepSizes(mean_cells=0.021, log_scale=0.015, rotation=0.03, colour=0.003)  # from a prediction
REFINE_SCALE_MAX = 4.0
# Adam's first steps move every parameter by about its full step size whatever its gradient (the moment
# estimates are one sample), which throws a good prediction off; a linear ramp lets them settle first.
# Measured at refine 50 (N = 1000, 256^2; dev / held-out clips): +0.55 / +0.47 dB over no ramp at 5
# steps, +0.67 / +0.57 at 10, +0.59 / +0.50 at 20; with the ramp, the means' step x0.7 and the scales'
# and rotation's x2 add +0.4 / +0.3.
REFINE_WARMUP = 10
# Session 27, the bundled network's predictions (256^2, 8 frames; dev / held-out clips): the step sizes
# above at 1.5x session 10's, ending in a half cosine over the last fifth of the steps, gained on every row:
# N = 1000 refine 10 +0.07 / +0.05 dB, 30 +0.11 / +0.08, 50 +0.04 / +0.10, 100 +0.02 / +0.14; N = 3000
# refine 50 +0.01 / +0.10; 480^2 crops at 14,400 refine 30 +0.10 / +0.06. The decay alone lost on the dev
# clips (-0.02 to -0.09 at N = 1000); 2x gained up to 0.1 dB more at 256^2 but raised the crops' flat
# ripple with refine 50 from 1.28x to 1.40x the source's (1.5x: 1.23x) and lost up to 0.14 dB on the
# smoothest crops.
REFINE_DECAY = 0.2
# Each frame is its own problem: the loss sums the frames' mean squared errors, so a frame's gradients, and
# Adam's steps, do not depend on how many frames share the batch (an encode refines chunks of 16, an eval
# 8, vs-fit 2-4). Adam's eps then meets one frame's gradients, 8x those of the mean over the 8 frames that
# refinement's step sizes were tuned on; 8x torch's default eps keeps those results. It matters where the
# gradients are small (48-53 dB 480^2 crops, 4-px cells): there, before, a batch of 2 frames took larger
# steps than one of 8, and 9 Adam steps took a smooth frame 0.5 dB below the colours they started from.
ADAM_EPS = 8e-8
# Fitting from scratch ramps up too when it starts from the grid (a warm start; 256^2, N = 1000, dev /
# held-out: +0.25 / +2.1 dB at 30 steps, +0.5 / +0.6 at 100, +0.8 / +0.5 at 300), not from random values
# (-0.6 / -1.3 dB at 100).
FIT_WARMUP = {"random": 0, "grid": REFINE_WARMUP}
# The least-squares colours' conjugate-gradient iterations, each a forward and a backward render (as an Adam
# step). Session 28, the bundled network's predictions (`tools/refine_sweep.py ... --variant cg=K`; dev /
# held-out, 256^2 N = 1000): 5 iterations against 10 give refine 1 29.08 / 32.88 dB against 29.08 / 32.89,
# refine 10 and 50 the same to the digit (29.56 / 33.26, 31.74 / 34.91), the 480^2 crops at 14,400 refine 1
# 41.43 against 41.44 and refine 30 42.34 against 42.33; 3 iterations lose up to 0.03 dB.
LS_ITERATIONS = 5


def refine_steps(steps: int) -> StepSizes:
    """REFINE_STEPS for a refinement of `steps` steps: a longer run affords larger steps. Measured (session
    10, after the network, dev 256^2 at N = 900 and a 480^2 crop at N = 14,400, with session 10's half-size
    REFINE_STEPS and no decay): the best scale was 1 for 10 steps, 2-3 for 30, 3-4 for 50 and >= 4 for 100
    (+0.5 to +1 dB over scale 1 at 50-100)."""
    scale = min(REFINE_SCALE_MAX, max(1.0, steps / 12))
    r = REFINE_STEPS
    return StepSizes(r.mean_cells * scale, r.log_scale * scale, r.rotation * scale, r.colour * scale)


def _render(params: torch.Tensor, width: int, height: int) -> torch.Tensor:
    return render_torch(params, width, height, width, height)


def _pack(params: torch.Tensor, width: int, height: int) -> list[torch.Tensor]:
    """params [..., 8] on a W x H canvas -> leaves: means in pixels, log scales, rotation, colours."""
    px = torch.tensor([width / 2, height / 2], dtype=params.dtype, device=params.device)
    return [((params[..., 0:2] + 1) * px).detach().clone(), torch.log(params[..., 2:4].clamp_min(1e-3)).detach(),
            params[..., 4:5].detach().clone(), params[..., 5:8].detach().clone()]


def _unpack(leaves: list[torch.Tensor], width: int, height: int) -> torch.Tensor:
    means, log_scales, rotation, colours = leaves
    px = torch.tensor([width / 2, height / 2], dtype=means.dtype, device=means.device)
    return torch.cat([means / px - 1, torch.exp(log_scales), rotation, colours], dim=-1)


def random_init(num_frames: int, n: int, width: int, height: int, seed: int = 0) -> np.ndarray:
    """Means uniform over the frame, isotropic sigma 0.6 x the grid spacing, random rotation, grey-ish colours."""
    rng = np.random.default_rng(seed)
    params = np.empty((num_frames, n, 8), np.float32)
    params[..., 0:2] = rng.uniform(-1, 1, (num_frames, n, 2))
    params[..., 2:4] = 0.6 * math.sqrt(width * height / n)
    params[..., 4] = rng.uniform(0, 2 * math.pi, (num_frames, n))
    params[..., 5:8] = rng.uniform(0.1, 0.5, (num_frames, n, 3))
    return params


def least_squares_colours(params: torch.Tensor, target: torch.Tensor, iterations: int = LS_ITERATIONS,
                          ridge: float = 1e-4) -> torch.Tensor:
    """Best colours for fixed geometry: CG on (A^T A + ridge I) c = A^T y, per frame and channel."""
    h, w = target.shape[-3:-1]
    geometry = params[..., :5].detach()

    def apply_a(c):
        return _render(torch.cat([geometry, c], -1), w, h)

    def apply_at(image):
        c = torch.zeros_like(params[..., 5:8], requires_grad=True)
        with torch.enable_grad():
            (apply_a(c) * image).sum().backward()
        return c.grad

    def normal(c):
        return apply_at(apply_a(c)) + ridge * c

    c = params[..., 5:8].detach().clone()
    r = apply_at(target) - normal(c)
    p = r.clone()
    rs = (r * r).sum(-2, keepdim=True)  # per frame and channel
    for _ in range(iterations):
        ap = normal(p)
        alpha = rs / (p * ap).sum(-2, keepdim=True).clamp_min(1e-20)
        c = c + alpha * p
        r = r - alpha * ap
        rs_new = (r * r).sum(-2, keepdim=True)
        p = r + (rs_new / rs.clamp_min(1e-20)) * p
        rs = rs_new
    return torch.cat([params[..., :5].detach(), c], -1)


def step_size_factor(step: int, iters: int, warmup: int = 0, decay: float = 1.0) -> float:
    """The share of its own step size each group takes at `step` of `iters`: a linear ramp up over the first
    `warmup` steps, then 1, then over the last `decay` share of the steps a half cosine down to 5 % (decay
    1: over the whole run; 0: constant step sizes)."""
    ramp = min(1.0, (step + 1) / warmup) if warmup else 1.0
    start = iters - round(decay * iters)
    if step < start:
        return ramp
    done = min(step - start, iters - start) / max(1, iters - start)
    return ramp * (0.05 + 0.95 * 0.5 * (1 + math.cos(math.pi * done)))


def fit(target: torch.Tensor, init: torch.Tensor, iters: int, steps: StepSizes = FIT_STEPS, decay: float = 1.0,
        warmup: int = 0) -> torch.Tensor:
    """Optimise params [T, N, 8] (canvas = the target's W x H) to target [T, H, W, 3] for `iters` Adam
    steps, each frame as if it were alone (ADAM_EPS), the step sizes scaled by step_size_factor(step, iters,
    warmup, decay); each frame's parameters with the lowest error seen, the start included (_keep_better)."""
    if not 0 <= decay <= 1:
        raise ValueError(f"fit: decay must be in [0, 1], got {decay}")
    h, w = target.shape[-3:-1]
    leaves = [leaf.requires_grad_(True) for leaf in _pack(init.detach(), w, h)]
    cell = math.sqrt(w * h / max(1, init.shape[-2]))
    sizes = (steps.mean_cells * cell, steps.log_scale, steps.rotation, steps.colour)
    optimizer = torch.optim.Adam([{"params": [leaf], "lr": lr} for leaf, lr in zip(leaves, sizes)], eps=ADAM_EPS)
    scheduler = torch.optim.lr_scheduler.LambdaLR(optimizer, lambda step: step_size_factor(step, iters, warmup, decay))

    def frame_errors(params):
        return ((_render(params, w, h) - target) ** 2).mean((-3, -2, -1))

    best = None
    for step in range(iters):
        params = _unpack(leaves, w, h)
        errors = frame_errors(params)
        best = _keep_better(best, params.detach(), errors.detach())
        optimizer.zero_grad(set_to_none=True)
        errors.sum().backward()  # each frame's own error (ADAM_EPS)
        optimizer.step()
        scheduler.step()
    params = _unpack([leaf.detach() for leaf in leaves], w, h)
    with torch.no_grad():
        return _keep_better(best, params, frame_errors(params))[0]


def _keep_better(best: tuple | None, params: torch.Tensor, errors: torch.Tensor) -> tuple:
    """(params, errors) per frame from `best` or the new ones, whichever has the lower error. Adam's last
    step is not always its best where the start is already close (a smooth 480^2 crop at 4-px cells: 30
    steps from the least-squares colours ended 0.09 dB below the best step on one of 4 clips), so `fit`
    returns each frame's best: refinement never leaves a frame worse than the colours it started from."""
    if best is None:
        return params, errors
    better = errors < best[1]
    return torch.where(better[..., None, None], params, best[0]), torch.minimum(errors, best[1])


def refine_params(params: np.ndarray, frames: np.ndarray, steps: int, device="cpu", sizes: StepSizes | None = None,
                  warmup: int = REFINE_WARMUP, decay: float = REFINE_DECAY,
                  ls_iterations: int = LS_ITERATIONS) -> np.ndarray:
    """Warm-started refinement of [T, N, 8] params on a W x H canvas against uint8 frames [T, H, W, 3]:
    least-squares colours (step 1, `ls_iterations` CG iterations), then `steps - 1` Adam steps from there (step
    sizes `sizes`, default refine_steps(steps), ramped up over `warmup` steps, constant, then decayed over the
    last `decay` share of them). The defaults are the product's; the others are for experiments
    (tools/refine_sweep.py)."""
    if steps < 1:
        raise ValueError(f"refine steps must be >= 1, got {steps}")
    target = torch.from_numpy(frames).to(device).float() / 255
    refined = least_squares_colours(torch.from_numpy(np.ascontiguousarray(params)).to(device), target, ls_iterations)
    if steps > 1:
        refined = fit(target, refined, steps - 1, sizes or refine_steps(steps), decay=decay, warmup=warmup)
    return refined.cpu().numpy()
