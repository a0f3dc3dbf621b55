import numpy as np
import pytest

from hypergs_blender.commands.cli import main
from hypergs_blender.io.clips import load_clip
from hypergs_blender.encode import Cancelled, EncodePlan, FloorEncoder, encode_frames, encode_video
from hypergs_blender.errors import HyperGSError
from hypergs_blender.metrics import psnr
from hypergs_blender.render import render_frames
from hypergs_blender.io.frames import read_frames


def test_encode_video_chunks_and_metadata(moving_video):
    calls = []
    video = encode_video(moving_video, FloorEncoder(canvas=32, clip_frames=4), 64, chunk_clips=1,
                         progress=lambda done, total: calls.append((done, total)))
    assert video.params.shape == (12, 64, 8)
    assert (video.canvas_width, video.canvas_height, video.fps) == (64, 48, 12.0)
    assert calls == [(0, 12), (4, 12), (8, 12), (12, 12)]
    # the floor reproduces the frames roughly (a blurred version)
    frames, _, _ = read_frames(moving_video)
    assert psnr(render_frames(video, 64, 48), frames / 255.0).mean() > 18


def test_chunking_does_not_change_the_result(moving_video):
    encoder = FloorEncoder(canvas=32, clip_frames=4)
    one = encode_video(moving_video, encoder, 64, chunk_clips=1)
    three = encode_video(moving_video, encoder, 64, chunk_clips=3)
    np.testing.assert_array_equal(one.params, three.params)


def test_grid_tiles_cover_the_frame(moving_video):
    frames, _, _ = read_frames(moving_video, 4)
    params = encode_frames(frames, FloorEncoder(canvas=16, clip_frames=4), 4 * 36, grid=2)
    assert params.shape == (4, 144, 8)
    # every tile's Gaussians stay in its quarter of the frame
    quarters = (params[0, :, 0] > 0).astype(int) + 2 * (params[0, :, 1] > 0)
    assert np.bincount(quarters).tolist() == [36, 36, 36, 36]
    with pytest.raises(HyperGSError, match="split evenly"):
        encode_frames(frames, FloorEncoder(canvas=16, clip_frames=4), 150, grid=2)


def test_cancel_raises_and_plan_knows_the_output(moving_video):
    plan = EncodePlan(moving_video, FloorEncoder(canvas=32, clip_frames=4), 64, start=2, stop=10)
    assert plan.indices == list(range(2, 10)) and (plan.width, plan.height) == (64, 48)
    with pytest.raises(Cancelled):
        list(plan.chunks(progress=lambda done, total: done < 4, chunk_clips=1))


@pytest.mark.parametrize("suffix", [".hgs", ".npz"])
def test_encode_command_writes_a_clip(moving_video, tmp_path, suffix):
    out = tmp_path / f"clip{suffix}"
    main(["encode", str(moving_video), "-o", str(out), "--encoder", "floor", "--gaussians", "250"])
    video = load_clip(out)
    assert video.params.shape == (12, 250, 8)
    main(["render", str(out), "-o", str(tmp_path / "frames"), "--width", "32"])
    assert len(list((tmp_path / "frames").glob("frame_*.png"))) == 12


def test_encode_command_errors_leave_no_file(tmp_path, capsys):
    bad = tmp_path / "notes.mp4"
    bad.write_text("not a video")
    out = tmp_path / "clip.hgs"
    with pytest.raises(SystemExit) as exit_info:
        main(["encode", str(bad), "-o", str(out), "--encoder", "floor"])
    assert exit_info.value.code == 2
    assert "notes.mp4" in capsys.readouterr().err
    assert not out.exists() and not list(tmp_path.glob("clip.hgs*"))


def test_estimate_scales_with_gaussians_frames_and_refine_steps():
    from hypergs_blender.encode import ENCODE_COSTS, estimate, plan_layout
    small, large = plan_layout(432, 240, 4, cell=8.0), plan_layout(864, 480, 4, cell=8.0)
    assert large.count == 4 * small.count
    a, b = estimate(small, 10), estimate(large, 10)
    assert b.seconds == pytest.approx(4 * a.seconds) and b.blend_bytes == 4 * a.blend_bytes
    assert estimate(small, 20).hgs_bytes == 2 * a.hgs_bytes
    cost = ENCODE_COSTS["network"]
    assert a.blend_bytes == small.count * 10 * cost.blend_bytes_per_gaussian
    refined = estimate(small, 10, refine=30)
    step = cost.refine_first_s_per_gaussian + 29 * cost.refine_s_per_gaussian_step
    assert refined.seconds - a.seconds == pytest.approx(small.count * 10 * step)
    assert estimate(small, 10, encoder="floor").seconds < a.seconds  # the network costs more
