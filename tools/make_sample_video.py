"""Make the bundled sample clip hypergs_blender/samples/sample.mp4: 2.5 s of procedural moving
coloured shapes (256 x 144, 24 fps, H.264), drawn with numpy and encoded with PyAV. Deterministic.

    python tools/make_sample_video.py [--out hypergs_blender/samples/sample.mp4]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import av
import numpy as np

WIDTH, HEIGHT, FPS, FRAMES = 256, 144, 24, 60
OUT = Path(__file__).resolve().parents[1] / "hypergs_blender" / "samples" / "sample.mp4"


def _coverage(distance: np.ndarray) -> np.ndarray:
    """Anti-aliased coverage from a signed distance in pixels (negative inside)."""
    return np.clip(0.5 - distance, 0.0, 1.0)[..., None]


def frame(t: float) -> np.ndarray:
    """RGB uint8 [HEIGHT, WIDTH, 3] at time t in [0, 1)."""
    y, x = np.mgrid[0:HEIGHT, 0:WIDTH].astype(np.float32) + 0.5
    # background: a slowly drifting diagonal gradient
    phase = 2 * np.pi * t
    bg = np.stack([0.15 + 0.25 * x / WIDTH, 0.2 + 0.2 * y / HEIGHT,
                   0.45 + 0.15 * np.sin(x / 40 + phase)], -1)
    img = bg
    # a red disc moving on an ellipse
    cx, cy = WIDTH * (0.5 + 0.3 * np.cos(phase)), HEIGHT * (0.5 + 0.25 * np.sin(phase))
    img = img * (1 - (a := _coverage(np.hypot(x - cx, y - cy) - 22))) + a * np.array([0.9, 0.2, 0.15])
    # a yellow square turning in place
    ang = phase / 2
    u = (x - 0.3 * WIDTH) * np.cos(ang) + (y - 0.35 * HEIGHT) * np.sin(ang)
    v = -(x - 0.3 * WIDTH) * np.sin(ang) + (y - 0.35 * HEIGHT) * np.cos(ang)
    img = img * (1 - (a := _coverage(np.maximum(np.abs(u), np.abs(v)) - 16))) + a * np.array([0.95, 0.85, 0.2])
    # a green bar sweeping left to right
    bx = WIDTH * (0.1 + 0.8 * t)
    img = img * (1 - (a := _coverage(np.maximum(np.abs(x - bx) - 6, np.abs(y - 0.75 * HEIGHT) - 18)))) \
        + a * np.array([0.2, 0.8, 0.35])
    return (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=str(OUT))
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(out), "w") as container:
        stream = container.add_stream("libx264", rate=FPS)
        stream.width, stream.height, stream.pix_fmt = WIDTH, HEIGHT, "yuv420p"
        stream.options = {"crf": "16", "preset": "slow"}
        container.metadata["comment"] = "HyperGS sample, tools/make_sample_video.py"
        for i in range(FRAMES):
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame(i / FRAMES), format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    print(out, out.stat().st_size, "bytes")


if __name__ == "__main__":
    main()
