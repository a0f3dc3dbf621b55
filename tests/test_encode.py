import math

import numpy as np
import pytest

from hypergs_blender.commands.cli import main
from hypergs_blender.encode import (DEFAULT_QUALITY, MAX_CELL, QUALITY, Cancelled, EncodePlan, EncodeSettings,
                                    FloorEncoder, encode_frames, encode_video, frames_layout, plan_layout,
                                    psnr_frame_picks, psnr_sample_count)
from hypergs_blender.errors import HyperGSError
from hypergs_blender.io.clips import load_clip
from hypergs_blender.io.frames import read_frames
from hypergs_blender.metrics import psnr
from hypergs_blender.render import render_frames, render_params


def test_layout_is_a_density():
    layout = plan_layout(1280, 720, 4, cell=8)
    assert (layout.cols, layout.rows, layout.count) == (160, 90, 14400) and layout.cell == pytest.approx(8)
    assert (layout.work_width, layout.work_height) == (640, 360) and not layout.note
    # a count becomes the cell size that gives about that many, on the frame's aspect
    by_count = plan_layout(1280, 720, 4, gaussians=14000)
    assert abs(by_count.count - 14000) < 300 and by_count.cols / by_count.rows == pytest.approx(16 / 9, rel=0.02)
    assert plan_layout(256, 256, 4, gaussians=1000).count == 32 * 32
    # more Gaussians always means a finer grid (the encoder sees more of the frame)
    counts = [plan_layout(640, 360, 4, gaussians=n).count for n in (250, 1000, 3000, 10000)]
    assert counts == sorted(counts) and len(set(counts)) == 4
    # multiples of a granule (a network whose coarsest level spans 4 cells)
    coarse = plan_layout(1000, 600, 4, cell=6, granule=4)
    assert coarse.cols % 4 == 0 and coarse.rows % 4 == 0


def test_layout_outside_the_trained_range_is_clamped_with_a_note():
    fine = plan_layout(256, 256, 4, gaussians=100_000)
    assert fine.count == 64 * 64 and "outside the trained range" in fine.note and "100000 Gaussians" in fine.note
    coarse = plan_layout(1920, 1080, 4, gaussians=10)
    assert coarse.cell == pytest.approx(MAX_CELL, rel=0.05) and "at most 32 px" in coarse.note
    with pytest.raises(HyperGSError, match="at least 1"):
        plan_layout(64, 64, 4, gaussians=0)
    with pytest.raises(HyperGSError, match="positive"):
        plan_layout(64, 64, 4, cell=-2)
    with pytest.raises(HyperGSError, match="not both"):
        plan_layout(64, 64, 4, gaussians=10, cell=8)


def test_floor_reproduces_flat_and_smooth_frames():
    """The grid floor: flat regions come back flat (no lattice of blobs), away from the frame's edges."""
    flat = np.full((1, 96, 128, 3), 140, np.uint8)
    for cell in (4, 6, 8):
        layout = frames_layout(flat, FloorEncoder(), cell=cell)
        out = render_params(encode_frames(flat, FloorEncoder(), layout), 128, 96, 128, 96)[0]
        inner = out[12:-12, 12:-12]
        assert abs(inner.mean() * 255 - 140) < 0.3 and inner.std() * 255 < 0.5, cell


def test_the_encoder_sees_the_frame_resized_with_the_working_filter():
    """The frame reaches the encoder at its working size through WORKING_INTERPOLATION (Lanczos: the area
    filter blurs at ratios between 1 and 2, as training never shows the network), 8-bit, in [0, 1]; at
    cells of the stride it is not resized at all."""
    from hypergs_blender.encode import WORKING_INTERPOLATION
    from hypergs_blender.io.images import resize_exact
    seen = []

    class Recording(FloorEncoder):
        def predict(self, frames, cells=None):
            seen.append(frames.copy())
            return super().predict(frames, cells)

    rng = np.random.default_rng(3)
    frames = rng.integers(0, 256, (1, 60, 90, 3), dtype=np.uint8)
    layout = plan_layout(90, 60, 4, cell=5)  # 18 x 12 cells: a 72 x 48 working frame
    encode_frames(frames, Recording(), layout)
    assert WORKING_INTERPOLATION == "LANCZOS"
    lanczos = resize_exact(frames[0], 72, 48, WORKING_INTERPOLATION).astype(np.float32) / 255
    np.testing.assert_array_equal(seen.pop()[0], lanczos)
    assert np.abs(resize_exact(frames[0], 72, 48).astype(np.float32) / 255 - lanczos).max() > 0.05  # not the area filter's
    exact = np.ascontiguousarray(frames[:, :, :88])  # 22 x 15 cells of 4 px: the frame itself
    encode_frames(exact, Recording(), plan_layout(88, 60, 4, cell=4))
    np.testing.assert_array_equal(seen.pop()[0], exact[0].astype(np.float32) / 255)


def test_encode_frames_stretches_back_exactly():
    """Working size 17 x 9 cells on a 100 x 50 frame: the Gaussians are stretched by the non-uniform
    factors; rendered at the frame's size they match the working-size render resized."""
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 256, (2, 50, 100, 3), dtype=np.uint8)
    layout = frames_layout(frames, FloorEncoder(), gaussians=150)
    params = encode_frames(frames, FloorEncoder(), layout)
    assert params.shape == (2, layout.count, 8)
    # means are at the cell centres of the frame, whatever the working size
    xs = np.unique(np.round(params[0, :, 0], 5))
    np.testing.assert_allclose(xs, (np.arange(layout.cols) + 0.5) / layout.cols * 2 - 1, atol=1e-5)
    # scales: sigma 0.6 cells in each direction of the frame
    np.testing.assert_allclose(sorted(params[0, 0, 2:4]), sorted([0.6 * 100 / layout.cols, 0.6 * 50 / layout.rows]),
                               rtol=1e-4)


def test_encode_video_chunks_and_metadata(moving_video):
    calls = []
    video = encode_video(moving_video, FloorEncoder(), EncodeSettings(cell=6), chunk_frames=4,
                         progress=lambda done, total: calls.append((done, total)))
    assert video.params.shape == (12, 88, 8) and video.grid == (11, 8)
    assert (video.canvas_width, video.canvas_height, video.fps) == (64, 48, 12.0)
    assert calls == [(0, 12), (4, 12), (8, 12), (12, 12)]
    frames, _, _ = read_frames(moving_video)
    assert psnr(render_frames(video, 64, 48), frames / 255.0).mean() > 18  # a blurred version


def test_chunking_does_not_change_the_result(moving_video):
    one = encode_video(moving_video, FloorEncoder(), EncodeSettings(cell=8), chunk_frames=1)
    three = encode_video(moving_video, FloorEncoder(), EncodeSettings(cell=8), chunk_frames=5)
    np.testing.assert_array_equal(one.params, three.params)


def test_cancel_raises_and_plan_knows_the_output(moving_video):
    plan = EncodePlan(moving_video, FloorEncoder(), EncodeSettings(gaussians=64), start=2, stop=10)
    assert plan.indices == list(range(2, 10)) and (plan.width, plan.height) == (64, 48)
    assert plan.layout.count == math.prod(plan.grid)
    with pytest.raises(Cancelled):
        list(plan.chunks(progress=lambda done, total: done < 4, chunk_frames=4))


@pytest.mark.parametrize("suffix", [".hgs", ".npz"])
def test_encode_command_writes_a_clip(moving_video, tmp_path, suffix, capsys):
    out = tmp_path / f"clip{suffix}"
    main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "192"])
    video = load_clip(out)
    assert video.params.shape == (12, 192, 8) and video.grid == (16, 12)
    main(["render", str(out), "-o", str(tmp_path / "frames"), "--width", "32"])
    assert len(list((tmp_path / "frames").glob("frame_*.png"))) == 12
    main(["encode", str(moving_video), "-o", str(tmp_path / "dense.npz"), "--encoder", "floor", "--gaussians", "5000"])
    assert "outside the trained range" in capsys.readouterr().err  # clamped, and said so
    assert load_clip(tmp_path / "dense.npz").num_gaussians == 16 * 12


def test_encode_command_position_bits_set_the_means_depth_only(moving_video, tmp_path):
    """.hgs means default to clip_bits' depth for the canvas and count; --position-bits replaces it for
    the means and leaves the other parameters at --bits."""
    from hypergs_blender.io.codec import clip_bits
    from hypergs_blender.io.hgs import HgsReader

    def depths(*argv):
        out = tmp_path / f"clip{len(argv)}.hgs"
        main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "192", *argv])
        with HgsReader(out) as reader:
            return tuple(reader.header.quantizer.bits), (reader.header.canvas_width, reader.header.canvas_height)

    default, (width, height) = depths()
    assert default == clip_bits(8, width, height, 192) and default[0] > 8
    assert depths("--position-bits", "12", "--bits", "6")[0] == (12, 12) + (6,) * 6


def test_encode_command_errors_leave_no_file(tmp_path, capsys):
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    out = tmp_path / "clip.hgs"
    with pytest.raises(SystemExit) as exit_info:
        main(["encode", str(bad), "-o", str(out), "--encoder", "floor"])
    assert exit_info.value.code == 1
    assert "notes.mp4" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("clip.hgs*"))


def test_encode_command_precision_reaches_the_torch_encoder(moving_video, tmp_path, capsys):
    """--precision bfloat16 encodes with torch in bfloat16 (the clip says so); with onnxruntime it is one line of
    error and no file."""
    out = tmp_path / "clip.npz"
    main(["encode", str(moving_video), "-o", str(out), "--gaussians", "48", "--backend", "torch", "--precision",
          "bfloat16"])
    assert load_clip(out).source["encoder"] == "network-torch-bfloat16"
    with pytest.raises(SystemExit) as exit_info:
        main(["encode", str(moving_video), "-o", str(tmp_path / "onnx.npz"), "--backend", "onnx", "--precision",
              "bfloat16"])
    assert exit_info.value.code == 1 and "onnxruntime runs float32" in capsys.readouterr().err
    assert not list(tmp_path.glob("onnx.npz*"))


def test_estimate_scales_with_gaussians_frames_refine_steps_and_threads():
    from hypergs_blender.encode import ADAPTIVE_MIN_REFINE, ENCODE_COSTS, THREAD_GAIN, estimate, plan_layout
    from hypergs_blender.placement import SPLIT_FRACTION
    small, large = plan_layout(432, 240, 4, cell=8.0), plan_layout(864, 480, 4, cell=8.0)
    assert large.count == 4 * small.count
    a, b = estimate(small, 10), estimate(large, 10)
    assert b.seconds == pytest.approx(4 * a.seconds) and b.cache_bytes == 4 * a.cache_bytes
    longer = estimate(small, 20)
    assert longer.cache_bytes == 2 * a.cache_bytes and longer.seconds == pytest.approx(2 * a.seconds)
    cost = ENCODE_COSTS["network"]
    # The .blend holds one frame whatever the clip's length; the cache grows with it.
    assert a.blend_bytes == estimate(small, 1000).blend_bytes == small.count * cost.blend_bytes_per_gaussian
    assert a.cache_bytes == small.count * 10 * cost.cache_bytes_per_gaussian
    refined = estimate(small, 10, refine=30)
    step = cost.refine_first_s_per_gaussian + 29 * cost.refine_s_per_gaussian_step
    predict = cost.predict_s_per_gaussian * small.count * 10
    adaptive = predict * 5 * SPLIT_FRACTION  # a long refinement's start runs the network at f and 4f of the count
    assert refined.seconds - a.seconds == pytest.approx(small.count * 10 * step + adaptive)
    short = ADAPTIVE_MIN_REFINE - 1  # a shorter one starts from the grid, as does one at the finest cell
    assert estimate(small, 10, refine=short).seconds - a.seconds == pytest.approx(
        small.count * 10 * (cost.refine_first_s_per_gaussian + (short - 1) * cost.refine_s_per_gaussian_step))
    finest = plan_layout(432, 240, 4, cell=4.0)
    assert estimate(finest, 10, refine=30).seconds - estimate(finest, 10).seconds == pytest.approx(
        finest.count * 10 * step)
    assert estimate(small, 10, encoder="floor").seconds < a.seconds  # the network costs more
    # More threads speed up the network's pass and refinement, by THREAD_GAIN per thread, and nothing else (the
    # floor, decoding, writing); the estimate says what it assumed.
    two = estimate(small, 10, threads=2)
    assert two.threads == 2 and a.threads == 1
    assert a.seconds - two.seconds == pytest.approx(predict - predict / (1 + THREAD_GAIN))
    assert estimate(small, 10, encoder="floor", threads=2).seconds == estimate(small, 10, encoder="floor").seconds
    refining = small.count * 10 * step
    assert refined.seconds - estimate(small, 10, refine=30, threads=2).seconds == pytest.approx(
        (predict + adaptive + refining) * (1 - 1 / (1 + THREAD_GAIN)))
    floor = estimate(small, 10, refine=30, encoder="floor").seconds
    assert floor - estimate(small, 10, refine=30, encoder="floor", threads=2).seconds == pytest.approx(
        refining * (1 - 1 / (1 + THREAD_GAIN)))
    # HDR video's decode costs more, per source pixel, whatever the encoder and threads.
    for kwargs in (dict(), dict(encoder="floor", threads=2)):
        assert estimate(small, 10, hdr=True, **kwargs).seconds - estimate(small, 10, **kwargs).seconds == pytest.approx(
            cost.hdr_decode_s_per_pixel * small.width * small.height * 10)
    # The encoder's kind is its name's first part; one without a cost is refused by name.
    assert estimate(small, 10, encoder="network-torch") == estimate(small, 10, encoder="network-onnx") == a
    with pytest.raises(ValueError, match="'mystery-onnx'"):
        estimate(small, 10, encoder="mystery-onnx")


def test_settings_read_a_preset_a_count_or_a_cell():
    assert EncodeSettings.choose() == EncodeSettings(cell=QUALITY[DEFAULT_QUALITY]["cell"])
    assert EncodeSettings.choose("high") == EncodeSettings(cell=QUALITY["high"]["cell"], refine=QUALITY["high"]["refine"])
    assert EncodeSettings.choose("high", refine=0) == EncodeSettings(cell=QUALITY["high"]["cell"])
    assert EncodeSettings.choose(default="draft") == EncodeSettings(cell=QUALITY["draft"]["cell"])
    assert EncodeSettings.choose(gaussians=500, cell=6.0, refine=3) == EncodeSettings(gaussians=500, refine=3)
    assert EncodeSettings.choose(cell=5.0) == EncodeSettings(cell=5.0)
    with pytest.raises(HyperGSError, match="unknown quality"):
        EncodeSettings.choose("ultra")


def test_settings_without_torch_skip_refining_and_say_so(monkeypatch):
    from hypergs_blender import optional
    monkeypatch.setattr(optional, "torch_available", lambda: False)
    chosen = EncodeSettings.choose("high").runnable()
    assert chosen.refine == 0 and "refining needs PyTorch" in chosen.note and "30 steps" in chosen.note
    assert EncodeSettings.choose("draft").runnable() == EncodeSettings.choose("draft")


def test_settings_layout_uses_the_encoders_granule():
    class Coarse(FloorEncoder):
        granule = 4
    chosen = EncodeSettings(cell=6)
    assert chosen.layout(1000, 600, Coarse()) == plan_layout(1000, 600, 4, cell=6, granule=4)
    assert chosen.layout(1000, 600, Coarse()).cols % 4 == 0
    assert chosen.layout(1000, 600, FloorEncoder()) == plan_layout(1000, 600, 4, cell=6)


def test_plan_measures_the_psnr_of_spread_frames(moving_video):
    plan = EncodePlan(moving_video, FloorEncoder(), EncodeSettings(cell=6))
    video = plan.video(chunk_frames=5, psnr_frames=3)
    frames, _, _ = read_frames(moving_video)
    rendered = render_frames(video, 64, 48, [0, 6, 11])  # frames 0, 5.5 -> 6, 11 of 12
    expected = psnr(rendered, frames[[0, 6, 11]] / np.float32(255))
    np.testing.assert_allclose(plan.psnr_values, expected, rtol=1e-6)
    assert plan.psnr == pytest.approx(float(np.mean(expected)))


@pytest.mark.parametrize("frames,sampled", [(0, 0), (1, 1), (30, 1), (32, 1), (33, 2), (100, 4), (256, 8), (1800, 8)])
def test_a_conversion_measures_one_frame_in_32_and_at_most_8(frames, sampled):
    # The PSNR check is a full render per sampled frame: its share of a conversion must not grow for short clips.
    assert psnr_sample_count(frames) == sampled


@pytest.mark.parametrize("total,count,picks", [(0, 3, []), (12, 0, []), (12, 1, [0]), (12, 3, [0, 6, 11]),
                                               (3, 8, [0, 1, 2]), (1800, 2, [0, 1799])])
def test_psnr_frame_picks_spread_over_the_clip(total, count, picks):
    assert psnr_frame_picks(total, count) == picks


def test_encode_command_reports_the_psnr_blenders_import_would(moving_video, tmp_path, capsys):
    out = tmp_path / "clip.npz"  # lossless: the file renders as the Gaussians measured (.hgs quantizes after)
    main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "192"])
    assert "PSNR" not in capsys.readouterr().out  # a full render per sampled frame: asked for, not by default
    main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "192", "--psnr"])
    printed = capsys.readouterr().out
    frames, _, _ = read_frames(moving_video)  # 12 frames: psnr_sample_count(12) == 1, frame 0
    video = load_clip(out)
    expected = psnr(render_frames(video, 64, 48, [0]), frames[[0]] / np.float32(255))[0]
    assert f"PSNR {expected:.2f} dB on 1 frame(s)" in printed
    hgs = tmp_path / "clip.hgs"  # streamed and quantized: measured as the file holds the frame
    main(["encode", str(moving_video), "-o", str(hgs), "--encoder", "floor", "--gaussians", "192", "--psnr"])
    quantized = psnr(render_frames(load_clip(hgs), 64, 48, [0]), frames[[0]] / np.float32(255))[0]
    assert quantized != expected and f"PSNR {quantized:.2f} dB on 1 frame(s)" in capsys.readouterr().out


def test_a_streamed_hgs_has_ranges_fitted_to_the_whole_clip(moving_video, tmp_path):
    """`encode -o clip.hgs` streams, yet quantizes as a whole clip's export does: every value within half
    a step of ranges fitted to the clip (fixed ranges, colours in [-1, 2], scales up to the canvas,
    cost a smooth 720p clip 6.6 dB at High)."""
    from hypergs_blender.io.codec import Quantizer, clip_bits, to_domain
    exact, hgs = tmp_path / "clip.npz", tmp_path / "clip.hgs"
    for out in (exact, hgs):
        main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "192"])
    params, decoded = load_clip(exact).params, load_clip(hgs).params
    fitted = Quantizer.fit(params, clip_bits(8, 64, 48, 192))
    error = np.abs(to_domain(decoded) - to_domain(params)).reshape(-1, 8).max(0)
    linear = [0, 1, 2, 3, 5, 6, 7]  # all but the rotation, whose domain wraps
    assert np.all(error[linear] <= fitted.max_error()[linear] * 1.01 + 1e-3)  # + the float16 of the streamed frames
    assert np.all(fitted.max_error()[5:] < Quantizer.default(64, 48, 8).max_error()[5:] / 2)  # a test that can fail


def test_an_interrupted_hgs_encode_leaves_the_folder_as_it_was(moving_video, tmp_path):
    out = tmp_path / "clip.hgs"
    out.write_bytes(b"the user's file")
    before = sorted(tmp_path.iterdir())
    plan = EncodePlan(moving_video, FloorEncoder(), EncodeSettings(gaussians=64))
    with pytest.raises(Cancelled):
        plan.write_hgs(out, progress=lambda done, total: done < 4, chunk_frames=4)
    assert out.read_bytes() == b"the user's file" and sorted(tmp_path.iterdir()) == before


def test_an_hgs_encode_without_room_for_its_frames_is_refused_before_it_starts(moving_video, tmp_path, monkeypatch,
                                                                               capsys):
    import shutil
    from collections import namedtuple
    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda folder: usage(10**9, 10**9 - 1000, 1000))  # 1 kB free
    out = tmp_path / "clip.hgs"
    with pytest.raises(SystemExit):
        main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "192"])
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "clip.hgs: the float16 file of its 12 frames' Gaussians and the .hgs" in error[0]
    assert "free in" in error[0] and "which has 1,000 bytes" in error[0]
    assert not out.exists() and not list(tmp_path.glob(".clip.hgs*"))
    monkeypatch.setattr(shutil, "disk_usage", lambda folder: usage(10**9, 0, 10**9))  # room: it runs
    main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "192"])
    assert load_clip(out).num_frames == 12


@pytest.mark.parametrize("argv,expected", [
    ([], EncodeSettings(cell=6.0)), (["--quality", "draft"], EncodeSettings(cell=8.0)),
    (["--quality", "high"], EncodeSettings(cell=4.0, refine=30)),
    (["--quality", "high", "--refine", "2"], EncodeSettings(cell=4.0, refine=2)),
    (["--gaussians", "300"], EncodeSettings(gaussians=300)), (["--cell", "5", "--refine", "1"], EncodeSettings(cell=5.0, refine=1)),
    (["--gaussians", "300", "--grid", "3x2"], EncodeSettings(gaussians=300, grid=(3, 2))),
    (["--quality", "draft", "--grid", "2"], EncodeSettings(cell=8.0, grid=(2, 2)))])
def test_encode_command_reads_quality_count_or_cell(argv, expected, tmp_path, moving_video):
    from hypergs_blender.commands import cli, options
    args = cli.build_parser().parse_args(["encode", str(moving_video), "-o", str(tmp_path / "c.hgs"), *argv])
    assert options.settings_from_args(args) == expected


def test_quality_excludes_a_count_or_a_cell(moving_video, tmp_path, capsys):
    for other in (["--cell", "6"], ["--gaussians", "100"]):
        with pytest.raises(SystemExit) as exit_info:
            main(["encode", str(moving_video), "-o", str(tmp_path / "c.hgs"), "--quality", "draft", *other])
        assert exit_info.value.code == 2 and "not allowed with argument --quality" in capsys.readouterr().err
    main(["encode", str(moving_video), "-o", str(tmp_path / "draft.npz"), "--encoder", "floor", "--quality", "draft"])
    layout = plan_layout(64, 48, 4, cell=QUALITY["draft"]["cell"])
    assert load_clip(tmp_path / "draft.npz").grid == (layout.cols, layout.rows)


def test_the_transformer_estimate_counts_its_windows():
    """The transformer pays per canvas-sized window (encode.TileLayout.windows), each for its k x k
    Gaussians and their pairs: more windows or more Gaussians per window cost more, as measured."""
    from hypergs_blender.encode import ENCODE_COSTS, TileLayout, estimate
    cost = ENCODE_COSTS["transformer"]
    one = TileLayout(256, 256, 32, 32, 4.0, tiles=(1, 1), canvas=128, windows=1)
    nine = TileLayout(256, 256, 64, 64, 4.0, tiles=(2, 2), canvas=128, windows=9)
    per_window = (cost.predict_s_per_window + cost.predict_s_per_gaussian * 1024 + cost.predict_s_per_pair * 1024 ** 2)
    fixed = cost.decode_s_per_pixel * 256 * 256
    assert estimate(one, 1, encoder="transformer-onnx").seconds == pytest.approx(
        fixed + cost.write_s_per_gaussian * 1024 + per_window)
    assert estimate(nine, 1, encoder="transformer-torch").seconds == pytest.approx(
        fixed + cost.write_s_per_gaussian * 4096 + 9 * per_window)
