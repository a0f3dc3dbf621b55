"""Session 19's stride-8 ablation (model card): the bundled stride-4 conv network as a stride-8 one that
starts as exactly the same function. The stride-8 stem reads each cell's 8 x 8 pixels (pixel-unshuffle
by 8); its filters are the stride-4 stem's spread over each 2 x 2 sub-block (divided by 4), so on a frame
it gives what the stride-4 network gives on the frame box-downsampled by 2. The trunk (blocks, head) is
shared as it is. Checks the equivalence on random frames, then writes the weights for `--init-from`:

    python tools/stride8_init.py hypergs_blender/weights/hypergs.safetensors runs/s19/stride8_init.safetensors
    hypergs train --out runs/s19/s8a --preset conv --config stride=8 --size 256 \
        --init-from runs/s19/stride8_init.safetensors ...
"""
from __future__ import annotations

import sys
from dataclasses import replace

import torch
import torch.nn.functional as F
from safetensors.torch import load_file, save_file

from hypergs_blender.model import PRESETS, ConvGS


def spread(weight: torch.Tensor, stride: int = 4) -> torch.Tensor:
    """[out, 3 s s, kh, kw] filters over a stride-s pixel-unshuffle -> [out, 3 (2s)^2, kh, kw] over stride 2s."""
    o, _, kh, kw = weight.shape
    expanded = weight.reshape(o, 3, stride, 1, stride, 1, kh, kw).expand(o, 3, stride, 2, stride, 2, kh, kw)
    return (expanded / 4).reshape(o, 3 * 4 * stride * stride, kh, kw).contiguous()


def main() -> None:
    source, out = sys.argv[1:3]
    weights = load_file(source)
    wide = dict(weights, **{k: spread(weights[k]) for k in ("stem.1.weight", "cell_pixels.weight")})
    narrow_model, wide_model = ConvGS(PRESETS["conv"]), ConvGS(replace(PRESETS["conv"], stride=8))
    narrow_model.load_state_dict(weights)
    wide_model.load_state_dict(wide)
    frames = torch.rand(2, 256, 256, 3)
    with torch.no_grad():
        a = narrow_model(F.avg_pool2d(frames.permute(0, 3, 1, 2), 2).permute(0, 2, 3, 1))
        b = wide_model(frames)
    b[..., 2:4] /= 2  # scales in pixels of a canvas twice as large
    print(f"largest difference from the stride-4 network on the 2x-downsampled frames: {(a - b).abs().max():.2e}")
    save_file(wide, out)


if __name__ == "__main__":
    main()
