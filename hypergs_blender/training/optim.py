"""LAMB (You et al., 2020): Adam moments with a per-tensor trust ratio ||w|| / ||update||.

A parameter group with adapt=False skips the trust ratio (plain Adam with decoupled decay), as
LAMB implementations allow for biases and norms: a tensor that starts at zero (an output head
initialised to the identity of its parametrization) would otherwise grow only by the factor
(1 + lr) per step."""
from __future__ import annotations

import torch


class Lamb(torch.optim.Optimizer):
    def __init__(self, params, lr=1e-3, betas=(0.9, 0.999), eps=1e-6, weight_decay=0.01):
        super().__init__(params, dict(lr=lr, betas=betas, eps=eps, weight_decay=weight_decay, adapt=True))

    @torch.no_grad()
    def step(self, closure=None):
        loss = closure() if closure is not None else None
        for group in self.param_groups:
            beta1, beta2 = group["betas"]
            for p in group["params"]:
                if p.grad is None:
                    continue
                state = self.state[p]
                if not state:
                    state["step"] = 0
                    state["exp_avg"] = torch.zeros_like(p)
                    state["exp_avg_sq"] = torch.zeros_like(p)
                state["step"] += 1
                m, v = state["exp_avg"], state["exp_avg_sq"]
                m.lerp_(p.grad, 1 - beta1)
                v.mul_(beta2).addcmul_(p.grad, p.grad, value=1 - beta2)
                m_hat = m / (1 - beta1 ** state["step"])
                v_hat = v / (1 - beta2 ** state["step"])
                update = m_hat / (v_hat.sqrt() + group["eps"])
                if group["weight_decay"] and p.ndim > 1:
                    update.add_(p, alpha=group["weight_decay"])
                trust = 1.0
                if group["adapt"]:
                    w_norm, u_norm = float(p.norm()), float(update.norm())
                    trust = w_norm / u_norm if w_norm > 0 and u_norm > 0 else 1.0
                p.add_(update, alpha=-group["lr"] * trust)
        return loss


def parameter_groups(model: torch.nn.Module, head_prefix: str = "head.", plain_lr_scale: float = 0.1) -> list[dict]:
    """Matrices get the trust ratio and weight decay; biases, norms and the output head do not, and
    take plain Adam steps at `plain_lr_scale` x the learning rate: without the trust ratio, a LAMB
    rate (~1e-3 relative per step) moves an output head fast enough to throw away its initialisation.
    The trainer sets each group's lr to schedule(step) x its "lr_scale"."""
    adapted, plain = [], []
    for name, p in model.named_parameters():
        (adapted if p.ndim > 1 and not name.startswith(head_prefix) else plain).append(p)
    return [dict(params=adapted, lr_scale=1.0),
            dict(params=plain, adapt=False, weight_decay=0.0, lr_scale=plain_lr_scale)]
