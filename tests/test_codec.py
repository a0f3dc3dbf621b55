"""Codec and .hgs container: quantization bounds, exact residual coding, round trips, random access,
streaming, the golden file, io.clips dispatch, `hypergs info`, and a tiny rate-distortion bench."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import moving_params, random_params
from hypergs_blender.io.codec import (ANCHOR, INTRA, MODES, PREVIOUS, CodecError, Quantizer, decode_group,
                                   encode_group, order_stability, to_domain)
from hypergs_blender.errors import HyperGSError, LimitError
from hypergs_blender.gaussians import GaussianVideo
from hypergs_blender.io.hgs import HgsError, HgsReader, HgsWriter, load_hgs, save_hgs

VIDEO = Path(__file__).resolve().parents[1] / "hypergs_blender" / "samples" / "sample.mp4"  # the bundled sample


def domain_error(a, b):
    """Per-parameter max error in the coding domain (rotation: circular distance modulo pi)."""
    da, db = to_domain(a), to_domain(b)
    err = np.abs(da - db)
    rot = np.mod(da[..., 4] - db[..., 4], np.pi)
    err[..., 4] = np.minimum(rot, np.pi - rot)
    return err.reshape(-1, 8).max(axis=0)


# ---- quantization ----------------------------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), bits=st.sampled_from([1, 2, 4, 6, 8, 12, 16]),
       t=st.integers(1, 3), n=st.integers(1, 30))
def test_quantizer_error_within_half_a_step(seed, bits, t, n):
    params = random_params(np.random.default_rng(seed), t, n)
    q = Quantizer.fit(params, bits)
    levels, clipped = q.quantize(params)
    assert clipped == 0
    assert levels.min() >= 0 and np.all(levels < (1 << bits))
    decoded = q.dequantize(levels)
    assert np.all(decoded[..., 2:4] > 0)
    # float32 output: allow its rounding on top of half a step
    assert np.all(domain_error(params, decoded) <= q.max_error() * (1 + 1e-5) + 1e-5)


def test_ranges_fitted_frame_by_frame_are_those_of_the_whole_clip():
    params = moving_params(np.random.default_rng(5), 6, 40)
    whole, streamed = Quantizer.fit(params, 8), Quantizer.fit(iter(params), 8)
    assert (whole.lo, whole.hi) == (streamed.lo, streamed.hi)
    with pytest.raises(CodecError, match="NaN"):
        Quantizer.fit(iter([params[0], np.full((2, 8), np.nan, np.float32)]))


def test_rotation_is_taken_modulo_pi():
    p = random_params(np.random.default_rng(1), 1, 50)
    turned = p.copy()
    turned[..., 4] = np.mod(p[..., 4] + np.pi, 2 * np.pi)
    q = Quantizer.fit(p, 8)
    assert np.array_equal(q.quantize(p)[0], q.quantize(turned)[0])


def test_quantizer_clips_and_counts_values_outside_the_ranges():
    q = Quantizer.default(64, 64, 8)
    p = random_params(np.random.default_rng(2), 1, 10)
    p[0, 0, 0] = 5.0
    p[0, 1, 5] = -9.0
    levels, clipped = q.quantize(p)
    assert clipped == 2
    assert levels[0, 0, 0] == 255 and levels[0, 1, 5] == 0


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_parameters_are_refused(bad):
    p = random_params(np.random.default_rng(3), 1, 4)
    p[0, 2, 6] = bad
    with pytest.raises(CodecError):
        Quantizer.fit(p, 8)


def test_non_positive_scale_is_refused():
    p = random_params(np.random.default_rng(3), 1, 4)
    p[0, 1, 3] = 0
    with pytest.raises(CodecError, match="scales"):
        Quantizer.fit(p, 8)


def test_constant_parameter_has_zero_step_and_decodes_exactly():
    p = random_params(np.random.default_rng(4), 2, 8)
    p[..., 5] = 0.25
    q = Quantizer.fit(p, 4)
    assert np.all(q.dequantize(q.quantize(p)[0])[..., 5] == np.float32(0.25))


# ---- residual + entropy coding ------------------------------------------------------------------

@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), bits=st.sampled_from([1, 4, 6, 8, 16]), g=st.integers(1, 6),
       n=st.integers(0, 40), mode=st.sampled_from(MODES), drift=st.integers(0, 3))
def test_group_coding_is_exact(seed, bits, g, n, mode, drift):
    rng = np.random.default_rng(seed)
    level = 1 << bits
    q = rng.integers(0, level, (1, n, 8)) + np.cumsum(rng.integers(-drift, drift + 1, (g, n, 8)), axis=0)
    q = np.mod(q, level).astype(np.int32)
    payload = encode_group(q, bits, mode)
    decoded = list(decode_group(payload, g, n, bits))
    assert len(decoded) == g
    assert np.array_equal(np.stack(decoded), q)


def test_auto_mode_is_never_larger_than_a_forced_mode():
    rng = np.random.default_rng(5)
    level = 256
    q = rng.integers(0, level, (1, 300, 8)) + np.cumsum(rng.integers(-2, 3, (12, 300, 8)), axis=0)
    q[6:, :, 0] = rng.integers(0, level, (6, 300))  # a cut half-way: a new anchor pays there
    q = np.mod(q, level)
    sizes = {m: len(encode_group(q, 8, m)) for m in MODES}
    assert sizes["auto"] <= min(sizes[m] for m in ("intra", "anchor", "previous"))
    assert sizes["previous"] < sizes["intra"]  # slow drift: residuals pay


def test_residuals_wrap_around_the_alphabet():
    # a value stepping 255 -> 0 -> 1 is a residual of +1, not -255
    q = np.zeros((3, 100, 8), np.int32)
    q[:, :, 0] = np.array([255, 0, 1])[:, None]
    q[:, :, 1] = np.arange(100)[None, :]
    assert np.array_equal(np.stack(list(decode_group(encode_group(q, 8, "previous"), 3, 100, 8))), q)


def test_decoder_detects_damaged_groups():
    rng = np.random.default_rng(6)
    q = rng.integers(0, 64, (4, 50, 8)).astype(np.int32)
    payload = bytearray(encode_group(q, 6, "previous"))
    with pytest.raises(CodecError):
        list(decode_group(bytes(payload[:-5]), 4, 50, 6))
    bad = bytearray(payload)
    bad[0] = INTRA + 7  # invalid reference kind
    with pytest.raises(CodecError):
        list(decode_group(bytes(bad), 4, 50, 6))
    bad = bytearray(payload)
    bad[8] = ANCHOR  # frame 0 must be an anchor
    with pytest.raises(CodecError):
        list(decode_group(bytes(bad), 4, 50, 6))
    with pytest.raises(CodecError, match="too little data"):
        list(decode_group(bytes(payload), 4, 500_000, 6))
    assert PREVIOUS in np.frombuffer(bytes(payload[:32]), np.uint8)


def test_encode_group_refuses_levels_out_of_range():
    with pytest.raises(CodecError):
        encode_group(np.full((1, 3, 8), 64, np.int32), 6)
    with pytest.raises(CodecError, match="mode"):
        encode_group(np.zeros((1, 3, 8), np.int32), 6, "sideways")


# ---- order stability -----------------------------------------------------------------------------

def test_order_stability_tells_a_stable_order_from_a_shuffled_one():
    rng = np.random.default_rng(7)
    p = moving_params(rng, 5, 400)
    stable = order_stability(p, 256, 256)
    assert stable["same_index_nearest"] > 0.95
    shuffled = p.copy()
    for t in range(1, 5):
        shuffled[t] = shuffled[t][rng.permutation(400)]
    assert order_stability(shuffled, 256, 256)["same_index_nearest"] < 0.1
    assert len(stable["per_pair"]) == 4


# ---- .hgs round trips ----------------------------------------------------------------------------

@pytest.mark.parametrize("bits", [8, 6, 4])
def test_hgs_round_trip_within_quantization_error(tmp_path, bits):
    rng = np.random.default_rng(bits)
    video = GaussianVideo(moving_params(rng, 11, 300), 64, 48, 30.0, (2, 1), {"path": "x.mp4", "frames": [1, 2]})
    path = tmp_path / "clip.hgs"
    size = save_hgs(video, path, bits=(bits,) * 8, group_size=4)
    assert size == path.stat().st_size
    assert list(tmp_path.iterdir()) == [path]  # no temporary file left
    out = load_hgs(path)
    assert out.params.shape == video.params.shape and out.params.dtype == np.float32
    assert (out.canvas_width, out.canvas_height, out.fps, out.grid) == (64, 48, 30.0, (2, 1))
    assert out.source == video.source
    q = Quantizer.fit(video.params, bits)
    assert np.all(domain_error(video.params, out.params) <= q.max_error() * (1 + 1e-5) + 1e-5)
    # residual coding pays on a slowly moving clip, and fewer bits make a smaller file
    assert size < video.params.size * bits / 8


def test_hgs_round_trip_of_floor_encoder_gaussians(tmp_path):
    from hypergs_blender.encode import EncodeSettings, FloorEncoder, encode_video
    video = encode_video(VIDEO, FloorEncoder(), EncodeSettings(gaussians=256), size=64, num_frames=6)
    sizes = {}
    for bits in (8, 4):
        sizes[bits] = save_hgs(video, tmp_path / f"c{bits}.hgs", bits=bits)
        out = load_hgs(tmp_path / f"c{bits}.hgs")
        q = Quantizer.fit(video.params, bits)
        assert np.all(domain_error(video.params, out.params) <= q.max_error() * (1 + 1e-5) + 1e-5)
    assert sizes[4] < sizes[8] < video.params.nbytes / 4


def test_random_access_matches_sequential_decoding(tmp_path):
    rng = np.random.default_rng(8)
    video = GaussianVideo(moving_params(rng, 13, 64), 32, 32)
    path = tmp_path / "c.hgs"
    save_hgs(video, path, bits=6, group_size=5)
    whole = load_hgs(path).params
    with HgsReader(path) as reader:
        assert reader.num_frames == 13 and reader.header.group_size == 5
        for t in rng.permutation(13).tolist() + [12, 12, 3, 4, 5, 0]:
            assert np.array_equal(reader.read_frame(t), whole[t])
        assert np.array_equal(reader.read_frames(4, 9), whole[4:9])
        with pytest.raises(HgsError, match="outside"):
            reader.read_frame(13)
        reader.verify()


def test_clip_packed_as_bytes_reads_like_a_file(tmp_path):
    from hypergs_blender.io.hgs import hgs_bytes
    video = GaussianVideo(moving_params(np.random.default_rng(10), 5, 30), 32, 32, 12.0)
    data = hgs_bytes(video, bits=6, group_size=2)
    save_hgs(video, tmp_path / "c.hgs", bits=6, group_size=2)
    assert data == (tmp_path / "c.hgs").read_bytes()
    assert np.array_equal(load_hgs(data).params, load_hgs(tmp_path / "c.hgs").params)
    with HgsReader(data) as reader:
        assert reader.num_frames == 5 and reader.read_frame(3).shape == (30, 8)
    with pytest.raises(HgsError, match="checksum"):
        load_hgs(data[:100] + bytes([data[100] ^ 1]) + data[101:])
    with open(tmp_path / "c.hgs", "rb") as f, HgsReader(f) as reader:  # a file object, named in errors
        assert reader.path.name == "c.hgs" and np.array_equal(reader.read_frame(4), load_hgs(data).params[4])


def test_streaming_writer_with_default_ranges(tmp_path):
    rng = np.random.default_rng(9)
    params = moving_params(rng, 7, 20)
    params[3, 0, 5] = 9.0  # outside the default colour range: clipped
    path = tmp_path / "s.hgs"
    with HgsWriter(path, 64, 64, 20, fps=12, group_size=3) as writer:
        for frame in params:
            writer.write(frame)
        assert writer.num_frames == 7
        assert not path.exists()  # written to clip.hgs.part until closed
    assert writer.clipped == 1
    out = load_hgs(path)
    assert out.num_frames == 7 and out.fps == 12
    assert out.params[3, 0, 5] == pytest.approx(2.0)


def test_failed_write_leaves_no_file(tmp_path):
    path = tmp_path / "f.hgs"
    with pytest.raises(RuntimeError):
        with HgsWriter(path, 64, 64, 5) as writer:
            writer.write(random_params(np.random.default_rng(0), 2, 5))
            raise RuntimeError("cancelled")
    assert list(tmp_path.iterdir()) == []
    with pytest.raises(HgsError, match="expected frames"):
        with HgsWriter(path, 64, 64, 5) as writer:
            writer.write(np.zeros((2, 6, 8), np.float32))
    assert list(tmp_path.iterdir()) == []


def test_hgs_refuses_a_clip_too_large_to_load_whole(tmp_path, monkeypatch):
    video = GaussianVideo(moving_params(np.random.default_rng(1), 3, 100), 32, 32)
    save_hgs(video, tmp_path / "c.hgs")
    monkeypatch.setenv("HYPERGS_LIMIT_BYTES", "9000")
    with HgsReader(tmp_path / "c.hgs") as reader:
        assert reader.read_frame(2).shape == (100, 8)  # frame by frame is fine
        with pytest.raises(LimitError, match=r"c.hgs \(3 frames x 100 Gaussians\): 9,600 bytes of data.* HYPERGS_LIMIT_BYTES"):
            reader.read_all()


def golden_clip():
    """A clip whose parameters sit exactly on quantization levels (no float rounding can move them)."""
    f, i, p = np.arange(5)[:, None, None], np.arange(6)[None, :, None], np.arange(8)[None, None, :]
    levels = ((i * 5 + p * 3 + f * (i % 3)) % 64).astype(np.int32)
    quantizer = Quantizer(6, (-1, -1, math.log(0.5), math.log(0.5), 0, -0.5, -0.5, -0.5),
                          (1, 1, math.log(32), math.log(32), math.pi, 1.5, 1.5, 1.5))
    return levels, quantizer


def test_golden_file_is_written_byte_for_byte(tmp_path):
    """The format (and the entropy coder under it) must not drift. If this fails after a change or a
    constriction upgrade, files written before may no longer decode: bump hgs.VERSION."""
    levels, quantizer = golden_clip()
    path = tmp_path / "golden.hgs"
    with HgsWriter(path, 32, 32, 6, quantizer, fps=24, source={"name": "golden"}, group_size=3) as writer:
        writer.write(quantizer.dequantize(levels))
    assert path.read_bytes() == GOLDEN_HGS


def test_golden_file_still_decodes(tmp_path):
    levels, quantizer = golden_clip()
    path = tmp_path / "golden.hgs"
    path.write_bytes(GOLDEN_HGS)
    video = load_hgs(path)
    assert video.source == {"name": "golden"} and (video.canvas_width, video.fps) == (32, 24.0)
    np.testing.assert_allclose(video.params, quantizer.dequantize(levels), rtol=1e-6)
    assert np.array_equal(quantizer.quantize(video.params)[0], levels)


GOLDEN_HGS = bytes.fromhex(
    "894847530d0a1a0a01000000200000002000000000000000000038400600000001000100050000000300000006060606"
    "060606060000010102000000000000000000f0bf000000000000f03f000000000000f0bf000000000000f03fef39fafe"
    "422ee6bf6bc8b8bed3b90b40ef39fafe422ee6bf6bc8b8bed3b90b400000000000000000182d4454fb21094000000000"
    "0000e0bf000000000000f83f000000000000e0bf000000000000f83f000000000000e0bf000000000000f83f53040000"
    "000000003b0000007b22736f75726365223a207b226e616d65223a2022676f6c64656e227d2c2022777269746572223a"
    "2022687970657267732d626c656e646572227dc58f1cfd48475343000000000300000094010000000000000000000000"
    "000000000000000000000000000000000000001e000000ff0000000055555500005500550055ff000000005555550000"
    "5500550055030000001e000000ff0000000055555500005500550055ff0000000055555500005500550055060000001e"
    "000000ff0000000055555500005500550055ff0000000055555500005500550055090000001e000000ff000000005555"
    "5500005500550055ff00000000555555000055005500550c0000001e000000ff0000000055555500005500550055ff00"
    "000000555555000055005500550f0000001e000000ff0000000055555500005500550055ff0000000055555500005500"
    "550055120000001e000000ff0000000055555500005500550055ff0000000055555500005500550055150000001e0000"
    "00ff0000000055555500005500550055ff000000005555550000550055005512000000c38c1e640018cda68c5c514b2e"
    "eccb4c194e77d907faef965abb6cd77aece3fff06370a068a9e99a9ba787da72930c332f4fa40fb2c81f3583a3a07d6a"
    "ca2f21ddc0222601000000d021c7bd484753430300000002000000900100000000000000000000000000000000000000"
    "00000022000000ff0000000000000080800000000000ff80008000000000808000000000000080008003000000220000"
    "00ff0000000000000080800000000000ff8000800000000080800000000000008000800600000022000000ff00000000"
    "00000080800000000000ff8000800000000080800000000000008000800900000022000000ff00000000000000808000"
    "00000000ff8000800000000080800000000000008000800c00000022000000ff0000000000000080800000000000ff80"
    "00800000000080800000000000008000800f00000022000000ff0000000000000080800000000000ff80008000000000"
    "80800000000000008000801200000022000000ff0000000000000080800000000000ff80008000000000808000000000"
    "00008000801500000022000000ff0000000000000080800000000000ff8000800000000080800000000000008000800b"
    "0000009ccffe93e30249dde6d176a1ab221d7bd6f281a7d3b1af8f59ce0bb0ed1e801d1a50d563f761227da0150000cd"
    "d12a4448475349020000000701000000000000a80100000000000003000000af02000000000000a40100000300000002"
    "000000279e72ea")


# ---- the float16 codec (the frame cache) -------------------------------------------------------------

def float16_error(a, b):
    """Per-parameter max error: means absolute, the rest relative (rotation: circular, modulo pi)."""
    err = np.abs(a.astype(np.float64) - b)
    err[..., 2:] /= np.maximum(np.abs(a[..., 2:]), 1e-30)
    rot = np.mod(a[..., 4].astype(np.float64) - b[..., 4], np.pi)
    err[..., 4] = np.minimum(rot, np.pi - rot)
    return err.reshape(-1, 8).max(axis=0)


@pytest.mark.parametrize("group_size", [1, 4])
def test_float16_round_trip_keeps_the_means_exactly(tmp_path, group_size):
    rng = np.random.default_rng(11)
    video = GaussianVideo(moving_params(rng, 9, 300, canvas=1920), 1920, 1080, 30.0, (20, 15), {"path": "x.mp4"})
    path = tmp_path / "cache.hgs"
    save_hgs(video, path, group_size=group_size, codec="float16")
    out = load_hgs(path)
    assert out.params.dtype == np.float32 and out.params.shape == video.params.shape
    assert (out.canvas_width, out.canvas_height, out.fps, out.grid, out.source) == (1920, 1080, 30.0, (20, 15),
                                                                                    video.source)
    assert np.array_equal(out.params[..., :2], video.params[..., :2])  # float32: a 1080p canvas keeps its means
    err = float16_error(video.params, out.params)
    assert np.all(err[2:4] <= 2.0 ** -11) and np.all(err[5:] <= 2.0 ** -11)  # float16's relative rounding
    assert err[4] <= np.pi * 2.0 ** -11  # rotations modulo pi, then float16
    assert np.all((out.params[..., 4] >= 0) & (out.params[..., 4] <= np.pi))
    with HgsReader(path) as reader:
        assert reader.codec == "float16" and reader.header.version == 2 and reader.info()["codec"] == "float16"
        assert "bits" not in reader.info()
        for t in rng.permutation(9).tolist():  # any frame on its own
            assert np.array_equal(reader.read_frame(t), out.params[t])


def test_float16_is_smaller_than_float32_and_larger_than_quantized(tmp_path):
    video = GaussianVideo(moving_params(np.random.default_rng(12), 6, 2000), 64, 64)
    f16 = save_hgs(video, tmp_path / "f.hgs", group_size=1, codec="float16")
    q8 = save_hgs(video, tmp_path / "q.hgs", bits=8)
    assert q8 < f16 < video.params.nbytes * 0.7


def test_float16_frames_stored_uncompressed_read_the_same(tmp_path):
    """zlib level 0 (write_hgs' float16 frames, read once): the same values as the frame cache's level 1, in
    the plain size of the frames (codec.float16_frame_bytes) plus the file's framing."""
    from hypergs_blender.io.codec import float16_frame_bytes
    video = GaussianVideo(moving_params(np.random.default_rng(13), 5, 3000), 64, 64)
    sizes = {}
    for level in (0, 1):
        with HgsWriter(tmp_path / f"l{level}.hgs", 64, 64, 3000, codec="float16", group_size=1, zlib_level=level) as w:
            w.write(video.params)
        sizes[level] = (tmp_path / f"l{level}.hgs").stat().st_size
    assert np.array_equal(load_hgs(tmp_path / "l0.hgs").params, load_hgs(tmp_path / "l1.hgs").params)
    plain = 5 * float16_frame_bytes(3000)
    assert sizes[1] < plain < sizes[0] < plain * 1.01


def test_float16_writer_clips_and_counts_what_float16_cannot_hold(tmp_path):
    params = moving_params(np.random.default_rng(13), 2, 10)
    params[0, 0, 2] = 1e-9  # a scale below float16's smallest normal: raised to it
    params[1, 3, 6] = 1e6  # a colour past float16's largest: lowered to it
    params[1, 4, 0] = 1e6  # a mean: float32, kept
    with HgsWriter(tmp_path / "c.hgs", 64, 64, 10, codec="float16") as writer:
        writer.write(params)
    assert writer.clipped == 2
    out = load_hgs(tmp_path / "c.hgs").params
    assert out[0, 0, 2] == pytest.approx(2.0 ** -14) and out[1, 3, 6] == 65504.0 and out[1, 4, 0] == 1e6
    with pytest.raises(HgsError, match="NaN"):
        with HgsWriter(tmp_path / "d.hgs", 64, 64, 10, codec="float16", group_size=1) as writer:
            writer.write(np.full((1, 10, 8), np.nan, np.float32))
    assert not (tmp_path / "d.hgs").exists()
    with pytest.raises(HgsError, match="unknown .hgs codec"):
        HgsWriter(tmp_path / "e.hgs", 64, 64, 10, codec="png")


def test_float16_decoder_refuses_damaged_payloads():
    from hypergs_blender.io.codec import decode_float16_group, encode_float16_group
    params = moving_params(np.random.default_rng(14), 2, 50)
    payload, _ = encode_float16_group(params)
    assert all(np.array_equal(a, b) for a, b in zip(decode_float16_group(payload, 2, 50),
                                                    decode_float16_group(payload, 2, 50)))
    with pytest.raises(CodecError, match="does not hold"):
        list(decode_float16_group(payload, 2, 49))  # inflates to another size
    with pytest.raises(CodecError, match="ends early"):
        list(decode_float16_group(payload, 3, 50))
    with pytest.raises(CodecError, match="left over"):
        list(decode_float16_group(payload, 1, 50))
    with pytest.raises(CodecError, match="damaged group"):
        list(decode_float16_group(payload[:4] + b"\x00" * 20 + payload[24:], 2, 50))
    bad = params[:1].copy()
    bad[0, 7, 0] = np.nan  # a frame that decodes to NaN (the writer refuses it; a crafted file may hold it)
    import struct
    import zlib
    from hypergs_blender.io.codec import _byte_planes
    data = zlib.compress(_byte_planes(bad[0, :, :2].astype("<f4")) + _byte_planes(bad[0, :, 2:].astype("<f2")))
    with pytest.raises(CodecError, match="NaN"):
        list(decode_float16_group(struct.pack("<I", len(data)) + data, 1, 50))


# ---- io.clips, info ---------------------------------------------------------------------------------

def test_clips_dispatch_on_suffix(tmp_path):
    from hypergs_blender.io.clips import load_clip, save_clip
    video = GaussianVideo(moving_params(np.random.default_rng(3), 3, 30), 40, 30, 25.0)
    for name in ("c.hgs", "c.npz", "c.usda"):
        save_clip(video, tmp_path / name, bits=8)
        out = load_clip(tmp_path / name)
        assert out.params.shape == video.params.shape and out.fps == 25.0
    with pytest.raises(HyperGSError, match="unknown Gaussian video format"):
        save_clip(video, tmp_path / "c.mp4")
    with pytest.raises(HyperGSError, match="do not apply"):
        save_clip(video, tmp_path / "c.npz", group_size=4)
    with pytest.raises(HyperGSError, match="no such file"):
        load_clip(tmp_path / "missing.hgs")


def hypergs(monkeypatch):
    """`hypergs` (cli.main) with only this module's commands registered: the others are not under test."""
    from hypergs_blender.commands import cli
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["clips"])
    return cli.main


def test_clips_commands_are_registered():
    from hypergs_blender.commands import cli
    assert "clips" in cli.COMMAND_MODULES


def test_info_command(tmp_path, capsys, monkeypatch):
    main = hypergs(monkeypatch)
    video = GaussianVideo(moving_params(np.random.default_rng(4), 5, 30), 40, 30, 25.0)
    save_hgs(video, tmp_path / "c.hgs", bits=6)
    main(["info", str(tmp_path / "c.hgs"), "--verify", "--json"])
    info = json.loads(capsys.readouterr().out)
    assert info["num_frames"] == 5 and info["num_gaussians"] == 30 and info["bits"] == [10, 10] + [6] * 6  # means: 1/100 of the 6.3-px spacing (clip_bits)
    assert info["verified"] is True
    main(["info", str(tmp_path / "c.hgs")])
    assert "30 per frame" in capsys.readouterr().out
    (tmp_path / "bad.hgs").write_bytes(b"not a clip")
    with pytest.raises(SystemExit):
        main(["info", str(tmp_path / "bad.hgs")])
    assert "not a .hgs" in capsys.readouterr().err


def test_bench_codec_reports_rate_and_distortion():
    from hypergs_blender.bench.codec import bench_codec, format_codec_table
    result = bench_codec([VIDEO], gaussians=[64], bits=[8, 4], crfs=[35], size=32, num_frames=4, encoder="floor",
                         preset="ultrafast", position_bits=10)
    video = result["videos"][0]
    assert video["frames"] == 4 and video["width"] == 32
    ref = video["reference"][0]
    assert ref["bpp"] > 0 and 10 < ref["psnr"] < 60
    g = video["gaussians"][0]
    assert g["order_stability"]["same_index_nearest"] == 1.0  # the floor's grid never moves
    rows = {json.dumps(r["bits"]): r for r in g["hgs"]}
    assert list(rows) == ["8", "4", json.dumps([10, 10] + [8] * 6), json.dumps([10, 10] + [4] * 6)]
    rows = {8: rows["8"], 4: rows["4"]}
    assert rows[4]["bpp"] < rows[8]["bpp"] < g["float_bpp"]
    assert rows[8]["psnr"] > rows[4]["psnr"] and abs(rows[8]["psnr"] - g["float_psnr"]) < 1.0
    assert set(rows[8]["bytes_by_mode"]) == {"intra", "anchor", "previous"}
    table = format_codec_table(result)
    assert "| .hgs | N=64, 8 bits |" in table and "| .hgs | N=64, 4 bits, x/y 10 bits |" in table


def test_means_keep_a_quarter_pixel_on_any_canvas(tmp_path):
    """8 bits for every value, but the means get the bits their canvas needs: a 1280 px canvas at 8-bit
    means would move every Gaussian by up to 2.5 px."""
    from hypergs_blender.io.codec import MEAN_STEP_PX, clip_bits
    from hypergs_blender.io.hgs import load_hgs, save_hgs
    assert clip_bits(8, 256, 144)[:2] == (11, 10) and clip_bits(8, 1280, 720)[:2] == (13, 12)
    assert clip_bits(8, 1280, 720)[2:] == (8,) * 6 and clip_bits((6,) * 8, 1280, 720) == (6,) * 8
    rng = np.random.default_rng(3)
    params = np.concatenate([rng.uniform(-1, 1, (2, 500, 2)), rng.uniform(2, 6, (2, 500, 2)),
                             rng.uniform(0, np.pi, (2, 500, 1)), rng.uniform(0, 1, (2, 500, 3))], -1).astype(np.float32)
    video = GaussianVideo(params, 1280, 720, 24.0)
    save_hgs(video, tmp_path / "c.hgs", bits=8)
    back = load_hgs(tmp_path / "c.hgs").params
    error_px = np.abs(back[..., :2] - params[..., :2]) * np.array([640, 360])
    assert error_px.max() <= MEAN_STEP_PX / 2 + 1e-3


def test_means_keep_a_hundredth_of_the_spacing_of_a_fine_clip(tmp_path):
    """A clip of 4-px cells (14,400 Gaussians on 480 x 480) gets steps of at most 1/100 cell (14 bits):
    quarter-pixel steps cost 4.3 dB there against the float clip (the codec's comment)."""
    from hypergs_blender.io.codec import MEAN_STEP_CELL, clip_bits
    from hypergs_blender.io.hgs import load_hgs, save_hgs
    assert clip_bits(8, 480, 480, 14400)[:2] == (14, 14) and clip_bits(8, 480, 480)[:2] == (12, 12)
    assert clip_bits(8, 256, 256, 1024)[:2] == (12, 12) and clip_bits(8, 256, 256, 4)[:2] == (11, 11)  # 1/4 px
    rng = np.random.default_rng(4)
    n = 14400
    params = np.concatenate([rng.uniform(-1, 1, (2, n, 2)), rng.uniform(1, 3, (2, n, 2)),
                             rng.uniform(0, np.pi, (2, n, 1)), rng.uniform(0, 1, (2, n, 3))], -1).astype(np.float32)
    save_hgs(GaussianVideo(params, 480, 480, 24.0), tmp_path / "fine.hgs", bits=8)
    back = load_hgs(tmp_path / "fine.hgs")
    assert back.params.shape == params.shape
    error_px = np.abs(back.params[..., :2] - params[..., :2]) * 240
    assert error_px.max() <= MEAN_STEP_CELL * 4 / 2 + 1e-3
