"""Image sequences through OpenImageIO: patterns, folders, formats, colour handling, writing."""
from __future__ import annotations

import sys

import numpy as np
import pytest
from conftest import write_image_tagged

from hypergs_blender.errors import HyperGSError, VideoError
from hypergs_blender.colour import linear_to_srgb, srgb_to_linear
from hypergs_blender.io.image_sequence import frame_path, is_image_sequence, iter_frames, list_frames, probe
from hypergs_blender.io.images import image_size, read_image, write_image


def frames_rgb(t=4, h=24, w=40, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0, 1, (t, h, w, 3)).astype(np.float32)


def write_sequence(folder, pattern, frames, first=1):
    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        write_image(frame_path(folder / pattern, first + i), f)


@pytest.mark.parametrize("ext,tolerance", [("png", 0), ("tif", 0), ("dpx", 1), ("exr", 1)])
def test_sequence_round_trip_per_format(tmp_path, ext, tolerance):
    frames = frames_rgb()
    write_sequence(tmp_path, f"shot.####.{ext}", frames, first=1001)
    expected = np.round(frames * 255).astype(int)
    info = probe(tmp_path / f"shot.####.{ext}", fps=25)
    assert (info.width, info.height, info.num_frames, info.fps) == (40, 24, 4, 25.0)
    got = list(iter_frames(tmp_path / f"shot.####.{ext}"))
    assert [i for i, _ in got] == [0, 1, 2, 3]
    for (_, image), want in zip(got, expected):
        assert image.dtype == np.uint8 and image.shape == (24, 40, 3)
        # 16-bit TIFF is exact; DPX (10-bit) and EXR (linear half float): one code value of slack
        assert np.abs(image.astype(int) - want).max() <= tolerance


@pytest.mark.parametrize("name", ["shot.####.png", "shot.%04d.png", "shot.{frame}.png", "shot.{frame:04d}.png",
                                  "", "shot.0003.png"])
def test_ways_to_name_a_sequence(tmp_path, name):
    write_sequence(tmp_path, "shot.####.png", frames_rgb(t=3), first=3)
    (tmp_path / "notes.txt").write_text("not an image")
    frames = list_frames(tmp_path / name if name else tmp_path)
    assert [n for n, _ in frames] == [3, 4, 5]
    assert is_image_sequence(tmp_path / name if name else tmp_path)


def test_gaps_and_unpadded_numbers_sort_by_frame_number(tmp_path):
    frames = frames_rgb(t=3)
    for number, f in zip([9, 10, 100], frames):
        write_image(tmp_path / f"f{number}.png", f)
    assert [n for n, _ in list_frames(tmp_path / "f#.png")] == [9, 10, 100]
    got = dict(iter_frames(tmp_path / "f#.png", indices=[2, 0]))
    assert sorted(got) == [0, 2]
    assert np.array_equal(got[2], np.round(frames[2] * 255).astype(np.uint8))


def test_resize_and_crop_like_video(tmp_path):
    write_sequence(tmp_path, "s.####.png", frames_rgb(t=2, h=24, w=40))
    (_, image), = list(iter_frames(tmp_path / "s.####.png", indices=[1], size=16))
    assert image.shape == (16, 16, 3)


def test_video_paths_are_not_sequences(tmp_path):
    assert not is_image_sequence(tmp_path / "clip#1.mp4")
    assert not is_image_sequence("take.mov")
    assert is_image_sequence("render/beauty.%04d.exr")


def test_sequence_errors(tmp_path):
    with pytest.raises(VideoError, match="no numbered image files"):
        list_frames(tmp_path)
    write_sequence(tmp_path / "a", "x.####.png", frames_rgb(t=1))
    write_sequence(tmp_path / "a", "y.####.png", frames_rgb(t=1))
    with pytest.raises(VideoError, match="several image sequences"):
        list_frames(tmp_path / "a")
    with pytest.raises(VideoError, match="no image files match"):
        list_frames(tmp_path / "a" / "z.####.png")
    with pytest.raises(VideoError, match="past the end"):
        list(iter_frames(tmp_path / "a" / "x.####.png", indices=[5]))
    (tmp_path / "b").mkdir()
    write_image(tmp_path / "b" / "m.0001.png", frames_rgb(t=1)[0])
    write_image(tmp_path / "b" / "m.0002.png", frames_rgb(t=1, h=10, w=10)[0])
    with pytest.raises(VideoError, match="differs"):
        list(iter_frames(tmp_path / "b" / "m.####.png"))
    (tmp_path / "b" / "m.0003.png").write_bytes(b"not a png")
    with pytest.raises(VideoError, match="not a readable image"):
        read_image(tmp_path / "b" / "m.0003.png")
    with pytest.raises(VideoError, match="more than one"):
        list_frames(tmp_path / "x.####.#.png")


def test_alpha_and_grey_images(tmp_path):
    rgba = np.random.default_rng(1).integers(0, 256, (8, 6, 4), dtype=np.uint8)
    grey = rgba[..., :1].copy()
    for name, pixels in (("rgba.png", rgba), ("grey.png", grey)):
        # store these values as they are (PNG alpha is straight)
        write_image_tagged(tmp_path / name, pixels, **{"oiio:UnassociatedAlpha": 1})
    # alpha dropped after premultiplying: the image composited over black
    over_black = rgba[..., :3].astype(int) * rgba[..., 3:].astype(int) / 255
    assert np.abs(read_image(tmp_path / "rgba.png").astype(int) - over_black).max() <= 1
    assert np.array_equal(read_image(tmp_path / "grey.png"), np.repeat(grey, 3, axis=-1))


@pytest.mark.parametrize("ext", ["png", "jpg", "tif"])
def test_an_exif_orientation_is_ignored_as_blender_ignores_it(tmp_path, ext):
    """A photo tagged "rotate 90" (EXIF orientation 6) reads as stored, landscape: Blender's image strips
    show it so (the Sequencer test converts one), and a converted strip must show what the strip showed."""
    import OpenImageIO as oiio

    stored = np.zeros((24, 40, 3), np.uint8)
    stored[:, :20] = 255  # the left half white: turned, the top half would be
    for i in (1, 2):
        write_image_tagged(tmp_path / f"phone.{i:04d}.{ext}", stored, Orientation=6)
    first = tmp_path / f"phone.0001.{ext}"
    read = oiio.ImageInput.open(str(first))
    assert read.spec().get_int_attribute("Orientation", 1) == 6  # the tag is in the file
    read.close()
    assert image_size(first) == (40, 24)
    assert np.abs(read_image(first).astype(int) - stored).max() <= 2  # JPEG's rounding at the edge
    info = probe(tmp_path / f"phone.####.{ext}", fps=24)
    assert (info.width, info.height, info.num_frames) == (40, 24, 2)


def test_write_image_formats(tmp_path):
    import OpenImageIO as oiio

    rgb = np.linspace(-0.2, 1.4, 5 * 7 * 3, dtype=np.float32).reshape(5, 7, 3)
    write_image(tmp_path / "a.png", rgb)
    png = oiio.ImageInput.open(str(tmp_path / "a.png"))
    assert png.spec().format == oiio.UINT8
    assert np.array_equal(png.read_image(0, 0, 0, 3, oiio.UINT8), np.round(np.clip(rgb, 0, 1) * 255).astype(np.uint8))
    png.close()
    write_image(tmp_path / "a.exr", rgb)
    exr = oiio.ImageInput.open(str(tmp_path / "a.exr"))
    assert exr.spec().format == oiio.HALF
    linear = exr.read_image(0, 0, 0, 3, oiio.FLOAT)
    exr.close()
    # EXR keeps values outside [0, 1] (additive sums overshoot), scene-linear
    np.testing.assert_allclose(linear_to_srgb(linear), rgb, atol=2e-3)
    assert linear.max() > 1 and linear.min() < 0
    with pytest.raises(HyperGSError):
        write_image(tmp_path / "a.png", np.zeros((4, 4), np.float32))
    with pytest.raises(HyperGSError):
        write_image(tmp_path / "a.unknownformat", rgb)


def test_srgb_curves_are_inverse():
    v = np.linspace(-2, 3, 101, dtype=np.float32)
    np.testing.assert_allclose(linear_to_srgb(srgb_to_linear(v)), v, atol=1e-5)


def test_frame_path():
    assert frame_path("out/f.####.exr", 7) == "out/f.0007.exr"
    assert frame_path("out/f.%03d.png", 12) == "out/f.012.png"
    assert frame_path("out/f.{frame}.png", 12) == "out/f.12.png"
    assert frame_path("out/f.{frame:05d}.png", 12) == "out/f.00012.png"
    assert frame_path("out/f.png", 3) == "out/f_0003.png"


def test_resize_with_a_kept_reformatter_is_a_fresh_one_at_every_size_filter_and_thread():
    """resize_exact keeps one swscale context per thread (io.images.kept_reformatter): as sizes and
    filters change from call to call, and from two threads at once, every result is the pixels a fresh
    context gives."""
    import threading

    import av

    from hypergs_blender.io.images import resize_exact

    rng = np.random.default_rng(5)
    jobs = [(rng.integers(0, 256, (h, w, 3), dtype=np.uint8), ow, oh, interpolation)
            for h, w, ow, oh in [(64, 96, 40, 30), (30, 40, 96, 64), (64, 96, 40, 30), (17, 23, 8, 9)]
            for interpolation in ("AREA", "LANCZOS")]

    def fresh(image, ow, oh, interpolation):
        frame = av.VideoFrame.from_ndarray(image, format="rgb24")
        return frame.to_ndarray(format="rgb24", width=ow, height=oh, interpolation=interpolation)

    expected = [fresh(*job) for job in jobs]
    results = {}

    def run(name, order):
        results[name] = [(i, resize_exact(*jobs[i])) for _ in range(20) for i in order]

    threads = [threading.Thread(target=run, args=("forward", range(len(jobs))), daemon=True),
               threading.Thread(target=run, args=("backward", range(len(jobs) - 1, -1, -1)), daemon=True)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join(timeout=60)
        assert not thread.is_alive(), "a resize hung (one swscale context used by two threads deadlocks)"
    assert sorted(results) == ["backward", "forward"]
    for done in results.values():
        assert len(done) == 20 * len(jobs)
        for i, got in done:
            np.testing.assert_array_equal(got, expected[i])


def test_a_python_without_openimageio_gets_a_clear_error_and_no_file(tmp_path, monkeypatch):
    """The bpy 4.2 wheel's Python has no OpenImageIO: reading and writing images say what is missing."""
    existing = tmp_path / "frame.0001.png"
    write_image(existing, np.full((4, 6, 3), 128, np.uint8))
    before = existing.read_bytes()
    monkeypatch.setitem(sys.modules, "OpenImageIO", None)  # import OpenImageIO raises ModuleNotFoundError
    message = r"Image files need the Python module 'OpenImageIO' \(PyPI package OpenImageIO\)"
    for call in (lambda: read_image(existing), lambda: image_size(existing), lambda: probe(existing, fps=24),
                 lambda: write_image(existing, np.zeros((4, 6, 3), np.uint8)),
                 lambda: write_image(tmp_path / "new.png", np.zeros((4, 6, 3), np.uint8))):
        with pytest.raises(HyperGSError, match=message):
            call()
    assert existing.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["frame.0001.png"]
