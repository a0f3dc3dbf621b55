"""Head-to-head benchmarks (issue #6), registered in bench.py's BENCH_COMMANDS:

- `hypergs bench vs-fit VIDEO...`: the encoder's feedforward prediction, the prediction + K refine
  steps (least-squares colours, then K - 1 warm-started fitting steps), and per-frame fitting from
  random initial values at a ladder of iteration counts, on the same frames; PSNR and seconds per
  frame, and the encode-time ratio (fitting / ours) at matched PSNR.
- `hypergs bench vs-x265 VIDEO...`: .hgs at each bit depth next to x265 at each CRF on the same
  frames and size: bpp, PSNR, SSIM, encode and decode frames/s, and matched-quality pairs.
- `hypergs bench scale`: a long video (by default a synthetic 60 s 720p pan, made with PyAV in a
  temporary folder) encoded end to end into .hgs, streamed chunk by chunk, with peak memory (RSS, in
  a subprocess) recorded after every chunk; then frames of it rendered at 1920 x 1080.

All timings are wall-clock on the machine that runs them (its description, the date and the load
average go into every report). `-o FILE` writes the JSON report; tools/make_plots.py turns the
reports in docs/bench/ into plots and Markdown tables.
"""
from __future__ import annotations

import datetime
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from .errors import HyperGSError

DEFAULT_GAUSSIANS = (250, 1000, 3000)
DEFAULT_REFINE_STEPS = (1, 10, 50, 200)
DEFAULT_FIT_ITERS = (10, 30, 100, 300, 1000, 3000, 10000)  # the issue's rungs, plus two cheap ones below
DEFAULT_FIT_BUDGET = 30.0  # CLI: seconds of fitting per (video, size, N) on 2 CPU cores; 0 = no limit
DEFAULT_SIZES = ("256", "native")
DEFAULT_BITS = (8, 6, 4)
DEFAULT_CRFS = (18, 23, 28, 33, 38, 43, 48, 51)  # up to x265's maximum: ours can sit below CRF 43's PSNR
REFINE_LR = 0.005  # fit.refine_params' Adam learning rate (tests check refine_ladder == refine_params)


# ---- shared helpers -----------------------------------------------------------------------------------

def machine_report(device: str = "cpu") -> dict:
    """codec_cli.machine_description() plus torch threads, the accelerator, the date and the load."""
    from .codec_cli import machine_description
    info = machine_description()
    info["date"] = datetime.datetime.now().astimezone().isoformat(timespec="seconds")
    try:
        info["load_average_1m"] = round(os.getloadavg()[0], 2)
    except OSError:
        pass
    try:
        import torch
        info["torch"] = torch.__version__
        info["torch_threads"] = torch.get_num_threads()
        if device.startswith("cuda"):
            info["gpu"] = torch.cuda.get_device_name(torch.device(device))
    except ImportError:
        pass
    info["device"] = device
    return info


def resolve_device(name: str = "auto") -> str:
    if name != "auto":
        if name.startswith("cuda"):
            import torch
            if not torch.cuda.is_available():
                raise HyperGSError(f"--device {name}: CUDA is not available to torch")
        return name
    try:
        import torch
        return "cuda" if torch.cuda.is_available() else "cpu"
    except ImportError:
        return "cpu"


def make_encoder(kind: str = "network", backend: str = "auto", weights=None, device: str = "cpu"):
    """('floor' | network name, encoder). The network on `device` (torch backend) or onnxruntime."""
    from .encode import FloorEncoder
    if kind == "floor":
        return "floor", FloorEncoder()
    from .network import WEIGHTS_DIR, load_bundled_encoder
    try:
        encoder = load_bundled_encoder(backend, weights or WEIGHTS_DIR, device=device)
    except HyperGSError:
        raise
    except Exception as e:  # noqa: BLE001 - a missing or broken weights file, said plainly
        raise HyperGSError(f"the trained network is not available ({e}); use --encoder floor") from e
    return getattr(encoder, "name", "network"), encoder


def _sync(device: str) -> None:
    if device.startswith("cuda"):
        import torch
        torch.cuda.synchronize()


def parse_size(text) -> int | None:
    """'native' -> None (the video's own W x H, patch grid), '256' -> 256 (short-side resize + crop)."""
    if text is None or str(text).lower() == "native":
        return None
    size = int(text)
    if size < 16:
        raise HyperGSError(f"size {size} is too small")
    return size


def auto_grid(width: int, height: int, canvas: int) -> int:
    """The G x G patch grid whose tiles are closest to the encoder's canvas on the short side."""
    return max(1, round(min(width, height) / canvas))


def split_count(n: int, grid: int) -> int:
    """The largest Gaussian count <= n that splits evenly over a G x G grid (at least one per tile)."""
    per_tile = max(1, n // (grid * grid))
    return per_tile * grid * grid


def load_frames(path, frames: int | None, size: int | None, start: int = 0):
    """Consecutive frames [start, start + frames) (all when None) as uint8 [T, H, W, 3]: short-side
    resized and centre-cropped to size x size, or native (cropped to even W and H, for yuv420p)."""
    from .video import probe, read_clip
    info = probe(path)
    start = min(start, info.num_frames - 1)
    stop = None if frames is None else start + frames
    video, _, indices = read_clip(path, None, start, stop, size=size)
    if size is None:
        h, w = video.shape[1] // 2 * 2, video.shape[2] // 2 * 2
        video = np.ascontiguousarray(video[:, :h, :w])
    return video, info, indices


def render(params: np.ndarray, width: int, height: int, device: str = "cpu", canvas=None) -> np.ndarray:
    """float32 [T, H, W, 3] of params [T, N, 8] on a canvas (default: W x H) rendered at W x H: the
    numpy path (numba) on the CPU, which is what a user's decode runs; the torch rasterizer on CUDA."""
    canvas_w, canvas_h = canvas or (width, height)
    if not device.startswith("cuda"):
        from .gaussians import GaussianVideo
        from .render import render_frames
        return render_frames(GaussianVideo(params, canvas_w, canvas_h), width, height)
    import torch

    from .render import render_torch
    with torch.no_grad():
        p = torch.from_numpy(np.ascontiguousarray(params)).to(device)
        out = render_torch(p, canvas_w, canvas_h, width, height)
        _sync(device)
        return out.cpu().numpy()


def psnr_of(rendered: np.ndarray, frames: np.ndarray) -> np.ndarray:
    from .metrics import psnr
    return psnr(rendered, frames.astype(np.float32) / 255)


def _timed(fn, repeats: int = 1):
    """(median seconds over `repeats` calls, the last result)."""
    times, result = [], None
    for _ in range(max(1, repeats)):
        started = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - started)
    return float(np.median(times)), result


def _say(progress, message: str) -> None:
    if progress is not None:
        progress(message)


# ---- refine and fit ladders -----------------------------------------------------------------------------

def refine_ladder(params: np.ndarray, frames: np.ndarray, steps=DEFAULT_REFINE_STEPS, device: str = "cpu"):
    """fit.refine_params(params, frames, K) for every K in `steps`, sharing its first step.

    refine_params(K) is the least-squares colours, then K - 1 Adam steps from them; the colour solve
    is the same for every K, so it runs once and its time is charged to every K.
    Returns [(K, refined params [T, N, 8] numpy, seconds)] in the order of `steps`."""
    import torch

    from .fit import fit, least_squares_colours
    target = torch.from_numpy(frames).to(device).float() / 255
    started = time.perf_counter()
    colours = least_squares_colours(torch.from_numpy(params).to(device), target)
    _sync(device)
    ls_seconds = time.perf_counter() - started
    out = []
    for k in steps:
        if k < 1:
            raise HyperGSError(f"refine steps must be >= 1, got {k}")
        started = time.perf_counter()
        refined = fit(target, colours, k - 1, lr=REFINE_LR) if k > 1 else colours
        refined = refined.detach().cpu().numpy()
        out.append((k, refined, ls_seconds + time.perf_counter() - started))
    return out


def fit_from_random(frames: np.ndarray, n: int, iters: int, device: str = "cpu", seed: int = 0):
    """Per-frame fitting from fit.random_init for `iters` Adam steps (fit.fit's default schedule).
    Returns (params numpy, seconds) for all frames at once (they are fitted as one batch)."""
    import torch

    from .fit import fit, random_init
    t, h, w = frames.shape[:3]
    target = torch.from_numpy(frames).to(device).float() / 255
    init = torch.from_numpy(random_init(t, n, w, h, seed)).to(device)
    _sync(device)
    started = time.perf_counter()
    params = fit(target, init, iters)
    _sync(device)
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


def _warm_up(frames: np.ndarray, encoder, device: str) -> None:
    """Compile/initialise every code path once (numba JIT, torch kernels) on tiny work."""
    from .encode import encode_frames
    small = frames[:1, :32, :32]
    params = encode_frames(small, encoder, 16)
    refine_ladder(params, small, (2,), device)
    fit_from_random(small, 16, 2, device)
    render(params, 32, 32, device)


# ---- vs-fit -------------------------------------------------------------------------------------------

def _feedforward(frames: np.ndarray, encoder, n: int, grid: int, device: str):
    """(seconds per frame, params) of encode_frames: the median of 3 runs when one takes under 2 s
    (short timings are noisy), else the one run."""
    from .encode import encode_frames

    def run():
        _sync(device)
        started = time.perf_counter()
        out = encode_frames(frames, encoder, n, grid)
        _sync(device)
        return time.perf_counter() - started, out
    seconds, params = run()
    if seconds < 2.0:
        seconds = float(np.median([seconds, run()[0], run()[0]]))
    return seconds / len(frames), params


def bench_vs_fit(videos, gaussians=DEFAULT_GAUSSIANS, refine_steps=DEFAULT_REFINE_STEPS, fit_iters=DEFAULT_FIT_ITERS,
                 sizes=DEFAULT_SIZES, frames: int = 4, start: int = 0, encoder="network", backend: str = "auto",
                 weights=None, device: str = "auto", grid: int | None = None, fit_budget: float | None = None,
                 fit_all: bool = False, progress=None) -> dict:
    """Feedforward vs feedforward + refine vs fitting from random, on the same consecutive frames.

    Per video, size ('256' or 'native': the video's own W x H, with a G x G patch grid, G = `grid` or
    the one whose tiles come closest to the encoder's canvas) and Gaussian count N (rounded down to a
    multiple of G^2): PSNR and seconds per frame of each method; for fitting, the rungs of
    `fit_iters` in order, each a separate run from the same random start (cosine schedule over its
    own length). Rungs stop early (marked skipped) once one reaches the best PSNR of ours (every
    ratio can then be interpolated) unless fit_all, and when the next rung would take fitting past
    `fit_budget` seconds for this (video, size, N), predicted from the last rung's time per step."""
    from .encode import encode_frames
    device = resolve_device(device)
    if isinstance(encoder, str):
        encoder_name, encoder = make_encoder(encoder, backend, weights, device)
    else:
        encoder_name = getattr(encoder, "name", type(encoder).__name__)
    refine_steps, fit_iters = sorted(set(refine_steps)), sorted(set(fit_iters))
    report = {"bench": "vs-fit", "machine": machine_report(device),
              "settings": {"gaussians": list(gaussians), "refine_steps": refine_steps, "fit_iters": fit_iters,
                           "sizes": [str(s) for s in sizes], "frames": frames, "start": start,
                           "encoder": encoder_name, "grid": grid, "fit_budget_s": fit_budget, "fit_all": fit_all,
                           "refine_lr": REFINE_LR, "timing": "seconds per frame, wall clock, all frames as one batch"},
              "videos": []}
    warmed = False
    for path in videos:
        entry = {"path": str(path), "sizes": []}
        for size_text in sizes:
            size = parse_size(size_text)
            clip, info, indices = load_frames(path, frames, size, start)
            t, h, w = clip.shape[:3]
            g = 1 if size is not None else (grid or auto_grid(w, h, encoder.canvas))
            if not warmed:
                _warm_up(clip, encoder, device)
                warmed = True
            block = {"size": "native" if size is None else str(size), "width": w, "height": h, "grid": g,
                     "frames": t, "frame_indices": indices, "rows": []}
            for n_asked in gaussians:
                n = split_count(n_asked, g)
                label = f"{Path(path).name} {w}x{h} N={n}"
                _say(progress, f"{label}: feedforward")
                encode_frames(clip[:1], encoder, n, g)  # warm-up at this N (shapes)
                ff_seconds, params = _feedforward(clip, encoder, n, g, device)
                ff_psnr = psnr_of(render(params, w, h, device), clip)
                row = {"n_requested": n_asked, "n": n,
                       "feedforward": {"seconds": ff_seconds, "psnr": float(np.mean(ff_psnr)),
                                       "psnr_per_frame": [round(float(q), 3) for q in ff_psnr]},
                       "refine": [], "fit": [], "matched": []}
                if refine_steps:
                    _say(progress, f"{label}: refine {refine_steps}")
                    for k, refined, seconds in refine_ladder(params, clip, refine_steps, device):
                        q = float(np.mean(psnr_of(render(refined, w, h, device), clip)))
                        row["refine"].append({"k": k, "seconds": ff_seconds + seconds / t, "refine_seconds": seconds / t,
                                              "psnr": q, "gain_db": q - row["feedforward"]["psnr"]})
                ours = [("feedforward", row["feedforward"]["psnr"], ff_seconds)]
                ours += [(f"refine {r['k']}", r["psnr"], r["seconds"]) for r in row["refine"]]
                target_psnr = max(p for _, p, _ in ours)
                spent, per_step, stop = 0.0, None, None
                for iters in fit_iters:
                    if stop is None and fit_budget is not None and per_step is not None \
                            and spent + per_step * iters > fit_budget:
                        stop = "budget"
                    if stop is not None:
                        row["fit"].append({"iters": iters, "skipped": stop})
                        continue
                    _say(progress, f"{label}: fitting {iters} iterations")
                    fitted, seconds = fit_from_random(clip, n, iters, device)
                    q = float(np.mean(psnr_of(render(fitted, w, h, device), clip)))
                    row["fit"].append({"iters": iters, "seconds": seconds / t, "psnr": q})
                    spent += seconds
                    per_step = seconds / iters
                    if not fit_all and q >= target_psnr:
                        stop = "reached"
                points = [(f["seconds"], f["psnr"]) for f in row["fit"] if "psnr" in f]
                for method, q, seconds in ours:
                    row["matched"].append({"method": method, "psnr": q, "seconds": seconds,
                                           **matched_ratio(q, seconds, points)})
                block["rows"].append(row)
            entry["sizes"].append(block)
        report["videos"].append(entry)
    report["summary"] = summarize_vs_fit(report)
    report["table"] = format_vs_fit_table(report)
    return report


def summarize_vs_fit(report: dict) -> list[dict]:
    """Per (size, N): means over the videos of each method's PSNR and seconds per frame (fitting rungs
    measured on every video only), and the matched ratios recomputed on those mean curves."""
    groups: dict = {}
    for video in report["videos"]:
        for block in video["sizes"]:
            for row in block["rows"]:
                groups.setdefault((block["size"], row["n_requested"]), []).append((block, row))
    out = []
    for (size, n_requested), items in groups.items():
        rows = [r for _, r in items]

        def mean(values):
            return float(np.mean(values))
        ff = {"psnr": mean([r["feedforward"]["psnr"] for r in rows]),
              "seconds": mean([r["feedforward"]["seconds"] for r in rows])}
        refine = []
        for i, first in enumerate(rows[0]["refine"]):
            refine.append({"k": first["k"], "psnr": mean([r["refine"][i]["psnr"] for r in rows]),
                           "seconds": mean([r["refine"][i]["seconds"] for r in rows]),
                           "gain_db": mean([r["refine"][i]["gain_db"] for r in rows])})
        fit = []
        for i, first in enumerate(rows[0]["fit"]):
            rungs = [r["fit"][i] for r in rows]
            if all("psnr" in f for f in rungs):
                fit.append({"iters": first["iters"], "psnr": mean([f["psnr"] for f in rungs]),
                            "seconds": mean([f["seconds"] for f in rungs])})
        points = [(f["seconds"], f["psnr"]) for f in fit]
        matched = [{"method": "feedforward", "psnr": ff["psnr"], "seconds": ff["seconds"],
                    **matched_ratio(ff["psnr"], ff["seconds"], points)}]
        matched += [{"method": f"refine {r['k']}", "psnr": r["psnr"], "seconds": r["seconds"],
                     **matched_ratio(r["psnr"], r["seconds"], points)} for r in refine]
        skipped = sorted({(f["iters"], f["skipped"]) for r in rows for f in r["fit"] if "skipped" in f})
        out.append({"size": size, "n_requested": n_requested, "n": sorted({r["n"] for r in rows}),
                    "fit_skipped": [{"iters": i, "reason": why} for i, why in skipped],
                    "resolution": sorted({f"{b['width']}x{b['height']}" for b, _ in items}),
                    "grid": sorted({b["grid"] for b, _ in items}), "videos": len(rows),
                    "feedforward": ff, "refine": refine, "fit": fit, "matched": matched})
    return out


_BOUND_TEXT = {"=": "", "<=": "≤ ", ">=": "≥ ", None: ""}


def _ratio_text(m: dict) -> str:
    if m.get("ratio") is None:
        return "n/a"
    r = m["ratio"]
    text = f"{r:.3g}" if r < 1000 else f"{r:.2e}"
    return _BOUND_TEXT[m["bound"]] + text + "×"


def format_vs_fit_table(report: dict) -> str:
    """Markdown: per size and N (means over the videos), each method's PSNR and seconds per frame and
    the fitting time at the same PSNR; then fitting's rungs."""
    m, s = report["machine"], report["settings"]
    lines = [f"{m['date'][:10]}, {m['cpu']} ({m['cores']} cores{', ' + m['gpu'] if m.get('gpu') else ''}; "
             f"device {m['device']}, torch {m.get('torch_threads', '?')} threads, load {m.get('load_average_1m', '?')}). "
             f"Encoder `{s['encoder']}`, {s['frames']} consecutive frames per video from frame {s['start']}, "
             f"{len(report['videos'])} video(s); times are seconds per frame.", "",
             "| size | N | method | PSNR dB | s/frame | fitting s/frame at this PSNR | fitting / ours |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for g in report["summary"]:
        n = "/".join(str(v) for v in g["n"])
        size = f"{g['size']} ({', '.join(g['resolution'])}, grid {'/'.join(str(v) for v in g['grid'])})"
        for mt in g["matched"]:
            fit_s = "n/a" if mt["fit_seconds"] is None else \
                {"=": "", "<=": "≤ ", ">=": "> "}[mt["bound"]] + f"{mt['fit_seconds']:.3g}"
            lines.append(f"| {size} | {n} | {mt['method']} | {mt['psnr']:.2f} | {mt['seconds']:.4g} | {fit_s} | "
                         f"{_ratio_text(mt)} |")
        for f in g["fit"]:
            lines.append(f"| {size} | {n} | fit {f['iters']} it | {f['psnr']:.2f} | {f['seconds']:.4g} | | |")
        for reason, why in (("reached", "reached ours' best PSNR at fewer iterations"), ("budget", "over --fit-budget")):
            its = [str(f["iters"]) for f in g["fit_skipped"] if f["reason"] == reason]
            if its:
                lines.append(f"| {size} | {n} | fit {', '.join(its)} it | skipped on some or all videos: {why} | | | |")
    return "\n".join(lines)


# ---- vs-x265 ------------------------------------------------------------------------------------------

def bpp_at_psnr(psnr: float, rows) -> tuple[float | None, str | None]:
    """A codec's bpp at `psnr` from its rows at several CRFs ({'psnr', 'bpp'}): interpolated linearly in
    log(bpp) against PSNR between the two rows around it (bound '='); below its lowest PSNR, the bpp of
    that row, which the codec needs at most ('<='); above its highest, that row's bpp, which it needs
    at least ('>=')."""
    pts = sorted((r["psnr"], r["bpp"]) for r in rows)
    if not pts:
        return None, None
    if psnr < pts[0][0]:
        return pts[0][1], "<="
    if psnr > pts[-1][0]:
        return pts[-1][1], ">="
    for (p0, v0), (p1, v1) in zip(pts, pts[1:]):
        if p0 <= psnr <= p1:
            a = 0.0 if p1 == p0 else (psnr - p0) / (p1 - p0)
            return math.exp(math.log(v0) + a * (math.log(v1) - math.log(v0))), "="
    return pts[-1][1], "="  # a single row at exactly this PSNR


def bench_vs_x265(videos, gaussians=DEFAULT_GAUSSIANS, bits=DEFAULT_BITS, crfs=DEFAULT_CRFS, size="256",
                  frames: int | None = 24, start: int = 0, refine_steps=(0,), encoder="network",
                  backend: str = "auto", weights=None, device: str = "auto", grid: int | None = None,
                  codec: str = "libx265", preset: str = "medium", group_size: int = 16, decode_repeats: int = 3,
                  position_bits: int | None = 10, progress=None) -> dict:
    """Matched-quality pairs: Gaussians (N, refine K, .hgs bit depth) against an FFmpeg codec's CRFs on
    the same consecutive frames at the same size.

    x265 rows: codec_cli.encode_reference (yuv420p, mp4, all cores), PSNR and SSIM in RGB against the
    frames, bpp, encode and decode frames/s (colour conversion included). Ours: encoder (+ refine) on
    `device`, then .hgs at each bit depth: encode frames/s = encoder + refine + .hgs write; decode
    frames/s = .hgs read + render (numpy/numba path on the CPU, torch on CUDA; medians of
    `decode_repeats` runs). position_bits: the means (x, y) get this many bits where a depth is lower
    (at 6 or 4 bits the grid of means snaps to 64 or 16 positions and larger N collapse; None: uniform
    depths). Pairs: for every row of
    ours, the CRF whose PSNR is closest, and x265's bpp and frames/s interpolated at our PSNR."""
    from .codec_cli import encode_reference, video_codec_available
    from .encode import encode_frames
    from .gaussians import GaussianVideo
    from .hgs import load_hgs, save_hgs
    from .metrics import ssim
    device = resolve_device(device)
    if isinstance(encoder, str):
        encoder_name, encoder = make_encoder(encoder, backend, weights, device)
    else:
        encoder_name = getattr(encoder, "name", type(encoder).__name__)
    notes = []
    if not video_codec_available(codec):
        notes.append(f"{codec} is not in PyAV's FFmpeg; used libx264")
        codec = "libx264"
    size_value = parse_size(size)
    report = {"bench": "vs-x265", "machine": machine_report(device),
              "settings": {"gaussians": list(gaussians), "bits": list(bits), "crfs": list(crfs),
                           "size": "native" if size_value is None else str(size_value), "frames": frames,
                           "start": start, "refine_steps": list(refine_steps), "encoder": encoder_name,
                           "codec": codec, "preset": preset, "group_size": group_size, "grid": grid,
                           "decode_repeats": decode_repeats, "position_bits": position_bits},
              "notes": notes, "videos": []}
    warmed = False
    with tempfile.TemporaryDirectory(prefix="hypergs-vs-x265-") as tmp:
        clip_path = Path(tmp) / "clip.hgs"
        for path in videos:
            clip, info, indices = load_frames(path, frames, size_value, start)
            t, h, w = clip.shape[:3]
            pixels = t * h * w
            target = clip.astype(np.float32) / 255
            g = 1 if size_value is not None else (grid or auto_grid(w, h, encoder.canvas))
            if not warmed:
                _warm_up(clip, encoder, device)
                warmed = True
            entry = {"path": str(path), "frames": t, "frame_indices": [indices[0], indices[-1]], "width": w,
                     "height": h, "grid": g, "fps": info.fps, "x265": [], "ours": [], "pairs": []}
            for crf in crfs:
                _say(progress, f"{Path(path).name}: {codec} crf {crf}")
                ref = encode_reference(clip, info.fps, codec, crf, preset)
                decoded = ref["frames"].astype(np.float32) / 255
                entry["x265"].append({"codec": codec, "crf": crf, "bytes": ref["bytes"], "bpp": 8 * ref["bytes"] / pixels,
                                      "psnr": float(np.mean(psnr_of(decoded, clip))),
                                      "ssim": float(np.mean(ssim(decoded, target))),
                                      "encode_fps": t / ref["encode_s"], "decode_fps": t / ref["decode_s"]})
            for n_asked in gaussians:
                n = split_count(n_asked, g)
                encode_frames(clip[:1], encoder, n, g)  # warm-up at this N
                _sync(device)
                started = time.perf_counter()
                params = encode_frames(clip, encoder, n, g)
                _sync(device)
                encoder_s = time.perf_counter() - started
                ks = sorted(set(refine_steps))
                variants = [(0, params, 0.0)] if 0 in ks else []
                if any(k > 0 for k in ks):
                    _say(progress, f"{Path(path).name}: N={n} refine {[k for k in ks if k > 0]}")
                    variants += refine_ladder(params, clip, [k for k in ks if k > 0], device)
                for k, p, refine_s in variants:
                    _say(progress, f"{Path(path).name}: N={n} refine {k}: .hgs at {list(bits)} bits")
                    render_s, rendered = _timed(lambda: render(p, w, h, device), decode_repeats)
                    row = {"n_requested": n_asked, "n": n, "refine": k, "encoder_fps": t / encoder_s,
                           "encode_fps_float": t / (encoder_s + refine_s), "render_fps": t / render_s,
                           "float_psnr": float(np.mean(psnr_of(rendered, clip))),
                           "float_ssim": float(np.mean(ssim(rendered, target))), "hgs": []}
                    video = GaussianVideo(p, w, h, info.fps, (g, g))
                    for b in bits:
                        started = time.perf_counter()
                        depths = (position_bits,) * 2 + (b,) * 6 if position_bits and position_bits > b else b
                        nbytes = save_hgs(video, clip_path, bits=depths, group_size=group_size)
                        write_s = time.perf_counter() - started
                        read_s, decoded = _timed(lambda: load_hgs(clip_path), decode_repeats)
                        render_s, rendered = _timed(lambda: render(decoded.params, w, h, device), decode_repeats)
                        row["hgs"].append({"bits": b, "position_bits": max(b, position_bits or 0), "bytes": nbytes, "bpp": 8 * nbytes / pixels,
                                           "psnr": float(np.mean(psnr_of(rendered, clip))),
                                           "ssim": float(np.mean(ssim(rendered, target))),
                                           "encode_fps": t / (encoder_s + refine_s + write_s),
                                           "decode_fps": t / (read_s + render_s)})
                    entry["ours"].append(row)
            entry["pairs"] = match_pairs(entry["ours"], entry["x265"])
            report["videos"].append(entry)
    report["table"] = format_vs_x265_table(report)
    return report


def match_pairs(ours, reference) -> list[dict]:
    """For each (N, refine, bits) row of ours: the reference row with the closest PSNR, and the
    reference's bpp at our PSNR (bpp_at_psnr) with bpp_ratio = ours / reference (> 1: we need more
    bits for the same PSNR); its bound is the ratio's ('>=': at least, '<=': at most)."""
    flip = {"=": "=", "<=": ">=", ">=": "<=", None: None}
    pairs = []
    for row in ours:
        for hg in row["hgs"]:
            nearest = min(reference, key=lambda r: abs(r["psnr"] - hg["psnr"]))
            bpp, bound = bpp_at_psnr(hg["psnr"], reference)
            pairs.append({"n": row["n"], "refine": row["refine"], "bits": hg["bits"],
                          "position_bits": hg.get("position_bits", hg["bits"]),
                          "ours": {k: hg[k] for k in ("bpp", "psnr", "ssim", "encode_fps", "decode_fps")},
                          "nearest": {k: nearest[k] for k in ("crf", "bpp", "psnr", "ssim", "encode_fps", "decode_fps")},
                          "reference_bpp_at_psnr": bpp, "reference_bpp_bound": bound,
                          "bpp_ratio": None if bpp is None else hg["bpp"] / bpp, "bpp_ratio_bound": flip[bound],
                          "encode_speed_ratio": hg["encode_fps"] / nearest["encode_fps"],
                          "decode_speed_ratio": hg["decode_fps"] / nearest["decode_fps"]})
    return pairs


def format_vs_x265_table(report: dict) -> str:
    m, s = report["machine"], report["settings"]
    lines = [f"{m['date'][:10]}, {m['cpu']} ({m['cores']} cores{', ' + m['gpu'] if m.get('gpu') else ''}; ours on "
             f"{m['device']}, {s['codec']} preset {s['preset']} on the CPU; load {m.get('load_average_1m', '?')}). "
             f"Encoder `{s['encoder']}`, size {s['size']}, {s['frames']} consecutive frames from frame {s['start']}. "
             "bpp = file bits per pixel per frame; fps = frames/s.", "",
             "| video | ours | bpp | PSNR | SSIM | enc fps | dec fps | nearest x265 | bpp | PSNR | SSIM | enc fps | "
             "dec fps | x265 bpp at our PSNR | bpp ours / x265 |",
             "|" + " --- |" * 15]
    for v in report["videos"]:
        for p in v["pairs"]:
            o, r = p["ours"], p["nearest"]
            label = f"N={p['n']}{', refine ' + str(p['refine']) if p['refine'] else ''}, {p['bits']} bits"
            if p.get("position_bits", p["bits"]) != p["bits"]:
                label += f" (x/y {p['position_bits']})"
            at, bound = p["reference_bpp_at_psnr"], p["reference_bpp_bound"]
            ratio = "n/a" if p["bpp_ratio"] is None else _BOUND_TEXT[p["bpp_ratio_bound"]] + f"{p['bpp_ratio']:.3g}×"
            lines.append(f"| {Path(v['path']).stem} | {label} | {o['bpp']:.4f} | {o['psnr']:.2f} | {o['ssim']:.4f} | "
                         f"{o['encode_fps']:.3g} | {o['decode_fps']:.3g} | crf {r['crf']} | {r['bpp']:.4f} | "
                         f"{r['psnr']:.2f} | {r['ssim']:.4f} | {r['encode_fps']:.3g} | {r['decode_fps']:.3g} | "
                         f"{'n/a' if at is None else _BOUND_TEXT[bound] + format(at, '.4f')} | {ratio} |")
    return "\n".join(lines)


# ---- scale --------------------------------------------------------------------------------------------

def pan_image(width: int, height: int, seed: int = 0) -> np.ndarray:
    """A deterministic procedural RGB uint8 image: a colour gradient under a few hundred soft-edged
    discs and boxes of power-law sizes (dead-leaves statistics), with fine sinusoidal texture."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    img = np.stack([0.2 + 0.5 * x / width, 0.3 + 0.3 * y / height, 0.6 - 0.3 * x / width], -1)
    count = 300
    radii = np.minimum(0.04 * min(width, height) / rng.uniform(0.02, 1, count) ** 0.6, 0.3 * min(width, height))
    for r in sorted(radii, reverse=True):
        cx, cy = rng.uniform(0, width), rng.uniform(0, height)
        x0, x1 = int(max(0, cx - r - 2)), int(min(width, cx + r + 2))
        y0, y1 = int(max(0, cy - r - 2)), int(min(height, cy + r + 2))
        if x1 <= x0 or y1 <= y0:
            continue
        px, py = x[y0:y1, x0:x1] - cx, y[y0:y1, x0:x1] - cy
        d = np.maximum(np.abs(px), np.abs(py)) - r if rng.random() < 0.4 else np.hypot(px, py) - r
        alpha = np.clip(0.5 - d, 0, 1)[..., None]
        colour = rng.uniform(0.05, 0.95, 3).astype(np.float32)
        freq = rng.uniform(0.05, 0.4)
        texture = 0.08 * np.sin(freq * (px * math.cos(r) + py * math.sin(r)))[..., None]
        img[y0:y1, x0:x1] = img[y0:y1, x0:x1] * (1 - alpha) + alpha * np.clip(colour + texture, 0, 1)
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def make_pan_video(path, seconds: float = 60.0, width: int = 1280, height: int = 720, fps: int = 24,
                   codec: str = "libx264", crf: int = 18, preset: str = "veryfast", seed: int = 0) -> dict:
    """Write a synthetic video: a smooth camera pan (Lissajous path, sub-pixel steps rounded to whole
    pixels) over a procedural image 1.5x the frame. yuv420p mp4. Returns its description."""
    import av
    frames = max(1, round(seconds * fps))
    big_w, big_h = int(width * 1.5) // 2 * 2, int(height * 1.5) // 2 * 2
    image = pan_image(big_w, big_h, seed)
    started = time.perf_counter()
    with av.open(str(path), "w") as container:
        stream = container.add_stream(codec, rate=fps, options={"crf": str(crf), "preset": preset})
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        for i in range(frames):
            phase = 2 * math.pi * i / max(frames, 1)
            x0 = round((big_w - width) * (0.5 - 0.5 * math.cos(3 * phase)))
            y0 = round((big_h - height) * (0.5 - 0.5 * math.cos(2 * phase)))
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(image[y0:y0 + height, x0:x0 + width]),
                                               format="rgb24")
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    return {"path": str(path), "frames": frames, "width": width, "height": height, "fps": fps, "codec": codec,
            "bytes": Path(path).stat().st_size, "seconds_to_make": time.perf_counter() - started}


def _peak_rss_mb() -> float:
    """This process's peak resident memory (MiB) since it started or since _reset_peak_rss()."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    import resource
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB


def _rss_mb() -> float | None:
    """This process's resident memory now (MiB); None where /proc is missing."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1]) / 1024
    except OSError:
        pass
    return None


def _reset_peak_rss() -> bool:
    """Reset the peak (Linux >= 4.0: write 5 to /proc/self/clear_refs), so that start-up and warm-up
    (imports, JIT) do not hide what the measured work needs. False where that is not possible."""
    try:
        with open("/proc/self/clear_refs", "w") as f:
            f.write("5")
        return True
    except OSError:
        return False


def stream_encode(path, out_path, encoder, gaussian_count: int, grid: int = 1, size: int | None = None,
                  chunk_clips: int = 4, refine: int = 0, bits: int = 8, device: str = "cpu",
                  hold_frames: bool = False, on_chunk=None) -> dict:
    """Video -> .hgs without ever holding the clip: frames decoded `chunk_clips` clips at a time
    (encode.encode_video's chunking), encoded (+ fit.refine_params), written through HgsWriter with
    the default quantizer ranges (values outside are clipped and counted). on_chunk(frames_done)
    after each chunk. hold_frames keeps every decoded frame (a control that must grow memory)."""
    from .codec import Quantizer
    from .encode import encode_frames
    from .hgs import HgsWriter
    from .video import iter_frames, probe
    info = probe(path)
    w, h = (size, size) if size else (info.width, info.height)
    chunk = chunk_clips * encoder.clip_frames
    held, buffer, seconds = [], [], {"decode": 0.0, "encode": 0.0, "refine": 0.0, "write": 0.0}
    with HgsWriter(out_path, w, h, gaussian_count, Quantizer.default(w, h, bits), info.fps, (grid, grid),
                   {"path": str(path)}) as writer:
        def flush():
            frames = np.stack(buffer)
            started = time.perf_counter()
            params = encode_frames(frames, encoder, gaussian_count, grid)
            _sync(device)
            seconds["encode"] += time.perf_counter() - started
            if refine:
                started = time.perf_counter()
                params = refine_ladder(params, frames, (refine,), device)[0][1]
                seconds["refine"] += time.perf_counter() - started
            started = time.perf_counter()
            writer.write(params)
            seconds["write"] += time.perf_counter() - started
            buffer.clear()
            if on_chunk is not None:
                on_chunk(writer.num_frames)

        started = time.perf_counter()
        for _, frame in iter_frames(path, None, size):
            if hold_frames:
                held.append(frame)
            buffer.append(frame)
            if len(buffer) == chunk:
                seconds["decode"] += time.perf_counter() - started
                flush()
                started = time.perf_counter()
        seconds["decode"] += time.perf_counter() - started
        if buffer:
            flush()
        frames_written, clipped = writer.num_frames, writer.clipped
    return {"frames": frames_written, "width": w, "height": h, "clipped_values": clipped,
            "seconds": seconds, "held_frames": len(held)}


def _scale_worker(spec: dict) -> dict:
    """Runs in its own process (so ru_maxrss is this job's peak): 'encode' or 'render'."""
    device = spec.get("device", "cpu")
    if spec["job"] == "encode_video":  # what `hypergs encode` runs: encode.encode_video, then save_clip
        from .clip_io import save_clip
        from .encode import encode_frames, encode_video
        name, encoder = make_encoder(spec["encoder"], spec.get("backend", "auto"), spec.get("weights"), device)
        encode_frames(np.zeros((1, 32, 32, 3), np.uint8), encoder, 16)
        reset = _reset_peak_rss()
        baseline = _rss_mb() or _peak_rss_mb()
        trace = []

        def progress(done, total):
            trace.append([done, round(_rss_mb() or 0.0, 1), round(_peak_rss_mb(), 1)])
            return True
        started = time.perf_counter()
        video = encode_video(spec["video"], encoder, spec["gaussians"], spec["grid"], spec.get("size"),
                             progress=progress, chunk_clips=spec.get("chunk_clips", 4), refine=spec.get("refine", 0))
        save_clip(video, spec["output"], bits=spec.get("bits", 8))
        seconds = time.perf_counter() - started
        return {"encoder": name, "frames": video.num_frames, "wall_seconds": seconds,
                "fps": video.num_frames / seconds, "peak_reset": reset, "rss_baseline_mb": round(baseline, 1),
                "peak_rss_mb": round(_peak_rss_mb(), 1), "rss_trace": trace}
    if spec["job"] == "encode":
        name, encoder = make_encoder(spec["encoder"], spec.get("backend", "auto"), spec.get("weights"), device)
        # warm-up on a tiny frame (numba / torch initialisation), then the baseline
        from .encode import encode_frames
        params = encode_frames(np.zeros((1, 32, 32, 3), np.uint8), encoder, 16)
        if spec.get("refine"):
            refine_ladder(params, np.zeros((1, 32, 32, 3), np.uint8), (2,), device)
        startup_peak = _peak_rss_mb()
        reset = _reset_peak_rss()
        baseline = _rss_mb() or _peak_rss_mb()
        trace = [[0, round(baseline, 1), round(_peak_rss_mb(), 1)]]  # [frames done, RSS now, peak so far] MiB

        def on_chunk(done):
            trace.append([done, round(_rss_mb() or 0.0, 1), round(_peak_rss_mb(), 1)])
        started = time.perf_counter()
        result = stream_encode(spec["video"], spec["output"], encoder, spec["gaussians"], spec["grid"],
                               spec.get("size"), spec.get("chunk_clips", 4), spec.get("refine", 0),
                               spec.get("bits", 8), device, spec.get("hold_frames", False), on_chunk=on_chunk)
        seconds = time.perf_counter() - started
        return {"encoder": name, **result, "wall_seconds": seconds, "fps": result["frames"] / seconds,
                "rss_startup_peak_mb": round(startup_peak, 1), "peak_reset": reset,
                "rss_baseline_mb": round(baseline, 1), "peak_rss_mb": round(_peak_rss_mb(), 1), "rss_trace": trace}
    if spec["job"] == "render":
        from .hgs import HgsReader
        from .video import iter_frames
        width, height = spec["width"], spec["height"]
        with HgsReader(spec["clip"]) as reader:
            cw, ch, total = reader.canvas_width, reader.canvas_height, reader.num_frames
            count = min(total, spec.get("frames") or total)
            render(reader.read_frame(0)[None], width, height, device, (cw, ch))  # warm-up
            _reset_peak_rss()
            baseline = _rss_mb() or _peak_rss_mb()
            stretch = {"read": 0.0, "render": 0.0}
            started = time.perf_counter()
            for i in range(count):
                t0 = time.perf_counter()
                params = reader.read_frame(i)
                t1 = time.perf_counter()
                render(params[None], width, height, device, (cw, ch))
                stretch["read"] += t1 - t0
                stretch["render"] += time.perf_counter() - t1
            seconds = time.perf_counter() - started
            quality = None
            if spec.get("psnr_frames") and spec.get("video"):
                picks = np.unique(np.linspace(0, total - 1, spec["psnr_frames"]).round().astype(int)).tolist()
                values = []
                for index, frame in iter_frames(spec["video"], picks):
                    pred = render(reader.read_frame(index)[None], cw, ch, device)[0]
                    values.append(float(psnr_of(pred[None], frame[None])[0]))
                quality = {"frames": picks, "psnr_at_source_size": float(np.mean(values))}
        return {"frames": count, "of": total, "width": width, "height": height, "wall_seconds": seconds,
                "fps": count / seconds, "seconds": stretch, "rss_baseline_mb": round(baseline, 1),
                "peak_rss_mb": round(_peak_rss_mb(), 1), "quality": quality}
    raise HyperGSError(f"unknown scale job {spec['job']!r}")


def memory_growth(result: dict) -> dict:
    """From an encode job's RSS trace: the peak when half the frames were done, and how much the peak
    rose over the second half (bounded memory: ~0; memory that grows with the video: ~ the first half's
    growth above the baseline)."""
    trace = result["rss_trace"]
    if not trace:
        return {"peak_rss_at_half_mb": None, "growth_first_half_mb": None, "growth_second_half_mb": None}
    half = next(peak for done, _, peak in trace if done >= result["frames"] / 2)
    return {"peak_rss_at_half_mb": half,
            "growth_first_half_mb": round(half - result["rss_baseline_mb"], 1),
            "growth_second_half_mb": round(result["peak_rss_mb"] - half, 1)}


def run_scale_job(spec: dict, timeout: float | None = None) -> dict:
    """_scale_worker(spec) in a fresh Python process; its JSON result."""
    code = ("import json, sys; from hypergs_blender.bench_compare import _scale_worker; "
            "print('@@RESULT@@' + json.dumps(_scale_worker(json.loads(sys.argv[1]))))")
    root = str(Path(__file__).resolve().parents[1])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
    done = subprocess.run([sys.executable, "-c", code, json.dumps(spec)], capture_output=True, text=True,
                          timeout=timeout, env=env)
    for line in done.stdout.splitlines():
        if line.startswith("@@RESULT@@"):
            return json.loads(line[len("@@RESULT@@"):])
    raise HyperGSError(f"scale job {spec['job']} failed (exit {done.returncode}):\n{done.stderr[-4000:]}")


def bench_scale(video=None, seconds: float = 60.0, width: int = 1280, height: int = 720, fps: int = 24,
                gaussians: int = 1000, grid: int = 1, chunk_clips: int = 4, refine: int = 0, bits: int = 8,
                render_width: int = 1920, render_height: int = 1080, render_frames: int | None = 48,
                psnr_frames: int = 8, encoder: str = "network", backend: str = "auto", weights=None,
                device: str = "auto", keep: str | None = None, also_encode_video: bool = False,
                progress=None) -> dict:
    """A long video (`video`, or a synthetic `seconds` s W x H pan) encoded end to end at its native
    size into .hgs, streamed: frames/s and peak RSS after every chunk (bounded memory means the peak
    stops rising after the first chunks). Then `render_frames` frames (None: all) rendered at
    render_width x render_height from the .hgs, and PSNR on `psnr_frames` frames at the source size.
    also_encode_video: also run what `hypergs encode` runs (encode.encode_video, which returns the
    whole clip, then save_clip), in its own process, for its peak memory and frames/s."""
    device = resolve_device(device)
    grid = max(1, grid)
    n = split_count(gaussians, grid)
    report = {"bench": "scale", "machine": machine_report(device),
              "settings": {"gaussians": n, "grid": grid, "chunk_clips": chunk_clips, "refine": refine, "bits": bits,
                           "render": [render_width, render_height], "render_frames": render_frames,
                           "encoder": encoder, "device": device}, "notes": []}
    with tempfile.TemporaryDirectory(prefix="hypergs-scale-") as tmp:
        folder = Path(keep) if keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        if video is None:
            video = folder / f"pan_{width}x{height}_{seconds:g}s.mp4"
            _say(progress, f"making {video.name}")
            report["source"] = {"synthetic": True, **make_pan_video(video, seconds, width, height, fps)}
        else:
            from .video import probe
            info = probe(video)
            report["source"] = {"synthetic": False, "path": str(video), "frames": info.num_frames,
                                "width": info.width, "height": info.height, "fps": info.fps}
        clip = folder / "scale.hgs"
        common = {"encoder": encoder, "backend": backend, "weights": weights, "device": device}
        _say(progress, f"encoding {report['source']['frames']} frames at N={n}, grid {grid}")
        enc = run_scale_job({"job": "encode", "video": str(video), "output": str(clip), "gaussians": n, "grid": grid,
                             "chunk_clips": chunk_clips, "refine": refine, "bits": bits, **common})
        enc.update(memory_growth(enc))
        enc["hgs_bytes"] = clip.stat().st_size
        enc["bpp"] = 8 * clip.stat().st_size / (enc["frames"] * enc["width"] * enc["height"])
        enc["in_memory_params_mb"] = round(enc["frames"] * n * 8 * 4 / 2**20, 1)
        report["encode"] = enc
        if also_encode_video:
            _say(progress, "encoding again with encode.encode_video + save_clip (the `hypergs encode` path)")
            ev = run_scale_job({"job": "encode_video", "video": str(video), "output": str(folder / "encode_video.hgs"),
                                "gaussians": n, "grid": grid, "chunk_clips": chunk_clips, "refine": refine,
                                "bits": bits, **common})
            ev.update(memory_growth(ev))
            report["encode_video"] = ev
        report["notes"].append(
            "encode: video -> .hgs streamed (HgsWriter, default quantizer ranges); `hypergs encode` (encode_video, "
            f"then save_clip) also holds the whole clip's float32 params, {enc['in_memory_params_mb']} MB here.")
        _say(progress, f"rendering {render_frames or 'all'} frames at {render_width}x{render_height}")
        report["render"] = run_scale_job({"job": "render", "clip": str(clip), "width": render_width,
                                          "height": render_height, "frames": render_frames, "video": str(video),
                                          "psnr_frames": psnr_frames, "device": device})
    report["table"] = format_scale_table(report)
    return report


def format_scale_table(report: dict) -> str:
    m, s, src, e, r = report["machine"], report["settings"], report["source"], report["encode"], report["render"]
    q = r.get("quality") or {}
    name = "synthetic pan" if src.get("synthetic") else Path(src["path"]).name
    lines = [f"{m['date'][:10]}, {m['cpu']} ({m['cores']} cores{', ' + m['gpu'] if m.get('gpu') else ''}; device "
             f"{m['device']}, load {m.get('load_average_1m', '?')}). Encoder `{e['encoder']}`, {s['gaussians']} Gaussians "
             f"per frame ({s['grid']}x{s['grid']} grid), chunks of {s['chunk_clips']} clips; source {name} "
             f"{src['width']}x{src['height']} at {src['fps']:g} fps, {src['frames']} frames. Peak RSS of the job's "
             "process after start-up (MiB): the peak when half the frames were done, and at the end.", "",
             "| path | frames | encode fps | RSS before | peak at half | peak at end | .hgs bpp |",
             "| --- | --- | --- | --- | --- | --- | --- |",
             f"| video -> .hgs streamed (HgsWriter) | {e['frames']} | {e['fps']:.3g} | {e['rss_baseline_mb']:.0f} | "
             f"{e['peak_rss_at_half_mb']:.0f} | {e['peak_rss_mb']:.0f} | {e['bpp']:.4f} |"]
    ev = report.get("encode_video")
    if ev:
        lines.append(f"| `hypergs encode` (encode_video + save_clip) | {ev['frames']} | {ev['fps']:.3g} | "
                     f"{ev['rss_baseline_mb']:.0f} | {ev['peak_rss_at_half_mb']:.0f} | {ev['peak_rss_mb']:.0f} | |")
    lines += ["", f"Render from the .hgs at {r['width']}x{r['height']}: {r['fps']:.3g} frames/s ({r['frames']} of "
              f"{r['of']} frames, peak RSS {r['peak_rss_mb']:.0f} MiB)"
              + ("" if not q else f"; PSNR at the source size {q['psnr_at_source_size']:.2f} dB on {len(q['frames'])} frames") + "."]
    return "\n".join(lines)


# ---- command line (bench.py BENCH_COMMANDS contract: add options, return args -> report) -------------------

def _encoder_options(parser, default: str = "network") -> None:
    parser.add_argument("--encoder", default=default, choices=["network", "floor"],
                        help="the bundled network, or the grid floor (no learning)")
    parser.add_argument("--backend", default="auto", choices=["auto", "torch", "onnx"])
    parser.add_argument("--weights", default=None, help="folder with <name>.json/.safetensors/.onnx")
    parser.add_argument("--device", default="auto", help="auto (cuda when available), cpu, cuda")
    parser.add_argument("-o", "--output", default=None, help="also write the JSON report here")


def _progress(message: str) -> None:
    print(message, file=sys.stderr, flush=True)


def _write(report: dict, output) -> dict:
    if output:
        Path(output).parent.mkdir(parents=True, exist_ok=True)
        Path(output).write_text(json.dumps(report, indent=2) + "\n")
    return report


def vs_fit_cli(parser):
    parser.add_argument("videos", nargs="+")
    parser.add_argument("--gaussians", type=int, nargs="+", default=list(DEFAULT_GAUSSIANS))
    parser.add_argument("--refine-steps", type=int, nargs="*", default=list(DEFAULT_REFINE_STEPS),
                        help="K values for feedforward + refine (1: least-squares colours only)")
    parser.add_argument("--fit-iters", type=int, nargs="+", default=list(DEFAULT_FIT_ITERS),
                        help="fitting-from-random rungs (iterations), each its own run")
    parser.add_argument("--sizes", nargs="+", default=list(DEFAULT_SIZES),
                        help="square sizes (short-side resize + crop) and/or 'native' (own W x H, patch grid)")
    parser.add_argument("--frames", type=int, default=4, help="consecutive frames per video")
    parser.add_argument("--start", type=int, default=0, help="first frame")
    parser.add_argument("--grid", type=int, default=None, help="patch grid at native size (default: tiles ~ canvas)")
    parser.add_argument("--fit-budget", type=float, default=DEFAULT_FIT_BUDGET,
                        help="seconds of fitting per (video, size, N): rungs predicted to exceed it are skipped "
                             f"(default {DEFAULT_FIT_BUDGET:g}; 0: no limit)")
    parser.add_argument("--fit-all", action="store_true",
                        help="run every rung (default: stop once fitting reaches ours' best PSNR)")
    _encoder_options(parser)

    def run(args) -> dict:
        return _write(bench_vs_fit(args.videos, args.gaussians, args.refine_steps, args.fit_iters, args.sizes,
                                   args.frames, args.start, args.encoder, args.backend, args.weights, args.device,
                                   args.grid, args.fit_budget or None, args.fit_all, progress=_progress), args.output)
    return run


def vs_x265_cli(parser):
    parser.add_argument("videos", nargs="+")
    parser.add_argument("--gaussians", type=int, nargs="+", default=list(DEFAULT_GAUSSIANS))
    parser.add_argument("--bits", type=int, nargs="+", default=list(DEFAULT_BITS), choices=[4, 6, 8])
    parser.add_argument("--crf", type=int, nargs="+", default=list(DEFAULT_CRFS))
    parser.add_argument("--refine-steps", type=int, nargs="+", default=[0],
                        help="rows of ours at these refine K (0: the feedforward prediction)")
    parser.add_argument("--sizes", "--size", dest="size", default="256",
                        help="square size (short-side resize + crop) or 'native' (own W x H, patch grid)")
    parser.add_argument("--frames", type=int, default=24, help="consecutive frames per video (0: all)")
    parser.add_argument("--start", type=int, default=0)
    parser.add_argument("--grid", type=int, default=None)
    parser.add_argument("--codec", default="libx265")
    parser.add_argument("--preset", default="medium")
    parser.add_argument("--group-size", type=int, default=16)
    parser.add_argument("--position-bits", type=int, default=10,
                        help="bits of the means where --bits is lower (0: every parameter at --bits)")
    _encoder_options(parser)

    def run(args) -> dict:
        return _write(bench_vs_x265(args.videos, args.gaussians, args.bits, args.crf, args.size, args.frames or None,
                                    args.start, args.refine_steps, args.encoder, args.backend, args.weights,
                                    args.device, args.grid, args.codec, args.preset, args.group_size,
                                    position_bits=args.position_bits or None, progress=_progress), args.output)
    return run


def scale_cli(parser):
    parser.add_argument("video", nargs="?", default=None, help="a video (default: a synthetic pan, made in a temp dir)")
    parser.add_argument("--seconds", type=float, default=60.0, help="length of the synthetic video")
    parser.add_argument("--resolution", default="1280x720", help="W x H of the synthetic video")
    parser.add_argument("--fps", type=int, default=24)
    parser.add_argument("--gaussians", type=int, default=1000)
    parser.add_argument("--grid", type=int, default=1)
    parser.add_argument("--chunk-clips", type=int, default=4)
    parser.add_argument("--refine", type=int, default=0)
    parser.add_argument("--bits", type=int, default=8, choices=[4, 6, 8])
    parser.add_argument("--render", default="1920x1080", help="render size")
    parser.add_argument("--render-frames", type=int, default=48, help="frames rendered (0: all)")
    parser.add_argument("--keep", default=None, help="folder to keep the video and the .hgs in")
    parser.add_argument("--also-encode-video", action="store_true",
                        help="also measure `hypergs encode`'s path (encode_video holds the clip, then save_clip)")
    _encoder_options(parser)

    def run(args) -> dict:
        w, h = (int(v) for v in args.resolution.lower().split("x"))
        rw, rh = (int(v) for v in args.render.lower().split("x"))
        return _write(bench_scale(args.video, args.seconds, w, h, args.fps, args.gaussians, args.grid, args.chunk_clips,
                                  args.refine, args.bits, rw, rh, args.render_frames or None, 8, args.encoder,
                                  args.backend, args.weights, args.device, args.keep, args.also_encode_video,
                                  progress=_progress), args.output)
    return run
