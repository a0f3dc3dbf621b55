"""Adaptive effective-rank and scale regularizers (HyperGS), with EMA-tracked percentile thresholds.

erank of a 2D Gaussian with scales s: q_k = s_k^2 / sum_j s_j^2, erank = exp(-sum_k q_k log q_k), in
[1, 2] (1: a needle, 2: a circle). Gaussians whose erank falls below tau = max(floor, EMA of the
batch's 1st erank percentile) pay the hinge tau - erank; scales above s_max = min(ceiling, EMA of
the 99th scale percentile) pay their squared excess. The EMAs are buffers: they live in the
module's state_dict and so in every checkpoint. Scales are in whatever unit the caller passes; the
trainer passes them in grid cells (the anchor spacing), so that the thresholds hold for every
Gaussian count it draws.
"""
from __future__ import annotations

import torch
import torch.nn as nn


def effective_rank(scales: torch.Tensor) -> torch.Tensor:
    """[..., 2] scales -> [...] erank in [1, 2]."""
    s2 = scales * scales
    q = s2 / s2.sum(-1, keepdim=True).clamp_min(1e-20)
    entropy = -(q * torch.log(q.clamp_min(1e-20))).sum(-1)
    return torch.exp(entropy)


class AdaptiveRegularizer(nn.Module):
    def __init__(self, erank_weight=0.01, scale_weight=0.01, tau0=1.05, s0=32.0, momentum=0.99,
                 erank_floor=1.005, scale_ceiling=80.0):
        super().__init__()
        self.erank_weight, self.scale_weight, self.momentum = erank_weight, scale_weight, momentum
        self.erank_floor, self.scale_ceiling = erank_floor, scale_ceiling
        self.register_buffer("erank_ema", torch.tensor(float(tau0)))
        self.register_buffer("scale_ema", torch.tensor(float(s0)))

    @property
    def tau(self) -> torch.Tensor:
        return self.erank_ema.clamp_min(self.erank_floor)

    @property
    def s_max(self) -> torch.Tensor:
        return self.scale_ema.clamp_max(self.scale_ceiling)

    def forward(self, scales: torch.Tensor) -> tuple[torch.Tensor, dict]:
        """scales [..., 2] -> (weighted loss, stats). Updates the EMAs in training."""
        erank = effective_rank(scales)
        tau, s_max = self.tau, self.s_max
        erank_loss = torch.relu(tau - erank).mean()
        scale_loss = torch.relu(scales - s_max).square().mean()
        if self.training:
            with torch.no_grad():
                flat_e, flat_s = erank.detach().flatten().float(), scales.detach().flatten().float()
                self.erank_ema.lerp_(torch.quantile(flat_e[:1 << 20], 0.01), 1 - self.momentum)
                self.scale_ema.lerp_(torch.quantile(flat_s[:1 << 20], 0.99), 1 - self.momentum)
        loss = self.erank_weight * erank_loss + self.scale_weight * scale_loss
        return loss, {"erank_min": float(erank.detach().min()), "tau": float(tau), "s_max": float(s_max)}
