"""`hypergs bench encode`: encode time of the bundled network through the whole encode path (resize to
the working size, the forward pass in tiles, the stretch back onto the canvas), on random frames:
256 x 256 at Gaussian counts, and 1280 x 720 and 1920 x 1080 at the Quality presets' densities. The
video decode before it is not included (about 10 ms per 1080p frame with PyAV here)."""
from __future__ import annotations

from ..encode import QUALITY, encode_frames, frames_layout
from ..network import resolve_encoder
from .common import machine_report, timed

FRAME_SIZES = {"256": (256, 256), "720p": (1280, 720), "1080p": (1920, 1080)}


def bench_encode(backends=("torch", "onnx"), counts=(250, 1000, 3000), presets=("draft", "standard", "high"),
                 sizes=tuple(FRAME_SIZES), frames: int = 8, large_frames: int = 2, repeats: int = 3, weights=None,
                 threads: int = 0, precision: str = "float32") -> dict:
    """Seconds per frame of each backend: `frames` frames per call at 256 x 256 for each count in
    `counts`, `large_frames` per call at 720p and 1080p for each Quality preset in `presets`; the
    fastest of `repeats` calls after one untimed call (on a shared machine the minimum is the figure
    that other jobs disturb least), in wall seconds and in this process's CPU seconds (which other jobs
    barely change; with one thread, the wall time of an idle core). threads: torch's and onnxruntime's CPU threads
    (0: their defaults, one per core); precision: the torch rows' (network.PRECISIONS; onnxruntime's are float32)."""
    import torch

    default_threads = torch.get_num_threads()
    torch.set_num_threads(threads or default_threads)
    try:
        rows = _encode_rows(backends, counts, presets, sizes, frames, large_frames, repeats, weights, threads, precision)
    finally:
        torch.set_num_threads(default_threads)
    report = dict(bench="encode", machine=machine_report("cpu"),
                  settings=dict(threads=threads or default_threads, frames_per_call=frames,
                                large_frames_per_call=large_frames, repeats=repeats, weights=str(weights or "bundled"),
                                precision=precision),
                  rows=rows)
    report["table"] = format_encode_table(report)
    return report


def _encode_rows(backends, counts, presets, sizes, frames, large_frames, repeats, weights, threads, precision) -> list[dict]:
    import time

    import numpy as np

    rng = np.random.default_rng(0)
    rows = []
    for backend in backends:
        encoder = resolve_encoder("network", backend, weights, device="cpu", threads=threads,
                                  precision=precision if backend == "torch" else "float32")
        for size in sizes:
            width, height = FRAME_SIZES[size]
            square = (width, height) == (256, 256)
            clip = rng.integers(0, 256, (frames if square else large_frames, height, width, 3), dtype=np.uint8)
            densities = ([("N", dict(gaussians=n)) for n in counts] if square
                         else [(preset, dict(cell=QUALITY[preset]["cell"])) for preset in presets])
            for label, density in densities:
                layout = frames_layout(clip, encoder, **density)
                cpu = []

                def encode():
                    started = time.process_time()
                    encode_frames(clip, encoder, layout)
                    cpu.append(time.process_time() - started)
                seconds = timed(encode, repeats, warmup=True, statistic=min)[0] / len(clip)
                rows.append(dict(backend=backend, encoder=encoder.name, size=f"{size}²" if square else size, width=width, height=height,
                                 setting=f"N = {density['gaussians']}" if label == "N" else label,
                                 gaussians=layout.count, s_per_frame=significant(seconds),
                                 cpu_s_per_frame=significant(min(cpu[1:]) / len(clip)),
                                 frames_per_s=significant(1 / seconds)))
    return rows


def significant(x: float, digits: int = 4) -> float:
    """x to `digits` significant digits (a millisecond frame keeps its precision)."""
    return float(f"{x:.{digits}g}")


def format_encode_table(report: dict) -> str:
    m, s = report["machine"], report["settings"]
    lines = [f"{m.get('date', '?')[:10]}, {m.get('cpu', '?')} ({m.get('cores', '?')} cores, load "
             f"{m.get('load_average_1m', '?')}), {s['threads']} threads",
             "", "| frames | setting | Gaussians | encoder | s/frame | frames/s | CPU s/frame |",
             "| --- | --- | --- | --- | --- | --- | --- |"]
    for r in report["rows"]:
        lines.append(f"| {r['size']} | {r['setting']} | {r['gaussians']:,} | {r.get('encoder', r['backend'])} | {r['s_per_frame']:.3f} | "
                     f"{r['frames_per_s']:.1f} | {r['cpu_s_per_frame']:.3f} |")
    return "\n".join(lines)
