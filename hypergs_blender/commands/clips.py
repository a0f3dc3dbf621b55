"""Gaussian video files: `hypergs info`, `hypergs export-usd`, `hypergs import-usd`."""
from __future__ import annotations

import json
import time
from pathlib import Path

from ..io.clips import CLIP_SUFFIXES
from ..io.usd import USD_SUFFIXES
from . import options


# ---- info, export-usd, import-usd ------------------------------------------------------------------

def clip_info(path, verify: bool = False) -> dict:
    """What `hypergs info` prints: header fields for .hgs (without decoding unless verify), basic
    figures for the other formats."""
    path = Path(path)
    if path.suffix.lower() == ".hgs":
        from ..io.hgs import HgsReader
        with HgsReader(path) as reader:
            info = reader.info()
            if verify:
                started = time.perf_counter()
                reader.verify()
                info["verified"] = True
                info["decode_fps"] = reader.num_frames / max(time.perf_counter() - started, 1e-9)
        return info
    from ..io.clips import load_clip
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
    if "codec" in info:
        lines.append(f"  codec        {info['codec']}")
    if "groups" in info:
        lines.append(f"  groups       {info['groups']} of up to {info['group_size']} frames "
                     f"({info['group_bytes']['min']}..{info['group_bytes']['max']} bytes)")
    if "bits" in info:
        lines.append(f"  bits         {' '.join(str(b) for b in info['bits'])} (x y sx sy rot r g b)")
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
    from ..io.clips import load_clip, save_clip
    video = load_clip(args.clip)
    save_clip(video, args.output, start_frame=args.start_frame)
    print(f"{args.output}: {video.num_frames} frames x {video.num_gaussians} Gaussians "
          f"(frames {args.start_frame}..{args.start_frame + video.num_frames - 1} at {video.fps:g} fps)")


def _import_usd_command(args) -> None:
    from ..io.clips import save_clip
    from ..io.usd import import_usd
    video = import_usd(args.usd, prim_path=args.prim)
    options = {"bits": args.bits} if Path(args.output).suffix.lower() == ".hgs" else {}
    save_clip(video, args.output, **options)
    print(f"{args.output}: {video.num_frames} frames x {video.num_gaussians} Gaussians")


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("info", help="describe a Gaussian video file (.hgs, .npz, .usd)")
    p.add_argument("clip", type=options.InputFile(CLIP_SUFFIXES))
    p.add_argument("--verify", action="store_true", help="also check every checksum and decode every group")
    p.add_argument("--json", action="store_true")
    p.set_defaults(func=_info_command)

    p = subparsers.add_parser("export-usd", help="Gaussian video file -> USD (UsdGeomPoints, a time sample per frame)")
    p.add_argument("clip", type=options.InputFile(CLIP_SUFFIXES))
    p.add_argument("output", type=options.OutputFile(USD_SUFFIXES), help="out.usd / .usda / .usdc")
    p.add_argument("--start-frame", type=options.Integer(-options.BIGGEST), default=1,
                   help="time code of the first frame (default 1)")
    p.set_defaults(func=_export_usd_command)

    p = subparsers.add_parser("import-usd", help="USD written by export-usd -> Gaussian video file")
    p.add_argument("usd", type=options.InputFile(USD_SUFFIXES))
    p.add_argument("output", type=options.OutputFile(CLIP_SUFFIXES), help="clip.hgs / .npz")
    p.add_argument("--prim", default=None, type=options.text,
                   help="path of the Points prim (default: the one with HyperGS metadata)")
    p.add_argument("--bits", type=int, default=8, choices=[4, 6, 8], help="quantization bits (.hgs)")
    p.set_defaults(func=_import_usd_command)
