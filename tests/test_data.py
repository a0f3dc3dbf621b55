"""Training-data pipeline: sources, batches, caches, spec parsing. Small and offline: photos and
videos are written by the tests themselves."""
import argparse
import warnings

import numpy as np
import pytest

from hypergs_blender.commands import data as data_commands
from hypergs_blender.io.images import list_images, read_image, write_image
from hypergs_blender.training import data, photos, prepare, procedural, videos
from hypergs_blender.training.sources import DataError, make_batch


def smooth_texture(rng, h, w, blur=6):
    """A random smooth RGB texture, uint8, with features of ~blur pixels (good for shift tests)."""
    noise = rng.random((h + 4 * blur, w + 4 * blur, 3))
    k = np.ones(blur) / blur
    for axis in (0, 1):
        for _ in range(2):
            noise = np.apply_along_axis(lambda m: np.convolve(m, k, mode="same"), axis, noise)
    noise = noise[2 * blur:2 * blur + h, 2 * blur:2 * blur + w]
    noise = (noise - noise.min()) / (noise.max() - noise.min())
    return (noise * 255).astype(np.uint8)


@pytest.fixture(scope="module")
def photo_folder(tmp_path_factory):
    folder = tmp_path_factory.mktemp("photos")
    rng = np.random.default_rng(0)
    for i, (h, w) in enumerate([(150, 200), (180, 140), (160, 160)]):
        write_image(folder / f"photo{i}.png", smooth_texture(rng, h, w))
    write_image(folder / "photo3.jpg", smooth_texture(rng, 140, 190))
    (folder / "notes.svg").write_text("<svg/>")  # ignored
    return folder


@pytest.fixture(scope="module")
def photo_root(tmp_path_factory, photo_folder):
    root = tmp_path_factory.mktemp("data")
    prepare.prepare_photos(root, folder=photo_folder, val_count=1, log=lambda *a: None)
    return root


@pytest.fixture(scope="module")
def video_folder(tmp_path_factory):
    """A 40-frame 96x72 video: a white square moving right over a dark gradient."""
    import av

    folder = tmp_path_factory.mktemp("videos")
    path = folder / "clip.mp4"
    with av.open(str(path), "w") as container:
        stream = container.add_stream("mpeg4", rate=24)
        stream.width, stream.height, stream.pix_fmt = 96, 72, "yuv420p"
        for t in range(40):
            frame = np.zeros((72, 96, 3), np.uint8)
            frame[:] = np.linspace(0, 80, 96).astype(np.uint8)[None, :, None]
            x = 4 + t * 2
            frame[20:44, x:x + 16] = 255
            for packet in stream.encode(av.VideoFrame.from_ndarray(frame, format="rgb24")):
                container.mux(packet)
        for packet in stream.encode():
            container.mux(packet)
    (folder / "readme.txt").write_text("not a video")
    return folder


def check_clip(clip, T, size):
    assert clip.shape == (T, size, size, 3)
    assert clip.dtype == np.float32
    assert np.isfinite(clip).all()
    assert clip.min() >= 0.0 and clip.max() <= 1.0


@pytest.mark.parametrize("mode", ["shapes", "leaves", "mixed"])
def test_procedural_clips(mode):
    source = procedural.ProceduralSource(mode)
    for i in range(4):
        clip = source.sample(np.random.default_rng(i), 3, 48)
        check_clip(clip, 3, 48)
        assert clip.std() > 0.01  # not a blank frame


def test_procedural_motion_and_edges():
    source = procedural.ProceduralSource()
    moving = sharp = 0
    for i in range(16):
        clip = source.sample(np.random.default_rng(100 + i), 4, 64)
        if np.abs(clip[-1] - clip[0]).mean() > 2e-3:
            moving += 1
        # dark beside bright: some neighbouring pixels differ by more than half the range
        if np.abs(np.diff(clip[0].mean(-1), axis=1)).max() > 0.5:
            sharp += 1
    assert moving >= 10
    assert sharp >= 6


def test_make_batch_is_a_pure_function():
    sources = data.build_sources("procedural:1")
    a = make_batch(sources, seed=3, step=10, rank=0, batch_size=3, clip_frames=2, size=32)
    b = make_batch(sources, seed=3, step=10, rank=0, batch_size=3, clip_frames=2, size=32)
    check_clip(a[0], 2, 32)
    assert a.shape == (3, 2, 32, 32, 3)
    np.testing.assert_array_equal(a, b)
    for other in (dict(seed=3, step=11, rank=0), dict(seed=3, step=10, rank=1), dict(seed=4, step=10, rank=0)):
        c = make_batch(sources, batch_size=3, clip_frames=2, size=32, **other)
        assert not np.array_equal(a, c), other
    # clip i does not depend on the batch size
    d = make_batch(sources, seed=3, step=10, rank=0, batch_size=1, clip_frames=2, size=32)
    np.testing.assert_array_equal(a[:1], d)


def test_make_batch_mixes_sources(photo_root):
    sources = data.build_sources("procedural:1,photos:1", root=photo_root)
    batch = make_batch(sources, seed=0, step=0, rank=0, batch_size=6, clip_frames=2, size=32)
    assert batch.shape == (6, 2, 32, 32, 3)
    # weight 0 is never drawn; clip i is its source's sample with clip i's generator
    photos = sources[1][0]
    only_photos = make_batch([(sources[0][0], 0.0), (photos, 1.0)], 0, 0, 0, 2, 2, 32)
    for i in range(2):
        rng = np.random.default_rng([0, 0, 0]).spawn(2)[i]
        rng.random()  # the source draw
        np.testing.assert_array_equal(only_photos[i], photos.sample(rng, 2, 32))


def test_photo_caches(photo_root, photo_folder):
    train, val = photo_root / photos.PHOTO_CACHE, photo_root / photos.PHOTO_VAL_CACHE
    images, names, _ = photos.load_photo_cache(train)
    val_images, val_names, _ = photos.load_photo_cache(val)
    assert len(images) == 3 and len(val_images) == 1
    assert not set(names) & set(val_names)
    assert set(names) | set(val_names) == {"photo0.png", "photo1.png", "photo2.png", "photo3.jpg"}
    assert val_names == ["photo3.jpg"]  # JPEGs (photographs) are held out first
    assert all(im.dtype == np.uint8 and im.ndim == 3 and im.shape[2] == 3 for im in images)
    lines = []
    prepare.prepare_photos(photo_root, folder=photo_folder, val_count=1, log=lines.append)
    assert "up to date" in lines[-1]  # idempotent


def shift_error(a, b, dx, dy, margin=10):
    """Mean |a(x + dx, y + dy) - b(x, y)| over the interior, a sampled bilinearly."""
    n = a.shape[0]
    ys, xs = np.mgrid[margin:n - margin, margin:n - margin].astype(np.float64)
    sx, sy = xs + dx, ys + dy
    x0, y0 = np.floor(sx).astype(int), np.floor(sy).astype(int)
    wx, wy = (sx - x0)[..., None], (sy - y0)[..., None]
    sample = ((1 - wy) * ((1 - wx) * a[y0, x0] + wx * a[y0, x0 + 1])
              + wy * ((1 - wx) * a[y0 + 1, x0] + wx * a[y0 + 1, x0 + 1]))
    return np.abs(sample - b[margin:n - margin, margin:n - margin]).mean()


def test_photo_source_pans(photo_folder):
    source = photos.PhotoSource(photo_folder, max_rotation=0.0, max_zoom=0.0)
    assert len(source) == 4
    source.MOTION_CLASSES = ((1.0, 3.0, 6.0),)  # always a clear pan (3-6 px per frame at 128 px)
    for i in range(3):
        clip = source.sample(np.random.default_rng(i), 3, 48)
        check_clip(clip, 3, 48)
        for t in range(2):
            a, b = clip[t], clip[t + 1]
            still = shift_error(a, b, 0, 0)
            assert still > 0.005  # consecutive frames differ...
            coarse = {(dx, dy): shift_error(a, b, dx, dy) for dx in range(-8, 9) for dy in range(-8, 9)}
            cx, cy = min(coarse, key=coarse.get)
            fine = min(shift_error(a, b, cx + fx, cy + fy)
                       for fx in np.linspace(-0.5, 0.5, 11) for fy in np.linspace(-0.5, 0.5, 11))
            assert (cx, cy) != (0, 0)
            assert fine < 0.2 * still  # ...but are shifted versions of each other (up to resampling)


def test_photo_source_zoom_rotation_stay_inside(photo_folder):
    source = photos.PhotoSource(photo_folder, max_rotation=0.3, max_zoom=0.5)
    for i in range(8):
        clip = source.sample(np.random.default_rng(i), 4, 32)
        check_clip(clip, 4, 32)
        # the window never leaves the photo: no clamped borders (constant edge rows)
        assert clip[:, 0].std() > 1e-3 and clip[:, :, 0].std() > 1e-3


def test_video_source(video_folder, tmp_path):
    lines = []
    cache = prepare.prepare_videos(video_folder, root=tmp_path, cache_size=48, cache_frames=8,
                                clips_per_video=3, log=lines.append)
    assert (cache / "clips.npy").is_file() and (cache / "index.json").is_file()
    clips = np.load(cache / "clips.npy", mmap_mode="r")
    assert clips.shape == (3, 8, 48, 48, 3) and clips.dtype == np.uint8
    prepare.prepare_videos(video_folder, root=tmp_path, cache_size=48, cache_frames=8, clips_per_video=3,
                        log=lines.append)
    assert "up to date" in lines[-1]
    [(source, weight)] = data.build_sources(f"videos={video_folder}:0.5", root=tmp_path)
    assert isinstance(source, videos.VideoSource) and weight == 0.5
    moved = 0
    for i in range(6):
        clip = source.sample(np.random.default_rng(i), 4, 32)
        check_clip(clip, 4, 32)
        assert clip.max() > 0.8  # the white square is in view
        moved += np.abs(clip[-1] - clip[0]).mean() > 0.01
    assert moved >= 4
    with pytest.raises(DataError, match="8-frame clips"):
        source.sample(np.random.default_rng(0), 9, 32)
    # a clip cache folder also works directly
    [(direct, _)] = data.build_sources(f"videos={cache}", root=tmp_path / "elsewhere")
    assert len(direct.clips) == 3


def test_build_sources(photo_root, tmp_path):
    sources = data.build_sources("procedural:0.4, photos:0.6", root=photo_root)
    assert [type(s) for s, _ in sources] == [procedural.ProceduralSource, photos.PhotoSource]
    assert [w for _, w in sources] == [0.4, 0.6]
    [(s, w)] = data.build_sources("procedural=leaves")
    assert s.mode == "leaves" and w == 1.0
    [(s, _)] = data.build_sources("photos_val", root=photo_root)
    assert len(s) == 1
    bad = ["", " ", "procedural,,photos", "procedural:abc", "noise:1", "procedural:-1", "procedural:0",
           "procedural=cubes", "videos", "videos="]
    for spec in bad:
        with pytest.raises(DataError):
            data.build_sources(spec, root=photo_root)
    with pytest.raises(DataError, match="no such folder"):
        data.build_sources(f"videos={tmp_path / 'missing'}:0.2")
    with pytest.raises(DataError, match="prepare-data"):
        data.build_sources("photos", root=tmp_path)  # no cache there
    (tmp_path / "vids").mkdir()
    with pytest.raises(DataError, match="prepare-data --root"):
        data.build_sources(f"procedural,videos={tmp_path / 'vids'}", root=tmp_path)


def test_media_folders_missing_or_empty_name_the_option(tmp_path):
    (tmp_path / "empty").mkdir()
    (tmp_path / "empty" / "notes.txt").write_text("not a video or an image")
    for folder, what in ((tmp_path / "missing", "no such folder"), (tmp_path / "empty", "none of .mp4")):
        with pytest.raises(DataError, match=f"^--videos {folder}: {what}"):
            prepare.prepare_videos(folder, root=tmp_path / "root")
    for folder, what in ((tmp_path / "missing", "no such folder"), (tmp_path / "empty", "none of .png")):
        with pytest.raises(DataError, match=f"^--photo-folder {folder}: {what}"):
            prepare.prepare_photos(root=tmp_path / "root", folder=folder)
    with pytest.raises(DataError, match=f"^photos={tmp_path / 'empty'}: none of .png"):
        photos.PhotoSource(tmp_path / "empty")
    assert not (tmp_path / "root").exists()  # nothing written


def test_collect_photos_dedupes_and_filters(tmp_path):
    rng = np.random.default_rng(5)
    image = smooth_texture(rng, 200, 300)
    write_image(tmp_path / "a.png", image)
    (tmp_path / "a_copy.png").write_bytes((tmp_path / "a.png").read_bytes())  # same file
    write_image(tmp_path / "a_small.png", image[::2, ::2])  # same picture, smaller
    write_image(tmp_path / "flat.png", np.full((200, 200, 3), 90, np.uint8))
    write_image(tmp_path / "b.png", smooth_texture(rng, 200, 200))
    lines = []
    keep, groups = prepare._collect_photos(list_images(tmp_path), log=lines.append)
    assert sorted(r["path"].name for r in keep) == ["a.png", "b.png"]
    assert len(lines) == 3


def test_package_images_take_the_largest_of_each_plasma_wallpaper(tmp_path):
    files = ["usr/share/backgrounds/mate/nature/Aqua.jpg", "usr/share/backgrounds/mate/Flow.png",
             "usr/share/backgrounds/mate/readme.txt",
             "usr/share/wallpapers/Altai/contents/images/1080x1920.png",
             "usr/share/wallpapers/Altai/contents/images/5120x2880.png",
             "usr/share/wallpapers/Altai/contents/images/2560x1440.png",
             "usr/share/wallpapers/Altai/contents/images_dark/5120x2880.png",
             "usr/share/wallpapers/Altai/contents/screenshot.png",
             "usr/share/wallpapers/Path/contents/images/2560x1600.jpg"]
    for f in files:
        (tmp_path / f).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / f).write_bytes(b"x")
    (tmp_path / "usr/share/backgrounds/link.jpg").symlink_to(tmp_path / files[0])
    found = {name: str(path.relative_to(tmp_path)) for path, name in prepare.package_images(tmp_path)}
    assert found == {"Aqua.jpg": files[0], "Flow.png": files[1], "Altai_5120x2880.png": files[4],
                     "Path_2560x1600.jpg": files[8]}


def test_pinned_photos_are_held_out_first(tmp_path):
    rng = np.random.default_rng(3)
    for name in ("a.jpg", "b.jpg", "c.jpg", "d.png"):
        write_image(tmp_path / name, smooth_texture(rng, 160, 200, blur=2))
    keep, groups = prepare._collect_photos(list_images(tmp_path), log=lambda *a: None)
    names = [r["path"].name for r in keep]
    by_hash = [names[i] for i in prepare._split_val(keep, groups, 2, pinned=())]
    pinned = [n for n in names if n not in by_hash][:1]  # one the hash rule would not hold out
    chosen = [names[i] for i in prepare._split_val(keep, groups, 2, pinned=pinned)]
    assert len(set(groups)) == 4 and pinned[0] in chosen and len(chosen) == 2
    assert set(chosen) - set(pinned) <= set(by_hash)


def test_validation_clips(photo_root, tmp_path):
    a = data.validation_clips(photo_root, clip_frames=2, size=32, count=4)
    b = data.validation_clips(photo_root, clip_frames=2, size=32, count=4)
    assert a.shape == (4, 2, 32, 32, 3) and a.dtype == np.float32
    np.testing.assert_array_equal(a, b)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        c = data.validation_clips(tmp_path, clip_frames=2, size=32, count=2)
    assert c.shape == (2, 2, 32, 32, 3)
    assert any("procedural" in str(w.message) for w in caught)


def test_cli_prepare_takes_the_packages_to_download():
    parser = argparse.ArgumentParser()
    data_commands.add_commands(parser.add_subparsers(dest="command"))
    assert parser.parse_args(["prepare-data"]).packages == list(prepare.WALLPAPER_PACKAGES)
    assert parser.parse_args(["prepare-data", "--packages", "a", "b"]).packages == ["a", "b"]


def test_cli_prepare_and_preview(photo_folder, tmp_path, capsys):
    parser = argparse.ArgumentParser()
    data_commands.add_commands(parser.add_subparsers(dest="command"))
    args = parser.parse_args(["prepare-data", "--root", str(tmp_path), "--photo-folder", str(photo_folder),
                              "--val-photos", "2"])
    args.func(args)
    assert (tmp_path / photos.PHOTO_CACHE).is_file() and (tmp_path / photos.PHOTO_VAL_CACHE).is_file()
    assert "2 held-out" in capsys.readouterr().out
    out = tmp_path / "sheet.png"
    args = parser.parse_args(["preview-data", "--root", str(tmp_path), "--spec", "procedural:1,photos:1",
                              "--clips", "2", "--frames", "3", "--size", "24", "--out", str(out)])
    args.func(args)
    sheet = read_image(out)
    assert sheet.shape == (2 * 26 + 2, 3 * 26 + 2, 3)
