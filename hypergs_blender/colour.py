"""The sRGB transfer function, extended to all reals (odd, and the standard formula above 1), so that
additive sums outside [0, 1] convert both ways without clipping; and HDR video (BT.2100 HLG or PQ, BT.2020
primaries) to the sRGB picture Blender 5's Sequencer shows of it."""
from __future__ import annotations

import functools

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


# BT.2100 HLG's inverse OETF (ARIB STD-B67) and its OOTF for a 1000-nit display
HLG_A, HLG_B, HLG_C = 0.17883277, 0.28466892, 0.55991073
HLG_PEAK_NITS, HLG_GAMMA = 1000.0, 1.2
# SMPTE ST 2084 (PQ)
PQ_M1, PQ_M2, PQ_C1, PQ_C2, PQ_C3 = 2610 / 16384, 2523 / 4096 * 128, 3424 / 4096, 2413 / 4096 * 32, 2392 / 4096 * 32
SDR_WHITE_NITS = 100.0  # Blender's colour management: scene-linear 1.0 is 100 nits on its HDR display spaces
BT2020_TO_BT709 = np.array([[1.6605, -0.5876, -0.0728],  # linear RGB, the primaries of BT.2020 to sRGB's
                            [-0.1246, 1.1329, -0.0083],
                            [-0.0182, -0.1006, 1.1187]], np.float32)
BT2020_LUMA = np.array([0.2627, 0.6780, 0.0593], np.float32)


def hdr_light(coded, transfer: str) -> np.ndarray:
    """HDR video's coded values in [0, 1] -> their light, float64: HLG's scene light E in [0, 1] (the inverse OETF),
    PQ's in nits / 100 (the EOTF; 100 nits is 1.0)."""
    e = np.clip(np.asarray(coded, np.float64), 0, 1)  # float64: PQ's 1/78.8 power of float32 loses levels
    if transfer == "hlg":
        return np.where(e <= 0.5, e * e / 3, (np.exp((np.maximum(e, 0.5) - HLG_C) / HLG_A) + HLG_B) / 12)
    if transfer == "pq":
        p = e ** (1 / PQ_M2)
        return 10000 / SDR_WHITE_NITS * (np.maximum(p - PQ_C1, 0) / (PQ_C2 - PQ_C3 * p)) ** (1 / PQ_M1)
    raise ValueError(f"unknown HDR transfer {transfer!r} (hlg or pq)")


def display_linear(light: np.ndarray, transfer: str) -> np.ndarray:
    """`hdr_light`'s [..., 3] -> linear sRGB, 1.0 at 100 nits: HLG through its OOTF for a 1000-nit display, then
    BT.2020's primaries to BT.709's."""
    if transfer == "hlg":
        luma = np.maximum(light @ BT2020_LUMA, 1e-12)
        light = light * (HLG_PEAK_NITS / SDR_WHITE_NITS * luma ** (HLG_GAMMA - 1))[..., None]
    return light @ BT2020_TO_BT709.T


def hdr_to_srgb(coded: np.ndarray, transfer: str) -> np.ndarray:
    """HDR video's decoded RGB [..., 3] in [0, 1] (`transfer` "hlg" or "pq"; BT.2020 primaries) -> the sRGB-encoded
    values in [0, 1] that Blender 5 shows of it: its light in nits, 100 nits to 1.0, BT.2020 to BT.709 primaries,
    clipped, sRGB-encoded (Blender 4.2 shows the coded values as they are). The formulas: the reference of
    `hdr_to_srgb_u8`."""
    return linear_to_srgb(np.clip(display_linear(hdr_light(coded, transfer), transfer), 0, 1))


OUTPUT_STEPS = 16383  # linear light in [0, 1] in this many steps before the sRGB table: under 0.25 of an 8-bit level


@functools.lru_cache(maxsize=None)
def _hdr_tables(transfer: str) -> tuple[np.ndarray, np.ndarray]:
    """(each 16-bit code's `hdr_light`, float32; linear light's sRGB uint8 in OUTPUT_STEPS)."""
    light = hdr_light(np.arange(65536) / 65535, transfer).astype(np.float32)
    return light, np.round(linear_to_srgb(np.linspace(0, 1, OUTPUT_STEPS + 1)) * 255).astype(np.uint8)


def hdr_to_srgb_u8(coded: np.ndarray, transfer: str) -> np.ndarray:
    """`hdr_to_srgb` of 16-bit coded values (uint16 [..., 3]) as uint8, through tables of the transfer functions:
    the decode's fast path (a 1080p frame in a fraction of the formulas' time), within a level of them."""
    light, srgb = _hdr_tables(transfer)
    linear = display_linear(light[coded], transfer)
    return srgb[np.clip(linear * OUTPUT_STEPS + 0.5, 0, OUTPUT_STEPS).astype(np.int32)]
