"""What the rasterizer's box costs in flat regions: encode videos at a Quality preset with the
bundled network, render them with the Gaussians cut at another box (`--cutoff`, in sigmas), and print
PSNR and the flat ripple (`metrics.flat_ripple`, as `hypergs eval` reports it) per video.

    python tools/cutoff_ripple.py runs/heldout720/*.mp4               # the product's box (raster.SIGMA_CUTOFF)
    python tools/cutoff_ripple.py runs/heldout720/*.mp4 --cutoff 4

The colours are scaled by the ratio of the Gaussian grid's gains at the two boxes (`gaussians.lattice_gain`),
since a wider box adds the tails' mass that the network learned to do without.
Each run compiles the numba kernels with its box in a fresh cache: numba bakes module constants in.
"""
from __future__ import annotations

import argparse
import os
import tempfile

os.environ["NUMBA_CACHE_DIR"] = tempfile.mkdtemp(prefix="hypergs-cutoff-")  # before numba is imported


def periodic_part(rendered, target, cell: float, bins: int = 6) -> float:
    """The std (1/255) of the render's error that repeats at the cell period, in the flat blocks of
    `metrics.flat_ripple` (blocks of 2 cells, as `hypergs eval`'s): each block's mean error removed, the
    rest averaged over the pixels at the same phase in their cell (bins x bins phases)."""
    import numpy as np
    from hypergs_blender import metrics

    k = round(2 * cell)
    error = (np.clip(rendered, 0, 1) - target) * 255
    t, h, w = error.shape[:3]
    hh, ww = h // k * k, w // k * k
    keep = metrics.flat_blocks(target, k)  # [T, h // k, w // k]
    blocks = error[:, :hh, :ww].reshape(t, hh // k, k, ww // k, k, 3)
    residual = blocks - blocks.mean(axis=(2, 4), keepdims=True)
    residual = residual.transpose(0, 1, 3, 2, 4, 5)[keep]  # [blocks, k, k, 3]
    if not len(residual):
        return float("nan")
    ys, xs = np.nonzero(keep)[1:]
    rows = ys[:, None] * k + np.arange(k)[None, :]  # [blocks, k] pixel rows
    cols = xs[:, None] * k + np.arange(k)[None, :]
    phase, folded = metrics.cell_phase_means(residual.reshape(-1, 3), rows[:, :, None], cols[:, None, :], cell, bins)
    return float(folded[phase].std())


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("videos", nargs="+")
    parser.add_argument("--cutoff", type=float, default=None,
                        help="the box's half-width in sigmas (default: the product's)")
    parser.add_argument("--quality", default="standard")
    parser.add_argument("--frames", type=int, default=2, help="whole frames spread over each video")
    args = parser.parse_args()

    import numpy as np
    from hypergs_blender import _raster_numba, metrics, raster
    from hypergs_blender.encode import EncodeSettings, encode_frames
    from hypergs_blender.evaluate import read_eval_frames
    from hypergs_blender.gaussians import COLOUR_GAIN, INITIAL_SIGMA, lattice_gain
    from hypergs_blender.render import render_params
    from hypergs_blender.runtime import make_encoder

    encoder = make_encoder()
    # After every import (COLOUR_GAIN and the network's colours stay the product box's), before the first
    # render (numba compiles the kernels then, with the constant it finds)
    args.cutoff = args.cutoff or raster.SIGMA_CUTOFF
    raster.SIGMA_CUTOFF = _raster_numba.SIGMA_CUTOFF = args.cutoff
    gain = lattice_gain(INITIAL_SIGMA, args.cutoff) / COLOUR_GAIN
    settings = EncodeSettings.choose(quality=args.quality, refine=0)
    for path in args.videos:
        source = read_eval_frames(path, args.frames, size=None)
        h, w = source.shape[1:3]
        layout = settings.layout(w, h, encoder)
        params = np.asarray(encode_frames(source, encoder, layout, 0), np.float32)
        params[..., 5:8] *= gain
        rendered = render_params(params, w, h, w, h)
        target = source / np.float32(255)
        ripple = metrics.flat_ripple(rendered, target, window=round(2 * layout.cell))
        psnr = metrics.psnr_from_mse(((np.clip(rendered, 0, 1) - target) ** 2).mean())
        flat = (f"flat ripple {ripple['render_std']:.3f} /255 (source {ripple['source_std']:.3f}, {ripple['blocks']} blocks; "
                f"periodic at the cell: {periodic_part(rendered, target, layout.cell):.3f} /255)"
                if ripple["blocks"] else "no flat blocks")
        print(f"{os.path.basename(path)}: cutoff {args.cutoff:g}, colour gain {gain:.4f}: PSNR {psnr:.2f} dB, {flat}",
              flush=True)


if __name__ == "__main__":
    main()
