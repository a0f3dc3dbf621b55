"""The probes of issue 12 (hostile and broken inputs), one test each, with the issue's numbers: small
inputs that demanded gigabytes or minutes are refused by the limits (limits.py) before anything is
allocated; writes are atomic and never go through a link onto an input; every failure of the command
line is one line on stderr and a non-zero exit, never a traceback, and leaves no file behind.
"""
from __future__ import annotations

import io
import json
import os
import signal
import struct
import subprocess
import sys
import time
import tracemalloc
import zlib
from pathlib import Path

import numpy as np
import pytest

from conftest import write_video
from hypergs_blender.commands.cli import main
from hypergs_blender.errors import Cancelled, HyperGSError, LimitError
from hypergs_blender.gaussians import GaussianVideo
from hypergs_blender.io.hgs import _CRC, _HEADER, HgsReader, load_hgs, save_hgs
from hypergs_blender.io.npz import load_npz, save_npz

ROOT = Path(__file__).resolve().parents[1]


def hypergs(capsys, *argv) -> tuple[int, list[str]]:
    """Run `hypergs ARGV` in this process: (exit status, stderr lines). An exception other than
    SystemExit (a traceback) fails the test by propagating."""
    try:
        main([str(a) for a in argv])
        code = 0
    except SystemExit as e:
        code = e.code
    return code, capsys.readouterr().err.splitlines()


def hypergs_process(cwd, *argv, limits=(), timeout=300, env=None) -> subprocess.CompletedProcess:
    """Run `hypergs ARGV` in a fresh Python with resource limits [(resource.RLIMIT_*, value)]."""
    import resource

    def preexec():
        for kind, value in limits:
            resource.setrlimit(kind, (value, value))
    return subprocess.run([sys.executable, "-m", "hypergs_blender", *map(str, argv)], cwd=cwd, capture_output=True,
                          text=True, timeout=timeout, preexec_fn=preexec, env=dict(os.environ, **(env or {})))


def assert_one_line_error(code, lines, *needles):
    assert code != 0
    assert len(lines) == 1, lines
    assert "Traceback" not in lines[0] and lines[0].startswith("hypergs ") and ": error: " in lines[0], lines
    for needle in needles:
        assert needle in lines[0], lines[0]


def peak_memory(fn):
    """(what fn() raised or returned, peak traced bytes)."""
    tracemalloc.start()
    try:
        result = fn()
    except Exception as e:
        result = e
    finally:
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
    return result, peak


def small_clip(t=3, n=40, seed=0) -> GaussianVideo:
    rng = np.random.default_rng(seed)
    p = np.empty((t, n, 8), np.float32)
    p[..., 0:2] = rng.uniform(-1, 1, (t, n, 2))
    p[..., 2:4] = rng.uniform(0.5, 4, (t, n, 2))
    p[..., 4] = rng.uniform(0, 3, (t, n))
    p[..., 5:8] = rng.uniform(0, 1, (t, n, 3))
    return GaussianVideo(p, 64, 48, 24.0)


@pytest.fixture
def video(tmp_path):
    frames = np.zeros((10, 48, 64, 3), np.uint8)
    frames[..., 1] = np.linspace(0, 250, 64, dtype=np.uint8)
    return write_video(tmp_path / "in.mp4", frames)


def resigned_hgs(path, **fields) -> Path:
    """A .hgs file with header fields changed and its header checksum re-signed, so the values are used."""
    from fuzzing import set_header_field
    data = bytearray(path.read_bytes())
    for name, value in fields.items():
        set_header_field(data, name, value)
    end = _HEADER.size + _HEADER.unpack_from(data)[-1]
    data[end:end + 4] = _CRC.pack(zlib.crc32(bytes(data[:end])))
    path.write_bytes(bytes(data))
    return path


def constant_hgs(path, frames: int, gaussians: int, scale: float, canvas=(256, 144)) -> Path:
    """A valid .hgs of `frames` x `gaussians` identical Gaussians in under 1 KB: written with one
    Gaussian, then the header says `gaussians` (every stream holds one symbol, which costs no bits)."""
    p = np.zeros((frames, 1, 8), np.float32)
    p[..., 2:4], p[..., 5:8] = scale, 0.01
    save_hgs(GaussianVideo(p, *canvas), path, bits=8, group_size=min(frames, 64))
    return resigned_hgs(path, n=gaussians)


# ---- 1. small inputs that exhausted memory or time ------------------------------------------------

@pytest.mark.parametrize("suffix", [".npz", ".hgs"])
def test_a_billion_gaussians_is_refused_before_any_work(tmp_path, capsys, video, suffix):
    before = set(tmp_path.iterdir())
    code, err = hypergs(capsys, "encode", video, "-o", tmp_path / f"x{suffix}", "--gaussians", "1000000000")
    assert_one_line_error(code, err, "--gaussians", "1,048,576", "HYPERGS_LIMIT_GAUSSIANS")
    assert set(tmp_path.iterdir()) == before


def test_constant_stream_hgs_of_2_gib_is_refused_whole_and_reads_frame_by_frame(tmp_path):
    path = constant_hgs(tmp_path / "c.hgs", frames=64, gaussians=1 << 20, scale=1.0)
    assert path.stat().st_size < 1024
    error, peak = peak_memory(lambda: load_hgs(path))
    assert isinstance(error, LimitError) and "2 GiB" in str(error) and "HYPERGS_LIMIT_BYTES" in str(error), error
    assert peak < 1 << 20
    with HgsReader(path) as reader:  # what a renderer does: one frame at a time, 32 MB
        assert reader.read_frame(0).shape == (1 << 20, 8)


def test_a_65535_pixel_canvas_is_refused_at_open(tmp_path, capsys):
    path = tmp_path / "c.hgs"
    save_hgs(small_clip(), path)
    resigned_hgs(path, canvas_w=65535, canvas_h=65535)
    with pytest.raises(LimitError, match=r"c.hgs: canvas: 65,535 pixels wide or high.*HYPERGS_LIMIT_SIDE"):
        HgsReader(path)
    code, err = hypergs(capsys, "render", path, "-o", tmp_path / "frames")
    assert_one_line_error(code, err, "HYPERGS_LIMIT_SIDE")
    assert not (tmp_path / "frames").exists()


def test_a_million_frame_filling_gaussians_are_refused_before_rendering(tmp_path):
    from hypergs_blender.render import render_params
    path = constant_hgs(tmp_path / "filling.hgs", frames=1, gaussians=1 << 20, scale=1000.0)
    assert path.stat().st_size < 1024
    params = HgsReader(path).read_frame(0)
    started = time.perf_counter()
    with pytest.raises(LimitError, match=r"256 x 144 render: 38,654,705,664 Gaussian-pixels.*HYPERGS_LIMIT_WORK"):
        render_params(params, 256, 144, 256, 144)
    assert time.perf_counter() - started < 5  # (the render itself took 17.7 s, the check is O(N))


@pytest.mark.parametrize("backend", ["numba", "numpy"])
def test_a_long_frame_can_be_cancelled_inside_the_frame(monkeypatch, backend):
    """Esc during a 17-second frame: keep_going is asked between pieces of one frame."""
    from hypergs_blender.gaussians import render_inputs
    from hypergs_blender.raster import rasterize_numpy
    monkeypatch.setenv("HYPERGS_LIMIT_WORK", "1e12")
    p = np.zeros((1, 1 << 16, 8), np.float32)
    p[..., 2:4], p[..., 5:8] = 1000.0, 0.01
    means, chol, colors = render_inputs(p, 256, 144, 256, 144)
    calls = []

    def keep_going():
        calls.append(time.perf_counter())
        return len(calls) < 3
    with pytest.raises(Cancelled, match="cancelled"):
        rasterize_numpy(means, chol, colors, 256, 144, backend=backend, keep_going=keep_going)
    assert len(calls) == 3  # asked twice inside the one frame, then stopped it


def test_a_2_mb_npz_zip_bomb_is_refused_without_decompressing(tmp_path):
    path = zip_bomb(tmp_path / "bomb.npz")
    assert path.stat().st_size < 3 << 20
    error, peak = peak_memory(lambda: load_npz(path))
    assert isinstance(error, LimitError), error
    assert "bomb.npz: params: 2.15 GiB of data decoded at once" in str(error) and "HYPERGS_LIMIT_BYTES" in str(error)
    assert peak < 1 << 20


def zip_bomb(path) -> Path:
    """An .npz whose params.npy (72 x 1,000,000 x 8 float32 zeros, 2.3 GB) deflates to 2 MB. Built from
    one compressed megabyte repeated (each ends with a full flush, so the copies are identical)."""
    header = io.BytesIO()
    np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False, "shape": (72, 10**6, 8)})
    zeros, copies = bytes(10**6), 72 * 8 * 4
    deflate = zlib.compressobj(9, zlib.DEFLATED, -15)
    head = deflate.compress(header.getvalue()) + deflate.flush(zlib.Z_FULL_FLUSH)
    block = deflate.compress(zeros) + deflate.flush(zlib.Z_FULL_FLUSH)
    assert deflate.compress(zeros) + deflate.flush(zlib.Z_FULL_FLUSH) == block
    stream = head + block * copies + deflate.flush(zlib.Z_FINISH)
    crc = zlib.crc32(header.getvalue())
    for _ in range(copies):
        crc = zlib.crc32(zeros, crc)
    meta = io.BytesIO()
    np.save(meta, np.frombuffer(json.dumps({"version": 1, "canvas": [64, 64], "fps": 24, "grid": [1, 1]}).encode(),
                                np.uint8))
    members = [("meta.npy", 0, meta.getvalue(), zlib.crc32(meta.getvalue()), len(meta.getvalue())),
               ("params.npy", 8, stream, crc, len(header.getvalue()) + copies * len(zeros))]
    data, directory = b"", b""
    for name, method, payload, crc, size in members:
        fields = struct.pack("<HHHHHIII", 20, 0, method, 0, 0x21, crc, len(payload), size)
        directory += (b"PK\x01\x02" + struct.pack("<H", 20) + fields + struct.pack("<HHHHHII", len(name), 0, 0, 0, 0,
                                                                                   0, len(data)) + name.encode())
        data += b"PK\x03\x04" + fields + struct.pack("<HH", len(name), 0) + name.encode() + payload
    end = b"PK\x05\x06" + struct.pack("<HHHHIIH", 0, 0, 2, 2, len(directory), len(data), 0)
    path.write_bytes(data + directory + end)
    return path


def png_16000(path) -> Path:
    """A valid 16000 x 16000 black PNG (about 750 KB): one deflated block of 1000 rows, repeated (each
    ends with a full flush, so the copies are identical), in a zlib stream with the right checksum."""
    rows = bytes(1 + 16000 * 3) * 1000  # filter byte 0, then black pixels
    deflate = zlib.compressobj(9, zlib.DEFLATED, -15)
    block = deflate.compress(rows) + deflate.flush(zlib.Z_FULL_FLUSH)
    assert deflate.compress(rows) + deflate.flush(zlib.Z_FULL_FLUSH) == block
    adler = 1
    for _ in range(16):
        adler = zlib.adler32(rows, adler)
    idat = b"\x78\xda" + block * 16 + deflate.flush(zlib.Z_FINISH) + struct.pack(">I", adler)

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    ihdr = struct.pack(">IIBBBBB", 16000, 16000, 8, 2, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", idat) + chunk(b"IEND", b""))
    return path


def test_two_16000_pixel_pngs_are_refused_before_decoding(tmp_path):
    import resource
    for frame in (1, 2):
        png_16000(tmp_path / f"shot.{frame:04d}.png")
    assert sum(f.stat().st_size for f in tmp_path.iterdir()) < 2 << 20
    # 3 GiB of address space: the 7.9 GB the encode took before cannot happen silently
    result = hypergs_process(tmp_path, "encode", "shot.####.png", "-o", "x.npz", "--encoder", "floor",
                             limits=[(resource.RLIMIT_AS, 6 << 30)])
    assert_one_line_error(result.returncode, result.stderr.splitlines(), "shot.0001.png", "HYPERGS_LIMIT_PIXELS")
    assert not (tmp_path / "x.npz").exists()


# ---- 2. atomic writes ------------------------------------------------------------------------------

@pytest.mark.parametrize("suffix,density,file_limit", [(".npz", ("--cell", "4"), 8192), (".hgs", ("--gaussians", "48"), 1024)])
def test_a_failed_write_keeps_the_good_file(tmp_path, video, suffix, density, file_limit):
    """Disk full / file-size limit while writing over a good clip: the good clip stays as it was,
    one line says why, no temporary file is left. (The small .hgs fails in the writer's close, whose
    clean-up used to fail again and hide the message behind a traceback.)"""
    import resource
    good = tmp_path / f"clip{suffix}"
    (save_npz if suffix == ".npz" else save_hgs)(small_clip(t=20, n=300), good)
    before = good.read_bytes()
    result = hypergs_process(tmp_path, "encode", video.name, "-o", good.name, "--encoder", "floor",
                             *density, limits=[(resource.RLIMIT_FSIZE, file_limit)])
    assert_one_line_error(result.returncode, result.stderr.splitlines(), "cannot write", "File too large")
    assert good.read_bytes() == before
    assert sorted(f.name for f in tmp_path.iterdir()) == sorted([video.name, good.name])


def test_an_output_link_to_the_input_is_refused_and_the_input_kept(tmp_path, capsys, video):
    before = video.read_bytes()
    (tmp_path / "link.npz").symlink_to(video)
    code, err = hypergs(capsys, "encode", video, "-o", tmp_path / "link.npz", "--encoder", "floor")
    assert_one_line_error(code, err, "link.npz is the input")
    assert video.read_bytes() == before


def test_writing_replaces_a_link_instead_of_writing_through_it(tmp_path, capsys, video):
    other = tmp_path / "other.bin"
    other.write_bytes(b"someone else's file")
    (tmp_path / "link.npz").symlink_to(other)
    assert hypergs(capsys, "encode", video, "-o", tmp_path / "link.npz", "--encoder", "floor",
                   "--gaussians", "48")[0] == 0  # 8 x 6 cells on the 64 x 48 video
    assert other.read_bytes() == b"someone else's file"
    assert not (tmp_path / "link.npz").is_symlink() and load_npz(tmp_path / "link.npz").num_gaussians == 48


# ---- 3. tracebacks instead of one-line errors ------------------------------------------------------

@pytest.mark.parametrize("argv,named", [
    (["encode", "{video}", "-o", "x.npz", "--gaussians", "0"], "--gaussians"),
    (["encode", "{video}", "-o", "x.npz", "--gaussians", "-5"], "--gaussians"),
    (["encode", "{video}", "-o", "x.npz", "--size", "-5"], "--size"),
    (["encode", "{video}", "-o", "x.npz", "--size", "0"], "--size"),
    (["eval", "{video}", "--frames", "0"], "--frames"),
    (["eval", "{video}", "--frames", "-3"], "--frames"),
    (["eval", "{video}", "--gaussians", "0"], "--gaussians"),
    (["render", "{clip}", "-o", "out", "--width", "-10"], "--width"),
    (["render", "{clip}", "-o", "out", "--width", "100000"], "--width"),
    (["render", "{clip}", "-o", "{clip}"], "--output"),
])
def test_bad_arguments_are_one_line(tmp_path, capsys, monkeypatch, video, argv, named):
    monkeypatch.chdir(tmp_path)
    save_npz(small_clip(), tmp_path / "clip.npz")
    before = set(tmp_path.iterdir())
    code, err = hypergs(capsys, *[a.format(video=video, clip="clip.npz") for a in argv])
    assert code == 2
    assert_one_line_error(code, err, named)
    assert set(tmp_path.iterdir()) == before


def test_render_into_a_read_only_folder_is_one_line(tmp_path, video):
    save_npz(small_clip(), tmp_path / "clip.npz")
    folder = tmp_path / "ro"
    folder.mkdir()
    command = [sys.executable, "-m", "hypergs_blender", "render", "clip.npz", "-o", "ro/frames"]
    if os.geteuid() == 0:  # root writes through permissions: a read-only bind mount, in a private namespace
        script = f'mount --bind "{folder}" "{folder}" && mount -o remount,ro,bind "{folder}" && exec "$@"'
        command = ["unshare", "-m", "sh", "-c", script, "sh", *command]
        probe = subprocess.run(["unshare", "-m", "true"], capture_output=True)
        if probe.returncode != 0:
            pytest.skip("root without mount namespaces: no way to make a folder read-only")
    else:
        folder.chmod(0o555)
    result = subprocess.run(command, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert_one_line_error(result.returncode, result.stderr.splitlines(), "the folder ro is not writable")
    assert list(folder.iterdir()) == []


@pytest.mark.parametrize("damage,needle", [
    ("no canvas", "damaged metadata"),
    ("not a zip", "BadZipFile"),
    ("truncated", "not a readable Gaussian video file"),
    ("29.1 TiB", "does not match"),
])
def test_malformed_npz_is_one_line(tmp_path, capsys, damage, needle):
    path = tmp_path / "bad.npz"
    save_npz(small_clip(), path)
    if damage == "no canvas":
        meta = json.dumps({"version": 1, "fps": 24, "grid": [1, 1]}).encode()
        with open(path, "wb") as f:
            np.savez(f, params=small_clip().params, meta=np.frombuffer(meta, np.uint8))
    elif damage == "not a zip":
        path.write_bytes(b"PK\x03\x04 but not a zip file at all")
    elif damage == "truncated":
        path.write_bytes(path.read_bytes()[:-300])
    else:  # a header declaring 1e6 x 1e6 x 8 float32 (29.1 TiB) over a few bytes of data
        header = io.BytesIO()
        np.lib.format.write_array_header_1_0(header, {"descr": "<f4", "fortran_order": False,
                                                      "shape": (10**6, 10**6, 8)})
        meta = json.dumps({"version": 1, "canvas": [64, 64], "fps": 24, "grid": [1, 1]}).encode()
        import zipfile
        with zipfile.ZipFile(path, "w") as z:
            z.writestr("params.npy", header.getvalue() + bytes(64))
            buffer = io.BytesIO()
            np.save(buffer, np.frombuffer(meta, np.uint8))
            z.writestr("meta.npy", buffer.getvalue())
    with pytest.raises(HyperGSError, match=needle):
        load_npz(path)
    code, err = hypergs(capsys, "info", path)
    assert_one_line_error(code, err, "bad.npz", needle)


def test_bad_output_suffix_or_folder_is_refused_before_the_encode(tmp_path, capsys, monkeypatch, video):
    from hypergs_blender.commands import encode
    monkeypatch.setattr(encode, "EncodePlan", lambda *a, **k: pytest.fail("the encode started"))
    for output, needle in [("x.bogus", "must end in"), ("missing/x.npz", "does not exist"),
                           ("missing/x.usd", "does not exist")]:
        code, err = hypergs(capsys, "encode", video, "-o", tmp_path / output, "--encoder", "floor")
        assert_one_line_error(code, err, needle)


@pytest.mark.parametrize("sig,word", [(signal.SIGINT, "interrupted"), (signal.SIGTERM, "terminated")])
def test_ctrl_c_and_sigterm_clean_up_say_one_line_and_end_by_the_signal(tmp_path, video, sig, word):
    """After the cleanup the process dies of the signal (a shell reads 128 + its number and a shell
    loop stops), whatever CPython's own flag for an unhandled Ctrl-C says: a plain exit 130 came
    back as -2 now and then, when Ctrl-C landed in numba's JIT."""
    proc = subprocess.Popen([sys.executable, "-m", "hypergs_blender", "encode", video.name, "-o", "out.hgs",
                             "--encoder", "floor", "--gaussians", "200", "--size", "64", "--refine", "400"],
                            cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 120
    while not any("out.hgs" in f.name for f in tmp_path.iterdir()):  # the writer's temporary file
        assert proc.poll() is None and time.time() < deadline, proc.communicate()
        time.sleep(0.05)
    time.sleep(0.5)
    proc.send_signal(sig)
    _, stderr = proc.communicate(timeout=60)
    assert proc.returncode == -sig, stderr
    assert_one_line_error(proc.returncode, stderr.splitlines(), word)
    assert [f.name for f in tmp_path.iterdir()] == [video.name]


def test_a_signal_inside_the_jit_is_raised_again_once_out_of_it():
    """numba's JIT runs Python callbacks from native code (llvmlite): Ctrl-C raised there was dropped
    (the encode went on to exit 0) or crashed the process, so the handler raises it again later."""
    from hypergs_blender.commands import cli
    namespace = {}
    exec(compile("import sys\nframe = sys._getframe()", "/site-packages/llvmlite/binding/executionengine.py",
                 "exec"), namespace)
    jit_frame, our_frame = namespace["frame"], sys._getframe()
    received = []
    previous = signal.signal(signal.SIGINT, lambda signum, frame: received.append(signum))
    try:
        assert cli._interrupt(signal.SIGINT, jit_frame) is None  # not raised there...
        deadline = time.time() + 5
        while not received and time.time() < deadline:
            time.sleep(0.01)
        assert received == [signal.SIGINT]  # ...but sent again, to land outside the JIT
    finally:
        signal.signal(signal.SIGINT, previous)
    with pytest.raises(KeyboardInterrupt) as raised:
        cli._interrupt(signal.SIGINT, our_frame)
    assert type(raised.value) is KeyboardInterrupt
    with pytest.raises(cli.Terminated):
        cli._interrupt(signal.SIGTERM, our_frame)


# ---- 5. unsafe loads -------------------------------------------------------------------------------

def test_every_torch_load_is_weights_only():
    call = "torch" + ".load("  # (spelt so that this line is not one of them)
    calls = [(path, line) for path in ROOT.rglob("*.py") if ".venv" not in path.parts
             for line in path.read_text().splitlines() if call in line]
    assert calls
    assert all("weights_only=True" in line for _, line in calls), [c for c in calls if "weights_only=True" not in c[1]]


class _Payload:
    """Unpickling this would create a file: a checkpoint must never execute it."""

    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (Path.touch, (Path(self.marker),))


def test_export_refuses_a_checkpoint_that_would_run_code(tmp_path, capsys):
    import torch
    run = tmp_path / "run"
    run.mkdir()
    torch.save({"config": {}, "model": _Payload(tmp_path / "pwned")}, run / "checkpoint.pt")
    code, err = hypergs(capsys, "export", run, "--out", tmp_path / "weights")
    assert_one_line_error(code, err, "checkpoint.pt: holds Python objects besides tensors and plain data")
    assert not (tmp_path / "pwned").exists() and not (tmp_path / "weights").exists()


# ---- 6. NaN, infinite, complex, wrong-dtype parameters ---------------------------------------------

def _with(index, value):
    def change(params):
        params = params.copy()
        params[index] = value
        return params
    return change


@pytest.mark.parametrize("change,needle", [
    (_with((1, 2, 0), np.nan), "NaN or infinite values (frame 1, Gaussian 2: x = nan)"),
    (_with((0, 3, 6), np.inf), "NaN or infinite values (frame 0, Gaussian 3: g = inf)"),
    (_with((2, 0, 3), 0.0), "scales must be > 0 (frame 2, Gaussian 0: scale_y = 0.0)"),
    (lambda p: p.astype(np.complex64), "real floating-point numbers, not complex64"),
    (lambda p: p.astype(np.int32), "real floating-point numbers, not int32"),
    (lambda p: p[:, :0], "empty clip"),
])
def test_npz_with_unusable_parameters_is_refused_at_load(tmp_path, change, needle):
    meta = json.dumps({"version": 1, "canvas": [64, 48], "fps": 24, "grid": [1, 1]}).encode()
    with open(tmp_path / "p.npz", "wb") as f:
        np.savez(f, params=change(small_clip().params), meta=np.frombuffer(meta, np.uint8))
    with pytest.raises(HyperGSError) as error:
        load_npz(tmp_path / "p.npz")
    assert str(error.value).startswith(f"{tmp_path / 'p.npz'}: ") and needle in str(error.value)


@pytest.mark.parametrize("scale", [np.nan, 0.0, -2.0])
def test_usd_with_nan_zero_or_negative_scales_is_refused_at_load(tmp_path, scale):
    from pxr import Usd, UsdGeom, Vt

    from hypergs_blender.io.usd import PRIM_PATH, export_usd, import_usd
    video = small_clip()
    export_usd(video, tmp_path / "c.usda")
    stage = Usd.Stage.Open(str(tmp_path / "c.usda"))  # as another tool would write it
    attribute = UsdGeom.PrimvarsAPI(stage.GetPrimAtPath(PRIM_PATH)).GetPrimvar("scale").GetAttr()
    scales = video.params[1, :, 2:4].copy()
    scales[5, 0] = scale
    attribute.Set(Vt.Vec2fArray.FromNumpy(scales), 2.0)  # frame 1 is time 2
    stage.Save()
    with pytest.raises(HyperGSError) as error:
        import_usd(tmp_path / "c.usda")
    message = str(error.value)
    assert message.startswith(f"{tmp_path / 'c.usda'}: ") and "(frame 1, Gaussian 5: scale_x = " in message


def test_writers_refuse_parameters_no_reader_would_accept(tmp_path):
    from hypergs_blender.io.clips import save_clip
    video = small_clip()
    video.params[0, 0, 3] = -1.0
    for name in ("c.npz", "c.usda", "c.hgs"):
        with pytest.raises(HyperGSError, match="scales must be > 0"):
            save_clip(video, tmp_path / name)
    assert list(tmp_path.iterdir()) == []
