"""Codec and interchange commands: `hypergs info`, `hypergs export-usd`, `hypergs import-usd`, and the
codec rate-distortion bench `bench_codec` (`hypergs bench codec`, registered in bench.py's
BENCH_COMMANDS through `bench_codec_cli`)."""
from __future__ import annotations

import io
import json
import os
import platform
import sys
import tempfile
import time
from fractions import Fraction
from pathlib import Path

import numpy as np

from .errors import HyperGSError

DEFAULT_CRFS = (18, 23, 28, 33, 38, 43)
DEFAULT_BITS = (8, 6, 4)
DEFAULT_GAUSSIANS = (1000, 4000)


# ---- info, export-usd, import-usd ------------------------------------------------------------------

def clip_info(path, verify: bool = False) -> dict:
    """What `hypergs info` prints: header fields for .hgs (without decoding unless verify), basic
    figures for the other formats."""
    path = Path(path)
    if path.suffix.lower() == ".hgs":
        from .hgs import HgsReader
        with HgsReader(path) as reader:
            info = reader.info()
            if verify:
                started = time.perf_counter()
                reader.verify()
                info["verified"] = True
                info["decode_fps"] = reader.num_frames / max(time.perf_counter() - started, 1e-9)
        return info
    from .clip_io import load_clip
    video = load_clip(path)
    size = path.stat().st_size
    frames, n = video.num_frames, video.num_gaussians
    return {"path": str(path), "format": path.suffix.lower().lstrip("."), "file_bytes": size,
            "canvas": [video.canvas_width, video.canvas_height], "fps": video.fps, "num_frames": frames,
            "duration_s": frames / video.fps, "num_gaussians": n, "grid": list(video.grid),
            "bits_per_gaussian": 8 * size / max(1, frames * n),
            "bpp_at_canvas": 8 * size / max(1, frames * video.canvas_width * video.canvas_height),
            "source": video.source}


def _format_info(info: dict) -> str:
    lines = [f"{info['path']}: {info['format']} Gaussian video"
             + (f" (version {info['version']})" if "version" in info else "")]
    lines.append(f"  canvas       {info['canvas'][0]} x {info['canvas'][1]}, grid {info['grid'][0]} x {info['grid'][1]}")
    lines.append(f"  frames       {info['num_frames']} at {info['fps']:g} fps ({info['duration_s']:.2f} s)")
    lines.append(f"  gaussians    {info['num_gaussians']} per frame")
    lines.append(f"  size         {info['file_bytes']} bytes, {info['bits_per_gaussian']:.2f} bits per Gaussian, "
                 f"{info['bpp_at_canvas']:.4f} bits per canvas pixel")
    if "bits" in info:
        lines.append(f"  bits         {' '.join(str(b) for b in info['bits'])} (x y sx sy rot r g b)")
        lines.append(f"  groups       {info['groups']} of up to {info['group_size']} frames "
                     f"({info['group_bytes']['min']}..{info['group_bytes']['max']} bytes)")
        for name, (lo, hi) in info["ranges"].items():
            lines.append(f"  range {name:<8} [{lo:.6g}, {hi:.6g}]")
    if info.get("verified"):
        lines.append(f"  verified     all checksums and groups decode ({info['decode_fps']:.0f} frames/s)")
    source = info.get("source") or {}
    for key in ("path", "encoder", "size"):
        if key in source:
            lines.append(f"  source.{key:<6} {source[key]}")
    return "\n".join(lines)


def _info_command(args) -> None:
    info = clip_info(args.clip, verify=args.verify)
    print(json.dumps(info, indent=2, default=str) if args.json else _format_info(info))


def _export_usd_command(args) -> None:
    from .clip_io import load_clip
    from .usd_io import export_usd
    video = load_clip(args.clip)
    export_usd(video, args.output, start_frame=args.start_frame)
    print(f"{args.output}: {video.num_frames} frames x {video.num_gaussians} Gaussians "
          f"(frames {args.start_frame}..{args.start_frame + video.num_frames - 1} at {video.fps:g} fps)")


def _import_usd_command(args) -> None:
    from .clip_io import save_clip
    from .usd_io import import_usd
    video = import_usd(args.usd, prim_path=args.prim)
    options = {"bits": args.bits} if Path(args.output).suffix.lower() == ".hgs" else {}
    save_clip(video, args.output, **options)
    print(f"{args.output}: {video.num_frames} frames x {video.num_gaussians} Gaussians")


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("info", help="describe a Gaussian video file (.hgs, .npz, .usd)")
    p.add_argument("clip")
    p.add_argument("--verify", action="store_true", help="also check every checksum and decode every group")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_info_command)

    p = subparsers.add_parser("export-usd", help="Gaussian video file -> USD (UsdGeomPoints, a time sample per frame)")
    p.add_argument("clip")
    p.add_argument("output", help="out.usd / .usda / .usdc")
    p.add_argument("--start-frame", type=int, default=1, help="time code of the first frame (default 1)")
    p.set_defaults(func=_export_usd_command)

    p = subparsers.add_parser("import-usd", help="USD written by export-usd -> Gaussian video file")
    p.add_argument("usd")
    p.add_argument("output", help="clip.hgs / .npz")
    p.add_argument("--prim", default=None, help="path of the Points prim (default: the one with HyperGS metadata)")
    p.add_argument("--bits", type=int, default=8, choices=[4, 6, 8], help="quantization bits (.hgs)")
    p.set_defaults(func=_import_usd_command)


# ---- rate-distortion bench ---------------------------------------------------------------------------

def machine_description() -> dict:
    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo") as f:
            for line in f:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import av
    return {"cpu": cpu, "cores": os.cpu_count(), "os": platform.platform(), "python": platform.python_version(),
            "numpy": np.__version__, "pyav": av.__version__,
            "libavcodec": ".".join(str(v) for v in av.library_versions.get("libavcodec", ()))}


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


def _render(video) -> np.ndarray:
    from .render import render_frames
    return render_frames(video, video.canvas_width, video.canvas_height)


def resolve_encoder(name: str = "auto"):
    """('floor' | 'network', encoder). 'auto': the trained network when it loads, else the floor."""
    from .encode import FloorEncoder, default_encoder
    if name == "floor":
        return "floor", FloorEncoder()
    try:
        return "network", default_encoder()
    except Exception as e:  # noqa: BLE001 - any failure to load the network falls back (auto) or reports
        if name == "network":
            raise HyperGSError(f"the trained network is not available ({e})") from e
        return "floor", FloorEncoder()


def bench_codec(videos, gaussians=DEFAULT_GAUSSIANS, bits=DEFAULT_BITS, crfs=DEFAULT_CRFS, size: int = 256,
                num_frames: int | None = None, encoder="auto", codec: str = "libx265", preset: str = "medium",
                group_size: int = 16, position_bits: int | None = None, progress=None) -> dict:
    """Rate-distortion of the .hgs codec next to an FFmpeg codec on the same frames at the same size.

    For each video: frames short-side resized and centre-cropped to size x size. Reference rows: the
    FFmpeg codec (libx265, else libx264) at each CRF, yuv420p in mp4: bpp (file bits per pixel per frame),
    PSNR (RGB, per frame, averaged), encode and decode frames/s. Gaussian rows: for each N, the encoder's
    Gaussians rendered without quantization (float32), then through .hgs at each bit depth: bpp, PSNR,
    encode frames/s (encoder + .hgs write), decode frames/s (.hgs read + render), plus the .hgs size with
    each forced residual mode and the Gaussian-order stability. position_bits: also code each bit depth
    with the means (x, y) at this many bits (rows with `bits` as 8 values). encoder: 'auto' | 'network' |
    'floor' or an object with predict()/canvas/clip_frames."""
    from .encode import encode_frames
    from .gaussians import GaussianVideo
    from .codec import MODES, order_stability
    from .hgs import load_hgs, save_hgs
    from .metrics import psnr
    from .video import read_clip

    if isinstance(encoder, str):
        encoder_name, encoder = resolve_encoder(encoder)
    else:
        encoder_name = getattr(encoder, "name", type(encoder).__name__)
    notes = []
    if not video_codec_available(codec):
        fallback = "libx264"
        notes.append(f"{codec} is not in PyAV's FFmpeg; used {fallback}")
        codec = fallback
    say = progress or (lambda message: None)
    depths = list(bits)
    if position_bits:
        depths += [(position_bits,) * 2 + (b,) * 6 for b in bits if b != position_bits]
    result = {"machine": machine_description(),
              "settings": {"size": size, "num_frames": num_frames, "encoder": encoder_name, "codec": codec,
                           "preset": preset, "crfs": list(crfs), "bits": list(bits), "gaussians": list(gaussians),
                           "group_size": group_size, "position_bits": position_bits},
              "notes": notes, "videos": []}
    with tempfile.TemporaryDirectory(prefix="hypergs-bench-") as tmp:
        clip_path = Path(tmp) / "clip.hgs"
        for path in videos:
            frames, info, indices = read_clip(path, num_frames, size=size)
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
                _render(GaussianVideo(encode_frames(frames[:1], encoder, n, 1), w, h))  # warm-up (JIT)
                started = time.perf_counter()
                params = encode_frames(frames, encoder, n, 1)
                encoder_s = time.perf_counter() - started
                video = GaussianVideo(params, w, h, info.fps, (1, 1), {"path": str(path), "frames": indices})
                started = time.perf_counter()
                rendered = _render(video)
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
                    rendered = _render(decoded)
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


def bench_codec_cli(parser):
    """Options of `hypergs bench codec` (bench.py's BENCH_COMMANDS contract: add the options, return
    args -> report dict; `--json` is bench.py's). The report carries its Markdown table under "table"."""
    parser.add_argument("videos", nargs="+")
    parser.add_argument("--gaussians", type=int, nargs="+", default=list(DEFAULT_GAUSSIANS))
    parser.add_argument("--bits", type=int, nargs="+", default=list(DEFAULT_BITS), choices=[4, 6, 8])
    parser.add_argument("--crf", type=int, nargs="+", default=list(DEFAULT_CRFS))
    parser.add_argument("--size", type=int, default=256, help="square frame size (short-side resize + centre crop)")
    parser.add_argument("--frames", type=int, default=None, help="frames sampled uniformly (default: all)")
    parser.add_argument("--encoder", default="auto", choices=["auto", "network", "floor"],
                        help="Gaussians from the trained network or the grid floor (auto: the network when it loads)")
    parser.add_argument("--codec", default="libx265", help="FFmpeg reference encoder (libx264 when libx265 is missing)")
    parser.add_argument("--preset", default="medium")
    parser.add_argument("--group-size", type=int, default=16)
    parser.add_argument("--position-bits", type=int, default=10,
                        help="also rows with the means at this many bits (0: none)")
    parser.add_argument("-o", "--output", default=None, help="also write the JSON report here")

    def run(args) -> dict:
        report = bench_codec(args.videos, args.gaussians, args.bits, args.crf, args.size, args.frames, args.encoder,
                             args.codec, args.preset, args.group_size, args.position_bits or None,
                             progress=lambda message: print(message, file=sys.stderr))
        report["table"] = format_codec_table(report)
        if args.output:
            Path(args.output).write_text(json.dumps(report, indent=2))
        return report
    return run
