"""Fuzzing the other readers beside .hgs (test_hgs_fuzz.py): .npz clips, USD import (.usda text and
.usdc binary) and image sequences. Every input must read, or fail with a one-line HyperGSError
(LimitError past the limits), within the memory and time caps of fuzzing.py: never another exception,
a crash or a hang.

In the test suite: hypothesis, a few seconds per format. Stand-alone, long runs in worker processes
(each under RLIMIT_AS, so that a native crash or a memory bomb is counted, its input saved, and the run
goes on), printing the counts:
    python tests/test_input_fuzz.py --inputs 100000 --workers 2            # every format
    python tests/test_input_fuzz.py --format usdc --seconds 600
"""
from __future__ import annotations

import io
import json
import random
import re
import struct
import subprocess
import sys
import tempfile
import time
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

if __name__ == "__main__":  # run as a script from anywhere: the package is in the checkout
    sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from fuzzing import Stats, cap_address_space, fuzz_limits, outcome  # noqa: E402
from hypergs_blender.gaussians import GaussianVideo  # noqa: E402

INTERESTING = ["0", "-1", "1", "-0", "nan", "inf", "-inf", "1e30", "-1e30", "1e400", "65535", "65536", "4294967296",
               "9223372036854775807", "1e-45", "3", "0.5", "-2.5", "100000", "1048577"]


def clip() -> GaussianVideo:
    rng = np.random.default_rng(0)
    t, n = 3, 12
    p = np.empty((t, n, 8), np.float32)
    p[..., 0:2] = rng.uniform(-1, 1, (t, n, 2))
    p[..., 2:4] = rng.uniform(0.5, 6, (t, n, 2))
    p[..., 4] = rng.uniform(0, 6, (t, n))
    p[..., 5:8] = rng.uniform(0, 1, (t, n, 3))
    return GaussianVideo(p, 40, 30, 24.0, (1, 1), {"path": "x.mp4"})


def _bytes_of(save, suffix: str) -> bytes:
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / f"base{suffix}"
        save(clip(), path)
        return path.read_bytes()


def _usd(video, path):
    from hypergs_blender.io.usd import export_usd
    export_usd(video, path)


def _npz(video, path):
    from hypergs_blender.io.npz import save_npz
    save_npz(video, path)


def byte_mutation(kind: str, rnd: random.Random, data: bytes) -> bytes:
    """Format-blind damage: truncate, flip bits, overwrite 8 bytes, insert or delete bytes."""
    out = bytearray(data)
    if kind == "truncate":
        return bytes(out[:rnd.randrange(len(out))])
    if kind == "flip":
        for _ in range(rnd.randint(1, 8)):
            out[rnd.randrange(len(out))] ^= 1 << rnd.randrange(8)
        return bytes(out)
    if kind == "overwrite":
        pos = rnd.randrange(len(out))
        out[pos:pos + 8] = rnd.choice([b"\xff" * 8, b"\x00" * 8, rnd.randbytes(8), struct.pack("<Q", 1 << 40),
                                       struct.pack("<q", -1), struct.pack("<I", 0x7FFFFFFF) * 2])
        return bytes(out[:len(data)])
    if kind == "splice":
        pos = rnd.randrange(len(out))
        if rnd.random() < 0.5:
            return bytes(out[:pos] + rnd.randbytes(rnd.randint(1, 64)) + out[pos:])
        return bytes(out[:pos] + out[pos + rnd.randint(1, 64):])
    raise ValueError(kind)


BYTE_KINDS = ("truncate", "flip", "overwrite", "splice")


# ---- .npz --------------------------------------------------------------------------------------------

NPZ_BASE = _bytes_of(_npz, ".npz")


def _npy(array: np.ndarray | None = None, header: dict | None = None, data: bytes | None = None) -> bytes:
    """An .npy member: an array, or a header dict and raw data (lying to each other if so wished)."""
    buffer = io.BytesIO()
    if header is None:
        np.lib.format.write_array(buffer, array, allow_pickle=False)
        return buffer.getvalue()
    np.lib.format.write_array_header_1_0(buffer, header)
    return buffer.getvalue() + data


def _zip(members: dict, compress: bool = False) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED) as z:
        for name, data in members.items():
            z.writestr(name, data)
    return buffer.getvalue()


def _meta(rnd: random.Random) -> bytes:
    meta = {"version": 1, "canvas": [40, 30], "fps": 24.0, "grid": [1, 1], "source": {}}
    key = rnd.choice(list(meta))
    choice = rnd.random()
    if choice < 0.2:
        del meta[key]
    elif choice < 0.7:
        value = rnd.choice(INTERESTING)
        meta[key] = json.loads(value) if value not in ("nan", "inf", "-inf") else float(value)
        if key in ("canvas", "grid") and rnd.random() < 0.7:
            meta[key] = [meta[key], rnd.choice([1, 30, -3, 70000, 1 << 40])]
    else:
        meta[key] = rnd.choice([None, "text", [], {}, [1, 2, 3], [[1], [2]], True])
    text = json.dumps(meta)
    if rnd.random() < 0.1:
        text = rnd.choice(["[" * 100000, "{", "\udcff", "null", '"string"', text[:rnd.randrange(len(text))]])
    return text.encode("utf-8", "surrogatepass")


def _params(rnd: random.Random) -> bytes:
    p = clip().params.copy()
    choice = rnd.randrange(6)
    if choice == 0:  # a bad value somewhere
        p[tuple(rnd.randrange(s) for s in p.shape)] = rnd.choice([np.nan, np.inf, -np.inf, 0.0, -1.0, 1e30])
        return _npy(p)
    if choice == 1:  # another dtype
        dtype = rnd.choice([np.float16, np.float64, np.complex64, np.int32, np.uint8, np.bool_, ">f4", "<f8"])
        return _npy(p.astype(dtype))
    if choice == 2:  # another shape
        shape = rnd.choice([(0, 12, 8), (3, 0, 8), (3, 12, 7), (36, 8), (3, 12, 8, 1), (), (1 << 20, 1 << 20, 8),
                            (1 << 62, 1, 8), (3, 12, 8)])
        data = rnd.choice([b"", p.tobytes(), p.tobytes()[:rnd.randrange(1, p.nbytes)]])
        return _npy(header={"descr": "<f4", "fortran_order": rnd.random() < 0.3, "shape": shape}, data=data)
    if choice == 3:  # a header that is not one
        raw = _npy(p)
        pos = rnd.randrange(8, 128)
        return raw[:pos] + rnd.choice([b"'descr': '|O'", b"\x00", b"{" * 50, b"(9999999999999999999,)"]) + raw[pos:]
    if choice == 4:
        return _npy(p.astype(rnd.choice(["<f4", "<f8"])).reshape(p.shape).T.copy().T)  # Fortran order
    return _npy(p)


def npz_mutation(kind: str, rnd: random.Random) -> bytes:
    if kind in BYTE_KINDS:
        return byte_mutation(kind, rnd, NPZ_BASE)
    if kind == "members":  # a valid zip of damaged, lying or missing members
        members = {"params.npy": _params(rnd), "meta.npy": _npy(np.frombuffer(_meta(rnd), np.uint8))}
        if rnd.random() < 0.15:
            del members[rnd.choice(list(members))]
        if rnd.random() < 0.1:
            members["extra.npy"] = _npy(np.zeros(3))
        if rnd.random() < 0.1:
            members["meta.npy"] = _npy(np.zeros((2, 2), np.uint8))
        return _zip(members, compress=rnd.random() < 0.3)
    if kind == "directory":  # the zip directory's sizes changed (what np.load would trust)
        data = bytearray(NPZ_BASE)
        headers = [m.start() for m in re.finditer(b"PK\x01\x02|PK\x03\x04", data)]  # central, local
        pos = rnd.choice(headers)
        offset = pos + (24 if data[pos + 2] == 1 else 22) - rnd.choice([0, 4])  # uncompressed or compressed size
        size = rnd.choice([0, 1, 0xFFFFFFFF, 1 << 30, 0x7FFFFFFF, rnd.randrange(1 << 32)])
        struct.pack_into("<I", data, offset, size)
        return bytes(data)
    if kind == "garbage":
        start = rnd.choice([b"PK\x03\x04", b"PK\x05\x06" + bytes(18), b"\x93NUMPY", b""])
        return start + rnd.randbytes(rnd.randint(0, 500))
    raise ValueError(kind)


NPZ_KINDS = BYTE_KINDS + ("members", "directory", "garbage")


def read_npz(path: Path):
    from hypergs_blender.io.npz import load_npz
    video = load_npz(path)
    assert video.params.dtype == np.float32 and np.isfinite(video.params).all() and (video.params[..., 2:4] > 0).all()


# ---- USD ---------------------------------------------------------------------------------------------

USDA_BASE = _bytes_of(_usd, ".usda").decode()
USDC_BASE = _bytes_of(_usd, ".usdc")
_NUMBER = re.compile(r"(?<![\w.])-?\d+(?:\.\d+)?(?:e[-+]?\d+)?")
_WORDS = ["float2[]", "float[]", "point3f[]", "color3f[]", "string", "int64[]", "double", "token", "dictionary",
          "hypergs", "canvas_width", "canvas_height", "grid", "source", "timeSamples", "Points", "Xform", "over",
          "def", "class", "subLayers", "references", "payload", "primvars:scale", "primvars:rotation"]


def usda_mutation(kind: str, rnd: random.Random) -> bytes:
    text = USDA_BASE
    if kind == "number":  # numbers (canvas, scales, counts, time codes) set to edge values
        numbers = list(_NUMBER.finditer(text))
        for m in rnd.sample(numbers, rnd.randint(1, 4)):
            text = text[:m.start()] + rnd.choice(INTERESTING) + text[m.end():]
            numbers = list(_NUMBER.finditer(text))
        return text.encode()
    lines = text.splitlines()
    if kind == "lines":  # lines deleted, duplicated or swapped
        for _ in range(rnd.randint(1, 3)):
            i, j = rnd.randrange(len(lines)), rnd.randrange(len(lines))
            choice = rnd.random()
            if choice < 0.4:
                del lines[i]
            elif choice < 0.7:
                lines.insert(i, lines[j])
            else:
                lines[i], lines[j] = lines[j], lines[i]
        return "\n".join(lines).encode()
    if kind == "words":  # types, keywords and names swapped
        words = [m for w in _WORDS for m in re.finditer(re.escape(w), text)]
        m = rnd.choice(words)
        return (text[:m.start()] + rnd.choice(_WORDS) + text[m.end():]).encode()
    if kind == "arcs":  # composition arcs to files that are missing, strange or the file itself
        target = rnd.choice(["missing.usda", "/dev/zero", "/proc/self/status", "base.usda", "", "x.usdc",
                             "../" * 50 + "etc/passwd"])
        arc = rnd.choice([f"subLayers = [@{target}@]", f"prepend references = @{target}@",
                          f"prepend payload = @{target}@"])
        if arc.startswith("subLayers"):
            return text.replace("(\n", f"(\n    {arc}\n", 1).encode()
        return text.replace('def Points "Gaussians" (', f'def Points "Gaussians" (\n    {arc}', 1).encode()
    if kind in BYTE_KINDS:
        return byte_mutation(kind, rnd, text.encode())
    raise ValueError(kind)


USDA_KINDS = ("number", "lines", "words", "arcs") + BYTE_KINDS
USDC_KINDS = BYTE_KINDS


def usdc_mutation(kind: str, rnd: random.Random) -> bytes:
    return byte_mutation(kind, rnd, USDC_BASE)


def read_usd(path: Path):
    from hypergs_blender.io.usd import import_usd
    video = import_usd(path)
    assert np.isfinite(video.params).all() and (video.params[..., 2:4] > 0).all()


# ---- image sequences ---------------------------------------------------------------------------------

def _image_bases() -> dict[str, bytes]:
    from hypergs_blender.io.images import write_image
    rng = np.random.default_rng(1)
    bases = {}
    with tempfile.TemporaryDirectory() as tmp:
        for suffix in (".png", ".exr", ".tif", ".jpg"):
            path = Path(tmp) / f"f{suffix}"
            write_image(path, rng.integers(0, 255, (12, 16, 3), dtype=np.uint8))
            bases[suffix] = path.read_bytes()
    return bases


IMAGE_BASES = _image_bases()


def _png_chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def image_mutation(kind: str, rnd: random.Random) -> tuple[str, bytes]:
    """(suffix, bytes) of one damaged frame of the sequence."""
    suffix = rnd.choice(list(IMAGE_BASES))
    data = IMAGE_BASES[suffix]
    if kind in BYTE_KINDS:
        return suffix, byte_mutation(kind, rnd, data)
    if kind == "png-header":  # the PNG header's size, depth and colour type set to edge values, CRC re-signed
        png = IMAGE_BASES[".png"]
        width, height, depth, colour = struct.unpack(">IIBB", png[16:26])
        field = rnd.randrange(4)
        values = [width, height, depth, colour]
        values[field] = rnd.choice([0, 1, 2, 3, 4, 6, 7, 8, 16, 255] + ([16000, 65535, 1 << 20, 0x7FFFFFFF, 0xFFFFFFFF]
                                                                       if field < 2 else []))
        ihdr = struct.pack(">IIBB", *values) + png[26:29]
        return ".png", png[:8] + _png_chunk(b"IHDR", ihdr) + png[33:]
    if kind == "header-bytes":  # the first 64 bytes of any format, where sizes live
        out = bytearray(data)
        for _ in range(rnd.randint(1, 4)):
            pos = rnd.randrange(min(64, len(out)))
            out[pos] = rnd.choice([0, 1, 0x7F, 0x80, 0xFF, rnd.randrange(256)])
        return suffix, bytes(out)
    if kind == "garbage":
        return suffix, rnd.randbytes(rnd.randint(0, 300))
    raise ValueError(kind)


IMAGE_KINDS = BYTE_KINDS + ("png-header", "header-bytes", "garbage", "other-size")


def write_sequence(folder: Path, kind: str, rnd: random.Random) -> Path:
    """A folder holding a 3-frame sequence (frame.0001.png ...) with one frame damaged."""
    for old in folder.iterdir():
        old.unlink()
    damaged = rnd.randrange(3)
    if kind == "other-size":  # a valid frame of another size
        from hypergs_blender.io.images import write_image
        suffix = rnd.choice(list(IMAGE_BASES))
        write_image(folder / f"frame.{damaged + 1:04d}{suffix}",
                    np.zeros((rnd.randint(1, 40), rnd.randint(1, 40), 3), np.uint8))
    else:
        suffix, data = image_mutation(kind, rnd)
        (folder / f"frame.{damaged + 1:04d}{suffix}").write_bytes(data)
    for i in {0, 1, 2} - {damaged}:
        (folder / f"frame.{i + 1:04d}{suffix}").write_bytes(IMAGE_BASES[suffix])
    return folder


def read_sequence(folder: Path):
    from hypergs_blender.io import image_sequence
    info = image_sequence.probe(folder)
    frames = [f for _, f in image_sequence.iter_frames(folder)]
    assert len(frames) == info.num_frames and frames[0].shape == (info.height, info.width, 3)
    assert all(f.shape == (8, 8, 3) for _, f in image_sequence.iter_frames(folder, size=8))


# ---- the formats, the suite and the stand-alone runs --------------------------------------------------

def _file_input(suffix, mutation):
    def make(kind, rnd, folder: Path) -> Path:
        path = folder / f"input{suffix}"
        path.write_bytes(mutation(kind, rnd))
        return path
    return make


# name -> (kinds, make(kind, rnd, folder) -> the path to read, read(path))
FORMATS = {
    "npz": (NPZ_KINDS, _file_input(".npz", npz_mutation), read_npz),
    "usda": (USDA_KINDS, _file_input(".usda", usda_mutation), read_usd),
    "usdc": (USDC_KINDS, _file_input(".usdc", usdc_mutation), read_usd),
    "images": (IMAGE_KINDS, lambda kind, rnd, folder: write_sequence(folder, kind, rnd), read_sequence),
}


def fuzz_one(name: str, kind: str, seed: int, folder: Path, stats: Stats | None = None) -> str:
    """Make input (kind, seed) of a format in `folder` and read it: 'ok', 'error' or 'limit'."""
    _, make, read = FORMATS[name]
    path = make(kind, random.Random(seed), folder)
    with fuzz_limits():
        return outcome(lambda: read(path), f"{name} input {kind}/{seed}", stats, kind)


def test_base_inputs_read(tmp_path):
    for name, (_, _, read) in FORMATS.items():
        folder = tmp_path / name
        folder.mkdir()
        path = folder / "input.npz" if name == "npz" else folder / f"input.{name}"
        if name == "images":
            path = folder
            for i in range(3):
                (folder / f"frame.{i + 1:04d}.png").write_bytes(IMAGE_BASES[".png"])
        else:
            path.write_bytes(NPZ_BASE if name == "npz" else USDA_BASE.encode() if name == "usda" else USDC_BASE)
        with fuzz_limits():
            assert outcome(lambda: read(path), name) == "ok"


def _fuzz_test(name: str, examples: int):
    @settings(max_examples=examples, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
    @given(kind=st.sampled_from(FORMATS[name][0]), seed=st.integers(0, 2**32 - 1))
    def test(tmp_path, kind, seed):
        folder = tmp_path / "in"
        folder.mkdir(exist_ok=True)
        fuzz_one(name, kind, seed, folder)
    return test


# Inputs on which usd-core's crate reader crashed the process (SIGSEGV) in stand-alone runs (16,000 .usdc
# inputs: 5), before .usdc files were read in a child process: now one-line errors naming the file.
USDC_CRASHES = [("flip", 3467491563), ("flip", 2139648169), ("flip", 2905395758), ("flip", 3316090229),
                ("overwrite", 4040751883)]


@pytest.mark.parametrize("kind,seed", USDC_CRASHES)
def test_usdc_inputs_that_crashed_usd_core_are_errors(tmp_path, kind, seed):
    from hypergs_blender.io.usd import UsdError
    assert fuzz_one("usdc", kind, seed, tmp_path) == "error"
    path = tmp_path / "input.usdc"
    with pytest.raises(UsdError) as error:
        read_usd(path)
    assert str(error.value).startswith(f"{path}: ") and "\n" not in str(error.value)


test_npz_inputs_read_or_fail_cleanly = _fuzz_test("npz", 150)
test_usda_inputs_read_or_fail_cleanly = _fuzz_test("usda", 80)
test_usdc_inputs_read_or_fail_cleanly = _fuzz_test("usdc", 40)
test_image_sequences_read_or_fail_cleanly = _fuzz_test("images", 80)


def run_worker(name: str, seed: int, inputs: int, seconds: float, crash_dir: Path) -> dict:
    """Fuzz one format in this process; writes the input about to be read to crash_dir/current so that
    the parent can keep it when this process dies."""
    kinds = FORMATS[name][0]
    rnd = random.Random(seed)
    stats = Stats()
    started = time.time()
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        while stats.count < inputs and time.time() - started < seconds:
            kind, input_seed = rnd.choice(kinds), rnd.randrange(2**32)
            (crash_dir / f"current-{name}-{seed}").write_text(f"{name} {kind} {input_seed}")
            try:
                fuzz_one(name, kind, input_seed, folder, stats)
            except Exception as e:
                stats.failures.append(f"{name} {kind} {input_seed}: {type(e).__name__}: {str(e)[:300]}")
    return stats.report()


def run(formats, inputs: int, seconds: float, workers: int, seed: int, address_space_gib: float) -> dict:
    """Fuzz each format with `workers` worker processes until `inputs` inputs (per format) or `seconds`;
    a worker that dies is counted as a crash (its input kept in ./fuzz-crashes) and replaced."""
    crash_dir = Path("fuzz-crashes").resolve()
    crash_dir.mkdir(exist_ok=True)
    report = {}
    for name in formats:
        totals, crashes, started, next_seed = [], [], time.time(), seed
        running, dispatched = [], 0
        while running or (dispatched < inputs and time.time() - started < seconds):
            while len(running) < workers and dispatched < inputs and time.time() - started < seconds:
                share = min(2000, inputs - dispatched)
                dispatched += share
                command = [sys.executable, __file__, "--worker", name, "--seed", str(next_seed), "--inputs", str(share),
                           "--seconds", str(max(1.0, seconds - (time.time() - started))),
                           "--address-space", str(address_space_gib)]
                running.append((next_seed, subprocess.Popen(command, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL,
                                                              text=True)))
                next_seed += 1
            for worker_seed, proc in list(running):
                if proc.poll() is None:
                    continue
                running.remove((worker_seed, proc))
                out = proc.stdout.read()
                if proc.returncode == 0:
                    totals.append(json.loads(out))
                else:
                    current = crash_dir / f"current-{name}-{worker_seed}"
                    crashes.append(f"exit {proc.returncode}: {current.read_text() if current.exists() else '?'}")
            time.sleep(0.2)
        report[name] = merge(totals, crashes, time.time() - started)
        print(json.dumps({name: report[name]}), flush=True)
    return report


def merge(reports: list[dict], crashes: list[str], seconds: float) -> dict:
    merged = {"inputs": sum(r["inputs"] for r in reports) + len(crashes), "outcomes": {}, "by_kind": {},
              "max_traced_peak_mib": max((r["max_traced_peak_mib"] for r in reports), default=0),
              "max_seconds": max((r["max_seconds"] for r in reports), default=0),
              "max_rss_mib": max((r["max_rss_mib"] for r in reports), default=0),
              "failures": [f for r in reports for f in r["failures"]], "crashes": crashes, "seconds": round(seconds, 1)}
    for r in reports:
        for key, value in r["outcomes"].items():
            merged["outcomes"][key] = merged["outcomes"].get(key, 0) + value
        for kind, counts in r["by_kind"].items():
            into = merged["by_kind"].setdefault(kind, {})
            for key, value in counts.items():
                into[key] = into.get(key, 0) + value
    if crashes:
        merged["outcomes"]["crash"] = len(crashes)
    return merged


if __name__ == "__main__":
    import argparse

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--format", choices=sorted(FORMATS) + ["all"], default="all")
    parser.add_argument("--inputs", type=int, default=100000, help="per format")
    parser.add_argument("--seconds", type=float, default=3600, help="per format")
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--address-space", type=float, default=4.0, help="GiB of address space per worker")
    parser.add_argument("--worker", choices=sorted(FORMATS), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.worker:
        cap_address_space(args.address_space)
        print(json.dumps(run_worker(args.worker, args.seed, args.inputs, args.seconds, Path("fuzz-crashes").resolve())))
    else:
        names = sorted(FORMATS) if args.format == "all" else [args.format]
        print(json.dumps(run(names, args.inputs, args.seconds, args.workers, args.seed, args.address_space), indent=1))
