"""The sRGB transfer function, extended to all reals (odd, and the standard formula above 1), so that
additive sums outside [0, 1] convert both ways without clipping."""
from __future__ import annotations

import numpy as np


def srgb_to_linear(v) -> np.ndarray:
    """sRGB-encoded values -> scene-linear, float32."""
    v = np.asarray(v, np.float32)
    a = np.abs(v)
    out = np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
    return (np.sign(v) * out).astype(np.float32)


def linear_to_srgb(v) -> np.ndarray:
    """Inverse of `srgb_to_linear`."""
    v = np.asarray(v, np.float32)
    a = np.abs(v)
    out = np.where(a <= 0.0031308, a * 12.92, 1.055 * a ** (1 / 2.4) - 0.055)
    return (np.sign(v) * out).astype(np.float32)


def srgb_image_to_linear_rgba(image: np.ndarray) -> np.ndarray:
    """An sRGB-encoded [H, W, 3] sum -> scene-linear RGBA float32 [H, W, 4], rows bottom to top
    (a Blender render pass). Negative sums clip to 0; values above 1 are kept."""
    h, w = image.shape[:2]
    out = np.ones((h, w, 4), np.float32)
    out[..., :3] = srgb_to_linear(np.maximum(image, 0))[::-1]
    return out
