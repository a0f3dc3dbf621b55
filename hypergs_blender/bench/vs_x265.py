"""`hypergs bench vs-x265`: .hgs at each bit depth next to x265 at each CRF on the same frames and
size: bpp, PSNR, SSIM, encode and decode frames/s, and matched-quality pairs."""
from __future__ import annotations

import math
import tempfile
import time
from pathlib import Path

import numpy as np

from ..encode import encode_frames, frames_layout
from ..gaussians import GaussianVideo
from ..io.codec import clip_bits
from ..io.hgs import load_hgs, save_hgs
from ..metrics import ssim
from ..network import resolve_encoder
from .common import (BOUND_TEXT, DEFAULT_BITS, DEFAULT_CRFS, DEFAULT_GAUSSIANS, encode_reference, load_frames,
                     machine_report, parse_frames, psnr_of, render, resolve_device, say, sync, timed,
                     video_codec_available)
from .vs_fit import refine_ladder, warm_up


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
                  backend: str = "auto", weights=None, device: str = "auto",
                  codec: str = "libx265", preset: str = "medium", group_size: int = 16, decode_repeats: int = 3,
                  position_bits: int | None = None, precision: str = "float32", progress=None) -> dict:
    """Matched-quality pairs: Gaussians (N, refine K, .hgs bit depth) against an FFmpeg codec's CRFs on
    the same consecutive frames at the same size.

    x265 rows: common.encode_reference (yuv420p, mp4, all cores), PSNR and SSIM in RGB against the
    frames, bpp, encode and decode frames/s (colour conversion included). Ours: encoder (+ refine) on
    `device`, then .hgs at each bit depth: encode frames/s = encoder + refine + .hgs write; decode
    frames/s = .hgs read + render (numpy/numba path on the CPU, torch on CUDA; medians of
    `decode_repeats` runs). position_bits: the means (x, y) get this many bits where a depth is lower;
    None: the depths the .hgs writer itself gives a clip (codec.clip_bits: the means get enough bits for
    the Gaussians' spacing), so the rows are the files `hypergs encode` and Blender write. Pairs: for every row of
    ours, the CRF whose PSNR is closest, and x265's bpp and frames/s interpolated at our PSNR."""
    device = resolve_device(device)
    if isinstance(encoder, str):
        encoder = resolve_encoder(encoder, backend, weights, device, precision=precision)
    encoder_name = encoder.name
    notes = []
    if not video_codec_available(codec):
        notes.append(f"{codec} is not in PyAV's FFmpeg; used libx264")
        codec = "libx264"
    size_value, crop = parse_frames(size)
    report = {"bench": "vs-x265", "machine": machine_report(device),
              "settings": {"gaussians": list(gaussians), "bits": list(bits), "crfs": list(crfs),
                           "size": str(size), "frames": frames,
                           "start": start, "refine_steps": list(refine_steps), "encoder": encoder_name,
                           "codec": codec, "preset": preset, "group_size": group_size,
                           "decode_repeats": decode_repeats, "position_bits": position_bits},
              "notes": notes, "videos": []}
    warmed = False
    with tempfile.TemporaryDirectory(prefix="hypergs-vs-x265-") as tmp:
        clip_path = Path(tmp) / "clip.hgs"
        for path in videos:
            clip, info, indices = load_frames(path, frames, size_value, start, crop)
            t, h, w = clip.shape[:3]
            pixels = t * h * w
            target = clip.astype(np.float32) / 255
            if not warmed:
                warm_up(clip, encoder, device)
                warmed = True
            entry = {"path": str(path), "frames": t, "frame_indices": [indices[0], indices[-1]], "width": w,
                     "height": h, "fps": info.fps, "x265": [], "ours": [], "pairs": []}
            for crf in crfs:
                say(progress, f"{Path(path).name}: {codec} crf {crf}")
                ref = encode_reference(clip, info.fps, codec, crf, preset)
                decoded = ref["frames"].astype(np.float32) / 255
                entry["x265"].append({"codec": codec, "crf": crf, "bytes": ref["bytes"], "bpp": 8 * ref["bytes"] / pixels,
                                      "psnr": float(np.mean(psnr_of(decoded, clip))),
                                      "ssim": float(np.mean(ssim(decoded, target))),
                                      "encode_fps": t / ref["encode_s"], "decode_fps": t / ref["decode_s"]})
            for n_asked in gaussians:
                layout = frames_layout(clip, encoder, gaussians=n_asked)
                n = layout.count
                encode_frames(clip[:1], encoder, layout)  # warm-up at this N
                sync(device)
                started = time.perf_counter()
                params = encode_frames(clip, encoder, layout)
                sync(device)
                encoder_s = time.perf_counter() - started
                ks = sorted(set(refine_steps))
                variants = [(0, params, 0.0)] if 0 in ks else []
                if any(k > 0 for k in ks):
                    say(progress, f"{Path(path).name}: N={n} refine {[k for k in ks if k > 0]}")
                    variants += refine_ladder(clip, encoder, layout, params, [k for k in ks if k > 0], device)
                for k, p, refine_s in variants:
                    say(progress, f"{Path(path).name}: N={n} refine {k}: .hgs at {list(bits)} bits")
                    render_s, rendered = timed(lambda: render(p, w, h, device), decode_repeats)
                    row = {"n_requested": n_asked, "n": n, "refine": k, "encoder_fps": t / encoder_s,
                           "encode_fps_float": t / (encoder_s + refine_s), "render_fps": t / render_s,
                           "float_psnr": float(np.mean(psnr_of(rendered, clip))),
                           "float_ssim": float(np.mean(ssim(rendered, target))), "hgs": []}
                    video = GaussianVideo(p, w, h, info.fps, (layout.cols, layout.rows))
                    for b in bits:
                        started = time.perf_counter()
                        depths = ((position_bits,) * 2 + (b,) * 6 if position_bits and position_bits > b
                                  else clip_bits(b, w, h, video.num_gaussians))
                        nbytes = save_hgs(video, clip_path, bits=depths, group_size=group_size)
                        write_s = time.perf_counter() - started
                        read_s, decoded = timed(lambda: load_hgs(clip_path), decode_repeats)
                        render_s, rendered = timed(lambda: render(decoded.params, w, h, device), decode_repeats)
                        row["hgs"].append({"bits": b, "position_bits": depths[0], "bytes": nbytes, "bpp": 8 * nbytes / pixels,
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
            ratio = "n/a" if p["bpp_ratio"] is None else BOUND_TEXT[p["bpp_ratio_bound"]] + f"{p['bpp_ratio']:.3g}×"
            lines.append(f"| {Path(v['path']).stem} | {label} | {o['bpp']:.4f} | {o['psnr']:.2f} | {o['ssim']:.4f} | "
                         f"{o['encode_fps']:.3g} | {o['decode_fps']:.3g} | crf {r['crf']} | {r['bpp']:.4f} | "
                         f"{r['psnr']:.2f} | {r['ssim']:.4f} | {r['encode_fps']:.3g} | {r['decode_fps']:.3g} | "
                         f"{'n/a' if at is None else BOUND_TEXT[bound] + format(at, '.4f')} | {ratio} |")
    return "\n".join(lines)
