from pathlib import Path

import numpy as np
import pytest

from hypergs_blender.errors import VideoError
from conftest import write_video
from hypergs_blender.io.frames import Display, iter_frames, probe, read_frames, sample_indices
from hypergs_blender.io.images import resize_crop


@pytest.fixture
def clip(tmp_path):
    t = np.arange(10)[:, None, None, None]
    frames = np.broadcast_to(((t * 20) % 256).astype(np.uint8), (10, 48, 80, 3)).copy()
    path = tmp_path / "clip.mp4"
    write_video(path, frames)
    return path


def test_probe_and_read(clip):
    info = probe(clip)
    assert (info.width, info.height, info.num_frames, info.fps) == (80, 48, 10, 12.0)
    frames, _, indices = read_frames(clip, 4)
    assert frames.shape == (4, 48, 80, 3) and indices == [0, 3, 6, 9]
    # frame t has value 20 t (lossless encode)
    np.testing.assert_allclose(frames[:, 0, 0, 0], [0, 60, 120, 180], atol=2)
    square, _, _ = read_frames(clip, 2, start=2, stop=5, size=32)
    assert square.shape == (2, 32, 32, 3)


@pytest.mark.parametrize("rotation", [90, 180, 270])
def test_a_video_with_a_display_rotation_comes_upright(tmp_path, rotation):
    """A phone's portrait video (landscape frames and a display rotation in the container) is read as players
    and Blender 5's Sequencer show it: probe's size and every frame upright, also resized and cropped."""
    stored = np.zeros((3, 48, 80, 3), np.uint8)
    stored[:, :8, :16] = 255  # a white block in the stored top-left corner
    stored[:, :, :, 1] = np.arange(3)[:, None, None] * 40
    path = write_video(tmp_path / "phone.mp4", stored, rotation=rotation)
    turns = rotation // 90
    upright = np.rot90(stored, turns, axes=(1, 2))
    info = probe(path)
    assert (info.width, info.height) == (upright.shape[2], upright.shape[1]) and info.num_frames == 3
    frames, _, _ = read_frames(path)
    np.testing.assert_allclose(frames, upright, atol=2)
    square, _, _ = read_frames(path, size=24)
    assert square.shape == (3, 24, 24, 3)
    np.testing.assert_allclose(square, np.stack([resize_crop(f, 24) for f in upright]), atol=8)
    # as Blender 4.2's movie strip shows it: as stored, sized as stored
    as_stored = Display(rotation=False)
    info = probe(path, as_stored)
    assert (info.width, info.height) == (80, 48)
    np.testing.assert_allclose(np.stack([f for _, f in iter_frames(path, display=as_stored)]), stored, atol=2)
    square = np.stack([f for _, f in iter_frames(path, size=24, display=as_stored)])
    np.testing.assert_allclose(square, np.stack([resize_crop(f, 24) for f in stored]), atol=8)


def test_a_variable_rate_video_is_read_on_its_nominal_rate_as_blender_shows_it(tmp_path):
    """A phone's variable-rate video, frames at slots 0 1 2 3 4 6 8 9 10 11 of 1/24 s: Blender's movie strip shows
    12 frames at 24 fps, holding a frame where a slot is skipped (bpy 5.0.1 and 4.2.23 read frames 10 30 50 70 90
    90 109 109 130 150 170 190 from this file's grey levels). The clip's frames must be those, or the Convert's
    scene strip drifts from the movie strip after each gap."""
    grey = np.arange(10) * 20 + 10
    frames = np.broadcast_to(grey[:, None, None, None].astype(np.uint8), (10, 48, 64, 3)).copy()
    path = write_video(tmp_path / "vfr.mp4", frames, fps=24, slots=[0, 1, 2, 3, 4, 6, 8, 9, 10, 11])
    info = probe(path)
    assert (info.fps, info.num_frames) == (24.0, 12)
    shown = [0, 1, 2, 3, 4, 4, 5, 5, 6, 7, 8, 9]  # the frame of each slot
    np.testing.assert_allclose([f[0, 0, 0] for _, f in iter_frames(path)], grey[shown], atol=1)
    picked = list(iter_frames(path, [5, 7, 11]))
    assert [i for i, _ in picked] == [5, 7, 11]
    np.testing.assert_allclose([f[0, 0, 0] for _, f in picked], grey[[4, 5, 9]], atol=1)
    with pytest.raises(VideoError, match="frame 12 is past the end"):
        list(iter_frames(path, [12]))


def test_a_cut_off_video_says_so(tmp_path):
    """A file cut in half whose header (moov first) still states the whole duration: the frames that are there
    are read, then a clear error instead of a second of frozen frames passed off as the rest."""
    import av
    path = tmp_path / "whole.mp4"
    with av.open(str(path), "w", options={"movflags": "faststart"}) as container:
        stream = container.add_stream("libx264", rate=24, options={"crf": "0"})
        stream.width, stream.height, stream.pix_fmt = 64, 48, "yuv444p"
        for i in range(72):
            noise = np.random.default_rng(i).integers(0, 256, (48, 64, 3), dtype=np.uint8)
            container.mux(stream.encode(av.VideoFrame.from_ndarray(noise, format="rgb24")))
        container.mux(stream.encode())
    cut = tmp_path / "cut.mp4"
    cut.write_bytes(path.read_bytes()[: path.stat().st_size // 2])
    assert probe(cut).num_frames == 72
    read = []
    with pytest.raises(VideoError, match=r"cut.mp4: only \d+ of its 72 frames can be decoded: the file is cut off"):
        for index, _ in iter_frames(cut):
            read.append(index)
    assert 24 < len(read) < 72


@pytest.mark.parametrize("hdr", ["hlg", "pq"])
def test_hdr_video_is_read_as_blender_5_shows_it(tmp_path, hdr):
    """An iPhone's HLG (or a PQ) video: Blender 5 colour-manages it, so a converted clip must show the sRGB
    picture of its light, not its coded values (which are far darker: mid-grey 128 shows as about 188)."""
    import av

    from hypergs_blender.colour import hdr_to_srgb
    ramp = np.broadcast_to(np.linspace(0, 255, 64).astype(np.uint8)[None, None, :, None], (2, 48, 64, 3)).copy()
    ramp[:, :16, :, 1:] = 0  # a red band
    path = write_video(tmp_path / "hdr.mp4", ramp, hdr=hdr)
    with av.open(str(path)) as container:
        coded = next(container.decode(video=0)).to_ndarray(format="rgb48le").astype(np.float32) / 65535
    frames, _, _ = read_frames(path)
    np.testing.assert_allclose(frames[0], np.round(hdr_to_srgb(coded, hdr) * 255), atol=1)
    assert frames[0, 30, 32].mean() > 160  # mid-grey, brightened
    assert probe(path).hdr == hdr  # what the dialogs' estimate counts the mapping's cost by
    assert probe(write_video(tmp_path / "sdr.mp4", ramp)).hdr is None
    # as Blender 4.5's movie strip shows it: the coded values, at no extra cost
    no_hdr = Display(hdr=False)
    shown = np.stack([f for _, f in iter_frames(path, display=no_hdr)])
    np.testing.assert_allclose(shown[0], np.round(coded * 255), atol=1)
    assert probe(path, no_hdr).hdr is None


def test_iter_frames_streams_a_range(clip):
    got = [i for i, _ in iter_frames(clip, [2, 3, 4])]
    assert got == [2, 3, 4]


def test_sample_indices():
    assert sample_indices(100, 5) == [0, 25, 50, 74, 99]
    assert sample_indices(10, None, 2, 5) == [2, 3, 4]
    with pytest.raises(VideoError):
        sample_indices(10, 3, 10)


def test_resize_crop_centre():
    image = np.zeros((40, 80, 3), np.uint8)
    image[:, 20:60] = 255
    out = resize_crop(image, 20)
    assert out.shape == (20, 20, 3) and out.min() > 240  # the white centre square


@pytest.mark.parametrize("content", [b"", b"hello, this is not a video\n" * 50])
def test_bad_files_name_the_file(tmp_path, content):
    path = tmp_path / "broken.mp4"
    path.write_bytes(content)
    with pytest.raises(VideoError, match="broken.mp4"):
        probe(path)


def test_truncated_video(clip, tmp_path):
    data = Path(clip).read_bytes()
    path = tmp_path / "truncated.mp4"
    path.write_bytes(data[: len(data) // 3])
    with pytest.raises(VideoError, match="truncated.mp4"):
        read_frames(path, 8)


def test_missing_file():
    with pytest.raises(VideoError, match="no such video file"):
        probe("/nonexistent/video.mp4")
