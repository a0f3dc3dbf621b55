"""hypergs_blender/colour.py's HDR video mapping against the BT.2100 / ST 2084 formulas written out for one value."""
import math

import numpy as np
import pytest

from hypergs_blender.colour import hdr_to_srgb, hdr_to_srgb_u8, linear_to_srgb


def hlg_inverse_oetf(e: float) -> float:  # BT.2100, written out for one value
    a, b, c = 0.17883277, 0.28466892, 0.55991073
    return e * e / 3 if e <= 0.5 else (math.exp((e - c) / a) + b) / 12


def pq_eotf_nits(e: float) -> float:  # SMPTE ST 2084
    m1, m2, c1, c2, c3 = 2610 / 16384, 2523 / 32, 3424 / 4096, 2413 / 128, 2392 / 128
    p = e ** (1 / m2)
    return 10000 * (max(p - c1, 0) / (c2 - c3 * p)) ** (1 / m1)


@pytest.mark.parametrize("transfer,coded", [("hlg", 0.0), ("hlg", 0.3), ("hlg", 0.5), ("hlg", 0.6),
                                            ("pq", 0.0), ("pq", 0.3), ("pq", 0.45), ("pq", 0.5081)])
def test_hdr_to_srgb_maps_grey_light_as_blender_5(transfer, coded):
    """A grey of HDR video: its light in nits (HLG through the 1000-nit OOTF, Lw Y^0.2 E), 100 nits as 1.0,
    sRGB-encoded and clipped; a grey stays grey across the primaries' conversion (its rows sum to 1)."""
    if transfer == "hlg":
        nits = 1000 * hlg_inverse_oetf(coded) ** 1.2
    else:
        nits = pq_eotf_nits(coded)
    expected = float(linear_to_srgb(np.float32(min(nits / 100, 1.0))))
    got = hdr_to_srgb(np.full((1, 3), coded, np.float32), transfer)[0]
    np.testing.assert_allclose(got, expected, atol=2e-3)


def test_hdr_to_srgb_clips_bright_and_out_of_gamut_colours():
    """HLG reference white (0.75) is 203 nits: past SDR white, it clips to 1; BT.2020's pure green is outside
    sRGB's gamut: its red and blue clip to 0."""
    np.testing.assert_allclose(hdr_to_srgb(np.full((1, 3), 0.75, np.float32), "hlg"), 1.0)
    green = hdr_to_srgb(np.array([[0.0, 0.5, 0.0]], np.float32), "hlg")[0]
    assert green[1] > 0.5 and green[0] == 0 and green[2] == 0
    with pytest.raises(ValueError, match="unknown HDR transfer"):
        hdr_to_srgb(np.zeros((1, 3)), "hdr10")


@pytest.mark.parametrize("transfer", ["hlg", "pq"])
def test_the_decodes_fast_hdr_mapping_is_the_formulas_within_a_level(transfer):
    """hdr_to_srgb_u8 (tables, the decode's path) against hdr_to_srgb (the formulas) on random 16-bit codes and on
    greys, darks and brights, each to the nearest 8-bit level or the next."""
    codes = np.random.default_rng(0).integers(0, 65536, (50000, 3)).astype(np.uint16)
    codes = np.concatenate([codes, np.repeat(np.linspace(0, 65535, 4097).astype(np.uint16)[:, None], 3, 1)])
    reference = np.round(hdr_to_srgb(codes / 65535, transfer) * 255)
    fast = hdr_to_srgb_u8(codes, transfer)
    assert fast.dtype == np.uint8 and fast.shape == codes.shape
    assert np.abs(fast - reference).max() <= 1 and np.mean(fast != reference) < 0.01
