"""The frame cache (hypergs_blender/io/cache.py): the streaming writer, random access that reads one frame's
bytes whatever the clip's length, the LRU of decoded frames, files that change or go away, threads."""
from __future__ import annotations

import os
import threading

import numpy as np
import pytest

from hypergs_blender.errors import HyperGSError
from hypergs_blender.io import cache
from hypergs_blender.io.cache import FrameCache, _FileOnDemand
from hypergs_blender.io.hgs import HgsError, HgsReader, load_hgs
from conftest import moving_params


def write_cache(path, frames: int, n: int = 40, seed: int = 0):
    params = moving_params(np.random.default_rng(seed), frames, n)
    with cache.writer(path, 64, 48, n, 30.0, (8, 5), {"path": "x.mp4"}) as w:
        for start in range(0, frames, 7):  # any number of frames at a time
            w.write(params[start:start + 7])
    return load_hgs(path).params


@pytest.fixture
def counted_reads(monkeypatch):
    """Bytes read from files by the cache, as a list of read sizes."""
    reads = []
    read = _FileOnDemand.read

    def counting(self, size=-1):
        data = read(self, size)
        reads.append(len(data))
        return data
    monkeypatch.setattr(_FileOnDemand, "read", counting)
    return reads


def test_writer_streams_one_frame_per_chunk_and_only_a_complete_file_appears(tmp_path):
    path = tmp_path / "clip.hgs"
    decoded = write_cache(path, 20)
    with HgsReader(path) as reader:
        assert (reader.codec, reader.header.group_size, reader.num_frames, reader.grid) == ("float16", 1, 20, (8, 5))
        assert reader.info()["groups"] == 20 and reader.source == {"path": "x.mp4"}
    with pytest.raises(RuntimeError):
        with cache.writer(tmp_path / "cancelled.hgs", 64, 48, 40, 30.0) as w:
            w.write(decoded[:3])
            raise RuntimeError("cancelled")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.hgs"]


def test_a_frame_costs_the_same_in_a_short_and_a_long_clip(tmp_path, counted_reads):
    frames = FrameCache()
    read = {}
    for length in (10, 300):
        path = str(tmp_path / f"c{length}.hgs")
        decoded = write_cache(path, length, seed=1)
        frames.reader(path)  # header and index, once
        counted_reads.clear()
        assert np.array_equal(frames.read_frame(path, 7), decoded[7])
        read[length] = sum(counted_reads)
    assert read[10] == read[300]  # one chunk: the frame's own bytes


def test_decoded_frames_are_kept_for_scrubbing_within_a_byte_budget(tmp_path, counted_reads):
    path = str(tmp_path / "c.hgs")
    decoded = write_cache(path, 30, n=100)
    frame_bytes = decoded[0].nbytes
    frames = FrameCache(max_frame_bytes=5 * frame_bytes)
    for t in (3, 4, 5):
        frames.read_frame(path, t)
    counted_reads.clear()
    again = frames.read_frame(path, 4)
    assert counted_reads == [] and np.array_equal(again, decoded[4])  # from memory
    with pytest.raises(ValueError):
        again[0, 0] = 1  # shared with the cache: read-only
    for t in range(10, 20):
        frames.read_frame(path, t)
    assert frames.frame_bytes == 5 * frame_bytes  # the oldest frames went
    counted_reads.clear()
    frames.read_frame(path, 4)
    assert counted_reads  # read again


def test_a_changed_file_is_read_again_and_a_missing_one_is_reported(tmp_path):
    path = str(tmp_path / "c.hgs")
    write_cache(path, 5, seed=2)
    frames = FrameCache()
    first = frames.read_frame(path, 2).copy()
    other = write_cache(path, 6, seed=3)  # replaced (another size): the cache notices
    os.utime(path, ns=(1, 1))
    assert np.array_equal(frames.read_frame(path, 2), other[2]) and not np.array_equal(first, other[2])
    assert frames.reader(path).num_frames == 6 and frames.problem(path) is None
    with pytest.raises(HgsError, match="outside the clip"):
        frames.read_frame(path, 6)
    os.remove(path)
    with pytest.raises(HgsError, match="no such file"):
        frames.read_frame(path, 2)
    assert "no such file" in frames.problem(path)
    (tmp_path / "c.hgs").write_bytes(b"not a clip")
    assert "not a .hgs" in frames.problem(path)
    with pytest.raises(HyperGSError, match="no cache file set"):
        frames.read_frame("", 0)


def test_threads_share_the_cache(tmp_path):
    paths = [str(tmp_path / f"c{i}.hgs") for i in range(3)]
    decoded = [write_cache(p, 12, seed=i) for i, p in enumerate(paths)]
    frames = FrameCache(max_open=2, max_frame_bytes=4 * decoded[0][0].nbytes)  # files and frames come and go
    wrong = []

    def work(seed):
        rng = np.random.default_rng(seed)
        for _ in range(60):
            i, t = int(rng.integers(3)), int(rng.integers(12))
            if not np.array_equal(frames.read_frame(paths[i], t), decoded[i][t]):
                wrong.append((i, t))
    threads = [threading.Thread(target=work, args=(s,)) for s in range(4)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert wrong == []


def clip(frames=9, n=30, seed=3):
    from hypergs_blender.gaussians import GaussianVideo
    return GaussianVideo(moving_params(np.random.default_rng(seed), frames, n), 64, 48, 29.97, (6, 5),
                         {"path": "x.mp4", "frames": list(range(frames))})


def test_a_clip_read_a_frame_at_a_time_is_copied_into_a_cache(tmp_path):
    from hypergs_blender.io.clips import ClipFrames
    video = clip()
    header = cache.write_clip(ClipFrames.of(video), tmp_path / "c.hgs")
    back = load_hgs(tmp_path / "c.hgs")
    assert (header.num_frames, header.num_gaussians, back.grid, back.source) == (9, 30, (6, 5), video.source)
    assert np.array_equal(back.params[..., :2], video.params[..., :2])  # means kept exactly
    np.testing.assert_allclose(back.params[..., 5:], video.params[..., 5:], rtol=2 ** -10, atol=1e-6)
    with HgsReader(tmp_path / "c.hgs") as reader:  # and a cache's frames copied again, as they are read
        cache.write_clip(ClipFrames.of(reader), tmp_path / "d.hgs")
    assert np.array_equal(load_hgs(tmp_path / "d.hgs").params, back.params)


def test_a_cancelled_or_failed_copy_leaves_no_file(tmp_path):
    from hypergs_blender.errors import Cancelled
    from hypergs_blender.io.clips import ClipFrames
    video = clip()
    with pytest.raises(Cancelled):
        cache.write_clip(ClipFrames.of(video), tmp_path / "c.hgs", progress=lambda done, total: done < 4)
    video.params[6, 3, 2] = np.nan  # a frame no reader would accept, found while copying
    with pytest.raises(HyperGSError, match=r"frame 6: .*NaN"):
        cache.write_clip(ClipFrames.of(video), tmp_path / "c.hgs")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("suffix", [".hgs", ".usd", ".npz"])
def test_save_clip_streams_a_clip_read_a_frame_at_a_time(tmp_path, suffix):
    """save_clip of ClipFrames writes what save_clip of the whole clip writes; .hgs and USD read the
    frames as they write (.hgs twice: its ranges are fitted first)."""
    from hypergs_blender.io.clips import ClipFrames, load_clip, save_clip
    video = clip()
    passes = []
    frames = ClipFrames.of(video)
    counted = ClipFrames(lambda: passes.append(1) or frames.frames(), *[getattr(frames, f) for f in
                         ("num_frames", "num_gaussians", "canvas_width", "canvas_height", "fps", "grid", "source")])
    save_clip(video, tmp_path / f"whole{suffix}")
    save_clip(counted, tmp_path / f"streamed{suffix}")
    assert len(passes) == (2 if suffix == ".hgs" else 1)
    if suffix == ".hgs":
        assert (tmp_path / f"whole{suffix}").read_bytes() == (tmp_path / f"streamed{suffix}").read_bytes()
    else:
        a, b = load_clip(tmp_path / f"whole{suffix}"), load_clip(tmp_path / f"streamed{suffix}")
        assert np.array_equal(a.params, b.params) and a.source == b.source and a.fps == b.fps


def test_save_clip_refuses_frames_that_do_not_fit_and_leaves_no_file(tmp_path):
    from hypergs_blender.io.clips import ClipFrames, save_clip
    video = clip()
    short = ClipFrames(lambda: iter(video.params[:5]), 9, 30, 64, 48)
    with pytest.raises(HyperGSError, match="5 frames read, expected 9"):
        save_clip(short, tmp_path / "c.usd")
    wrong = ClipFrames(lambda: iter(video.params[:, :20]), 9, 30, 64, 48)
    with pytest.raises(HyperGSError, match=r"frame 0 holds \(20, 8\) parameters, expected \(30, 8\)"):
        save_clip(wrong, tmp_path / "c.hgs")
    assert list(tmp_path.iterdir()) == []


def test_folders_made_for_a_file_are_removed_again_only_when_empty(tmp_path):
    from hypergs_blender.io.files import make_folders, remove_folders
    made = make_folders(tmp_path / "a" / "b" / "c")
    assert made == [tmp_path / "a", tmp_path / "a" / "b", tmp_path / "a" / "b" / "c"]
    assert make_folders(tmp_path / "a" / "b") == []  # there already
    (tmp_path / "a" / "keep.txt").write_text("someone else's")
    remove_folders(made)
    assert sorted(p.name for p in (tmp_path / "a").iterdir()) == ["keep.txt"]
    (tmp_path / "file").write_text("x")
    with pytest.raises(HyperGSError, match="cannot make the folder"):
        make_folders(tmp_path / "file" / "sub")


def _in_a_small_file_system(tmp_path, script: str, size_kb: int = 64):
    """Run `script` (bash) where $FS is an empty tmpfs of `size_kb` kB (a user and mount namespace:
    unshare); skips where this system does not allow one. Returns the CompletedProcess."""
    import shutil
    import subprocess
    if shutil.which("unshare") is None:
        pytest.skip("no unshare")
    fs = tmp_path / "fs"
    fs.mkdir()
    probe = subprocess.run(["unshare", "-Urm", "sh", "-c", f"mount -t tmpfs -o size={size_kb}k tmpfs {fs}"],
                           capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"no user mount namespace here: {probe.stderr.decode().strip()}")
    return subprocess.run(["unshare", "-Urm", "bash", "-c",
                           f"mount -t tmpfs -o size={size_kb}k tmpfs {fs} && export FS={fs} && {script}"],
                          capture_output=True, text=True, timeout=300)


def test_a_full_disk_is_a_one_line_error_and_leaves_no_file(tmp_path):
    """On a real full file system (a 64 kB tmpfs): `hypergs encode` to a .hgs file is refused before it starts
    (its float16 frames will not fit); with that check skipped it fails while writing them; a frame cache
    written from Python fails too. Each is one line naming the file and the reason, and leaves the file
    system empty."""
    import sys
    from conftest import make_pan_clip
    video = make_pan_clip(tmp_path / "pan.mp4", frames=24)
    python = sys.executable
    encode = f"['encode', '{video}', '-o', os.environ['FS'] + '/clip.hgs', '--encoder', 'floor', '--quality', 'draft']"
    unchecked = ("import os; import hypergs_blender.io.files as files; files.check_free_space = lambda *a: None; "
                 f"from hypergs_blender.commands.cli import main; main({encode})")
    copy = ("from hypergs_blender.gaussians import GaussianVideo; from hypergs_blender.io import cache; "
            "from hypergs_blender.io.clips import ClipFrames; import numpy as np, os; "
            "p = np.random.default_rng(0).uniform(0.5, 1, (40, 2000, 8)).astype(np.float32); "
            "cache.write_clip(ClipFrames.of(GaussianVideo(p, 64, 48)), os.environ['FS'] + '/c.hgs')")
    proc = _in_a_small_file_system(tmp_path, f"""
        {python} -m hypergs_blender encode {video} -o $FS/clip.hgs --encoder floor --quality draft 2>&1 \
            | sed 's/^/cli: /'; echo "rc=${{PIPESTATUS[0]}}"
        echo "left: $(ls -A $FS)"
        {python} -c "{unchecked}" 2>&1 | sed 's/^/unchecked: /'; echo "rc=${{PIPESTATUS[0]}}"
        echo "left: $(ls -A $FS)"
        {python} -c "{copy}"; echo "rc=$?"
        echo "left: $(ls -A $FS)"
    """)
    lines = proc.stdout.splitlines()
    assert [line for line in lines if line.startswith(("rc=", "left:"))] == ["rc=1", "left: "] * 3, proc
    cli = [line for line in lines if line.startswith("cli: ") and line.strip() != "cli:"]
    assert len(cli) == 1 and "clip.hgs: the float16 file of its" in cli[0] and "free in" in cli[0], cli
    unchecked = [line for line in lines if line.startswith("unchecked: ") and line.strip() != "unchecked:"]
    assert len(unchecked) == 1 and "clip.hgs: cannot write (No space left on device)" in unchecked[0], unchecked
    assert proc.stderr.strip().splitlines()[-1].endswith("c.hgs: cannot write (No space left on device)"), proc.stderr
