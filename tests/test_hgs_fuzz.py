"""Fuzzing the .hgs reader (both codecs: a quantized file and a float16 frame cache): truncated files, flipped bits, overwritten bytes, huge declared sizes (with the
checksums re-signed so the values get past them), wrong versions, garbage. Every input must either
read as a valid clip or raise HgsError (LimitError past the limits), within bounded memory and time
(fuzzing.py): never another exception, a crash or a hang.

In the test suite: hypothesis, a bounded number of examples. Stand-alone, a longer run that prints
how many inputs it tried:
    python tests/test_hgs_fuzz.py --seconds 600            # random structured mutations
    python tests/test_hgs_fuzz.py --atheris -- -max_total_time=600   # coverage-guided (pip install atheris)
"""
from __future__ import annotations

import math
import random
import struct
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

if __name__ == "__main__":  # run as a script from anywhere: the package is in the checkout
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fuzzing import HEADER_FIELDS, Stats, fuzz_limits, outcome, set_header_field  # noqa: E402
from hypergs_blender.errors import HyperGSError, LimitError
from hypergs_blender.gaussians import GaussianVideo
from hypergs_blender.io.hgs import _CRC, _ENTRY, _HEADER, _INDEX, HgsError, HgsReader, save_hgs

INTERESTING_INTS = [0, 1, 2, 3, 7, 8, 15, 16, 17, 63, 64, 65, 255, 256, 4096, 65535, 65536, 1 << 20, (1 << 20) + 1,
                    (1 << 31) - 1, 1 << 31, (1 << 32) - 1, 1 << 32, (1 << 63) - 1, (1 << 64) - 1]
INTERESTING_FLOATS = [0.0, -0.0, 1.0, -1.0, 1e-300, 1e300, -1e300, math.inf, -math.inf, math.nan, 88.0, 70.0, 1e30]


def base_file(codec: str = "quantized") -> bytes:
    rng = np.random.default_rng(0)
    t, n = 7, 10
    p = np.empty((t, n, 8), np.float32)
    p[..., 0:2] = rng.uniform(-1, 1, (1, n, 2)) + np.cumsum(rng.normal(0, 0.01, (t, n, 2)), axis=0)
    p[..., 2:4] = rng.uniform(0.5, 8, (t, n, 2))
    p[..., 4] = rng.uniform(0, 6, (t, n))
    p[..., 5:8] = rng.uniform(-0.2, 1.2, (t, n, 3))
    p[..., 3] = 2.0  # one constant parameter: a stream that costs no data
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "base.hgs"
        save_hgs(GaussianVideo(p, 48, 32, 24.0, (1, 1), {"k": "v"}), path, bits=6, group_size=3, codec=codec)
        return path.read_bytes()


BASES = {codec: base_file(codec) for codec in ("quantized", "float16")}
BASE = BASES["quantized"]


def layout(data: bytes) -> dict:
    """Offsets of the regions of a valid file: header end, chunks (offset, length), index offset."""
    fields = _HEADER.unpack_from(data)
    json_len = fields[-1]
    header_end = _HEADER.size + json_len + _CRC.size
    index_offset = fields[-2]
    count = _INDEX.unpack_from(data, index_offset)[1]
    chunks = [_ENTRY.unpack_from(data, index_offset + _INDEX.size + i * _ENTRY.size)[:2] for i in range(count)]
    return {"header_end": header_end, "chunks": chunks, "index": index_offset}


LAYOUTS = {codec: layout(data) for codec, data in BASES.items()}
LAYOUT = LAYOUTS["quantized"]


# ---- mutations (shared by hypothesis and the stand-alone runs) ----------------------------------------

def resign_header(data: bytearray, lay: dict = LAYOUT) -> None:
    end = lay["header_end"] - _CRC.size
    data[end:end + 4] = _CRC.pack(zlib.crc32(bytes(data[:end])))


def resign_chunk(data: bytearray, chunk: int, lay: dict = LAYOUT) -> None:
    off, length = lay["chunks"][chunk]
    end = off + length - _CRC.size
    data[end:end + 4] = _CRC.pack(zlib.crc32(bytes(data[off:end])))


def resign_index(data: bytearray, lay: dict = LAYOUT) -> None:
    end = len(data) - _CRC.size
    data[end:] = _CRC.pack(zlib.crc32(bytes(data[lay["index"]:end])))


def mutate(kind: str, rnd: random.Random, data: bytes = BASE, codec: str = "quantized") -> bytes:
    """One mutation of a valid file of `codec` (BASES[codec], or `data` of its layout), its parameters
    drawn from `rnd`."""
    lay = LAYOUTS[codec]
    out = bytearray(data)
    if kind == "truncate":
        return bytes(out[:rnd.randrange(len(out))])
    if kind == "flip":
        for _ in range(rnd.randint(1, 8)):
            pos = rnd.randrange(len(out))
            out[pos] ^= 1 << rnd.randrange(8)
        return bytes(out)
    if kind == "overwrite":
        pos = rnd.randrange(len(out))
        out[pos:pos + 8] = rnd.choice([b"\xff" * 8, b"\x00" * 8, rnd.randbytes(8), struct.pack("<Q", 1 << 40)])
        return bytes(out[:len(data)])
    if kind == "header":  # a field set to an edge value, checksum re-signed so the value is used
        name, fmt = rnd.choice(HEADER_FIELDS[1:])
        value = rnd.choice(INTERESTING_FLOATS) if fmt == "d" else rnd.choice(INTERESTING_INTS)
        set_header_field(out, name, value)
        resign_header(out, lay)
        return bytes(out)
    if kind == "chunk":  # damaged payload or chunk header, checksum re-signed
        chunk = rnd.randrange(len(lay["chunks"]))
        off, length = lay["chunks"][chunk]
        for _ in range(rnd.randint(1, 4)):
            pos = off + rnd.randrange(length - _CRC.size)
            out[pos] = rnd.choice([0, 1, 2, 3, 0x7F, 0x80, 0xFF, rnd.randrange(256)])
        resign_chunk(out, chunk, lay)
        return bytes(out)
    if kind == "index":  # damaged index entries, checksum re-signed
        start = lay["index"]
        pos = start + rnd.randrange(len(out) - start - _CRC.size)
        out[pos:pos + 4] = rnd.choice([b"\xff\xff\xff\xff", b"\x00\x00\x00\x00", rnd.randbytes(4), b"\x01\x00\x00\x00"])
        out = out[:len(data)]
        resign_index(out, lay)
        return bytes(out)
    if kind == "splice":  # bytes inserted or removed somewhere
        pos = rnd.randrange(len(out))
        if rnd.random() < 0.5:
            return bytes(out[:pos] + rnd.randbytes(rnd.randint(1, 64)) + out[pos:])
        return bytes(out[:pos] + out[pos + rnd.randint(1, 64):])
    if kind == "garbage":  # the magic, then noise
        return bytes(out[:8]) + rnd.randbytes(rnd.randint(0, 2000))
    raise ValueError(kind)


KINDS = ("truncate", "flip", "overwrite", "header", "chunk", "index", "splice", "garbage")


def read_outcome(data: bytes, path: Path, stats: Stats | None = None, kind: str = "") -> str:
    """'ok' (a valid clip), 'error' (HgsError) or 'limit' (past the fuzzing limits); anything else
    propagates and fails the test. Asserts the memory and time bounds."""
    path.write_bytes(data)

    def read():
        try:
            with HgsReader(path) as reader:
                video = reader.read_all()
                reader.verify()
        except HyperGSError as e:
            assert isinstance(e, (HgsError, LimitError)), f"{type(e).__name__}: {e}"
            raise
        assert video.params.shape[1:] == (video.num_gaussians, 8)
        assert np.all(np.isfinite(video.params)) and np.all(video.params[..., 2:4] > 0)

    with fuzz_limits():
        return outcome(read, f"a {len(data)}-byte file", stats, kind)


# ---- the test suite -------------------------------------------------------------------------------

@pytest.mark.parametrize("codec", BASES)
def test_base_file_reads(tmp_path, codec):
    assert read_outcome(BASES[codec], tmp_path / "f.hgs") == "ok"
    assert len(LAYOUTS[codec]["chunks"]) == 3


@pytest.mark.parametrize("codec", BASES)
@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(kind=st.sampled_from(KINDS), seed=st.integers(0, 2**32 - 1))
def test_fuzzed_files_read_or_fail_cleanly(tmp_path, codec, kind, seed):
    read_outcome(mutate(kind, random.Random(seed), BASES[codec], codec), tmp_path / "f.hgs")


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=600))
def test_arbitrary_bytes_fail_cleanly(tmp_path, data):
    assert read_outcome(data, tmp_path / "f.hgs") == "error"


def test_every_truncation_is_an_error(tmp_path):
    for length in range(0, len(BASE), 3):
        assert read_outcome(BASE[:length], tmp_path / "f.hgs") == "error"


@pytest.mark.parametrize("version", [0, 3, 65535])
def test_wrong_version_says_so(tmp_path, version):
    data = bytearray(BASE)
    set_header_field(data, "version", version)
    (tmp_path / "f.hgs").write_bytes(bytes(data))
    with pytest.raises(HgsError, match=f"unsupported .hgs version {version}"):
        HgsReader(tmp_path / "f.hgs")


@pytest.mark.parametrize("field,value", [("n", (1 << 20)), ("n", 1 << 31), ("frames", (1 << 32) - 1),
                                         ("json_len", (1 << 32) - 1), ("index_offset", (1 << 63)),
                                         ("group", 65535), ("canvas_w", 0), ("fps", math.nan),
                                         ("range5", math.inf), ("bits0", 17)])
def test_huge_or_invalid_declared_sizes_are_refused_quickly(tmp_path, field, value):
    data = bytearray(BASE)
    set_header_field(data, field, value)
    resign_header(data)
    assert read_outcome(bytes(data), tmp_path / "f.hgs") in ("error", "limit")


@pytest.mark.parametrize("codec,field,value,expect", [("quantized", "version", 2, "codec 0 in a version 2 file"),
                                                       ("float16", "codec", 0, "codec 0 in a version 2 file"),
                                                       ("float16", "codec", 7, "codec 7 in a version 2 file")])
def test_a_codec_and_version_that_do_not_match_are_refused(tmp_path, codec, field, value, expect):
    data = bytearray(BASES[codec])
    set_header_field(data, field, value)
    resign_header(data, LAYOUTS[codec])
    (tmp_path / "f.hgs").write_bytes(bytes(data))
    with pytest.raises(HgsError, match=expect):
        HgsReader(tmp_path / "f.hgs")


@pytest.mark.parametrize("codec", BASES)
def test_each_chunk_checksum_is_checked(tmp_path, codec):
    for off, length in LAYOUTS[codec]["chunks"]:
        data = bytearray(BASES[codec])
        data[off + length // 2] ^= 0x10
        with pytest.raises(HgsError, match="checksum"):
            _read_all(data, tmp_path)


def _read_all(data, tmp_path):
    (tmp_path / "f.hgs").write_bytes(bytes(data))
    with HgsReader(tmp_path / "f.hgs") as reader:
        reader.read_all()


def test_unfinished_file_is_reported(tmp_path):
    data = bytearray(BASE)
    set_header_field(data, "index_offset", 0)
    resign_header(data)
    (tmp_path / "f.hgs").write_bytes(bytes(data))
    with pytest.raises(HgsError, match="did not finish"):
        HgsReader(tmp_path / "f.hgs")


# ---- stand-alone runs -------------------------------------------------------------------------------

def run_random(seconds: float, seed: int, max_inputs: int | None = None) -> dict:
    rnd = random.Random(seed)
    stats = Stats()
    started = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "f.hgs"
        while time.time() - started < seconds and (max_inputs is None or sum(stats.outcomes.values()) < max_inputs):
            codec = rnd.choice(list(BASES))
            if rnd.random() < 0.05:
                kind, data = "bytes", rnd.randbytes(rnd.randint(0, 300))
            else:
                kind = rnd.choice(KINDS)
                data = mutate(kind, rnd, BASES[codec], codec)
                if rnd.random() < 0.2:  # stack a second mutation
                    data = mutate(rnd.choice(KINDS), rnd, data, codec) if len(data) == len(BASES[codec]) else data
            try:
                read_outcome(data, path, stats, kind)
            except Exception:
                crash = Path(f"hgs-crash-{sum(stats.outcomes.values())}.hgs")
                crash.write_bytes(data)
                print(f"FAILURE on input saved to {crash}", file=sys.stderr)
                raise
    return {**stats.report(), "seconds": round(time.time() - started, 1), "seed": seed}


def run_atheris(argv) -> None:
    import atheris

    tmp = Path(tempfile.mkdtemp())
    path = tmp / "f.hgs"
    stats = {"inputs": 0}

    def one_input(raw: bytes) -> None:
        fdp = atheris.FuzzedDataProvider(raw)
        choice = fdp.ConsumeIntInRange(0, len(KINDS))
        codec = list(BASES)[fdp.ConsumeIntInRange(0, len(BASES) - 1)]
        if choice == len(KINDS):
            data = fdp.ConsumeBytes(fdp.remaining_bytes())
        else:
            data = mutate(KINDS[choice], random.Random(fdp.ConsumeInt(8)), BASES[codec], codec)
        stats["inputs"] += 1
        read_outcome(data, path)

    atheris.instrument_all()
    atheris.Setup(argv, one_input)
    try:
        atheris.Fuzz()
    finally:
        print(f"atheris: {stats['inputs']} inputs", file=sys.stderr)


if __name__ == "__main__":
    import argparse
    import json

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=60)
    parser.add_argument("--inputs", type=int, default=None, help="stop after this many inputs")
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--atheris", action="store_true", help="coverage-guided; pass libFuzzer flags after --")
    args, rest = parser.parse_known_args()
    if args.atheris:
        run_atheris([sys.argv[0]] + [a for a in rest if a != "--"])
    else:
        print(json.dumps(run_random(args.seconds, args.seed, args.inputs)))
