import numpy as np
import pytest

from hypergs_blender import encode
from hypergs_blender.encode import (ADAPTIVE_MIN_REFINE, adaptive_start, encode_frames, encoder_layout, frames_layout,
                                    predict_frames, refine_frames)
from hypergs_blender.gaussians import grid_anchors
from hypergs_blender.placement import (SPLIT_FRACTION, SPLIT_MAX_PSNR, SPLIT_MIN_GAIN_DB, cell_errors, choose_start,
                                       owner_cells, pixel_errors, split_frame, split_may_pay)
from hypergs_blender.runtime import make_encoder


def grid_params(cols, rows, tag):
    """One Gaussian at each cell centre of a cols x rows grid over [-1, 1]^2 (row-major), its colour `tag`."""
    params = np.zeros((cols * rows, 8), np.float32)
    params[:, :2] = grid_anchors(cols * rows, cols / rows)
    params[:, 2:4] = 1
    params[:, 5:8] = tag
    return params


def test_cell_errors_against_a_loop_over_pixels():
    rng = np.random.default_rng(0)
    h, w, cols, rows = 7, 11, 3, 2  # cells of unequal pixel counts
    rendered = rng.uniform(-0.3, 1.3, (h, w, 3)).astype(np.float32)
    target = rng.uniform(0, 1, (h, w, 3)).astype(np.float32)
    expected = np.zeros(cols * rows)
    for i in range(h):
        for j in range(w):
            cell = int((i + 0.5) / h * rows) * cols + int((j + 0.5) / w * cols)
            expected[cell] += ((np.clip(rendered[i, j], 0, 1) - target[i, j]) ** 2).sum()
    np.testing.assert_allclose(cell_errors(rendered, target, cols, rows), expected, rtol=1e-6)


def test_owner_cells_of_means_inside_and_outside_the_canvas():
    params = np.zeros((4, 8), np.float32)
    params[:, :2] = [[-0.9, -0.9], [0.1, -0.1], [1.5, 0.2], [-3.0, 2.0]]
    np.testing.assert_array_equal(owner_cells(params, 2, 2), [0, 1, 3, 2])


def test_split_frame_spends_the_count_on_the_cells_that_score_worst():
    coarse, fine = grid_params(4, 2, 1.0), grid_params(8, 4, 2.0)  # four fine Gaussians in each coarse cell
    score = np.array([0, 5, 1, 0, 9, 0, 3, 0], float)  # cells 4, 1, 6, 2 worst, in that order
    out, split = split_frame(coarse, fine, score, 4, 2, 8 + 3 * 2 + 2)  # room to split two cells, and 2 more
    assert out.shape == (16, 8) and np.flatnonzero(split).tolist() == [1, 4]
    owners = owner_cells(out, 4, 2)
    fine_rows = out[:, 5] == 2.0
    # the coarse Gaussians of all but the two worst cells, the fine ones of those two, two of the third's
    assert sorted(owners[~fine_rows]) == [0, 2, 3, 5, 6, 7]
    assert np.bincount(owners[fine_rows], minlength=8).tolist() == [0, 4, 0, 0, 4, 0, 2, 0]
    # every output Gaussian is one of the runs' own
    assert all(any((p == q).all() for q in np.concatenate([coarse, fine])) for p in out)
    # the extremes: the coarse run alone, the fine run alone
    np.testing.assert_array_equal(split_frame(coarse, fine, score, 4, 2, 8)[0], coarse)
    assert sorted(map(tuple, split_frame(coarse, fine, score, 4, 2, 32)[0])) == sorted(map(tuple, fine))


def test_split_frame_counts_a_cell_no_fine_mean_fell_in():
    coarse, fine = grid_params(2, 1, 1.0), grid_params(4, 1, 2.0)
    fine[:, 0] = [0.1, 0.3, 0.5, 0.7]  # every fine mean in the right cell: splitting the left one loses one
    out, split = split_frame(coarse, fine, np.array([9.0, 1.0]), 2, 1, 4)
    assert len(out) == 4 and split.all() and (out[:, 5] == 2.0).sum() == 4  # both cells split: exactly the count


def test_split_frame_refuses_a_count_outside_its_runs():
    coarse, fine = grid_params(2, 2, 1.0), grid_params(4, 4, 2.0)
    for count in (3, 17):
        with pytest.raises(ValueError, match="between the coarse"):
            split_frame(coarse, fine, np.zeros(4), 2, 2, count)


@pytest.mark.parametrize("gain_db, taken", [(SPLIT_MIN_GAIN_DB + 0.05, True), (SPLIT_MIN_GAIN_DB - 0.05, False)])
def test_the_split_is_taken_where_its_seamless_render_beats_the_grid_by_enough(gain_db, taken):
    h, w = 4, 8
    coarse, fine, grid = grid_params(2, 1, 1.0), grid_params(4, 1, 2.0), grid_params(3, 1, 3.0)
    target = np.full((h, w, 3), 0.5, np.float32)
    # the coarse run errs by 0.2 on its left cell (which is split) and 0.1 on its right one; the fine run is
    # exact; so the seamless split errs as the coarse run's right cell, and the grid by 10^(gain / 10) times that
    seamless = 16 * 3 * 0.1 ** 2
    grid_error = seamless * 10 ** (gain_db / 10)

    def render(params):
        image = target.copy()
        if params[0, 5] == 1.0:
            image[:, :4] += 0.2
            image[:, 4:] += 0.1
        return image

    start = choose_start(grid, grid_error, coarse, fine, target, 2, 1, render)
    assert start.shape == (3, 8)
    if taken:
        assert sorted(start[:, 5].tolist()) == [1.0, 2.0, 2.0]  # the right coarse cell, two of the left's fine
    else:
        np.testing.assert_array_equal(start, grid)


def test_only_a_frame_below_the_ceiling_may_split():
    target = np.full((8, 8, 3), 0.5, np.float32)
    for psnr, may in ((SPLIT_MAX_PSNR - 0.1, True), (SPLIT_MAX_PSNR + 0.1, False)):
        render = target + np.float32(10 ** (-psnr / 20))  # an error of that PSNR everywhere
        assert split_may_pay(pixel_errors(render, target).sum(), target) == may
    assert pixel_errors(np.full_like(target, 1.4), np.ones_like(target)).sum() == 0  # clipped as a viewer shows it


def half_detailed_frames(t=2, h=96, w=192, seed=0):
    """Frames flat grey on the left half and on the right a texture of about 4 px (noise upsampled): the
    coarse run cannot draw it, the fine one can."""
    import torch
    import torch.nn.functional as F
    noise = torch.from_numpy(np.random.default_rng(seed).uniform(0, 255, (t, 3, h // 4, w // 8))).float()
    frames = np.full((t, h, w, 3), 128, np.uint8)
    texture = F.interpolate(noise, size=(h, w // 2), mode="bicubic", align_corners=False).clamp(0, 255)
    frames[:, :, w // 2:] = texture.permute(0, 2, 3, 1).numpy().astype(np.uint8)
    return frames


def test_the_adaptive_start_puts_the_gaussians_where_the_frame_has_detail():
    flat = np.full((1, 96, 192, 3), 128, np.uint8)  # the grid draws it above the ceiling: it keeps the grid
    frames = np.concatenate([half_detailed_frames(), flat])
    encoder = make_encoder()
    layout = frames_layout(frames, encoder, gaussians=288)
    grid = predict_frames(frames, encoder, layout)
    params = adaptive_start(frames, encoder, layout, grid)
    assert params.shape == (3, layout.count, 8) and np.isfinite(params).all()
    np.testing.assert_array_equal(params[2], grid[2])
    params, grid = params[:2], grid[:2]
    # no cell of the flat half split: its Gaussians are the coarse run's there (0.6 of the grid's), and the
    # textured half has the rest
    coarse = encoder_layout(encoder, 192, 96, gaussians=round(SPLIT_FRACTION * layout.count))
    left = (params[..., 0] < 0).sum(axis=1)
    assert (left <= -(-coarse.cols // 2) * coarse.rows).all() and (left < 0.35 * layout.count).all(), left
    assert (grid[..., 0] > 0).mean() == pytest.approx(0.5, abs=0.01)


def test_only_a_long_enough_refinement_by_the_network_starts_from_the_adaptive_placement(monkeypatch):
    import hypergs_blender.refine as refine
    monkeypatch.setattr(refine, "refine_params", lambda params, frames, steps, device: params)  # the start itself
    frames = half_detailed_frames(t=1)
    encoder = make_encoder()
    layout = frames_layout(frames, encoder, gaussians=288)
    grid = predict_frames(frames, encoder, layout)
    adaptive = adaptive_start(frames, encoder, layout, grid)
    assert not np.array_equal(grid, adaptive)
    np.testing.assert_array_equal(encode_frames(frames, encoder, layout, ADAPTIVE_MIN_REFINE), adaptive)
    np.testing.assert_array_equal(encode_frames(frames, encoder, layout, ADAPTIVE_MIN_REFINE - 1), grid)
    np.testing.assert_array_equal(refine_frames(frames, encoder, layout, grid, ADAPTIVE_MIN_REFINE, adaptive=False),
                                  grid)
    floor = encode.FloorEncoder()
    np.testing.assert_array_equal(encode_frames(frames, floor, frames_layout(frames, floor, gaussians=288),
                                                ADAPTIVE_MIN_REFINE),
                                  predict_frames(frames, floor, frames_layout(frames, floor, gaussians=288)))
    # at the finest cell the fine run cannot hold more than the grid: the grid
    finest = frames_layout(frames, encoder, cell=4)
    grid = predict_frames(frames, encoder, finest)
    assert adaptive_start(frames, encoder, finest, grid) is grid


def test_eval_refines_from_the_adaptive_start_unless_asked_for_the_uniform_one(tmp_path, capsys):
    import json

    from conftest import write_video
    from hypergs_blender.commands.cli import main
    video = write_video(tmp_path / "half.mp4", half_detailed_frames(t=2))
    reports = {}
    for flag in ([], ["--uniform-start"]):
        main(["eval", str(video), "--full", "--gaussians", "288", "--refine", str(ADAPTIVE_MIN_REFINE), "--frames", "1",
              "--temporal-frames", "0", "--json", *flag])
        report = json.loads(capsys.readouterr().out)
        reports[report["adaptive_start"]] = report["mean"]["psnr"]
    assert set(reports) == {True, False} and reports[True] != reports[False]
