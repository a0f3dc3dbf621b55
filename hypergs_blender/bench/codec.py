"""`hypergs bench codec`: rate-distortion of the .hgs codec next to an FFmpeg codec (x265) on the same
frames at the same size, with the Gaussian-order stability that residual coding relies on."""
from __future__ import annotations

import tempfile
import time
from pathlib import Path

import numpy as np

from ..encode import encode_frames, frames_layout
from ..gaussians import GaussianVideo
from ..io.codec import MODES, order_stability
from ..io.frames import read_frames
from ..io.hgs import load_hgs, save_hgs
from ..metrics import psnr
from ..network import resolve_encoder
from ..render import render_frames
from .common import (DEFAULT_BITS, DEFAULT_CRFS, DEFAULT_GAUSSIANS, encode_reference, machine_report,
                     video_codec_available)


def bench_codec(videos, gaussians=DEFAULT_GAUSSIANS, bits=DEFAULT_BITS, crfs=DEFAULT_CRFS, size: int = 256,
                num_frames: int | None = None, encoder="network", codec: str = "libx265", preset: str = "medium",
                group_size: int = 16, position_bits: int | None = None, progress=None) -> dict:
    """Rate-distortion of the .hgs codec next to an FFmpeg codec on the same frames at the same size.

    For each video: frames short-side resized and centre-cropped to size x size. Reference rows: the
    FFmpeg codec (libx265, else libx264) at each CRF, yuv420p in mp4: bpp (file bits per pixel per frame),
    PSNR (RGB, per frame, averaged), encode and decode frames/s. Gaussian rows: for each N, the encoder's
    Gaussians rendered without quantization (float32), then through .hgs at each bit depth: bpp, PSNR,
    encode frames/s (encoder + .hgs write), decode frames/s (.hgs read + render), plus the .hgs size with
    each forced residual mode and the Gaussian-order stability. position_bits: also code each bit depth
    with the means (x, y) at this many bits (rows with `bits` as 8 values). encoder: 'network' | 'floor'
    or an encoder object."""
    if isinstance(encoder, str):
        encoder = resolve_encoder(encoder)
    encoder_name = encoder.name
    notes = []
    if not video_codec_available(codec):
        fallback = "libx264"
        notes.append(f"{codec} is not in PyAV's FFmpeg; used {fallback}")
        codec = fallback
    say = progress or (lambda message: None)
    depths = list(bits)
    if position_bits:
        depths += [(position_bits,) * 2 + (b,) * 6 for b in bits if b != position_bits]
    result = {"machine": machine_report(),
              "settings": {"size": size, "num_frames": num_frames, "encoder": encoder_name, "codec": codec,
                           "preset": preset, "crfs": list(crfs), "bits": list(bits), "gaussians": list(gaussians),
                           "group_size": group_size, "position_bits": position_bits},
              "notes": notes, "videos": []}
    with tempfile.TemporaryDirectory(prefix="hypergs-bench-") as tmp:
        clip_path = Path(tmp) / "clip.hgs"
        for path in videos:
            frames, info, indices = read_frames(path, num_frames, size=size)
            t, h, w = frames.shape[:3]
            pixels = t * h * w
            target = frames.astype(np.float32) / 255
            entry = {"path": str(path), "frames": t, "width": w, "height": h, "reference": [], "gaussians": []}
            for crf in crfs:
                say(f"{Path(path).name}: {codec} crf {crf}")
                ref = encode_reference(frames, info.fps, codec, crf, preset)
                entry["reference"].append({
                    "codec": codec, "crf": crf, "bytes": ref["bytes"], "bpp": 8 * ref["bytes"] / pixels,
                    "psnr": float(np.mean(psnr(ref["frames"].astype(np.float32) / 255, target))),
                    "encode_fps": t / ref["encode_s"], "decode_fps": t / ref["decode_s"]})
            for n in gaussians:
                say(f"{Path(path).name}: {n} Gaussians")
                layout = frames_layout(frames, encoder, gaussians=n)
                render_frames(GaussianVideo(encode_frames(frames[:1], encoder, layout), w, h), w, h)  # warm-up (JIT)
                started = time.perf_counter()
                params = encode_frames(frames, encoder, layout)
                encoder_s = time.perf_counter() - started
                video = GaussianVideo(params, w, h, info.fps, (1, 1), {"path": str(path), "frames": indices})
                started = time.perf_counter()
                rendered = render_frames(video, video.canvas_width, video.canvas_height)
                render_s = time.perf_counter() - started
                stability = order_stability(params, w, h)
                row = {"n": n, "encoder_fps": t / encoder_s, "render_fps": t / render_s,
                       "float_psnr": float(np.mean(psnr(rendered, target))),
                       "float_bpp": 8 * params.nbytes / pixels,
                       "order_stability": {k: v for k, v in stability.items() if k != "per_pair"},
                       "hgs": []}
                for b in depths:
                    started = time.perf_counter()
                    nbytes = save_hgs(video, clip_path, bits=b, group_size=group_size)
                    write_s = time.perf_counter() - started
                    started = time.perf_counter()
                    decoded = load_hgs(clip_path)
                    read_s = time.perf_counter() - started
                    started = time.perf_counter()
                    rendered = render_frames(decoded, decoded.canvas_width, decoded.canvas_height)
                    render_s = time.perf_counter() - started
                    by_mode = {m: save_hgs(video, clip_path, bits=b, group_size=group_size, mode=m)
                               for m in MODES if m != "auto"}
                    row["hgs"].append({
                        "bits": b if isinstance(b, int) else list(b), "bytes": nbytes, "bpp": 8 * nbytes / pixels,
                        "bits_per_gaussian": 8 * nbytes / (t * n),
                        "psnr": float(np.mean(psnr(rendered, target))),
                        "encode_fps": t / (encoder_s + write_s), "codec_encode_fps": t / write_s,
                        "decode_fps": t / (read_s + render_s), "codec_decode_fps": t / read_s,
                        "bytes_by_mode": by_mode})
                entry["gaussians"].append(row)
            result["videos"].append(entry)
    return result


def format_codec_table(result: dict) -> str:
    """The bench result as a Markdown table (one row per codec setting, videos side by side)."""
    m, s = result["machine"], result["settings"]
    lines = [f"Machine: {m['cpu']}, {m['cores']} cores, {m['os']}; PyAV {m['pyav']} (libavcodec {m['libavcodec']}). "
             f"Frames {s['size']}x{s['size']} (short side resized, centre crop), Gaussians from the "
             f"`{s['encoder']}` encoder, .hgs group size {s['group_size']}; {s['codec']} preset {s['preset']}, yuv420p, mp4.",
             ""]
    videos = result["videos"]
    head = "| codec | setting |" + "".join(f" {Path(v['path']).stem} bpp | PSNR dB |" for v in videos)
    head += " enc fps | dec fps |"
    lines += [head, "|" + " --- |" * (2 + 2 * len(videos) + 2)]

    def row(label, setting, cells, enc, dec):
        body = "".join(f" {bpp:.4f} | {p:.2f} |" for bpp, p in cells)
        lines.append(f"| {label} | {setting} |{body} {enc:.0f} | {dec:.0f} |")

    for i, ref in enumerate(videos[0]["reference"]):
        refs = [v["reference"][i] for v in videos]
        row(ref["codec"], f"crf {ref['crf']}", [(r["bpp"], r["psnr"]) for r in refs],
            np.mean([r["encode_fps"] for r in refs]), np.mean([r["decode_fps"] for r in refs]))
    for j, g in enumerate(videos[0]["gaussians"]):
        gs = [v["gaussians"][j] for v in videos]
        row("Gaussians float32", f"N={g['n']}", [(x["float_bpp"], x["float_psnr"]) for x in gs],
            np.mean([x["encoder_fps"] for x in gs]), np.mean([x["render_fps"] for x in gs]))
        for k, hg in enumerate(g["hgs"]):
            hs = [x["hgs"][k] for x in gs]
            row(".hgs", f"N={g['n']}, {_bits_label(hg['bits'])}", [(x["bpp"], x["psnr"]) for x in hs],
                np.mean([x["encode_fps"] for x in hs]), np.mean([x["decode_fps"] for x in hs]))
    return "\n".join(lines)


def _bits_label(bits) -> str:
    if isinstance(bits, int) or len(set(bits)) == 1:
        return f"{bits if isinstance(bits, int) else bits[0]} bits"
    return f"{bits[2]} bits, x/y {bits[0]} bits"
