"""The part of the error that repeats at the cell period: encode centre crops at the video's own
resolution (as `hypergs eval --crop C --gaussians N --frames F`), render them, fold render minus source
(in /255) by each pixel's phase in its cell, and print per video the PSNR, the error's rms, the rms of its
periodic part (the folded means, less their mean) and the mean error per channel.

    python tools/cell_pattern.py runs/heldout720/Aqua.mp4 runs/heldout720/LadyBird.mp4 [--weights DIR]

It measures the installed `hypergs_blender`; `PYTHONPATH=TREE` measures another tree's (a worktree with
other constants), whose render box the weights must be for (the runtime refuses others).
"""
from __future__ import annotations

import argparse
import os


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("videos", nargs="+")
    parser.add_argument("--weights", default=None, help="a network's folder or card (default: the bundled one)")
    parser.add_argument("--crop", type=int, default=480)
    parser.add_argument("--gaussians", type=int, default=16000)
    parser.add_argument("--frames", type=int, default=4)
    parser.add_argument("--bins", type=int, default=4, help="phases per cell side")
    args = parser.parse_args()

    import numpy as np

    from hypergs_blender import metrics
    from hypergs_blender.encode import EncodeSettings
    from hypergs_blender.evaluate import encode_render, read_eval_frames
    from hypergs_blender.network import resolve_encoder

    encoder = resolve_encoder("network", backend="torch", weights=args.weights)
    settings = EncodeSettings(gaussians=args.gaussians)
    for path in args.videos:
        source = read_eval_frames(path, args.frames, size=None, crop=args.crop)
        t, h, w = source.shape[:3]
        layout = settings.layout(w, h, encoder)
        rendered, _, _ = encode_render(source, encoder, layout)
        rendered = np.clip(rendered, 0, 1)
        target = source / np.float32(255)
        error = (rendered - target) * 255
        rows, cols = np.arange(h)[:, None], np.arange(w)[None, :]
        folded = np.stack([metrics.cell_phase_means(frame.reshape(-1, 3), rows, cols, layout.cell, args.bins)[1]
                           for frame in error])  # [T, bins^2, 3]
        periodic = folded - folded.mean(1, keepdims=True)
        psnr = float(np.mean(metrics.psnr(rendered, target)))
        print(f"{os.path.basename(path)}: {layout.count} Gaussians (cells of {layout.cell:.2f} px), PSNR {psnr:.3f} dB, "
              f"error rms {np.sqrt((error ** 2).mean()):.3f} /255, periodic part {np.sqrt((periodic ** 2).mean()):.3f}, "
              f"mean RGB {np.array2string(error.mean((0, 1, 2)), precision=3)}", flush=True)


if __name__ == "__main__":
    main()
