"""What every benchmark shares: timing, the machine's description, devices, frames, rendering and
PSNR the same way everywhere, the FFmpeg reference codec, and writing reports.

All timings are wall-clock on the machine that runs them; its description, the date and the load
average go into every report (`machine_report`). Reports are dicts; `write_report` saves them as JSON
(docs/bench/), and plots.py turns those into plots and Markdown tables.
"""
from __future__ import annotations

import datetime
import io
import json
import os
import platform
import statistics
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

from ..errors import HyperGSError

DEFAULT_GAUSSIANS = (250, 1000, 3000)
DEFAULT_BITS = (8, 6, 4)
DEFAULT_CRFS = (18, 23, 28, 33, 38, 43, 48, 51)  # up to x265's maximum: ours can sit below CRF 43's PSNR
BOUND_TEXT = {"=": "", "<=": "≤ ", ">=": "≥ ", None: ""}  # how an interpolated figure's bound is printed


def timed(fn, repeats: int = 1, warmup: bool = False, sync=None, statistic=statistics.median):
    """(`statistic` of the wall seconds of fn() over `repeats` calls, default the median; the last call's
    result); `warmup` runs it once first, untimed; `sync()` (a device synchronisation) is called before
    each clock reading."""
    if warmup:
        fn()
        if sync:
            sync()
    times, result = [], None
    for _ in range(max(1, repeats)):
        started = time.perf_counter()
        result = fn()
        if sync:
            sync()
        times.append(time.perf_counter() - started)
    return statistic(times), result


def use_threads(threads: int) -> None:
    """The CPU threads of everything a bench times: torch's ops and the numba rasterizer (fitting and
    refinement), which torch's setting does not reach; a comparison gives each side the same."""
    import torch

    from .. import raster
    torch.set_num_threads(threads)
    raster.set_threads(threads)


def machine_report(device: str = "cpu") -> dict:
    """CPU, cores, OS, library versions, torch and numba threads, the accelerator, the date and the load."""
    import av
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    info = {"cpu": cpu, "cores": os.cpu_count(), "os": platform.platform(), "python": platform.python_version(),
            "numpy": np.__version__, "pyav": av.__version__,
            "libavcodec": ".".join(str(v) for v in av.library_versions.get("libavcodec", ())),
            "date": datetime.datetime.now().astimezone().isoformat(timespec="seconds")}
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
    from .. import raster
    if raster.numba_available():
        import numba
        info["numba_threads"] = numba.get_num_threads()
    info["device"] = device
    return info


def resolve_device(name: str = "auto") -> str:
    """'auto': cuda when torch sees one, else cpu; 'cuda...' is checked."""
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


def sync(device: str) -> None:
    if device.startswith("cuda"):
        import torch
        torch.cuda.synchronize()


def parse_frames(text) -> tuple[int | None, int | None]:
    """A frames spec -> (size, crop): '256' short-side resize + crop to 256 x 256, 'crop480' a 480 x 480
    centre crop at the video's own resolution, 'native' whole frames."""
    text = str(text).lower()
    if text == "native":
        return None, None
    crop = text.startswith("crop")
    try:
        value = int(text[4:] if crop else text)
    except ValueError:
        raise HyperGSError(f"frames {text!r}: expected a size (256), 'cropN' (crop480) or 'native'") from None
    if value < 16:
        raise HyperGSError(f"frames {text!r}: {value} px is too small")
    return (None, value) if crop else (value, None)


def load_frames(path, frames: int | None, size: int | None, start: int = 0, crop: int | None = None):
    """Consecutive frames [start, start + frames) (all when None) as uint8 [T, H, W, 3]: short-side
    resized and centre-cropped to size x size, or a crop x crop centre crop, or whole; even W and H
    (for yuv420p)."""
    from ..io.frames import probe, read_frames
    info = probe(path)
    start = min(start, info.num_frames - 1)
    stop = None if frames is None else start + frames
    video, _, indices = read_frames(path, None, start, stop, size=size)
    h, w = video.shape[1:3]
    if crop:
        y0, x0 = max(0, (h - crop) // 2), max(0, (w - crop) // 2)
        video = video[:, y0:y0 + crop, x0:x0 + crop]
    h, w = video.shape[1] // 2 * 2, video.shape[2] // 2 * 2
    return np.ascontiguousarray(video[:, :h, :w]), info, indices


def render(params: np.ndarray, width: int, height: int, device: str = "cpu", canvas=None) -> np.ndarray:
    """float32 [T, H, W, 3] of params [T, N, 8] on a canvas (default: W x H) rendered at W x H: the
    numpy path (numba) on the CPU, which is what a user's decode runs; the torch rasterizer on CUDA."""
    canvas_w, canvas_h = canvas or (width, height)
    if not device.startswith("cuda"):
        from ..render import render_params
        return render_params(params, canvas_w, canvas_h, width, height)
    import torch

    from ..render import render_torch
    with torch.no_grad():
        p = torch.from_numpy(np.ascontiguousarray(params)).to(device)
        out = render_torch(p, canvas_w, canvas_h, width, height)
        sync(device)
        return out.cpu().numpy()


def psnr_of(rendered: np.ndarray, frames: np.ndarray) -> np.ndarray:
    """Per-frame PSNR of renders against uint8 frames."""
    from ..metrics import psnr
    return psnr(rendered, frames.astype(np.float32) / 255)


def say(progress, message: str) -> None:
    if progress is not None:
        progress(message)


def video_codec_available(name: str) -> bool:
    import av
    return name in av.codecs_available


def encode_reference(frames: np.ndarray, fps: float, codec: str, crf: int, preset: str = "medium") -> dict:
    """uint8 RGB frames [T, H, W, 3] through an FFmpeg encoder (yuv420p, mp4) and back.
    Returns bytes, decoded frames (uint8) and encode / decode seconds (colour conversion included)."""
    import av

    options = {"crf": str(crf), "preset": preset}
    if codec == "libx265":
        options["x265-params"] = "log-level=error"
    buf = io.BytesIO()
    started = time.perf_counter()
    with av.open(buf, "w", format="mp4") as container:
        stream = container.add_stream(codec, rate=Fraction(fps).limit_denominator(1001), options=options)
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], "yuv420p"
        for frame in frames:
            yuv = av.VideoFrame.from_ndarray(np.ascontiguousarray(frame), format="rgb24").reformat(format="yuv420p")
            container.mux(stream.encode(yuv))
        container.mux(stream.encode())
    encode_s = time.perf_counter() - started
    data = buf.getvalue()
    started = time.perf_counter()
    with av.open(io.BytesIO(data)) as container:
        decoded = np.stack([f.to_ndarray(format="rgb24") for f in container.decode(video=0)])
    return {"bytes": len(data), "frames": decoded, "encode_s": encode_s, "decode_s": time.perf_counter() - started}


def write_report(report: dict, output) -> dict:
    """Save the report as JSON at `output` (when given); returns it."""
    if output:
        from ..io.files import write_bytes
        Path(output).parent.mkdir(parents=True, exist_ok=True)
        write_bytes(output, (json.dumps(report, indent=2) + "\n").encode())
    return report
