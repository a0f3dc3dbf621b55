"""hypergs_blender/points.py: GaussianVideo <-> image-plane point arrays (the Blender storage). No bpy."""
import numpy as np
import pytest

from hypergs_blender.gaussians import GaussianVideo
from hypergs_blender.colour import linear_to_srgb, srgb_image_to_linear_rgba, srgb_to_linear
from hypergs_blender.points import (FRAME_COUNTS, clip_frame_index, frame_counts, params_to_points, points_to_params,
                                    points_to_video, video_to_points)
from hypergs_blender.render import render_frames, render_params


def random_params(t, n, seed=0):
    rng = np.random.default_rng(seed)
    p = np.empty((t, n, 8), np.float32)
    p[..., 0:2] = rng.uniform(-1, 1, (t, n, 2))
    p[..., 2:4] = rng.uniform(0.5, 6, (t, n, 2))
    p[..., 4] = rng.uniform(0, 2 * np.pi, (t, n))
    p[..., 5:8] = rng.uniform(-0.2, 1.3, (t, n, 3))
    return p


def test_srgb_transfer_is_inverted_everywhere():
    v = np.linspace(-2, 3, 2001, dtype=np.float32)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(v)), v, atol=2e-6)
    # the standard curve on [0, 1]
    assert srgb_to_linear(np.float32(0.5)) == pytest.approx(0.21404, abs=1e-5)
    assert srgb_to_linear(np.float32(1.0)) == pytest.approx(1.0, abs=1e-6)


def test_points_layout():
    p = random_params(3, 5)
    pts = params_to_points(p, 432, 240)
    assert pts["position"].shape == (15, 3) and pts["scale"].shape == (15, 2)
    assert pts["color"].shape == (15, 4) and pts["rotation"].shape == (15,)
    assert all(a.dtype == np.float32 for k, a in pts.items() if k != "frame")
    np.testing.assert_array_equal(pts["frame"], np.repeat(np.arange(3), 5))
    # the canvas' corners map to the plane's: x in [-aspect, aspect], y up
    corner = np.array([[-1, -1, 2, 2, 0, 0.5, 0.5, 0.5]], np.float32)
    c = params_to_points(corner, 432, 240)
    np.testing.assert_allclose(c["position"][0], [-432 / 240, 1, 0], rtol=1e-6)
    np.testing.assert_allclose(c["scale"][0], [2 * 2 / 240] * 2, rtol=1e-6)
    np.testing.assert_allclose(c["color"][0], [0.21404] * 3 + [1], atol=1e-5)


def test_round_trip():
    p = random_params(4, 50)
    pts = params_to_points(p, 432, 240)
    back = points_to_video(pts, 432, 240).params
    np.testing.assert_allclose(back[..., [0, 1, 2, 3, 5, 6, 7]], p[..., [0, 1, 2, 3, 5, 6, 7]], atol=2e-5)
    # rotations agree modulo 2 pi
    d = np.angle(np.exp(1j * (back[..., 4] - p[..., 4])))
    assert np.abs(d).max() < 1e-5


def test_round_trip_renders_the_same_at_another_aspect():
    """Stretched to a square output, points -> params renders exactly what the original params do."""
    p = random_params(1, 80, seed=3)
    pts = params_to_points(p, 432, 240)
    params = points_to_params(pts["position"], pts["scale"], pts["rotation"], pts["color"], 432, 240)
    ours = render_params(params, 432, 240, 128, 128)
    ref = render_frames(GaussianVideo(p, 432, 240), 128, 128)[0]
    np.testing.assert_allclose(ours, ref, atol=1e-4)


def test_empty_frame_renders_black():
    assert not render_params(np.zeros((0, 8), np.float32), 10, 10, 7, 5).any()


def test_render_pass_is_linear_and_bottom_up():
    img = np.zeros((2, 3, 3), np.float32)
    img[0] = 0.5  # top row
    img[1] = -0.1  # bottom row, negative sum
    rgba = srgb_image_to_linear_rgba(img)
    assert rgba.shape == (2, 3, 4)
    np.testing.assert_allclose(rgba[1, :, :3], 0.21404, atol=1e-5)  # top row is last
    np.testing.assert_array_equal(rgba[0, :, :3], 0)
    np.testing.assert_array_equal(rgba[..., 3], 1)


def test_clip_frame_index_matches_the_frame_filter():
    assert [clip_frame_index(f, 1, 1.0) for f in (0, 1, 2, 70)] == [-1, 0, 1, 69]
    assert [clip_frame_index(f, 10, 1 / 3) for f in (10, 12, 13, 16)] == [0, 0, 1, 2]  # the 1e-4 margin
    assert clip_frame_index(5.5, 1, 2.0) == 9


def test_ragged_frames_are_padded_and_unpadded():
    """Points deleted in one frame and added in another: padded to N, the real counts recorded."""
    p = random_params(3, 6, seed=5)
    pts = params_to_points(p, 64, 48)
    keep = np.ones(18, bool)
    keep[[7, 8]] = False  # frame 1 loses two points
    pts = {k: v[keep] for k, v in pts.items()}
    extra = params_to_points(random_params(1, 1, seed=6), 64, 48)
    extra["frame"][:] = 2  # frame 2 gains one
    pts = {k: np.concatenate([pts[k], extra[k]]) for k in pts}
    video = points_to_video(pts, 64, 48, 30.0, num_frames=5, grid=(2, 2), source={"path": "x.mp4"})
    assert video.params.shape == (5, 7, 8) and video.fps == 30.0 and video.grid == (2, 2)
    assert video.source == {"path": "x.mp4", FRAME_COUNTS: [6, 4, 7, 0, 0]}
    assert frame_counts(video).tolist() == [6, 4, 7, 0, 0]
    np.testing.assert_allclose(video.params[1, :4][:, [0, 1, 5]], p[1, [0, 3, 4, 5]][:, [0, 1, 5]], atol=2e-5)
    np.testing.assert_array_equal(video.params[1, 4:, 5:8], 0)  # padding is invisible
    assert np.all(video.params[..., 2:4] > 0)  # and a valid Gaussian for the codec
    back = video_to_points(video)
    assert len(back["frame"]) == 17
    for k in ("position", "scale", "color"):
        np.testing.assert_allclose(back[k], pts[k][np.argsort(pts["frame"], kind="stable")], atol=2e-5)
    # the padding renders nothing
    np.testing.assert_allclose(render_params(video.params[1], 64, 48, 32, 24),
                               render_params(video.params[1, :4], 64, 48, 32, 24), atol=1e-6)


def test_regular_clip_has_no_frame_counts_and_bad_points_are_left_out():
    p = random_params(2, 4, seed=7)
    pts = params_to_points(p, 64, 48)
    video = points_to_video(pts, 64, 48, source={FRAME_COUNTS: [1, 1]})  # a stale entry is dropped
    assert FRAME_COUNTS not in video.source and video.params.shape == (2, 4, 8)
    pts["scale"][0] = 0  # a zero scale, a NaN, a negative frame: not Gaussians
    pts["color"][1, 0] = np.nan
    pts["frame"][5] = -1
    pts["scale"][6] *= -1  # only the square of a scale matters
    video = points_to_video(pts, 64, 48)
    assert frame_counts(video).tolist() == [2, 3]
    np.testing.assert_allclose(video.params[1, 1, 2:4], p[1, 2, 2:4], rtol=1e-5)
    # malformed counts are ignored
    video.source[FRAME_COUNTS] = ["a", None]
    assert frame_counts(video).tolist() == [3, 3]


@pytest.mark.parametrize("fps, stored", [(30.0, (30, 1.0)), (24.0, (24, 1.0)), (29.97003, (30, 1.001)),
                                         (23.976, (24, 1.001)), (59.94, (60, 1.001)), (12.5, (12, 0.96)),
                                         (0.5, (1, 2.0))])
def test_a_clip_frame_rate_as_blender_stores_it(fps, stored):
    """Whole rates and the NTSC ones as Blender's presets write them (base 1 or 1.001); others exactly."""
    from hypergs_blender.points import blender_fps
    whole, base = blender_fps(fps)
    assert (whole, base) == pytest.approx(stored) and isinstance(whole, int)
    assert whole / base == pytest.approx(fps, rel=1e-4)
