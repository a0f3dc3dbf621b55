"""bench vs-fit / vs-x265 / scale / plots (hypergs_blender/bench/): the matched-PSNR and
matched-quality interpolation, refine_ladder against encode.refine_frames, the reports' JSON shape on a tiny synthetic video with tiny settings, and the scale bench's bounded memory."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from conftest import write_video
from hypergs_blender.bench import common, plots, scale, vs_fit, vs_x265
from hypergs_blender.commands.cli import build_parser
from hypergs_blender.encode import FloorEncoder, encode_frames, frames_layout, refine_frames
from hypergs_blender.io.codec import clip_bits
from hypergs_blender.errors import HyperGSError
from hypergs_blender.io.hgs import HgsReader

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def tiny_video(tmp_path_factory):
    """8 frames, 64 x 48: a soft blob drifting over a gradient (enough structure for PSNR to move)."""
    y, x = np.mgrid[0:48, 0:64].astype(np.float32)
    frames = []
    for t in range(8):
        blob = np.exp(-((x - 20 - 3 * t) ** 2 + (y - 24) ** 2) / 60.0)
        img = np.stack([0.2 + 0.6 * x / 64, 0.3 + 0.4 * y / 48, 0.5 * np.ones_like(x)], -1) * (1 - blob[..., None])
        img += blob[..., None] * np.array([0.9, 0.3, 0.1])
        frames.append((np.clip(img, 0, 1) * 255).astype(np.uint8))
    path = tmp_path_factory.mktemp("video") / "tiny.mp4"
    write_video(path, np.stack(frames), fps=24)
    return path


# ---- matched PSNR / matched quality ---------------------------------------------------------------------

def test_matched_ratio_interpolates_in_log_time():
    points = [(10.0, 30.0), (1.0, 20.0)]  # any order
    m = vs_fit.matched_ratio(25.0, 0.01, points)
    assert m["bound"] == "="
    assert m["fit_seconds"] == pytest.approx(math.sqrt(10.0))  # halfway in PSNR = halfway in log time
    assert m["ratio"] == pytest.approx(100 * math.sqrt(10.0))
    assert vs_fit.matched_ratio(30.0, 1.0, points)["fit_seconds"] == pytest.approx(10.0)


def test_matched_ratio_bounds_outside_the_fitting_curve():
    points = [(1.0, 20.0), (10.0, 30.0)]
    below = vs_fit.matched_ratio(15.0, 0.5, points)  # fitting's cheapest rung already beats us
    assert below["bound"] == "<=" and below["fit_seconds"] == 1.0 and below["ratio"] == pytest.approx(2.0)
    above = vs_fit.matched_ratio(35.0, 0.5, points)  # no rung reaches us: at least the last rung's time
    assert above["bound"] == ">=" and above["fit_seconds"] == 10.0 and above["ratio"] == pytest.approx(20.0)
    assert vs_fit.matched_ratio(25.0, 1.0, [])["ratio"] is None


def test_matched_ratio_uses_the_first_rung_that_reaches_us():
    # fitting is not monotone (a longer run ended lower): the first crossing counts
    points = [(1.0, 20.0), (3.0, 26.0), (10.0, 24.0), (30.0, 32.0)]
    m = vs_fit.matched_ratio(23.0, 1.0, points)
    assert m["bound"] == "="
    expected = math.exp(math.log(1.0) + 0.5 * (math.log(3.0) - math.log(1.0)))
    assert m["fit_seconds"] == pytest.approx(expected)


def test_bpp_at_psnr_and_pairs():
    ref = [{"crf": 23, "psnr": 34.0, "bpp": 0.4, "ssim": 0.9, "encode_fps": 50.0, "decode_fps": 500.0},
           {"crf": 33, "psnr": 30.0, "bpp": 0.1, "ssim": 0.8, "encode_fps": 60.0, "decode_fps": 600.0}]
    bpp, bound = vs_x265.bpp_at_psnr(32.0, ref)
    assert bound == "=" and bpp == pytest.approx(0.2)  # geometric mean of 0.1 and 0.4
    assert vs_x265.bpp_at_psnr(28.0, ref) == (0.1, "<=")
    assert vs_x265.bpp_at_psnr(36.0, ref) == (0.4, ">=")
    ours = [{"n": 100, "refine": 0, "hgs": [{"bits": 8, "bpp": 0.4, "psnr": 31.0, "ssim": 0.85, "encode_fps": 120.0,
                                             "decode_fps": 300.0},
                                            {"bits": 4, "bpp": 0.3, "psnr": 28.0, "ssim": 0.7, "encode_fps": 120.0,
                                             "decode_fps": 300.0}]}]
    pairs = vs_x265.match_pairs(ours, ref)
    assert [p["nearest"]["crf"] for p in pairs] == [33, 33]
    assert pairs[0]["reference_bpp_at_psnr"] == pytest.approx(0.1 * 4 ** 0.25)  # a quarter of the way in log
    assert pairs[0]["bpp_ratio"] == pytest.approx(4 / 4 ** 0.25) and pairs[0]["bpp_ratio_bound"] == "="
    # below x265's lowest PSNR: x265 needs at most 0.1 bpp, so we need at least 3x the bits
    assert pairs[1]["bpp_ratio"] == pytest.approx(3.0) and pairs[1]["bpp_ratio_bound"] == ">="
    assert pairs[0]["encode_speed_ratio"] == pytest.approx(2.0)


def test_frames_specs():
    assert common.parse_frames("native") == (None, None) and common.parse_frames("256") == (256, None)
    assert common.parse_frames("crop480") == (None, 480)
    with pytest.raises(HyperGSError, match="expected a size"):
        common.parse_frames("big")


def test_fit_psnr_at_interpolates_between_rungs():
    points = [(1.0, 20.0), (10.0, 30.0)]
    assert vs_fit.fit_psnr_at(math.sqrt(10.0), points) == pytest.approx(25.0)
    assert vs_fit.fit_psnr_at(0.5, points) is None and vs_fit.fit_psnr_at(20.0, points) is None


# ---- refine ----------------------------------------------------------------------------------------------

def test_refine_step_sizes_grow_with_the_steps_up_to_a_cap():
    from hypergs_blender.refine import REFINE_SCALE_MAX, REFINE_STEPS, refine_steps
    assert refine_steps(1) == refine_steps(10) == REFINE_STEPS
    assert refine_steps(30).mean_cells == pytest.approx(2.5 * REFINE_STEPS.mean_cells)
    assert refine_steps(100).colour == refine_steps(1000).colour == pytest.approx(REFINE_SCALE_MAX * REFINE_STEPS.colour)


def test_refine_ramps_its_step_sizes_up_over_its_warmup(tiny_video):
    """Adam's first step moves every parameter by about its full step size whatever its gradient: with the
    ramp, the first step of a refinement moves the means by 1/REFINE_WARMUP of that; then up to the whole."""
    import torch

    from hypergs_blender.refine import REFINE_STEPS, REFINE_WARMUP, fit

    frames, _, _ = common.load_frames(tiny_video, 2, 32)
    params = encode_frames(frames, FloorEncoder(), frames_layout(frames, FloorEncoder(), gaussians=16))
    target, start = torch.from_numpy(frames).float() / 255, torch.from_numpy(params)
    step = REFINE_STEPS.mean_cells * math.sqrt(32 * 32 / 16) / 16  # pixels -> the canvas' [-1, 1] (32 px wide)

    def largest_move(iters, warmup):
        moved = fit(target, start, iters, REFINE_STEPS, decay=0, warmup=warmup)
        return float((moved[..., :2] - start[..., :2]).abs().max())

    assert largest_move(1, 0) == pytest.approx(step, rel=0.01)
    assert largest_move(1, REFINE_WARMUP) == pytest.approx(step / REFINE_WARMUP, rel=0.01)
    assert largest_move(REFINE_WARMUP + 1, REFINE_WARMUP) > 2 * largest_move(REFINE_WARMUP + 1, REFINE_WARMUP * 4)


def test_step_size_factor_ramps_holds_and_decays_over_its_tail():
    from hypergs_blender.refine import step_size_factor

    factors = [step_size_factor(step, 20, warmup=4, decay=0.25) for step in range(20)]
    assert factors[:4] == pytest.approx([0.25, 0.5, 0.75, 1.0])
    assert factors[4:15] == pytest.approx([1.0] * 11)
    assert factors[15] == pytest.approx(1.0)
    assert factors[19] == pytest.approx(0.05 + 0.95 * 0.5 * (1 + math.cos(0.8 * math.pi)))
    assert all(later < earlier for earlier, later in zip(factors[15:], factors[16:]))
    # decay 1 is the whole run's cosine (a fit from scratch), decay 0 constant step sizes
    assert step_size_factor(0, 10) == 1.0 and step_size_factor(5, 10) == pytest.approx(0.525)
    assert [step_size_factor(step, 10, decay=0) for step in range(10)] == [1.0] * 10


def test_fit_refuses_a_decay_outside_0_1():
    import torch

    from hypergs_blender.refine import fit

    with pytest.raises(ValueError, match="decay must be in"):
        fit(torch.zeros(1, 8, 8, 3), torch.zeros(1, 4, 8), 2, decay=1.5)


def test_a_frame_refines_the_same_alone_or_in_a_batch():
    """Each frame is its own problem: its steps must not depend on the frames beside it, also where its
    gradients are as small as Adam's eps (a start already within 1e-5 of the target)."""
    import torch

    from hypergs_blender.refine import StepSizes, fit, random_init
    from hypergs_blender.render import render_torch

    start = torch.from_numpy(random_init(4, 16, 32, 32, seed=3))
    target = render_torch(start, 32, 32, 32, 32) * (1 + 1e-5)  # the colours 1e-5 too dark: gradients near eps
    colours_only = StepSizes(mean_cells=0, log_scale=0, rotation=0, colour=1e-6)  # steps that gain here
    together = fit(target, start, 3, colours_only, decay=0)
    alone = torch.cat([fit(target[i:i + 1], start[i:i + 1], 3, colours_only, decay=0) for i in range(4)])
    assert torch.allclose(together, alone, rtol=0, atol=1e-9)
    assert not torch.allclose(together, start, rtol=0, atol=1e-7)  # and the steps did move it


def test_fit_returns_each_frames_best_step():
    """Adam's last step is not always its best: from colours 1e-3 off their target, steps of REFINE_STEPS'
    size overshoot and leave the frame worse (86x its start's error after 5 steps), and `fit` returns that
    frame's start; from 0.05 off, the same steps gain."""
    import torch

    from hypergs_blender.refine import REFINE_STEPS, fit, random_init
    from hypergs_blender.render import render_torch

    exact = torch.from_numpy(random_init(2, 16, 32, 32, seed=3))
    target = render_torch(exact, 32, 32, 32, 32)
    start = exact.clone()
    start[0, :, 5:8] += 1e-3
    start[1, :, 5:8] += 0.05

    def errors(params):
        return ((render_torch(params, 32, 32, 32, 32) - target) ** 2).mean((1, 2, 3))

    before, after = errors(start), errors(fit(target, start, 5, REFINE_STEPS, decay=0))
    assert after[0] <= before[0] * (1 + 1e-4)
    assert after[1] < before[1] / 4


def test_least_squares_colours_against_a_dense_solve():
    """refine.least_squares_colours (conjugate gradients through the rasterizer) against numpy's solve of the
    same normal equations, built column by column from renders of one unit colour: exact with as many
    iterations as unknowns per channel, and within 1 % of the start's excess error over the optimum's at
    LS_ITERATIONS from colours near the optimum, as a prediction's are."""
    import torch

    from hypergs_blender.refine import LS_ITERATIONS, least_squares_colours, random_init
    from hypergs_blender.render import render_torch

    n, size, ridge = 16, 16, 1e-4
    params = torch.from_numpy(random_init(1, n, size, size, seed=5)).double()
    grid = (torch.arange(4, dtype=torch.float64) + 0.5) / 2 - 1  # a 4 x 4 lattice of 4-px cells: well posed
    params[0, :, 0], params[0, :, 1] = grid.repeat(4), grid.repeat_interleave(4)
    params[0, :, 2:4] = torch.tensor([2.5, 1.5], dtype=torch.float64)
    target = torch.from_numpy(np.random.default_rng(1).uniform(0, 1, (1, size, size, 3)))
    columns = []
    for i in range(n):  # A's column i: Gaussian i at colour 1, the others black (one channel; all alike)
        unit = params.clone()
        unit[..., 5:8] = 0
        unit[0, i, 5:8] = 1
        columns.append(render_torch(unit, size, size, size, size)[0, ..., 0].reshape(-1))
    a = torch.stack(columns, 1).numpy()
    y = target[0].reshape(-1, 3).numpy()
    exact = np.linalg.solve(a.T @ a + ridge * np.eye(n), a.T @ y)  # [n, 3]
    solved = least_squares_colours(params, target, iterations=n, ridge=ridge)
    np.testing.assert_allclose(solved[0, :, 5:8].numpy(), exact, rtol=1e-5, atol=1e-6)
    assert torch.equal(solved[..., :5], params[..., :5])  # the geometry stays

    def error(colours):
        return float(((a @ colours - y) ** 2).sum() + ridge * (colours ** 2).sum())
    start = exact + np.random.default_rng(2).normal(0, 0.1, exact.shape)  # a prediction near the optimum
    near = params.clone()
    near[0, :, 5:8] = torch.from_numpy(start)
    quick = least_squares_colours(near, target)[0, :, 5:8].numpy()
    assert error(start) - error(exact) > 1e-2  # there is something to gain
    assert error(quick) - error(exact) <= 0.01 * (error(start) - error(exact))
    assert LS_ITERATIONS < n  # so the second check is not the first


def test_refine_ladder_matches_the_products_refinement(tiny_video):
    """The bench times every K as its own run; each K must equal encode.refine_frames(K), the product's path."""
    frames, _, _ = common.load_frames(tiny_video, 4, 32)
    floor = FloorEncoder()
    layout = frames_layout(frames, floor, gaussians=16)
    params = encode_frames(frames, floor, layout)
    ladder = vs_fit.refine_ladder(frames, floor, layout, params, (1, 4))
    for k, refined, seconds in ladder:
        np.testing.assert_allclose(refined, refine_frames(frames, floor, layout, params, k), atol=2e-4)
        assert seconds > 0
    assert not np.allclose(ladder[0][1], ladder[1][1])  # 3 Adam steps did move something
    before = common.psnr_of(common.render(params, 32, 32), frames).mean()
    after = common.psnr_of(common.render(ladder[1][1], 32, 32), frames).mean()
    assert after > before  # refining the grid floor helps


# ---- reports ----------------------------------------------------------------------------------------------

def test_vs_fit_report_shape(tiny_video, tmp_path):
    report = vs_fit.bench_vs_fit([tiny_video], gaussians=(18,), refine_steps=(1, 3), fit_iters=(2, 4, 8),
                                 sizes=("32", "crop40", "native"), frames=4, encoder="floor", device="cpu",
                                 fit_budget=0.0)
    report = json.loads(json.dumps(report))  # JSON-clean
    assert report["bench"] == "vs-fit" and report["machine"]["device"] == "cpu"
    from hypergs_blender import refine  # the settings name the refinement the ratios were measured with
    assert report["settings"]["refine_schedule"] == {"warmup": refine.REFINE_WARMUP, "decay": refine.REFINE_DECAY,
                                                     "adam_eps": refine.ADAM_EPS}
    assert report["settings"]["fit_warmup"] == refine.FIT_WARMUP
    (video,) = report["videos"]
    square, crop, native = video["sizes"]
    assert [(b["size"], b["width"], b["height"]) for b in video["sizes"]] == [("32", 32, 32), ("crop40", 40, 40),
                                                                             ("native", 64, 48)]
    assert square["rows"][0]["n"] == 16 and square["rows"][0]["cells"] == [4, 4]  # the layout nearest 18
    for block in (square, crop, native):
        (row,) = block["rows"]
        assert block["frames"] == 4 and len(row["feedforward"]["psnr_per_frame"]) == 4
        assert [r["k"] for r in row["refine"]] == [1, 3]
        assert all(r["seconds"] > row["feedforward"]["seconds"] for r in row["refine"])
        for init in ("random", "grid"):
            rungs = row[f"fit_{init}"]
            # a zero budget lets the first rung run (it measures the cost per step) and skips the rest
            assert "psnr" in rungs[0] and rungs[0]["iters"] == 2
            assert rungs[1:] == [{"iters": 4, "skipped": "budget"}, {"iters": 8, "skipped": "budget"}] or \
                rungs[1]["skipped"] == "reached"
        assert [m["method"] for m in row["matched"]] == ["feedforward", "refine 1", "refine 3"]
        assert all(m[init]["bound"] in ("=", "<=", ">=") and m[init]["ratio"] > 0
                   for m in row["matched"] for init in ("random", "grid"))
    assert {g["size"] for g in report["summary"]} == {"32", "crop40", "native"}
    assert "| 32 (32x32) | 16 | feedforward |" in report["table"]


def test_vs_fit_stops_once_fitting_reaches_us(tiny_video):
    report = vs_fit.bench_vs_fit([tiny_video], gaussians=(16,), refine_steps=(), fit_iters=(30, 60), sizes=("32",),
                             frames=4, encoder="floor", device="cpu")
    row = report["videos"][0]["sizes"][0]["rows"][0]
    # the grid floor is easy to beat: 30 fitting steps reach it, so the 60-step rung is not run
    for init in ("random", "grid"):
        assert row[f"fit_{init}"][0]["psnr"] >= row["feedforward"]["psnr"]
        assert row[f"fit_{init}"][1] == {"iters": 60, "skipped": "reached"}
        assert row["matched"][0][init]["bound"] in ("<=", "=")


def test_vs_x265_report_shape(tiny_video):
    report = vs_x265.bench_vs_x265([tiny_video], gaussians=(16,), bits=(8, 4), crfs=(20, 40), size="32", frames=8,
                              refine_steps=(0, 2), encoder="floor", device="cpu", preset="ultrafast")
    report = json.loads(json.dumps(report))
    (video,) = report["videos"]
    assert (video["frames"], video["width"], video["height"]) == (8, 32, 32)
    assert [r["crf"] for r in video["x265"]] == [20, 40]
    assert video["x265"][0]["psnr"] > video["x265"][1]["psnr"] and video["x265"][0]["bpp"] > video["x265"][1]["bpp"]
    assert [(r["refine"], [h["bits"] for h in r["hgs"]]) for r in video["ours"]] == [(0, [8, 4]), (2, [8, 4])]
    for row in video["ours"]:
        for h in row["hgs"]:
            assert h["bpp"] > 0 and 0 < h["ssim"] <= 1 and h["encode_fps"] > 0 and h["decode_fps"] > 0
        assert row["hgs"][0]["bpp"] > row["hgs"][1]["bpp"]  # 8 bits cost more than 4
        # the files `hypergs encode` writes: the means at the writer's own depth for this canvas and count
        assert [h["position_bits"] for h in row["hgs"]] == [clip_bits(b, 32, 32, 16)[0] for b in (8, 4)]
    assert len(video["pairs"]) == 4
    assert all(p["nearest"]["crf"] in (20, 40) and p["bpp_ratio"] > 0 for p in video["pairs"])
    assert report["table"].count("| tiny |") == 4


# ---- scale: bounded memory --------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def pan_video(tmp_path_factory):
    path = tmp_path_factory.mktemp("pan") / "pan.mp4"
    info = scale.make_pan_video(path, seconds=6, width=480, height=272, fps=24, preset="ultrafast")
    assert info["frames"] == 144
    return path


def _encode_job(video, out, hold):
    return scale.run_scale_job({"job": "encode", "video": str(video), "output": str(out), "gaussians": 64,
                                "chunk_frames": 8, "encoder": "floor", "device": "cpu", "hold_frames": hold},
                            timeout=300)


def test_scale_encode_memory_is_bounded(pan_video, tmp_path):
    """Peak RSS after all 144 frames vs after the first 72: streaming adds next to nothing over the
    second half. The control keeps every decoded frame (72 more frames = 28 MB), and the same
    measurement must see it, so the test can fail."""
    frame_mb = 480 * 272 * 3 / 2**20
    streamed = _encode_job(pan_video, tmp_path / "a.hgs", hold=False)
    streamed.update(scale.memory_growth(streamed))
    held = _encode_job(pan_video, tmp_path / "b.hgs", hold=True)
    held.update(scale.memory_growth(held))
    assert streamed["frames"] == held["frames"] == 144 and held["held_frames"] == 144
    if not streamed["peak_reset"]:
        pytest.skip("cannot reset the peak RSS here (/proc/self/clear_refs): start-up would hide the encode's")
    assert held["growth_second_half_mb"] > 0.7 * 72 * frame_mb  # the measurement sees held frames
    # < ~8 MB: bounded by the chunk (the allocator's own noise here: 0 to 4.1 MB over repeated runs)
    assert streamed["growth_second_half_mb"] < 0.3 * 72 * frame_mb
    assert held["peak_rss_mb"] - streamed["peak_rss_mb"] > 0.7 * 144 * frame_mb  # 144 held frames = 54 MB
    with HgsReader(tmp_path / "a.hgs") as reader:
        assert (reader.num_frames, reader.num_gaussians, reader.canvas_width) == (144, 120, 480)  # 64 clamped: 15 x 8 cells


def test_bench_scale_report(tmp_path):
    report = scale.bench_scale(None, seconds=1, width=160, height=96, gaussians=32, chunk_frames=4,
                            render_width=240, render_height=144, render_frames=3, psnr_frames=2, encoder="floor",
                            device="cpu", keep=str(tmp_path), also_encode_video=True)
    report = json.loads(json.dumps(report))
    assert report["source"]["synthetic"] and report["source"]["frames"] == 24
    e, r = report["encode"], report["render"]
    assert e["frames"] == 24 and e["fps"] > 0 and e["hgs_bytes"] == (tmp_path / "scale.hgs").stat().st_size
    assert len(e["rss_trace"]) == 1 + 24 // 4 and e["growth_second_half_mb"] is not None
    assert report["settings"]["gaussians"] == 32 and e["gaussians"] == 28  # 7 x 4 cells
    assert report["encode_video"]["frames"] == 24 and report["encode_video"]["growth_second_half_mb"] is not None
    assert (r["frames"], r["of"], r["width"], r["height"]) == (3, 24, 240, 144)
    assert r["quality"]["psnr_at_source_size"] > 10
    assert "| video -> .hgs streamed (EncodePlan.write_hgs) | 24 |" in report["table"] and "240x144" in report["table"]


# ---- command line and plots ------------------------------------------------------------------------------

def test_bench_commands_are_registered(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    for name in ("a.mp4", "b.mp4"):  # inputs must exist (commands/options.py)
        (tmp_path / name).touch()
    parser = build_parser()
    args = parser.parse_args(["bench", "vs-fit", "a.mp4", "b.mp4", "--frames", "4", "--sizes", "256", "native",
                              "--gaussians", "250", "--fit-iters", "100", "300", "--refine-steps", "1", "10",
                              "--encoder", "floor", "--json"])
    assert args.videos == ["a.mp4", "b.mp4"] and args.sizes == ["256", "native"] and args.fit_iters == [100, 300]
    args = parser.parse_args(["bench", "vs-x265", "a.mp4", "--crf", "28", "--bits", "8", "--encoder", "floor"])
    assert args.crf == [28] and args.refine_steps == [0]
    args = parser.parse_args(["bench", "scale", "--seconds", "2", "--resolution", "320x180", "--encoder", "floor"])
    assert args.video is None and args.seconds == 2.0


@pytest.mark.skipif((__import__("os").cpu_count() or 1) < 2, reason="one core: every count is 1")
def test_vs_fit_runs_every_method_on_the_threads_asked(tiny_video, tmp_path):
    """Fitting is nearly all rasterizer: on its default threads (all cores) it would race a one-thread
    network. The command gives torch and the numba rasterizer `--threads` (run in a thread of its own, as
    numba's setting is per thread; torch's is restored after)."""
    import threading

    import torch

    from hypergs_blender.commands.cli import main

    out, before = tmp_path / "vs_fit.json", torch.get_num_threads()
    argv = ["bench", "vs-fit", str(tiny_video), "--encoder", "floor", "--sizes", "32", "--frames", "2",
            "--gaussians", "16", "--refine-steps", "1", "--fit-iters", "2", "--threads", "1", "-o", str(out)]
    worker = threading.Thread(target=main, args=(argv,))
    try:
        worker.start()
        worker.join()
    finally:
        torch.set_num_threads(before)
    report = json.loads(out.read_text())
    machine = report["machine"]
    assert (machine["torch_threads"], machine.get("numba_threads", 1), report["settings"]["threads"]) == (1, 1, 1)


def test_make_plots_writes_pngs_and_tables(tiny_video, tmp_path):
    bench = tmp_path / "bench"
    bench.mkdir()
    fit = vs_fit.bench_vs_fit([tiny_video], gaussians=(16,), refine_steps=(1,), fit_iters=(2,), sizes=("32",), frames=4,
                          encoder="floor", device="cpu")
    x265 = vs_x265.bench_vs_x265([tiny_video], gaussians=(16,), bits=(8, 4), crfs=(30,), size="32", frames=4,
                            encoder="floor", device="cpu", preset="ultrafast")
    (bench / "vs_fit.json").write_text(json.dumps(fit))
    (bench / "vs_x265.json").write_text(json.dumps(x265))
    (bench / "other.json").write_text(json.dumps({"machine": {}}))  # e.g. `bench codec -o`: skipped
    written = plots.make_plots(bench, tmp_path / "docs", log=lambda message: None)
    names = sorted(p.name for p in written)
    assert names == ["tables.md", "vs_fit.png", "vs_x265.png"]
    for p in written:
        assert p.stat().st_size > 1000
    assert (tmp_path / "docs" / "vs_fit.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    tables = (bench / "tables.md").read_text()
    assert "| frames | N | method |" in tables and "| video | ours |" in tables


def test_bench_picture_renders_each_preset(tmp_path):
    from hypergs_blender.bench.picture import bench_presets, save_picture
    report = bench_presets(ROOT / "hypergs_blender" / "samples" / "sample.mp4", presets=("draft", "standard"),
                           width=128, height=72, frames=2, encoder="floor")
    draft, standard = report["presets"]["draft"], report["presets"]["standard"]
    assert report["source_size"] == [256, 144] and standard["gaussians"] > draft["gaussians"]
    assert standard["psnr"] > draft["psnr"] > 15  # more Gaussians look better
    picture = save_picture(report, tmp_path / "picture.png")
    assert picture.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_bench_plots_command_writes_the_plots(tmp_path, capsys):
    """`hypergs bench plots --bench DIR --out DIR` (its --bench once overwrote the subcommand's name)."""
    from hypergs_blender.commands.cli import main
    reports, out = tmp_path / "bench", tmp_path / "docs"
    reports.mkdir()
    (reports / "vs_fit.json").write_text((Path(__file__).resolve().parents[1] / "docs/bench/vs_fit.json").read_text())
    main(["bench", "plots", "--bench", str(reports), "--out", str(out)])
    assert (out / "vs_fit.png").stat().st_size > 0 and (reports / "tables.md").is_file()
