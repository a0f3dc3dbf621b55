"""`hypergs bench picture`: what a user sees, as Blender does it: a video encoded at its own resolution
with each quality preset (encode.QUALITY), rendered at another size (864 x 480 by default), next to the
source resized to that size; PSNR and seconds per frame of each preset, and a picture (source | each
preset, with two enlarged crops) for docs/."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..encode import QUALITY, encode_frames, frames_layout
from ..io.frames import read_frames
from ..io.images import resize_exact
from ..metrics import psnr
from ..network import resolve_encoder
from ..render import render_params
from .common import machine_report, timed


def bench_presets(video, presets=tuple(QUALITY), width: int = 864, height: int = 480, frames: int = 4,
                  encoder="network", crop: int | None = None) -> dict:
    """Encode `frames` consecutive frames of `video` (a crop x crop centre crop when given) at its own
    resolution with each preset, render at width x height, and compare with the source resized so."""
    if isinstance(encoder, str):
        encoder = resolve_encoder(encoder)
    source, info, indices = read_frames(video, None, 0, frames)
    if crop:
        h, w = source.shape[1:3]
        source = np.ascontiguousarray(source[:, (h - crop) // 2:(h + crop) // 2, (w - crop) // 2:(w + crop) // 2])
    t, h, w = source.shape[:3]
    target = np.stack([resize_exact(f, width, height) for f in source])
    report = {"bench": "picture", "machine": machine_report(), "video": str(video), "source_size": [w, h],
              "render_size": [width, height], "frames": t, "encoder": encoder.name, "presets": {}}
    renders = {}
    for name in presets:
        setting = QUALITY[name]
        layout = frames_layout(source, encoder, cell=setting["cell"])

        def encode():
            return encode_frames(source, encoder, layout, setting["refine"])
        encode()  # warm-up (JIT, shapes)
        seconds, params = timed(encode)
        rendered = render_params(params, w, h, width, height)
        renders[name] = rendered
        report["presets"][name] = {"cell": setting["cell"], "refine": setting["refine"], "gaussians": layout.count,
                                   "seconds_per_frame": seconds / t,
                                   "psnr": float(np.mean(psnr(rendered, target / np.float32(255))))}
    report["_renders"], report["_target"] = renders, target
    return report


def save_picture(report: dict, path, crop_size: int = 96) -> Path:
    """Source | each preset for the first frame, with two enlarged crops (the most detailed spots)."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    target = report["_target"][0]
    images = [("source", target / 255.0)] + [
        (f"{name}: {p['gaussians']} Gaussians (cell {p['cell']:g} px{', refine ' + str(p['refine']) if p['refine'] else ''})"
         f"\n{p['psnr']:.2f} dB, {p['seconds_per_frame']:.2f} s/frame", np.clip(report["_renders"][name][0], 0, 1))
        for name, p in report["presets"].items()]
    spots = _detailed_spots(target, crop_size)
    fig, axes = plt.subplots(1 + len(spots), len(images), figsize=(4.4 * len(images), 2.6 + 2.3 * len(spots)),
                             gridspec_kw={"height_ratios": [target.shape[0] / target.shape[1] * 2] + [1] * len(spots)},
                             squeeze=False)
    for col, (title, image) in enumerate(images):
        axes[0, col].imshow(image)
        axes[0, col].set_title(title, fontsize=8)
        for row, (y, x) in enumerate(spots, start=1):
            axes[0, col].add_patch(plt.Rectangle((x, y), crop_size, crop_size, fill=False, color="yellow", lw=0.8))
            axes[row, col].imshow(image[y:y + crop_size, x:x + crop_size], interpolation="nearest")
        for ax in axes[:, col]:
            ax.set_xticks([])
            ax.set_yticks([])
    w, h = report["render_size"]
    sw, sh = report["source_size"]
    fig.suptitle(f"{Path(report['video']).name}: encoded at {sw}x{sh}, rendered at {w}x{h} "
                 f"(encoder {report['encoder']}; {report['machine']['date'][:10]})", fontsize=9)
    fig.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _detailed_spots(image: np.ndarray, size: int, count: int = 2) -> list[tuple[int, int]]:
    """Top-left corners of the `count` most detailed non-overlapping size x size blocks."""
    grey = image.astype(np.float32).mean(-1)
    h, w = grey.shape
    detail = np.abs(np.diff(grey, axis=0))[:, :-1] + np.abs(np.diff(grey, axis=1))[:-1, :]
    scores = [(detail[y:y + size, x:x + size].mean(), y, x) for y in range(0, h - size, size // 2)
              for x in range(0, w - size, size // 2)]
    spots = []
    for _, y, x in sorted(scores, reverse=True):
        if all(abs(y - sy) >= size or abs(x - sx) >= size for sy, sx in spots):
            spots.append((y, x))
        if len(spots) == count:
            break
    return spots

