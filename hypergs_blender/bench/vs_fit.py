"""`hypergs bench vs-fit`: the encoder's feedforward prediction and the prediction + K refine steps
(least-squares colours, then K - 1 warm-started Adam steps), against per-frame fitting from random
initial values and from the Gaussian grid (the strongest cheap baseline), each at a ladder of iteration
counts, on the same frames; PSNR and seconds per frame, the encode-time ratio (fitting / ours) at
matched PSNR, and fitting's PSNR at our time (the PSNR-versus-seconds curves of docs/vs_fit.png)."""
from __future__ import annotations

import math
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

from ..encode import FloorEncoder, encode_frames, frames_layout, refine_frames
from ..network import resolve_encoder
from ..refine import ADAM_EPS, FIT_WARMUP, REFINE_DECAY, REFINE_WARMUP, fit, random_init
from ..refine import refine_steps as refine_step_sizes
from .common import (BOUND_TEXT, DEFAULT_GAUSSIANS, load_frames, machine_report, parse_frames, psnr_of, render,
                     resolve_device, say, sync)

DEFAULT_REFINE_STEPS = (1, 10, 30, 100)
DEFAULT_FIT_ITERS = (10, 30, 100, 300, 1000, 3000)
DEFAULT_FIT_BUDGET = 30.0  # CLI: seconds of fitting per (video, frames, N, init) on 2 CPU cores; 0 = no limit
DEFAULT_SIZES = ("256", "crop480")
FIT_INITS = ("random", "grid")


def refine_ladder(frames: np.ndarray, encoder, layout, params: np.ndarray, steps=DEFAULT_REFINE_STEPS,
                  device: str = "cpu"):
    """encode.refine_frames of the encoder's params on `layout` for every K in `steps`, each its own run (the
    step size depends on K: refine.refine_steps; from K = encode.ADAPTIVE_MIN_REFINE the start is the
    content-adaptive placement's, whose work is timed with it), timed. Returns [(K, refined params [T, N, 8]
    numpy, seconds)] in the order of `steps`."""
    out = []
    for k in steps:
        sync(device)
        started = time.perf_counter()
        refined = refine_frames(frames, encoder, layout, params, k, device=device)
        sync(device)
        out.append((k, refined, time.perf_counter() - started))
    return out


def fit_from(frames: np.ndarray, n: int, iters: int, init: str = "random", device: str = "cpu", seed: int = 0):
    """Per-frame fitting for `iters` Adam steps (refine.fit's cosine schedule, ramped up by refine.FIT_WARMUP)
    from random initial values (refine.random_init, N Gaussians) or from the Gaussian grid (the floor, on
    the layout for N).
    Returns (params numpy, seconds) for all frames at once (they are fitted as one batch); the grid's
    initial values count in its time."""
    import torch

    t, h, w = frames.shape[:3]
    target = torch.from_numpy(frames).to(device).float() / 255
    sync(device)
    started = time.perf_counter()
    if init == "grid":
        floor = FloorEncoder()
        start = encode_frames(frames, floor, frames_layout(frames, floor, gaussians=n))
    else:
        start = random_init(t, n, w, h, seed)
    params = fit(target, torch.from_numpy(start).to(device), iters, warmup=FIT_WARMUP[init])
    sync(device)
    seconds = time.perf_counter() - started
    return params.detach().cpu().numpy(), seconds


def matched_ratio(our_psnr: float, our_seconds: float, fit_points) -> dict:
    """Fitting time to reach `our_psnr`, and its ratio to `our_seconds`, from fitting's measured
    (seconds, psnr) points (per frame, any order; points of skipped rungs left out).

    Between two rungs the time is interpolated linearly in log(seconds) against PSNR, from the
    first rung at or above our PSNR. bound: '=' interpolated; '<=' fitting's cheapest rung already
    reaches our PSNR (the ratio is at most the one given); '>=' no rung reaches it (at least)."""
    points = sorted((float(s), float(p)) for s, p in fit_points)
    if not points or our_seconds <= 0:
        return {"fit_seconds": None, "ratio": None, "bound": None}
    if points[0][1] >= our_psnr:
        fit_seconds, bound = points[0][0], "<="
    else:
        for (s0, p0), (s1, p1) in zip(points, points[1:]):
            if p1 >= our_psnr:
                a = (our_psnr - p0) / (p1 - p0) if p1 > p0 else 1.0
                fit_seconds, bound = math.exp(math.log(s0) + a * (math.log(s1) - math.log(s0))), "="
                break
        else:
            fit_seconds, bound = points[-1][0], ">="
    return {"fit_seconds": fit_seconds, "ratio": fit_seconds / our_seconds, "bound": bound}


def fit_psnr_at(seconds: float, fit_points) -> float | None:
    """Fitting's PSNR after `seconds` per frame, interpolated linearly in log(seconds) between its rungs
    (None outside them)."""
    points = sorted((float(s), float(p)) for s, p in fit_points)
    for (s0, p0), (s1, p1) in zip(points, points[1:]):
        if s0 <= seconds <= s1:
            a = (math.log(seconds) - math.log(s0)) / (math.log(s1) - math.log(s0)) if s1 > s0 else 1.0
            return p0 + a * (p1 - p0)
    return None


def warm_up(frames: np.ndarray, encoder, device: str) -> None:
    """Compile/initialise every code path once (numba JIT, torch kernels) on tiny work."""
    small = frames[:1, :32, :32]
    layout = frames_layout(small, encoder, gaussians=16)
    params = encode_frames(small, encoder, layout)
    refine_ladder(small, encoder, layout, params, (2,), device)
    fit_from(small, 16, 2, "grid", device)
    render(params, 32, 32, device)


def timed_encode(frames: np.ndarray, encoder, layout, device: str):
    """(seconds per frame, params) of encode_frames: the median of 3 runs when one takes under 2 s
    (short timings are noisy), else the one run."""
    def run():
        sync(device)
        started = time.perf_counter()
        out = encode_frames(frames, encoder, layout)
        sync(device)
        return time.perf_counter() - started, out
    seconds, params = run()
    if seconds < 2.0:
        seconds = float(np.median([seconds, run()[0], run()[0]]))
    return seconds / len(frames), params


def bench_vs_fit(videos, gaussians=DEFAULT_GAUSSIANS, refine_steps=DEFAULT_REFINE_STEPS, fit_iters=DEFAULT_FIT_ITERS,
                 sizes=DEFAULT_SIZES, frames: int = 4, start: int = 0, encoder="network", backend: str = "auto",
                 weights=None, device: str = "auto", fit_budget: float | None = None, fit_all: bool = False,
                 fit_inits=FIT_INITS, threads: int = 1, precision: str = "float32", progress=None) -> dict:
    """Feedforward vs feedforward + refine vs fitting (from random, from the grid), on the same
    consecutive frames.

    Per video, frames spec ('256': short-side resize + crop; 'crop480': a 480 x 480 centre crop at the
    video's own resolution; 'native': whole frames) and Gaussian count N (the layout's count nearest N):
    PSNR and seconds per frame of each method; for fitting, the rungs of `fit_iters` in order, each a
    separate run (cosine schedule over its own length). Rungs stop early (marked skipped) once one
    reaches the best PSNR of ours (every ratio can then be interpolated) unless fit_all, and when the
    next rung would take fitting past `fit_budget` seconds, predicted from the last rung's time per step.
    threads: the CPU threads of an onnxruntime encoder, and the report's; the command gives torch and
    the rasterizer as many (common.use_threads), so that every method runs on the same."""
    device = resolve_device(device)
    if isinstance(encoder, str):
        encoder = resolve_encoder(encoder, backend, weights, device, threads=threads, precision=precision)
    refine_steps, fit_iters = sorted(set(refine_steps)), sorted(set(fit_iters))
    report = {"bench": "vs-fit", "machine": machine_report(device),
              "settings": {"gaussians": list(gaussians), "refine_steps": refine_steps, "fit_iters": fit_iters,
                           "fit_inits": list(fit_inits), "sizes": [str(s) for s in sizes], "frames": frames,
                           "start": start, "encoder": encoder.name, "threads": threads, "fit_budget_s": fit_budget,
                           "fit_all": fit_all,
                           "refine_steps_sizes": {k: asdict(refine_step_sizes(k)) for k in refine_steps},
                           "refine_schedule": {"warmup": REFINE_WARMUP, "decay": REFINE_DECAY, "adam_eps": ADAM_EPS},
                           "fit_warmup": dict(FIT_WARMUP),
                           "timing": "seconds per frame, wall clock, all frames as one batch"},
              "videos": []}
    warmed = False
    for path in videos:
        entry = {"path": str(path), "sizes": []}
        for size_text in sizes:
            size, crop = parse_frames(size_text)
            clip, info, indices = load_frames(path, frames, size, start, crop)
            t, h, w = clip.shape[:3]
            if not warmed:
                warm_up(clip, encoder, device)
                warmed = True
            block = {"size": str(size_text), "width": w, "height": h, "frames": t, "frame_indices": indices,
                     "rows": []}
            for n_asked in gaussians:
                layout = frames_layout(clip, encoder, gaussians=n_asked)
                n = layout.count
                label = f"{Path(path).name} {w}x{h} N={n}"
                say(progress, f"{label}: feedforward")
                encode_frames(clip[:1], encoder, layout)  # warm-up at this N (shapes)
                ff_seconds, params = timed_encode(clip, encoder, layout, device)
                ff_psnr = psnr_of(render(params, w, h, device), clip)
                row = {"n_requested": n_asked, "n": n, "cells": [layout.cols, layout.rows],
                       "feedforward": {"seconds": ff_seconds, "psnr": float(np.mean(ff_psnr)),
                                       "psnr_per_frame": [round(float(q), 3) for q in ff_psnr]},
                       "refine": [], "matched": []}
                if refine_steps:
                    say(progress, f"{label}: refine {refine_steps}")
                    for k, refined, seconds in refine_ladder(clip, encoder, layout, params, refine_steps, device):
                        q = float(np.mean(psnr_of(render(refined, w, h, device), clip)))
                        row["refine"].append({"k": k, "seconds": ff_seconds + seconds / t, "refine_seconds": seconds / t,
                                              "psnr": q, "gain_db": q - row["feedforward"]["psnr"]})
                ours = [("feedforward", row["feedforward"]["psnr"], ff_seconds)]
                ours += [(f"refine {r['k']}", r["psnr"], r["seconds"]) for r in row["refine"]]
                target_psnr = max(p for _, p, _ in ours)
                for init in fit_inits:
                    rungs, spent, per_step, stop = [], 0.0, None, None
                    for iters in fit_iters:
                        if stop is None and fit_budget is not None and per_step is not None \
                                and spent + per_step * iters > fit_budget:
                            stop = "budget"
                        if stop is not None:
                            rungs.append({"iters": iters, "skipped": stop})
                            continue
                        say(progress, f"{label}: fitting from {init}, {iters} iterations")
                        fitted, seconds = fit_from(clip, n, iters, init, device)
                        q = float(np.mean(psnr_of(render(fitted, w, h, device), clip)))
                        rungs.append({"iters": iters, "seconds": seconds / t, "psnr": q})
                        spent += seconds
                        per_step = seconds / iters
                        if not fit_all and q >= target_psnr:
                            stop = "reached"
                    row[f"fit_{init}"] = rungs
                row["matched"] = matched_rows(ours, {init: row[f"fit_{init}"] for init in fit_inits})
                block["rows"].append(row)
            entry["sizes"].append(block)
        report["videos"].append(entry)
    report["summary"] = summarize_vs_fit(report)
    report["table"] = format_vs_fit_table(report)
    return report


def matched_rows(ours, fits: dict) -> list[dict]:
    """For each of our methods (name, psnr, seconds): per fitting init, the fitting time to our PSNR
    (and the ratio) and fitting's PSNR at our time (and our lead over it)."""
    out = []
    for method, q, seconds in ours:
        row = {"method": method, "psnr": q, "seconds": seconds}
        for init, rungs in fits.items():
            points = [(f["seconds"], f["psnr"]) for f in rungs if "psnr" in f]
            row[init] = matched_ratio(q, seconds, points)
            at = fit_psnr_at(seconds, points)
            row[init]["fit_psnr_at_our_seconds"] = at
            row[init]["lead_db"] = None if at is None else q - at
        out.append(row)
    return out


def summarize_vs_fit(report: dict) -> list[dict]:
    """Per (frames spec, N): means over the videos of each method's PSNR and seconds per frame (fitting
    rungs measured on every video only), and the matched figures recomputed on those mean curves."""
    groups: dict = {}
    for video in report["videos"]:
        for block in video["sizes"]:
            for row in block["rows"]:
                groups.setdefault((block["size"], row["n_requested"]), []).append((block, row))
    inits = report["settings"]["fit_inits"]
    out = []
    for (size, n_requested), items in groups.items():
        rows = [r for _, r in items]

        def mean(values):
            return float(np.mean(values))
        ff = {"psnr": mean([r["feedforward"]["psnr"] for r in rows]),
              "seconds": mean([r["feedforward"]["seconds"] for r in rows])}
        refine = [{"k": first["k"], "psnr": mean([r["refine"][i]["psnr"] for r in rows]),
                   "seconds": mean([r["refine"][i]["seconds"] for r in rows]),
                   "gain_db": mean([r["refine"][i]["gain_db"] for r in rows])}
                  for i, first in enumerate(rows[0]["refine"])]
        fits, skipped = {}, {}
        for init in inits:
            fits[init] = []
            for i, first in enumerate(rows[0][f"fit_{init}"]):
                rungs = [r[f"fit_{init}"][i] for r in rows]
                if all("psnr" in f for f in rungs):
                    fits[init].append({"iters": first["iters"], "psnr": mean([f["psnr"] for f in rungs]),
                                       "seconds": mean([f["seconds"] for f in rungs])})
            skipped[init] = [{"iters": i, "reason": why} for i, why in
                             sorted({(f["iters"], f["skipped"]) for r in rows for f in r[f"fit_{init}"] if "skipped" in f})]
        ours = [("feedforward", ff["psnr"], ff["seconds"])] + [(f"refine {r['k']}", r["psnr"], r["seconds"])
                                                               for r in refine]
        out.append({"size": size, "n_requested": n_requested, "n": sorted({r["n"] for r in rows}),
                    "resolution": sorted({f"{b['width']}x{b['height']}" for b, _ in items}), "videos": len(rows),
                    "feedforward": ff, "refine": refine, "fit": fits, "fit_skipped": skipped,
                    "matched": matched_rows(ours, fits)})
    return out


def ratio_text(m: dict) -> str:
    if m.get("ratio") is None:
        return "n/a"
    r = m["ratio"]
    text = f"{r:.3g}" if r < 1000 else f"{r:.2e}"
    return BOUND_TEXT[m["bound"]] + text + "×"


def format_vs_fit_table(report: dict) -> str:
    """Markdown: per frames spec and N (means over the videos), each method's PSNR and seconds per frame,
    per fitting init the fitting time at the same PSNR (ratio) and fitting's PSNR at the same time;
    then fitting's rungs."""
    m, s = report["machine"], report["settings"]
    inits = s["fit_inits"]
    lines = [f"{m['date'][:10]}, {m['cpu']} ({m['cores']} cores{', ' + m['gpu'] if m.get('gpu') else ''}; "
             f"device {m['device']}, torch {m.get('torch_threads', '?')} threads, load {m.get('load_average_1m', '?')}). "
             f"Encoder `{s['encoder']}`, {s['frames']} consecutive frames per video from frame {s['start']}, "
             f"{len(report['videos'])} video(s); times are seconds per frame.", "",
             "| frames | N | method | PSNR dB | s/frame |"
             + "".join(f" fit from {i}: s/frame to this PSNR (ratio) | fit from {i}: PSNR at this time |" for i in inits),
             "|" + " --- |" * (5 + 2 * len(inits))]
    for g in report["summary"]:
        n = "/".join(str(v) for v in g["n"])
        size = f"{g['size']} ({', '.join(g['resolution'])})"
        for mt in g["matched"]:
            cells = ""
            for init in inits:
                x = mt[init]
                fit_s = "n/a" if x["fit_seconds"] is None else \
                    {"=": "", "<=": "≤ ", ">=": "> "}[x["bound"]] + f"{x['fit_seconds']:.3g} ({ratio_text(x)})"
                at = "n/a" if x["fit_psnr_at_our_seconds"] is None else f"{x['fit_psnr_at_our_seconds']:.2f}"
                cells += f" {fit_s} | {at} |"
            lines.append(f"| {size} | {n} | {mt['method']} | {mt['psnr']:.2f} | {mt['seconds']:.4g} |{cells}")
        for init in inits:
            for f in g["fit"][init]:
                lines.append(f"| {size} | {n} | fit from {init}, {f['iters']} it | {f['psnr']:.2f} | {f['seconds']:.4g} |"
                             + " |" * (2 * len(inits)))
            for reason, why in (("reached", "reached ours' best PSNR at fewer iterations"), ("budget", "over --fit-budget")):
                its = [str(f["iters"]) for f in g["fit_skipped"][init] if f["reason"] == reason]
                if its:
                    lines.append(f"| {size} | {n} | fit from {init}, {', '.join(its)} it | skipped on some or all "
                                 f"videos: {why} | |" + " |" * (2 * len(inits)))
    return "\n".join(lines)
