"""The limits (limits.py) and the safe writes (io/files.py) on their own."""
from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

from hypergs_blender import limits
from hypergs_blender.errors import HyperGSError, LimitError
from hypergs_blender.io import files

README = Path(__file__).resolve().parents[1] / "README.md"


def test_a_limit_is_raised_by_its_environment_variable(monkeypatch):
    assert limits.GAUSSIANS.value == 1 << 20
    limits.GAUSSIANS.check(1 << 20, "x")
    with pytest.raises(LimitError, match=r"^clip.hgs: 1,048,577 Gaussians per frame, over the limit of 1,048,576 "
                                         r"\(set HYPERGS_LIMIT_GAUSSIANS to raise it\)$"):
        limits.GAUSSIANS.check((1 << 20) + 1, "clip.hgs")
    for text, value in [("2000000", 2000000), ("2e6", 2000000), ("2_000_000", 2000000), (" 7 ", 7)]:
        monkeypatch.setenv("HYPERGS_LIMIT_GAUSSIANS", text)
        assert limits.GAUSSIANS.value == value
    for text in ["0", "-5", "1.5", "abc", "inf", "nan"]:
        monkeypatch.setenv("HYPERGS_LIMIT_GAUSSIANS", text)
        with pytest.raises(LimitError, match="HYPERGS_LIMIT_GAUSSIANS=.*whole number >= 1"):
            limits.GAUSSIANS.check(1, "x")


def test_sizes_print_readably(monkeypatch):
    with pytest.raises(LimitError, match=r"^x: 2 GiB of data decoded at once, over the limit of 1 GiB"):
        limits.BYTES.check(2 << 30, "x")
    monkeypatch.setenv("HYPERGS_LIMIT_BYTES", "1000")
    with pytest.raises(LimitError, match=r"^x: 9,600 bytes of data decoded at once, over the limit of 1,000 bytes"):
        limits.BYTES.check(9600, "x")
    with pytest.raises(HyperGSError, match="0 x 5 is not an image size"):
        limits.check_image_size(0, 5, "x")
    with pytest.raises(LimitError, match=r"x \(10000 x 10000\): 100,000,000 pixels in one image.*PIXELS"):
        limits.check_image_size(10000, 10000, "x")


def test_the_readme_tables_every_limit_with_its_default():
    rows = dict(re.findall(r"^\| `HYPERGS_LIMIT_(\w+)` \| ([^|]+) \|", README.read_text(), re.M))
    assert set(rows) == {limit.name for limit in limits.ALL}
    for limit in limits.ALL:
        text = rows[limit.name].strip()
        value = int(text.replace(",", "")) if text[0].isdigit() and "iB" not in text else \
            int(text.split()[0]) << (30 if "GiB" in text else 20)
        assert value == limit.default, (limit.name, text)


def test_atomic_output_replaces_only_when_complete(tmp_path):
    target = tmp_path / "clip.npz"
    target.write_bytes(b"good")
    with pytest.raises(RuntimeError):
        with files.AtomicOutput(target) as temp:
            assert temp.parent == tmp_path and temp.suffix == ".npz" and temp != target
            temp.write_bytes(b"half")
            raise RuntimeError("interrupted")
    assert target.read_bytes() == b"good" and sorted(tmp_path.iterdir()) == [target]
    with files.AtomicOutput(target) as temp:
        temp.write_bytes(b"new")
    assert target.read_bytes() == b"new" and sorted(tmp_path.iterdir()) == [target]


def test_atomic_output_reports_write_errors_on_one_line(tmp_path):
    out = files.AtomicOutput(tmp_path / "a.hgs")
    f = out.open()
    f.write(b"x")
    with pytest.raises(HyperGSError, match=r"a.hgs: cannot write \(disk full\)"):
        with out:
            raise OSError(28, "disk full")
    assert list(tmp_path.iterdir()) == []


def test_files_left_by_an_interrupted_command_are_removed(tmp_path):
    out = files.AtomicOutput(tmp_path / "a.hgs")
    out.open().write(b"partial")
    files.discard_pending()
    assert list(tmp_path.iterdir()) == []


def test_a_streamed_write_removes_what_killed_writers_of_its_output_left(tmp_path):
    import subprocess
    import sys
    target = tmp_path / "a.hgs"
    code = "import os; from hypergs_blender.io import files; files.AtomicOutput(os.environ['T']).open().write(b'x'); os._exit(9)"
    subprocess.run([sys.executable, "-c", code], env={**os.environ, "T": str(target)}, check=False)
    killed = list(tmp_path.iterdir())
    assert len(killed) == 1 and killed[0].name.startswith(".a.hgs.") and killed[0].name.endswith(".part.hgs")
    running = tmp_path / f".a.hgs.{files._HOST}-{os.getpid()}-0123abcd.part.hgs"  # this process: running
    elsewhere = tmp_path / ".a.hgs.otherhost-1-0123abcd.part.hgs"  # another host's, on a shared folder
    other_output = tmp_path / f".b.hgs.{killed[0].name.split('.')[3]}.part.hgs"
    for path in (running, elsewhere, other_output):
        path.write_bytes(b"x")
    files.AtomicOutput(target).discard()  # a whole-file write does not list the folder
    assert killed[0].exists()
    out = files.AtomicOutput(target, streamed=True)
    out.discard()
    assert sorted(tmp_path.iterdir()) == sorted([running, elsewhere, other_output])


def test_a_streamed_write_also_removes_the_temporary_files_of_a_killed_writers_temporary_file(tmp_path):
    """`hypergs encode -o a.hgs` writes its float16 frames through a writer of its own temporary file, which
    has a temporary file of its own: killed then, it leaves both, and the next write of a.hgs removes both."""
    import subprocess
    import sys
    target = tmp_path / "a.hgs"
    code = ("import os; from hypergs_blender.io import files; held = files.AtomicOutput(os.environ['T'], streamed=True); "
            "files.AtomicOutput(held.temp, streamed=True).open().write(b'x'); os._exit(9)")
    subprocess.run([sys.executable, "-c", code], env={**os.environ, "T": str(target)}, check=False)
    held, nested = sorted(tmp_path.iterdir(), key=lambda p: len(p.name))
    assert held.name.startswith(".a.hgs.") and nested.name.startswith(f".{held.name}."), (held, nested)
    files.AtomicOutput(target, streamed=True).discard()
    assert list(tmp_path.iterdir()) == []


def test_atomic_output_keeps_the_umask_permissions(tmp_path):
    with files.AtomicOutput(tmp_path / "a.json") as temp:
        temp.write_text("{}")
    umask = os.umask(0)
    os.umask(umask)
    assert (tmp_path / "a.json").stat().st_mode & 0o777 == 0o666 & ~umask


@pytest.mark.parametrize("name,needle", [("missing/x.npz", "the folder .*missing does not exist"),
                                         ("x.bogus", "must end in .npz"), ("folder", "is a folder"),
                                         ("in.mp4", "is the input"), ("link.npz", "is the input"),
                                         ("a\0b.npz", "NUL")])
def test_check_output_refuses(tmp_path, name, needle):
    (tmp_path / "folder").mkdir()
    (tmp_path / "in.mp4").write_bytes(b"video")
    (tmp_path / "link.npz").symlink_to(tmp_path / "in.mp4")
    suffixes = (".npz",) if name.endswith("bogus") else ()
    with pytest.raises(HyperGSError, match=needle):
        files.check_output(tmp_path / name, suffixes, inputs=[tmp_path / "in.mp4"])
