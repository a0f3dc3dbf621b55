"""Content-adaptive placement: where a refined encode's Gaussians start (issue 18, item 1).

The network puts one Gaussian in every cell, so at a sparse count a flat wall gets as many as a face. A
refined encode starts instead from two runs of the network: at a coarse density (SPLIT_FRACTION of the
count) and at half its cell (four times as many Gaussians, or the finest cell the network takes). The
coarse cells whose render is furthest from the frame give their Gaussian up for the fine Gaussians whose
means fall inside them, as many cells as the count holds (`split_frame`): the count per frame stays the
user's, and the detail gets the Gaussians.

Such a start is not seamless (the network was trained on uniform grids, and a coarse Gaussian's colour is
its share of a sum with its coarse neighbours): unrefined it reads 23.7 dB where the uniform grid reads
28.6 (dev clips, 256², N = 1000). Refinement's least-squares colours and Adam steps repair the borders, and
then it is ahead: `hypergs eval --gaussians 1000 --refine 50` 32.21 against 31.37 dB, 36.41 against 34.85 on
the held-out pans (model card, session 29). So it is only ever the start of a refinement of
encode.ADAPTIVE_MIN_REFINE steps or more (encode.refine_frames), and only where it pays
(`choose_start`): where the seamless split, each coarse cell rendered by the run it keeps, would beat the
grid's render by SPLIT_MIN_GAIN_DB, and where the grid's render is below SPLIT_MAX_PSNR. On smooth frames at
high PSNR refinement cannot repair the borders (a held-out 480² pan at Standard's density, `--refine 30`: the
grid 52.02 dB, the split 45.01).
"""
from __future__ import annotations

import numpy as np

# The coarse run's share of the count. Session 29 (256², N = 1000, --refine 50, dev / held-out): 0.5 32.27 /
# 36.28 dB, 0.6 32.23 / 36.49, 0.7 32.14 / 36.59 (uniform 31.37 / 34.85).
SPLIT_FRACTION = 0.6
# The split is taken where its seamless version beats the grid's render by this much. Session 29, per video
# (the seamless split's gain -> the refined split's gain over the refined grid): 0.09 -> -7.01 dB and 0.18 ->
# -1.54 (smooth 480² pans at 6-px cells, refine 30), 0.34 -> +0.22, 0.50 -> +0.26, 0.51 -> +0.06, 0.53 -> +0.41,
# and from 0.75 up +0.49 to +2.57 (256² at N = 1000 and 3000, refine 50; 480² at 6-px cells, refine 30).
SPLIT_MIN_GAIN_DB = 0.5
# Above this PSNR of the grid's render the borders cost more than the split gains, though its seamless version
# would gain: refine 30 at Standard's 6-px cells on whole 720p held-out frames (3 per pan), Aqua 47.2 dB -> -1.70,
# LadyBird 44.6 -> -0.11 (the split taken on one of its frames); below it every mean gained (the grid's PSNR ->
# the gain): 42.5 -> +0.68, 41.1 -> +0.49, 40.6 -> +1.54, 37.6 -> +2.57 and 27.9-35.2 -> +0.15 to +1.97 dB.
SPLIT_MAX_PSNR = 43.0


def pixel_cells(width: int, height: int, cols: int, rows: int) -> np.ndarray:
    """The cell (row-major on a cols x rows grid over the frame) of each pixel centre of a width x height
    image -> int64 [height, width]."""
    ix = np.minimum((np.arange(width) + 0.5) * cols // width, cols - 1).astype(np.int64)
    iy = np.minimum((np.arange(height) + 0.5) * rows // height, rows - 1).astype(np.int64)
    return iy[:, None] * cols + ix[None, :]


def pixel_errors(rendered: np.ndarray, target: np.ndarray) -> np.ndarray:
    """The squared error of a render (clipped to [0, 1], as a viewer shows it) against float target [H, W, 3],
    summed over the channels -> [H, W]."""
    return ((np.clip(rendered, 0, 1) - target) ** 2).sum(-1)


def cell_sums(values: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """Per-pixel values [..., H, W] summed over each cell of a cols x rows grid -> float64 [..., cols * rows]."""
    h, w = values.shape[-2:]
    cells = pixel_cells(w, h, cols, rows).ravel()
    sums = [np.bincount(cells, v, cols * rows) for v in values.reshape(-1, h * w)]
    return np.stack(sums).reshape(values.shape[:-2] + (cols * rows,))


def cell_errors(rendered: np.ndarray, target: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """`pixel_errors` summed over each cell of a cols x rows grid -> float64 [cols * rows]."""
    return cell_sums(pixel_errors(rendered, target), cols, rows)


def owner_cells(params: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """The cell (row-major, cols x rows over the canvas) of each Gaussian's mean, params [N, 8] on [-1, 1]
    coordinates; a mean outside the canvas counts for the nearest cell."""
    ix = np.clip(np.floor((params[:, 0] + 1) / 2 * cols), 0, cols - 1).astype(np.int64)
    iy = np.clip(np.floor((params[:, 1] + 1) / 2 * rows), 0, rows - 1).astype(np.int64)
    return iy * cols + ix


def split_frame(coarse: np.ndarray, fine: np.ndarray, score: np.ndarray, cols: int, rows: int,
                count: int) -> tuple[np.ndarray, np.ndarray]:
    """One frame: coarse params [Nc, 8] (one per cell of a cols x rows grid, row-major), fine params
    [Nf, 8] and a score per coarse cell -> exactly `count` params: the coarse Gaussians of the cells
    that score least, then the fine Gaussians whose means fall in the others, the highest-scoring cells
    first, as many cells as `count` holds; the few left to make up the count are the first fine
    Gaussians of the next cell, beside its coarse Gaussian (refinement's colours share them out).
    Needs Nc <= count <= Nf. -> (params [count, 8], which coarse cells were split [Nc])."""
    nc = len(coarse)
    if not nc <= count <= len(fine):
        raise ValueError(f"split_frame: the count ({count}) must lie between the coarse ({nc}) and the fine "
                         f"({len(fine)}) Gaussians")
    owner = owner_cells(fine, cols, rows)
    order = np.argsort(-score, kind="stable")
    totals = nc + np.cumsum(np.bincount(owner, minlength=nc)[order] - 1)  # the count after splitting 1, 2, ...
    over = np.flatnonzero(totals > count)  # (a cell no fine mean fell in lowers it: not sorted)
    k = int(over[0]) if len(over) else nc
    split = np.zeros(nc, bool)
    split[order[:k]] = True
    parts = [coarse[~split], fine[split[owner]]]
    short = count - len(parts[0]) - len(parts[1])
    if short:  # then k < nc, and the next cell holds more than `short` fine Gaussians (totals[k] > count)
        parts.append(fine[owner == order[k]][:short])
    return np.concatenate(parts), split


def split_may_pay(grid_error: float, target: np.ndarray) -> bool:
    """Whether a frame (float [H, W, 3] in [0, 1]) whose grid renders with `grid_error` (`pixel_errors`, summed)
    is below SPLIT_MAX_PSNR: only then are the coarse and fine runs worth making (`choose_start`)."""
    return grid_error > target.size * 10 ** (-SPLIT_MAX_PSNR / 10)  # PSNR = 10 log10(1 / mean squared error)


def choose_start(grid: np.ndarray, grid_error: float, coarse: np.ndarray, fine: np.ndarray, target: np.ndarray,
                 cols: int, rows: int, render) -> np.ndarray:
    """One frame's start: the split (`split_frame` of the coarse run's params on its cols x rows cells and the
    fine run's, the coarse cells scored by their render's error) where it pays, else the grid's params [N, 8]
    (whose render errs by grid_error: `pixel_errors`, summed). target: the frame, float [H, W, 3] in [0, 1];
    render: params -> the frame's render."""
    coarse_errors = cell_errors(render(coarse), target, cols, rows)
    split_params, split = split_frame(coarse, fine, coarse_errors, cols, rows, len(grid))
    seamless = np.where(split, cell_errors(render(fine), target, cols, rows), coarse_errors).sum()
    return split_params if seamless * 10 ** (SPLIT_MIN_GAIN_DB / 10) <= grid_error else grid
