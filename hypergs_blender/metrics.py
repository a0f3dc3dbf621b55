"""Image quality metrics on RGB frames in [0, 1], shape [..., H, W, 3] (numpy or torch).

PSNR is plain numpy (the Blender side needs it without torch); SSIM and MS-SSIM come from
pytorch-msssim (Gaussian window 11, sigma 1.5, the standard constants)."""
from __future__ import annotations

import numpy as np


def psnr(pred, target, data_range: float = 1.0) -> np.ndarray:
    """Per-frame PSNR in dB over the last three axes; inf for identical frames."""
    pred, target = _numpy(pred).astype(np.float64), _numpy(target).astype(np.float64)
    mse = np.mean((np.clip(pred, 0, data_range) - target) ** 2, axis=(-3, -2, -1))
    with np.errstate(divide="ignore"):
        return 10 * np.log10(data_range ** 2 / mse)


def ssim(pred, target) -> np.ndarray:
    from pytorch_msssim import ssim as _ssim
    return _per_frame(_ssim, pred, target)


def ms_ssim(pred, target) -> np.ndarray:
    """MS-SSIM with the standard 5 scales; NaN for frames whose short side is 160 px or less."""
    from pytorch_msssim import ms_ssim as _ms_ssim
    if min(_numpy(pred).shape[-3:-1]) <= 160:
        return np.full(_numpy(pred).shape[:-3], np.nan)
    return _per_frame(_ms_ssim, pred, target)


def summary(pred, target) -> dict:
    """Mean PSNR, SSIM and MS-SSIM of a clip (PSNR averaged per frame, as in the literature)."""
    return {"psnr": float(np.mean(psnr(pred, target))), "ssim": float(np.mean(ssim(pred, target))),
            "ms_ssim": float(np.mean(ms_ssim(pred, target)))}


def _per_frame(fn, pred, target, **kwargs) -> np.ndarray:
    import torch
    p = torch.as_tensor(_numpy(pred), dtype=torch.float32).clamp(0, 1)
    t = torch.as_tensor(_numpy(target), dtype=torch.float32)
    lead = p.shape[:-3]
    p = p.reshape(-1, *p.shape[-3:]).permute(0, 3, 1, 2)
    t = t.reshape(-1, *t.shape[-3:]).permute(0, 3, 1, 2)
    values = fn(p, t, data_range=1.0, size_average=False, **kwargs)
    return values.reshape(lead).numpy().astype(np.float64)


def _numpy(a) -> np.ndarray:
    if isinstance(a, np.ndarray):
        return a
    return a.detach().cpu().numpy()
