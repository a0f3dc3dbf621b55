"""`hypergs bench designs`: the paper's transformer against the conv network (the default) on the same
consecutive frames, at equal Gaussian count and at equal encode time.

Per set of videos (the videos' folder: the dev clips, the held-out pans) and per Gaussian count N
(per frame): PSNR, SSIM, Δ-PSNR (PSNR of the frame differences, render against source: what changes
from frame to frame, i.e. flicker) and encode seconds per frame of
- the conv network's feedforward prediction on N cells,
- the transformer on each patch grid g of `grids`, N / g² Gaussians per tile (so N per frame; grid 1
  sees the frame at its canvas, grid 2 at twice that),
- the conv network + K refine steps (the ladder `refine_steps`), from which the conv network's PSNR at
  the transformer's encode time is interpolated (equal encode time: the time the transformer costs,
  spent on the conv network refining),
- the bilinear floor (the frame average-pooled to N colours, upsampled).
Next to them, for reference only, the HyperGS paper's own figures (Kinetics-400, N per 256² frame:
PAPER_FIGURES; other data, other training budget).
"""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from ..evaluate import bilinear_floor_psnr
from ..metrics import ssim
from .common import DEFAULT_GAUSSIANS, load_frames, machine_report, psnr_of, render, resolve_device, say
from .vs_fit import fit_psnr_at, refine_ladder, timed_encode, warm_up

DEFAULT_REFINE_STEPS = (1, 10, 30)
DEFAULT_GRIDS = (1, 2)
PAPER_FIGURES = {1000: 30.3, 3000: 33.1}  # HyperGS paper, PSNR on Kinetics-400 at N Gaussians per frame


def delta_psnr(rendered: np.ndarray, frames: np.ndarray) -> float:
    """PSNR (peak 1) of the frame differences, render t+1 - render t against source t+1 - source t,
    averaged over the pairs of consecutive frames [T, H, W, 3]."""
    pred = np.clip(rendered, 0, 1).astype(np.float64)
    target = frames.astype(np.float64) / 255
    mse = np.mean((np.diff(pred, axis=0) - np.diff(target, axis=0)) ** 2, axis=(1, 2, 3))
    return float(np.mean(-10 * np.log10(np.maximum(mse, 1e-12))))


def _measure(params: np.ndarray, frames: np.ndarray, seconds: float, device: str) -> dict:
    t, h, w = frames.shape[:3]
    rendered = render(params, w, h, device)
    return {"psnr": float(np.mean(psnr_of(rendered, frames))), "ssim": float(np.mean(ssim(rendered, frames / 255.0))),
            "delta_psnr": delta_psnr(rendered, frames), "seconds": seconds, "gaussians": int(params.shape[1])}


def bench_designs(videos, conv, transformer, gaussians=DEFAULT_GAUSSIANS, grids=DEFAULT_GRIDS,
                  refine_steps=DEFAULT_REFINE_STEPS, size: int = 256, frames: int = 8, start: int = 0,
                  device: str = "auto", progress=None, training: dict | None = None) -> dict:
    """conv, transformer: the two encoders (network.resolve_encoder); training: the transformer card's
    training info (`info`: step, cpu_hours, train_args), said beside the table. See the module doc."""
    from ..encode import frames_layout
    device = resolve_device(device)
    report = {"bench": "designs", "machine": machine_report(device),
              "settings": {"conv": conv.name, "transformer": transformer.name, "gaussians": list(gaussians),
                           "grids": list(grids), "refine_steps": list(refine_steps), "size": size, "frames": frames,
                           "start": start, "videos": [str(v) for v in videos],
                           "transformer_training": training_summary(training)},
              "paper": {str(n): p for n, p in PAPER_FIGURES.items()}, "videos": []}
    for path in videos:
        clip, _, _ = load_frames(path, frames, size, start)
        warm_up(clip, conv, device)
        warm_up(clip, transformer, device)
        row = {"video": str(path), "set": Path(path).parent.name, "results": []}
        for n in gaussians:
            say(progress, f"{Path(path).name}: N={n}")
            layout = frames_layout(clip, conv, gaussians=n)
            seconds, params = timed_encode(clip, conv, layout, device)
            result = {"n": n, "floor_bilinear": bilinear_floor_psnr(clip, layout.count),
                      "conv": _measure(params, clip, seconds, device), "refine": [], "transformer": {}}
            for k, refined, took in refine_ladder(clip, conv, layout, params, refine_steps, device):
                result["refine"].append(dict(_measure(refined, clip, seconds + took / len(clip), device), k=k))
            for g in grids:
                tiled = frames_layout(clip, transformer, gaussians=max(1, round(n / g ** 2)), grid=(g, g))
                seconds, params = timed_encode(clip, transformer, tiled, device)
                result["transformer"][str(g)] = dict(_measure(params, clip, seconds, device), note=tiled.note)
            row["results"].append(result)
        report["videos"].append(row)
    report["summary"] = summarize(report)
    report["table"] = format_designs_table(report)
    return report


def summarize(report: dict) -> list[dict]:
    """Means over the videos of each set, per N; the conv network's PSNR at the transformer's time (each
    grid), interpolated in log(seconds) over its feedforward and refine points (None where the
    transformer is faster than the conv network's feedforward, or slower than its longest refine)."""
    out = []
    sets = list(dict.fromkeys(v["set"] for v in report["videos"]))
    for name in sets:
        rows = [v for v in report["videos"] if v["set"] == name]
        for i, n in enumerate(report["settings"]["gaussians"]):
            results = [r["results"][i] for r in rows]

            def mean(get):
                values = [get(r) for r in results]
                return None if any(v is None for v in values) else float(np.mean(values))

            entry = {"set": name, "videos": len(rows), "n": n, "floor_bilinear": mean(lambda r: r["floor_bilinear"]),
                     "conv": {k: mean(lambda r, k=k: r["conv"][k]) for k in ("psnr", "ssim", "delta_psnr", "seconds",
                                                                             "gaussians")},
                     "refine": [{"k": step["k"], **{key: mean(lambda r, j=j, key=key: r["refine"][j][key])
                                                    for key in ("psnr", "seconds")}}
                                for j, step in enumerate(results[0]["refine"])],
                     "transformer": {}}
            for g in results[0]["transformer"]:
                t = {k: mean(lambda r, k=k: r["transformer"][g][k])
                     for k in ("psnr", "ssim", "delta_psnr", "seconds", "gaussians")}
                t["conv_psnr_at_this_time"] = mean(lambda r, g=g: fit_psnr_at(
                    r["transformer"][g]["seconds"],
                    [(r["conv"]["seconds"], r["conv"]["psnr"])] + [(s["seconds"], s["psnr"]) for s in r["refine"]]))
                entry["transformer"][g] = t
            out.append(entry)
    return out


def _f(value, digits=2) -> str:
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else f"{value:.{digits}f}"


def training_summary(info: dict | None) -> dict | None:
    """step, planned steps and CPU hours of a model card's training info, and the totals over the chain of
    runs its card records (each run's `init_from` holds the card of the weights it started from); None: unknown."""
    if not info or "step" not in info:
        return None
    links, steps, cpu_hours = 0, 0, 0.0
    link = info
    while link and "step" in link:
        links, steps, cpu_hours = links + 1, steps + link["step"], cpu_hours + (link.get("cpu_hours") or 0.0)
        link = (link.get("train_args", {}).get("init_from") or {}).get("info")
    return dict(step=info["step"], planned=info.get("train_args", {}).get("steps"), cpu_hours=info.get("cpu_hours"),
                chain=dict(runs=links, steps=steps, cpu_hours=round(cpu_hours, 2)))


def _chain_text(chain: dict | None) -> str:
    if not chain or chain["runs"] < 2:
        return ""
    return (f" That run started from earlier weights: {chain['runs']} runs, {chain['steps']:,} steps and "
            f"{chain['cpu_hours']} CPU hours in all, as far as its card records them.")


def format_designs_table(report: dict) -> str:
    m, s = report["machine"], report["settings"]
    lines = [f"{m['date'][:10]}, {m['cpu']} ({m['cores']} cores; device {m['device']}, torch "
             f"{m.get('torch_threads', '?')} threads, load {m.get('load_average_1m', '?')}). {s['frames']} consecutive "
             f"frames per video from frame {s['start']}, {s['size']}x{s['size']}; encoders `{s['conv']}` and "
             f"`{s['transformer']}`; seconds are encode seconds per frame. Conv + refine at equal time: the conv "
             "network's PSNR after refining for the transformer's encode time (n/a: outside its refine ladder "
             f"{s['refine_steps']}).", ""]
    trained = s.get("transformer_training")
    if trained:
        planned = trained["planned"]
        short = planned and trained["step"] < planned
        lines += [f"**The transformer's weights: step {trained['step']}" + (f" of the {planned} its run planned" if planned else "")
                  + f", {trained['cpu_hours']} CPU hours of training" + (": undertrained, so its rows say what this "
                  "checkpoint does, not what the design can do." if short else ".") + "**"
                  + _chain_text(trained.get("chain")), ""]
    lines += ["| videos | N per frame | design | Gaussians | PSNR dB | SSIM | Δ-PSNR dB | s/frame | conv + refine at equal time |",
              "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for e in report["summary"]:
        where = f"{e['set']} ({e['videos']})"
        c = e["conv"]
        lines.append(f"| {where} | {e['n']} | conv (default) | {c['gaussians']:.0f} | {_f(c['psnr'])} | {_f(c['ssim'], 3)} "
                     f"| {_f(c['delta_psnr'])} | {_f(c['seconds'], 4)} | |")
        for g, t in e["transformer"].items():
            lines.append(f"| {where} | {e['n']} | transformer, grid {g}x{g} | {t['gaussians']:.0f} | {_f(t['psnr'])} | "
                         f"{_f(t['ssim'], 3)} | {_f(t['delta_psnr'])} | {_f(t['seconds'], 4)} | "
                         f"{_f(t['conv_psnr_at_this_time'])} |")
        for r in e["refine"]:
            lines.append(f"| {where} | {e['n']} | conv + refine {r['k']} | {c['gaussians']:.0f} | {_f(r['psnr'])} | | | "
                         f"{_f(r['seconds'], 4)} | |")
        lines.append(f"| {where} | {e['n']} | bilinear floor | | {_f(e['floor_bilinear'])} | | | | |")
    paper = ", ".join(f"N = {n}: {p} dB" for n, p in report["paper"].items())
    lines += ["", f"For reference, the HyperGS paper's own figures (Kinetics-400, 256²; other data and training "
                  f"budget): {paper}."]
    return "\n".join(lines)
