"""Experiment (issue 18, item 1): content-adaptive Gaussians at a fixed total per frame, without
retraining. The bundled network runs at a coarse density (a fraction of the budget) and at twice the
density (half the cell, or the finest the network takes); the coarse cells that need it most (a score
per cell) give their Gaussian up for the fine Gaussians whose means fall inside them, as many cells as
keep the total at the uniform layout's count. Measured like `hypergs eval --gaussians N --frames 8
--size 256` (its frame sampling, metrics.psnr, the numpy renderer), with and without the least-squares
colours that refinement starts with (refine.least_squares_colours: `hypergs encode --refine 1` at its
default 10 iterations), and (--ceiling) the PSNR of a seamless split, the ideal composite.
The product's placement (hypergs_blender/placement.py, session 29) is this tool's `error` score at f = 0.6 without
a seam fix, its few Gaussians short of the count taken from the next cell rather than halves, taken only where
the ideal composite pays, and only for a refinement: `--refine 50 --ls 0.6:error` measures it without that check.

    OMP_NUM_THREADS=1 .venv/bin/python tools/adaptive_split.py VIDEOS... --gaussians 1000 --json out.json
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

from hypergs_blender import metrics
from hypergs_blender.encode import encode_frames, frames_layout, encoder_layout
from hypergs_blender.evaluate import read_eval_frames, warm_up
from hypergs_blender.network import resolve_encoder
from hypergs_blender.placement import cell_sums, owner_cells, pixel_cells
from hypergs_blender.refine import least_squares_colours, refine_params
from hypergs_blender.render import render_params

SCORES = ("error", "diff", "gain")


def split_cells(coarse: np.ndarray, fine: np.ndarray, score: np.ndarray, cols: int, rows: int,
                budget: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One frame: coarse params [Nc, 8] on a cols x rows grid, fine params [Nf, 8], a score per coarse
    cell -> exactly `budget` params: the highest-scoring cells' coarse Gaussians replaced by the fine
    Gaussians whose means fall inside them, as many cells as the budget holds; what is left over (a
    few Gaussians) goes to the best unsplit coarse Gaussians, each halved into two identical halves of
    its colour (the same render). Also returns the split mask per coarse cell and, per output Gaussian,
    whether it is a fine one and its weight (0.5 for the halves)."""
    nc = len(coarse)
    owner = owner_cells(fine, cols, rows)
    counts = np.bincount(owner, minlength=nc)
    order = np.argsort(-score, kind="stable")
    totals = nc + np.cumsum(counts[order] - 1)
    over = np.nonzero(totals > budget)[0]
    k = int(over[0]) if len(over) else nc
    split = np.zeros(nc, bool)
    split[order[:k]] = True
    kept = coarse[~split]
    taken = fine[split[owner]]
    deficit = budget - len(kept) - len(taken)
    if deficit < 0:
        raise ValueError("the coarse layout alone is over the budget")
    rest = order[k:][:deficit] if deficit else order[:0]
    rest_in_kept = np.searchsorted(np.nonzero(~split)[0], rest)
    halves = kept[rest_in_kept].copy()
    halves[:, 5:8] *= 0.5
    kept = kept.copy()
    kept[rest_in_kept, 5:8] *= 0.5
    out = np.concatenate([kept, taken, halves])
    assert len(out) == budget, (len(out), budget, deficit)
    fine_from = len(kept)
    weight = np.ones(budget, np.float32)
    weight[rest_in_kept] = 0.5
    weight[len(kept) + len(taken):] = 0.5
    origin = np.zeros(budget, bool)  # True: a fine Gaussian
    origin[fine_from:fine_from + len(taken)] = True
    return out, split, origin, weight


def coarse_share(split: np.ndarray, x: np.ndarray, y: np.ndarray, cols: int, rows: int) -> np.ndarray:
    """The coarse layout's share at points x, y ([-1, 1] coordinates): 1 in unsplit cells, 0 in split
    ones, interpolated bilinearly between cell centres (a ramp one coarse cell wide across a border)."""
    a = 1 - split.reshape(rows, cols).astype(np.float32)
    u = np.clip((x + 1) / 2 * cols - 0.5, 0, cols - 1)
    v = np.clip((y + 1) / 2 * rows - 0.5, 0, rows - 1)
    i0 = np.clip(np.floor(v), 0, max(rows - 2, 0)).astype(np.int64)
    j0 = np.clip(np.floor(u), 0, max(cols - 2, 0)).astype(np.int64)
    i1, j1 = np.minimum(i0 + 1, rows - 1), np.minimum(j0 + 1, cols - 1)
    fv, fu = v - i0, u - j0
    return ((a[i0, j0] * (1 - fu) + a[i0, j1] * fu) * (1 - fv) + (a[i1, j0] * (1 - fu) + a[i1, j1] * fu) * fv)


def blend_cells(coarse: np.ndarray, fine: np.ndarray, score: np.ndarray, cols: int, rows: int,
                budget: int, eps: float = 1e-3):
    """split_cells without a hard border: every coarse Gaussian's colour times the coarse share at its
    mean (coarse_share), every fine one's times 1 - that; Gaussians whose share is 0 are left out. The
    render is then about share x coarse render + (1 - share) x fine render, seamless by construction;
    the ramp costs the fine Gaussians on the unsplit side of each border. As many of the best cells are
    split as the budget holds (bisection), the rest filled with halves as in split_cells."""
    nc = len(coarse)
    order = np.argsort(-score, kind="stable")

    def sets(k):
        split = np.zeros(nc, bool)
        split[order[:k]] = True
        wc = coarse_share(split, coarse[:, 0], coarse[:, 1], cols, rows)
        wf = 1 - coarse_share(split, fine[:, 0], fine[:, 1], cols, rows)
        return split, wc, wf, int((wc > eps).sum() + (wf > eps).sum())

    lo, hi = 0, nc  # the largest k whose count fits (counts grow with k, nearly monotonically)
    while lo < hi:
        mid = (lo + hi + 1) // 2
        if sets(mid)[3] <= budget:
            lo = mid
        else:
            hi = mid - 1
    split, wc, wf, count = sets(lo)
    kc, kf = wc > eps, wf > eps
    parts = [coarse[kc].copy(), fine[kf].copy()]
    parts[0][:, 5:8] *= wc[kc, None]
    parts[1][:, 5:8] *= wf[kf, None]
    weight = np.concatenate([wc[kc], wf[kf]]).astype(np.float32)
    out = np.concatenate(parts)
    deficit = budget - len(out)
    full = np.nonzero(wc[kc] >= 1 - eps)[0]  # whole coarse Gaussians, best scores first
    rank = np.argsort(-score[np.nonzero(kc)[0][full]], kind="stable")
    halve = full[rank][:deficit]
    out[halve, 5:8] *= 0.5
    weight[halve] *= 0.5
    out = np.concatenate([out, out[halve]])
    weight = np.concatenate([weight, weight[halve]])
    assert len(out) == budget, (len(out), budget)
    return out, split, weight


def normalise(params, origin, weight, coarse, fine, w, h):
    """Seam fix without a solve: each Gaussian's colour scaled by the kernel sum its own layout has at
    its mean (all coarse, or all fine) over the kernel sum of the mixed set there."""
    mixed = coverage_at(params, weight, params, w, h)
    ones_c = np.ones(coarse.shape[:2], np.float32)
    ones_f = np.ones(fine.shape[:2], np.float32)
    pure = np.where(origin, coverage_at(fine, ones_f, params, w, h), coverage_at(coarse, ones_c, params, w, h))
    out = params.copy()
    out[..., 5:8] *= (pure / np.maximum(mixed, 1e-3))[..., None]
    return out


def sample_at(image, points, w, h):
    """image [T, H, W, C] at the nearest pixel of each mean of points [T, N, 8] -> [T, N, C]."""
    x = np.clip(((points[..., 0] + 1) / 2 * w).astype(np.int64), 0, w - 1)
    y = np.clip(((points[..., 1] + 1) / 2 * h).astype(np.int64), 0, h - 1)
    flat = image.reshape(image.shape[0], -1, image.shape[-1])
    return np.take_along_axis(flat, (y * w + x)[..., None], axis=1)


def correct(params, weight, ideal, iterations, w, h):
    """Seam fix without a solve: `iterations` residual steps, each Gaussian's colour moved by the
    residual (ideal render - mixed render) at its mean over the mixed set's kernel sum there."""
    cov = coverage_at(params, weight, params, w, h)[..., None]
    out = params.copy()
    for _ in range(iterations):
        residual = ideal - render_params(out, w, h, w, h)
        out[..., 5:8] += sample_at(residual, out, w, h) * (weight[..., None] / np.maximum(cov, 1e-3))
    return out


def coverage_at(params, weight, points, w, h):
    """The kernel sum of `params` (times weight) at the means of `points`."""
    ones = params.copy()
    ones[..., 5:8] = weight[..., None]
    return sample_at(render_params(ones, w, h, w, h)[..., :1], points, w, h)[..., 0]


def adaptive(source: np.ndarray, encoder, budget_layout, fraction: float, score: str):
    """params [T, budget, 8], the split masks [T, Nc], the coarse and fine params, the coarse layout. score: one of
    SCORES (error: the coarse render's squared error in the cell; diff: coarse against fine render;
    gain: coarse error - fine error), then optionally -s (scores summed over 3 x 3 cells), +n (colours
    normalised by kernel sums, `normalise`) or +b (a blended border, `blend_cells`), +rK (K residual steps towards the ideal composite, `correct`),
    in that order: e.g. error-s+r3, error-s+b."""
    score, corrections = (score.split("+r")[0], int(score.split("+r")[1])) if "+r" in score else (score, 0)
    score, blend = score.removesuffix("+b"), score.endswith("+b")
    score, norm = score.removesuffix("+n"), score.endswith("+n")
    score, smooth = score.removesuffix("-s"), score.endswith("-s")
    t, h, w = source.shape[:3]
    budget = budget_layout.count
    coarse_layout = encoder_layout(encoder, w, h, gaussians=max(1, round(fraction * budget)))
    fine_layout = encoder_layout(encoder, w, h, cell=coarse_layout.cell / 2)
    coarse = encode_frames(source, encoder, coarse_layout)
    fine = encode_frames(source, encoder, fine_layout)
    target = source / np.float32(255)
    cols, rows = coarse_layout.cols, coarse_layout.rows
    coarse_render = np.clip(render_params(coarse, w, h, w, h), 0, 1)
    if score == "error":
        s = cell_sums(((coarse_render - target) ** 2).sum(-1), cols, rows)
    else:
        fine_render = np.clip(render_params(fine, w, h, w, h), 0, 1)
        if score == "diff":
            s = cell_sums(((coarse_render - fine_render) ** 2).sum(-1), cols, rows)
        else:
            s = cell_sums(((coarse_render - target) ** 2).sum(-1) - ((fine_render - target) ** 2).sum(-1), cols, rows)
    if smooth:  # 3 x 3 box over the cells: compact split regions, shorter coarse/fine borders
        g = np.pad(s.reshape(t, rows, cols), ((0, 0), (1, 1), (1, 1)), mode="edge")
        s = sum(g[:, dy:dy + rows, dx:dx + cols] for dy in range(3) for dx in range(3)).reshape(t, -1)
    if blend:
        out, masks, weight = map(np.stack, zip(*(blend_cells(coarse[i], fine[i], s[i], cols, rows, budget)
                                                 for i in range(t))))
    else:
        out, masks, origin, weight = map(np.stack, zip(*(split_cells(coarse[i], fine[i], s[i], cols, rows, budget)
                                                         for i in range(t))))
    if norm:
        out = normalise(out, origin, weight, coarse, fine, w, h)
    if corrections:
        ideal = ideal_composite(coarse, fine, masks, cols, rows, w, h, blend)
        out = correct(out, weight, ideal, corrections, w, h)
    return out, masks, coarse, fine, coarse_layout


def ideal_composite(coarse, fine, masks, cols: int, rows: int, w: int, h: int, blend: bool = False) -> np.ndarray:
    """What a seamless split would render: the fine render in the split cells, the coarse one elsewhere
    (blend: mixed by the coarse share at each pixel, coarse_share)."""
    if blend:
        ys = (np.arange(h) + 0.5) / h * 2 - 1
        xs = (np.arange(w) + 0.5) / w * 2 - 1
        share = np.stack([coarse_share(m, xs[None, :], ys[:, None], cols, rows) for m in masks])[..., None]
    else:
        share = 1 - masks[:, pixel_cells(w, h, cols, rows)][..., None].astype(np.float32)
    return share * render_params(coarse, w, h, w, h) + (1 - share) * render_params(fine, w, h, w, h)


def boundary_ratio(rendered, target, masks, cols: int, rows: int, band: int = 2):
    """Mean squared error within `band` pixels of the borders between split and unsplit cells over the
    mean squared error elsewhere (metrics.seam_ratio's figure for coarse/fine seams)."""
    t, h, w = target.shape[:3]
    err = ((np.clip(rendered, 0, 1) - target) ** 2).mean(-1)
    near_all, far_all = [], []
    cells = pixel_cells(w, h, cols, rows)
    for i in range(t):
        pix = masks[i][cells]
        edge = np.zeros((h, w), bool)
        edge[:, 1:] |= pix[:, 1:] != pix[:, :-1]
        edge[1:, :] |= pix[1:, :] != pix[:-1, :]
        near = edge.copy()
        for _ in range(band):
            grown = near.copy()
            grown[:, 1:] |= near[:, :-1]
            grown[:, :-1] |= near[:, 1:]
            grown[1:, :] |= near[:-1, :]
            grown[:-1, :] |= near[1:, :]
            near = grown
        near_all.append(err[i][near])
        far_all.append(err[i][~near])
    near, far = np.concatenate(near_all), np.concatenate(far_all)
    return float(near.mean() / max(far.mean(), 1e-12)) if len(near) else None


def ls_colours(params: np.ndarray, source: np.ndarray, iterations: int, refine: int = 1) -> np.ndarray:
    """refine.least_squares_colours of params [T, N, 8] against uint8 frames (what refine step 1 does),
    or (refine > 1) refine.refine_params: those colours, then refine - 1 Adam steps on everything."""
    if refine > 1:
        return refine_params(params, source, refine)
    import torch
    target = torch.from_numpy(source).float() / 255
    return least_squares_colours(torch.from_numpy(np.ascontiguousarray(params)), target, iterations).numpy()


def measure(source, params, layout_cell):
    h, w = source.shape[1:3]
    rendered = render_params(params, w, h, w, h)
    target = source / np.float32(255)
    ripple = metrics.flat_ripple(rendered, target, window=round(2 * layout_cell))
    return rendered, dict(psnr=float(np.mean(metrics.psnr(rendered, target))), ripple=ripple)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("videos", nargs="+")
    p.add_argument("--gaussians", type=int, default=1000)
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--fractions", default="0.35,0.5,0.7")
    p.add_argument("--scores", default=",".join(SCORES), help="comma-separated score variants (see `adaptive`)")
    p.add_argument("--ls", default="", help="variants (FRACTION:SCORE, comma-separated) also measured with LS colours")
    p.add_argument("--ls-iterations", type=int, default=10, help="conjugate-gradient iterations of the LS colours")
    p.add_argument("--refine", type=int, default=1,
                   help="the LS variants refine this many steps (1: the LS colours only; more: refine_params)")
    p.add_argument("--temporal-frames", type=int, default=0,
                   help="also eval's temporal figures on this many consecutive frames (0: none; eval uses 8)")
    p.add_argument("--ceiling", action="store_true", help="also the PSNR of each variant's ideal composite")
    p.add_argument("--backend", default="onnx")
    p.add_argument("--json", default=None)
    args = p.parse_args(argv)
    encoder = resolve_encoder("network", args.backend, threads=1)
    warm_up(encoder)
    fractions = [float(f) for f in args.fractions.split(",") if f]
    scores = [s for s in args.scores.split(",") if s]
    ls_variants = {(float(v.split(":")[0]), v.split(":")[1]) for v in args.ls.split(",") if v}
    rows = []
    for video in args.videos:
        source = read_eval_frames(video, args.frames, args.size)
        t, h, w = source.shape[:3]
        layout = frames_layout(source, encoder, gaussians=args.gaussians)
        target = source / np.float32(255)
        row = dict(video=video, gaussians=layout.count, variants={})
        started = time.perf_counter()
        uniform = encode_frames(source, encoder, layout)
        enc_s = (time.perf_counter() - started) / t
        _, m = measure(source, uniform, layout.cell)
        row["variants"]["uniform"] = dict(m, seconds_per_frame=enc_s)
        started = time.perf_counter()
        uniform_ls = ls_colours(uniform, source, args.ls_iterations, args.refine)
        ls_s = (time.perf_counter() - started) / t
        _, m = measure(source, uniform_ls, layout.cell)
        row["variants"]["uniform+ls"] = dict(m, seconds_per_frame=enc_s + ls_s, ls_seconds_per_frame=ls_s)
        for f in fractions:
            for sc in scores:
                started = time.perf_counter()
                params, masks, coarse, fine, cl = adaptive(source, encoder, layout, f, sc)
                ad_s = (time.perf_counter() - started) / t
                assert params.shape == (t, layout.count, 8)
                rendered, m = measure(source, params, layout.cell)
                name = f"adaptive f={f:g} {sc}"
                row["variants"][name] = dict(m, seconds_per_frame=ad_s, coarse=cl.count, fine=fine.shape[1],
                                             split_fraction=float(masks.mean()),
                                             boundary_ratio=boundary_ratio(rendered, target, masks, cl.cols, cl.rows))
                if args.ceiling:
                    ideal = ideal_composite(coarse, fine, masks, cl.cols, cl.rows, w, h, blend="+b" in sc)
                    row["variants"][name]["ideal_psnr"] = float(np.mean(metrics.psnr(ideal, target)))
                if (f, sc) in ls_variants:
                    started = time.perf_counter()
                    params_ls = ls_colours(params, source, args.ls_iterations, args.refine)
                    ls2 = (time.perf_counter() - started) / t
                    rendered, m = measure(source, params_ls, layout.cell)
                    row["variants"][name + " +ls"] = dict(
                        m, seconds_per_frame=ad_s + ls2, ls_seconds_per_frame=ls2,
                        boundary_ratio=boundary_ratio(rendered, target, masks, cl.cols, cl.rows))
        if args.temporal_frames >= 2:  # eval's temporal figures, on consecutive frames from the middle
            run = read_eval_frames(video, args.temporal_frames, args.size, consecutive=True)
            base = encode_frames(run, encoder, frames_layout(run, encoder, gaussians=args.gaussians))
            runs = {"uniform": base, "uniform+ls": ls_colours(base, run, args.ls_iterations, args.refine)}
            for f in fractions:
                for sc in scores:
                    name = f"adaptive f={f:g} {sc}"
                    runs[name] = adaptive(run, encoder, layout, f, sc)[0]
                    if (f, sc) in ls_variants:
                        runs[name + " +ls"] = ls_colours(runs[name], run, args.ls_iterations, args.refine)
            for name, params in runs.items():
                rendered = render_params(params, w, h, w, h)
                row["variants"][name]["temporal"] = dict(
                    delta_psnr=metrics.delta_psnr(rendered, run / np.float32(255)),
                    still_change=metrics.still_change(rendered, run / np.float32(255)))
        rows.append(row)
        print(video, {k: round(v["psnr"], 2) for k, v in row["variants"].items()}, file=sys.stderr, flush=True)
    names = list(rows[0]["variants"])
    mean = {n: dict(psnr=float(np.mean([r["variants"][n]["psnr"] for r in rows])),
                    seconds_per_frame=float(np.mean([r["variants"][n]["seconds_per_frame"] for r in rows])))
            for n in names}
    for n in names:
        for key in ("boundary_ratio", "ideal_psnr"):
            values = [r["variants"][n].get(key) for r in rows]
            if values[0] is not None:
                mean[n][key] = float(np.mean(values))
        temporal = [r["variants"][n]["temporal"] for r in rows if "temporal" in r["variants"][n]]
        if temporal:
            still = [q["still_change"] for q in temporal if q["still_change"]["render"] is not None]
            mean[n]["delta_psnr"] = float(np.mean([q["delta_psnr"] for q in temporal]))
            mean[n]["still_change"] = (float(np.average([c["render"] for c in still], weights=[c["fraction"] for c in still]))
                                       if still else None)
        rip = [r["variants"][n]["ripple"] for r in rows if r["variants"][n]["ripple"]["blocks"]]
        if rip:
            mean[n]["flat_ripple_render_std"] = float(np.mean([q["render_std"] for q in rip]))
            mean[n]["flat_ripple_source_std"] = float(np.mean([q["source_std"] for q in rip]))
    report = dict(gaussians=args.gaussians, frames=args.frames, size=args.size, videos=rows, mean=mean)
    for n in names:
        extra = f"  boundary {mean[n]['boundary_ratio']:.3f}" if "boundary_ratio" in mean[n] else ""
        extra += f"  ideal composite {mean[n]['ideal_psnr']:.2f} dB" if "ideal_psnr" in mean[n] else ""
        extra += f"  delta-PSNR {mean[n]['delta_psnr']:.2f} dB" if "delta_psnr" in mean[n] else ""
        extra += f"  still change {mean[n]['still_change']:.2f}/255" if mean[n].get("still_change") else ""
        print(f"{n:32s} {mean[n]['psnr']:6.2f} dB  {mean[n]['seconds_per_frame'] * 1000:7.1f} ms/frame{extra}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(report, fh, indent=2)


if __name__ == "__main__":
    main()
