"""Image quality metrics on RGB frames in [0, 1], shape [..., H, W, 3] (numpy or torch), the artefact
checks and the temporal figures.

PSNR is plain numpy (the Blender side needs it without torch); SSIM and MS-SSIM come from
pytorch-msssim (Gaussian window 11, sigma 1.5, the standard constants)."""
from __future__ import annotations

import numpy as np


def psnr(pred, target, data_range: float = 1.0) -> np.ndarray:
    """Per-frame PSNR in dB over the last three axes (pred clipped to [0, data_range]); inf for
    identical frames."""
    pred, target = _numpy(pred).astype(np.float64), _numpy(target).astype(np.float64)
    return psnr_from_mse(np.mean((np.clip(pred, 0, data_range) - target) ** 2, axis=(-3, -2, -1)), data_range)


def psnr_from_mse(mse, data_range: float = 1.0):
    """PSNR in dB of a mean squared error (a number or an array); inf for 0."""
    with np.errstate(divide="ignore"):
        return 10 * np.log10(data_range ** 2 / np.asarray(mse, np.float64))


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


# ---- artefacts: seams at tile borders, a lattice in flat regions, dark frame edges ---------------------
# Each compares the render with the source on frames [T, H, W, 3] in [0, 1]; figures in 1/255 units.

def seam_ratio(pred, target, xs=(), ys=(), band: int = 2) -> float | None:
    """Mean squared error within `band` pixels of the tile borders (columns xs, rows ys) over the mean
    squared error elsewhere: about 1 without seams. None when there are no borders."""
    pred, target = _numpy(pred), _numpy(target)
    h, w = pred.shape[-3:-1]
    near = np.zeros((h, w), bool)
    for x in xs:
        near[:, max(0, x - band):x + band] = True
    for y in ys:
        near[max(0, y - band):y + band, :] = True
    if not near.any() or near.all():
        return None
    err = ((np.clip(pred, 0, 1) - target) ** 2).mean(-1).reshape(-1, h, w)
    return float(err[:, near].mean() / max(err[:, ~near].mean(), 1e-12))


def _block_std(a: np.ndarray, k: int) -> np.ndarray:
    """[..., H, W, 3] -> the std of each k x k block in 1/255 units [T, H // k, W // k, 3]."""
    h, w = a.shape[-3:-1]
    hh, ww = h // k * k, w // k * k
    a = a.reshape(-1, h, w, 3)[:, :hh, :ww]
    return a.reshape(a.shape[0], hh // k, k, ww // k, k, 3).std(axis=(2, 4)) * 255


def flat_blocks(target, window: int, flat: float = 1.0) -> np.ndarray:
    """Which `window` x `window` blocks of the source lie inside flat regions: the block and its 8
    neighbours all have a std < `flat`/255 in every channel (so neither the frame's edge nor an object's
    is near). Bool [T, H // window, W // window]."""
    return _flat_keep(_block_std(_numpy(target), max(2, int(window))), flat)


def _flat_keep(source_std: np.ndarray, flat: float) -> np.ndarray:
    """flat_blocks from the source's block stds [T, by, bx, 3]."""
    flat_block = (source_std < flat).all(-1)
    keep = np.zeros_like(flat_block)
    keep[:, 1:-1, 1:-1] = True
    for dy in (-1, 0, 1):
        for dx in (-1, 0, 1):
            keep[:, 1:-1, 1:-1] &= flat_block[:, 1 + dy:flat_block.shape[1] - 1 + dy, 1 + dx:flat_block.shape[2] - 1 + dx]
    return keep


def flat_ripple(pred, target, window: int, flat: float = 1.0) -> dict:
    """In `window` x `window` blocks inside flat regions (`flat_blocks`), the std of the source and of the
    render (a lattice of blobs at the Gaussians' spacing shows as a render std well above the source's):
    means over those blocks, in 1/255 units, and their count."""
    pred, target = _numpy(pred), _numpy(target)
    k = max(2, int(window))
    src, out = _block_std(target, k), _block_std(np.clip(pred, 0, 1), k)
    keep = _flat_keep(src, flat)
    if not keep.any():
        return {"blocks": 0, "source_std": None, "render_std": None}
    return {"blocks": int(keep.sum()), "source_std": float(src[keep].mean()), "render_std": float(out[keep].mean())}


def cell_phase_means(values, rows, cols, cell: float, bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Fold per-pixel values by where each pixel lies in its cell: pixel (row, col), whose centre is at
    (row + 0.5, col + 0.5), has phase py * bins + px, py and px its centre's bin among `bins` equal parts
    of the cell side (`cell` px) along each axis. values [P, C], rows and cols [P] (any shapes that
    broadcast to P) -> (the phase of each pixel [P], the mean value at each phase [bins * bins, C], 0 at a
    phase no pixel has). What repeats at the cell period in an error: the tools that look for a lattice."""
    rows, cols = np.broadcast_arrays(np.asarray(rows), np.asarray(cols))
    phase_y = np.floor(((rows.ravel() + 0.5) / cell) % 1 * bins).astype(int)
    phase_x = np.floor(((cols.ravel() + 0.5) / cell) % 1 * bins).astype(int)
    phase = phase_y * bins + phase_x
    values = np.asarray(values).reshape(len(phase), -1)
    counts = np.maximum(np.bincount(phase, minlength=bins * bins), 1)
    means = np.stack([np.bincount(phase, values[:, c], bins * bins) / counts for c in range(values.shape[1])], 1)
    return phase, means


def edge_bias(pred, target, band: int = 6) -> float:
    """Mean signed error (render - source) in the `band`-pixel frame border minus that of the interior,
    in 1/255 units: negative when the frame's edges come back darker."""
    pred, target = _numpy(pred), _numpy(target)
    h, w = pred.shape[-3:-1]
    err = (np.clip(pred, 0, 1) - target).mean(-1).reshape(-1, h, w) * 255
    border = np.ones((h, w), bool)
    border[band:h - band, band:w - band] = False
    return float(err[:, border].mean() - err[:, ~border].mean())


# ---- temporal behaviour: consecutive frames [T, H, W, 3], T >= 2 -----------------------------------------

def delta_psnr(pred, target) -> float:
    """PSNR of the frame differences (render t+1 - render t against source t+1 - source t), peak 1,
    averaged over the pairs: how faithfully the render changes from frame to frame. An error that stays
    from frame to frame costs nothing here, one that changes (flicker) does."""
    pred, target = np.clip(_numpy(pred), 0, 1).astype(np.float64), _numpy(target).astype(np.float64)
    mse = np.mean((np.diff(pred, axis=0) - np.diff(target, axis=0)) ** 2, axis=(-3, -2, -1))
    with np.errstate(divide="ignore"):
        return float(np.mean(-10 * np.log10(mse)))


def still_change(pred, target, still: float = 2.0) -> dict:
    """Where the source is still between consecutive frames (every channel changes by less than `still`
    /255), the mean absolute change of the render and of the source there, in 1/255 units, and the
    fraction of pixels that are still: the flicker a viewer sees on what does not move."""
    pred, target = np.clip(_numpy(pred), 0, 1), _numpy(target)
    source = np.abs(np.diff(target, axis=0)) * 255
    render = np.abs(np.diff(pred, axis=0)) * 255
    mask = (source < still).all(-1)
    if not mask.any():
        return {"fraction": 0.0, "source": None, "render": None}
    return {"fraction": float(mask.mean()), "source": float(source[mask].mean()), "render": float(render[mask].mean())}


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
