"""`hypergs bench scale`: a long video (by default a synthetic 60 s 720p pan, made with PyAV in a
temporary folder) encoded end to end into .hgs, streamed chunk by chunk, with peak memory (RSS, in a
subprocess) recorded after every chunk; then frames of it rendered at 1920 x 1080."""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from ..encode import EncodePlan, EncodeSettings, encode_frames, encode_video, frames_layout, psnr_frame_picks
from ..evaluate import warm_up
from ..errors import HyperGSError
from ..io.clips import save_clip
from ..io.frames import iter_frames, probe
from ..io.hgs import HgsReader
from ..network import resolve_encoder
from .common import machine_report, psnr_of, render, resolve_device, say
from .vs_fit import refine_ladder


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
                   codec: str = "libx264", crf: int = 18, preset: str = "veryfast", seed: int = 0,
                   image: np.ndarray | None = None) -> dict:
    """Write a video: a smooth camera pan (Lissajous path, sub-pixel steps rounded to whole pixels) over
    an image 1.5x the frame: `image` (uint8 RGB, resized and cropped to that) or a procedural one.
    yuv420p mp4. Returns its description."""
    import av
    frames = max(1, round(seconds * fps))
    big_w, big_h = int(width * 1.5) // 2 * 2, int(height * 1.5) // 2 * 2
    if image is None:
        image = pan_image(big_w, big_h, seed)
    else:
        from ..io.images import resize_exact
        scale = max(big_w / image.shape[1], big_h / image.shape[0])
        image = resize_exact(image, max(big_w, round(image.shape[1] * scale)), max(big_h, round(image.shape[0] * scale)))
        image = np.ascontiguousarray(image[:big_h, :big_w])
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


def stream_encode(path, out_path, encoder, gaussians: int | None = None, cell: float | None = None,
                  size: int | None = None, chunk_frames: int = 16, refine: int = 0, bits: int = 8,
                  hold_frames: bool = False, on_chunk=None) -> dict:
    """Video -> .hgs without ever holding the clip, as `hypergs encode` streams it (EncodePlan.write_hgs: the
    Gaussians into a float16 file, then quantized with ranges fitted to the whole clip). on_chunk(frames_done)
    after each chunk. hold_frames keeps every decoded frame (a control that must grow memory). Seconds:
    decoding and encoding (+ refine) with the float16 write, then the passes that fit the ranges and quantize."""
    plan = EncodePlan(path, encoder, EncodeSettings(gaussians, cell, refine), size)
    held, done, streamed = [], 0, None

    def chunk(frames, params):
        nonlocal done, streamed
        done += len(frames)
        if hold_frames:
            held.append(frames)
        if on_chunk is not None:
            on_chunk(done)
        streamed = time.perf_counter()

    started = time.perf_counter()
    plan.write_hgs(out_path, bits, chunk_frames=chunk_frames, on_chunk=chunk)
    seconds = {"decode_encode": streamed - started, "quantize": time.perf_counter() - streamed}
    return {"frames": done, "width": plan.width, "height": plan.height, "gaussians": plan.layout.count,
            "seconds": seconds, "held_frames": sum(len(f) for f in held)}


def _scale_worker(spec: dict) -> dict:
    """Runs in its own process (so ru_maxrss is this job's peak): 'encode' or 'render'."""
    device = spec.get("device", "cpu")
    if spec["job"] == "encode_video":  # what `hypergs encode` runs: encode.encode_video, then save_clip
        encoder = resolve_encoder(spec["encoder"], spec.get("backend", "auto"), spec.get("weights"), device,
                                  precision=spec.get("precision", "float32"))
        warm_up(encoder)
        reset = _reset_peak_rss()
        baseline = _rss_mb() or _peak_rss_mb()
        trace = []

        def progress(done, total):
            trace.append([done, round(_rss_mb() or 0.0, 1), round(_peak_rss_mb(), 1)])
            return True
        started = time.perf_counter()
        settings = EncodeSettings(spec.get("gaussians"), spec.get("cell"), spec.get("refine", 0))
        video = encode_video(spec["video"], encoder, settings, spec.get("size"), progress=progress,
                             chunk_frames=spec.get("chunk_frames", 16))
        save_clip(video, spec["output"], bits=spec.get("bits", 8))
        seconds = time.perf_counter() - started
        return {"encoder": encoder.name, "frames": video.num_frames, "wall_seconds": seconds,
                "fps": video.num_frames / seconds, "peak_reset": reset, "rss_baseline_mb": round(baseline, 1),
                "peak_rss_mb": round(_peak_rss_mb(), 1), "rss_trace": trace}
    if spec["job"] == "encode":
        encoder = resolve_encoder(spec["encoder"], spec.get("backend", "auto"), spec.get("weights"), device,
                                  precision=spec.get("precision", "float32"))
        # warm-up on a tiny frame (numba / torch initialisation), then the baseline
        warm_up(encoder)
        if spec.get("refine"):
            blank = np.zeros((1, 32, 32, 3), np.uint8)
            layout = frames_layout(blank, encoder, gaussians=16)
            refine_ladder(blank, encoder, layout, encode_frames(blank, encoder, layout), (2,), device)
        startup_peak = _peak_rss_mb()
        reset = _reset_peak_rss()
        baseline = _rss_mb() or _peak_rss_mb()
        trace = [[0, round(baseline, 1), round(_peak_rss_mb(), 1)]]  # [frames done, RSS now, peak so far] MiB

        def on_chunk(done):
            trace.append([done, round(_rss_mb() or 0.0, 1), round(_peak_rss_mb(), 1)])
        started = time.perf_counter()
        result = stream_encode(spec["video"], spec["output"], encoder, spec.get("gaussians"), spec.get("cell"),
                               spec.get("size"), spec.get("chunk_frames", 16), spec.get("refine", 0),
                               spec.get("bits", 8), spec.get("hold_frames", False), on_chunk=on_chunk)
        seconds = time.perf_counter() - started
        return {"encoder": encoder.name, **result, "wall_seconds": seconds, "fps": result["frames"] / seconds,
                "rss_startup_peak_mb": round(startup_peak, 1), "peak_reset": reset,
                "rss_baseline_mb": round(baseline, 1), "peak_rss_mb": round(_peak_rss_mb(), 1), "rss_trace": trace}
    if spec["job"] == "render":
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
                picks = psnr_frame_picks(total, spec["psnr_frames"])
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
    code = ("import json, sys; from hypergs_blender.bench.scale import _scale_worker; "
            "print('@@RESULT@@' + json.dumps(_scale_worker(json.loads(sys.argv[1]))))")
    root = str(Path(__file__).resolve().parents[2])
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, [root, os.environ.get("PYTHONPATH")])))
    done = subprocess.run([sys.executable, "-c", code, json.dumps(spec)], capture_output=True, text=True,
                          timeout=timeout, env=env)
    for line in done.stdout.splitlines():
        if line.startswith("@@RESULT@@"):
            return json.loads(line[len("@@RESULT@@"):])
    raise HyperGSError(f"scale job {spec['job']} failed (exit {done.returncode}):\n{done.stderr[-4000:]}")


def bench_scale(video=None, seconds: float = 60.0, width: int = 1280, height: int = 720, fps: int = 24,
                gaussians: int | None = None, cell: float | None = 6.0, chunk_frames: int = 16, refine: int = 0,
                bits: int = 8,
                render_width: int = 1920, render_height: int = 1080, render_frames: int | None = 48,
                psnr_frames: int = 8, encoder: str = "network", backend: str = "auto", weights=None,
                device: str = "auto", keep: str | None = None, also_encode_video: bool = False,
                precision: str = "float32", progress=None) -> dict:
    """A long video (`video`, or a synthetic `seconds` s W x H pan) encoded end to end at its native
    size into .hgs, streamed: frames/s and peak RSS after every chunk (bounded memory means the peak
    stops rising after the first chunks). Then `render_frames` frames (None: all) rendered at
    render_width x render_height from the .hgs, and PSNR on `psnr_frames` frames at the source size.
    also_encode_video: also run what `hypergs encode` runs (encode.encode_video, which returns the
    whole clip, then save_clip), in its own process, for its peak memory and frames/s."""
    device = resolve_device(device)
    density = dict(gaussians=gaussians, cell=None if gaussians else cell)
    report = {"bench": "scale", "machine": machine_report(device),
              "settings": {**density, "chunk_frames": chunk_frames, "refine": refine, "bits": bits,
                           "render": [render_width, render_height], "render_frames": render_frames,
                           "encoder": encoder, "device": device}, "notes": []}
    with tempfile.TemporaryDirectory(prefix="hypergs-scale-") as tmp:
        folder = Path(keep) if keep else Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        if video is None:
            video = folder / f"pan_{width}x{height}_{seconds:g}s.mp4"
            say(progress, f"making {video.name}")
            report["source"] = {"synthetic": True, **make_pan_video(video, seconds, width, height, fps)}
        else:
            info = probe(video)
            report["source"] = {"synthetic": False, "path": str(video), "frames": info.num_frames,
                                "width": info.width, "height": info.height, "fps": info.fps}
        clip = folder / "scale.hgs"
        common = {"encoder": encoder, "backend": backend, "weights": weights, "device": device, "precision": precision}
        say(progress, f"encoding {report['source']['frames']} frames ({density})")
        enc = run_scale_job({"job": "encode", "video": str(video), "output": str(clip), **density,
                             "chunk_frames": chunk_frames, "refine": refine, "bits": bits, **common})
        n = enc["gaussians"]
        enc.update(memory_growth(enc))
        enc["hgs_bytes"] = clip.stat().st_size
        enc["bpp"] = 8 * clip.stat().st_size / (enc["frames"] * enc["width"] * enc["height"])
        enc["in_memory_params_mb"] = round(enc["frames"] * n * 8 * 4 / 2**20, 1)
        report["encode"] = enc
        if also_encode_video:
            say(progress, "encoding again with encode.encode_video + save_clip (the `hypergs encode` path)")
            ev = run_scale_job({"job": "encode_video", "video": str(video), "output": str(folder / "encode_video.hgs"),
                                **density, "chunk_frames": chunk_frames, "refine": refine,
                                "bits": bits, **common})
            ev.update(memory_growth(ev))
            report["encode_video"] = ev
        report["notes"].append(
            "encode: video -> .hgs streamed (EncodePlan.write_hgs, as `hypergs encode` writes .hgs); to .npz or USD it "
            f"(encode_video, then save_clip) holds the whole clip's float32 params, {enc['in_memory_params_mb']} MB here.")
        say(progress, f"rendering {render_frames or 'all'} frames at {render_width}x{render_height}")
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
             f"{m['device']}, load {m.get('load_average_1m', '?')}). Encoder `{e['encoder']}`, {e['gaussians']} Gaussians "
             f"per frame, chunks of {s['chunk_frames']} frames; source {name} "
             f"{src['width']}x{src['height']} at {src['fps']:g} fps, {src['frames']} frames. Peak RSS of the job's "
             "process after start-up (MiB): the peak when half the frames were done, and at the end.", "",
             "| path | frames | encode fps | RSS before | peak at half | peak at end | .hgs bpp |",
             "| --- | --- | --- | --- | --- | --- | --- |",
             f"| video -> .hgs streamed (EncodePlan.write_hgs) | {e['frames']} | {e['fps']:.3g} | {e['rss_baseline_mb']:.0f} | "
             f"{e['peak_rss_at_half_mb']:.0f} | {e['peak_rss_mb']:.0f} | {e['bpp']:.4f} |"]
    ev = report.get("encode_video")
    if ev:
        lines.append(f"| `hypergs encode` (encode_video + save_clip) | {ev['frames']} | {ev['fps']:.3g} | "
                     f"{ev['rss_baseline_mb']:.0f} | {ev['peak_rss_at_half_mb']:.0f} | {ev['peak_rss_mb']:.0f} | |")
    lines += ["", f"Render from the .hgs at {r['width']}x{r['height']}: {r['fps']:.3g} frames/s ({r['frames']} of "
              f"{r['of']} frames, peak RSS {r['peak_rss_mb']:.0f} MiB)"
              + ("" if not q else f"; PSNR at the source size {q['psnr_at_source_size']:.2f} dB on {len(q['frames'])} frames") + "."]
    return "\n".join(lines)
