from pathlib import Path

import math

import av
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def write_video(path, frames, fps=12, rotation=0, slots=None, hdr=None):
    """Lossless H.264 (yuv444p, crf 0) of uint8 RGB frames [T, H, W, 3], stored as they are with a display
    rotation of `rotation` degrees counter-clockwise in the container (a phone's portrait video: 90 or 270).
    slots: each frame's time in 1 / fps seconds (a variable-rate video where they skip some; default 0, 1, ...).
    hdr: "hlg" or "pq": the values tagged as that HDR transfer with BT.2020 primaries and matrix (an iPhone's)."""
    from fractions import Fraction
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps, options={"crf": "0"})
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], "yuv444p"
        if rotation:
            stream.set_display_rotation(rotation)
        if hdr:
            from hypergs_blender.io.video import BT2020_PRIMARIES, HDR_TRANSFERS
            codec = stream.codec_context
            codec.color_primaries, codec.colorspace = BT2020_PRIMARIES, 9  # AVCOL_SPC_BT2020_NCL
            codec.color_trc = next(code for code, name in HDR_TRANSFERS.items() if name == hdr)
        for f, slot in zip(frames, range(len(frames)) if slots is None else slots):
            frame = av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")
            frame.pts, frame.time_base = slot, Fraction(1, fps)
            container.mux(stream.encode(frame))
        container.mux(stream.encode())
    return path


def write_image_tagged(path, pixels, **attributes):
    """uint8 pixels [H, W, C] written by OpenImageIO as they are, with these attributes in the file's
    header (Orientation=6: a phone photo's "rotate 90"; oiio:UnassociatedAlpha=1: straight alpha)."""
    import OpenImageIO as oiio
    spec = oiio.ImageSpec(pixels.shape[1], pixels.shape[0], pixels.shape[2], oiio.UINT8)
    for name, value in attributes.items():
        spec.attribute(name, value)
    out = oiio.ImageOutput.create(str(path))
    out.open(str(path), spec)
    out.write_image(np.ascontiguousarray(pixels))
    out.close()
    return path


@pytest.fixture
def moving_video(tmp_path):
    """12 frames 64 x 48: a bright square moving right over a horizontal gradient."""
    frames = np.zeros((12, 48, 64, 3), np.uint8)
    frames[..., 0] = np.linspace(20, 200, 64, dtype=np.uint8)[None, None, :]
    for t in range(12):
        frames[t, 12:28, 4 + 3 * t:20 + 3 * t] = (250, 240, 60)
    return write_video(tmp_path / "moving.mp4", frames)


def make_pan_clip(path, width=432, height=240, frames=70):
    """A real-looking test movie: a camera pan over a procedural image (H.264 yuv420p, 24 fps, crf 18),
    the size of the DAVIS clips; its mdat comes before its moov."""
    from hypergs_blender.bench.scale import make_pan_video
    make_pan_video(path, seconds=frames / 24, width=width, height=height, fps=24, crf=18)
    return path


def random_params(rng, t, n, canvas=64):
    p = np.empty((t, n, 8), np.float32)
    p[..., 0:2] = rng.uniform(-1, 1, (t, n, 2))
    p[..., 2:4] = np.exp(rng.uniform(math.log(0.3), math.log(canvas / 4), (t, n, 2)))
    p[..., 4] = rng.uniform(0, 2 * np.pi, (t, n))
    p[..., 5:8] = rng.uniform(-0.5, 1.5, (t, n, 3))
    return p


def moving_params(rng, t, n, canvas=64):
    """Gaussians that drift slowly, like a real clip (residuals are small)."""
    p = np.repeat(random_params(rng, 1, n, canvas), t, axis=0)
    p[..., 0:2] += np.cumsum(rng.normal(0, 0.005, (t, n, 2)), axis=0)
    p[..., 5:8] += np.cumsum(rng.normal(0, 0.01, (t, n, 3)), axis=0)
    return p


def hard_params(n, seed=0, invalid=True):
    """Anisotropic Gaussians on a canvas: some off the image, needles (aspect 300), tiny and huge ones,
    negative colours, and (`invalid`) two invalid ones (zero or NaN scale)."""
    rng = np.random.default_rng(seed)
    p = np.empty((n, 8), np.float32)
    p[:, 0:2] = rng.uniform(-1.4, 1.4, (n, 2))
    p[:, 2:4] = np.exp(rng.uniform(np.log(0.05), np.log(12), (n, 2)))
    p[:, 4] = rng.uniform(0, 2 * np.pi, n)
    p[:, 5:8] = rng.uniform(-0.1, 0.4, (n, 3))
    p[:8, 2:4] = [[15, 0.05]] * 8  # needles
    p[8, 2:4] = [400, 300]  # larger than the image, centre off it
    p[8, 0:2] = [1.5, -1.2]
    p[9, 0:2] = [9.0, 0.0]  # far off
    if invalid:
        p[10, 2] = 0.0  # l11 = 0
        p[11, 3] = np.nan
    return p


def random_conv(cfg, seed: int = 0, error_strength: float = 0.05):
    """A conv network with every block, every way back up from a coarser level and the heads away from
    their zero initialisation (the error pass's by error_strength); cfg: a model.ConvConfig."""
    import torch

    from hypergs_blender.model import ConvGS
    torch.manual_seed(seed)
    model = ConvGS(cfg)
    with torch.no_grad():
        model.head.weight.normal_(0, 0.05)
        for up in model.up:
            up.weight.normal_(0, 0.2)
        for block in [b for level in model.encoder for b in level] + list(model.decoder):
            block.b.weight.normal_(0, 0.05)
        if model.error_pass is not None:
            model.error_pass.head.weight.normal_(0, error_strength)
            for block in model.error_pass.blocks:
                block.b.weight.normal_(0, error_strength)
    return model.eval()


def training_args(out, steps, preset, minutes=None, loader_threads=1):
    """`hypergs train`'s arguments for a few steps of a tiny run on procedural data."""
    import argparse

    from hypergs_blender.commands import train as train_commands
    parser = argparse.ArgumentParser()
    train_commands.add_commands(parser.add_subparsers())
    argv = ["train", "--out", str(out), "--preset", preset, "--data", "procedural:1", "--steps", str(steps),
            "--batch", "2", "--size", "32", "--gaussians", "16:64", "--log-every", "1", "--eval-every", "1000",
            "--checkpoint-every", "2", "--warmup", "2", "--loader-threads", str(loader_threads)]
    argv += [] if minutes is None else ["--minutes", str(minutes)]
    return parser.parse_args(argv)
