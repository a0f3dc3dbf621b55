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
