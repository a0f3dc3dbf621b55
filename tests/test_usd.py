"""USD export / import: a UsdGeomPoints prim with a time sample per frame, read back exactly."""
from __future__ import annotations

import json
import sys

import numpy as np
import pytest

from hypergs_blender.errors import HyperGSError
from hypergs_blender.gaussians import GaussianVideo
from hypergs_blender.io.usd import PRIM_PATH, UsdError, export_usd, import_usd


def make_video(t=4, n=50, seed=0):
    rng = np.random.default_rng(seed)
    p = np.empty((t, n, 8), np.float32)
    p[..., 0:2] = rng.uniform(-1.1, 1.1, (t, n, 2))
    p[..., 2:4] = rng.uniform(0.2, 30, (t, n, 2))
    p[..., 4] = rng.uniform(0, 2 * np.pi, (t, n))
    p[..., 5:8] = rng.uniform(-0.5, 1.5, (t, n, 3))
    return GaussianVideo(p, 320, 180, 29.97, (2, 3), {"path": "shot.mp4", "frames": [0, 2, 4, 6], "psnr": 31.5})


@pytest.mark.parametrize("suffix", [".usd", ".usda", ".usdc"])
def test_usd_round_trip_is_exact(tmp_path, suffix):
    video = make_video()
    path = tmp_path / f"clip{suffix}"
    export_usd(video, path)
    out = import_usd(path)
    assert out.params.shape == video.params.shape
    # positions go through pixels (x * W/2) in float32: exact up to float rounding
    np.testing.assert_allclose(out.params[..., 0:2], video.params[..., 0:2], rtol=0, atol=1e-6)
    assert np.array_equal(out.params[..., 2:8], video.params[..., 2:8])  # stored as they are
    assert (out.canvas_width, out.canvas_height, out.grid) == (320, 180, (2, 3))
    assert out.fps == pytest.approx(29.97)
    assert out.source == video.source


def test_usd_stage_layout(tmp_path):
    from pxr import Usd, UsdGeom

    video = make_video(t=3, n=20)
    path = tmp_path / "clip.usda"
    export_usd(video, path, start_frame=101)
    stage = Usd.Stage.Open(str(path))
    assert stage.GetTimeCodesPerSecond() == pytest.approx(29.97)
    assert stage.GetFramesPerSecond() == pytest.approx(29.97)
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (101, 103)
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y
    points = UsdGeom.Points(stage.GetPrimAtPath(PRIM_PATH))
    assert points and stage.GetDefaultPrim().GetPath() == "/GaussianVideo"
    assert points.GetPointsAttr().GetTimeSamples() == [101.0, 102.0, 103.0]
    pts = np.asarray(points.GetPointsAttr().Get(102))
    np.testing.assert_allclose(pts[:, 0], video.params[1, :, 0] * 160, rtol=1e-6)
    np.testing.assert_allclose(pts[:, 1], -video.params[1, :, 1] * 90, rtol=1e-6)
    widths = np.asarray(points.GetWidthsAttr().Get(101))
    np.testing.assert_allclose(widths, 2 * np.sqrt(video.params[0, :, 2] * video.params[0, :, 3]), rtol=1e-6)
    primvars = UsdGeom.PrimvarsAPI(points)
    for name in ("scale", "rotation", "displayColor"):
        assert primvars.GetPrimvar(name).GetInterpolation() == UsdGeom.Tokens.vertex
    np.testing.assert_array_equal(np.asarray(primvars.GetPrimvar("displayColor").Get(103)), video.params[2, :, 5:8])
    meta = points.GetPrim().GetCustomDataByKey("hypergs")
    assert meta["canvas_width"] == 320 and json.loads(meta["source"])["psnr"] == 31.5
    extent = np.asarray(points.GetExtentAttr().Get(101))
    assert np.all(extent[0, :2] <= pts.min(0)[:2]) and np.all(extent[1, :2] >= pts.max(0)[:2])


def test_usd_frames_import_in_time_order(tmp_path):
    video = make_video(t=5, n=8, seed=3)
    export_usd(video, tmp_path / "c.usd", start_frame=0)
    np.testing.assert_array_equal(import_usd(tmp_path / "c.usd").params[..., 5:8], video.params[..., 5:8])


def test_usd_import_errors(tmp_path):
    from pxr import Usd, UsdGeom

    with pytest.raises(UsdError, match="no such file"):
        import_usd(tmp_path / "missing.usd")
    (tmp_path / "bad.usda").write_text("#usda 1.0\nthis is not usd")
    with pytest.raises(UsdError, match="not a readable USD"):
        import_usd(tmp_path / "bad.usda")
    stage = Usd.Stage.CreateNew(str(tmp_path / "other.usda"))
    UsdGeom.Points.Define(stage, "/P")
    stage.Save()
    with pytest.raises(UsdError, match="no Gaussian video"):
        import_usd(tmp_path / "other.usda")
    with pytest.raises(UsdError, match="must end in"):
        export_usd(make_video(), tmp_path / "c.abc")


def test_usd_cli_round_trip(tmp_path, capsys, monkeypatch):
    from hypergs_blender.commands import cli
    monkeypatch.setattr(cli, "COMMAND_MODULES", ["clips"])  # only the commands under test
    main = cli.main
    from hypergs_blender.io.hgs import load_hgs, save_hgs

    video = make_video(t=3, n=30)
    save_hgs(video, tmp_path / "c.hgs", bits=8)
    main(["export-usd", str(tmp_path / "c.hgs"), str(tmp_path / "c.usd")])
    main(["import-usd", str(tmp_path / "c.usd"), str(tmp_path / "back.hgs")])
    assert "3 frames x 30 Gaussians" in capsys.readouterr().out
    a, b = load_hgs(tmp_path / "c.hgs"), load_hgs(tmp_path / "back.hgs")
    # .hgs -> USD -> .hgs: the second quantization lands on the same levels, up to float rounding
    np.testing.assert_allclose(b.params[..., 5:8], a.params[..., 5:8], atol=1e-5)


@pytest.mark.parametrize("suffix", [".usd", ".usda"])
def test_streaming_writer_saves_as_it_goes_and_reads_back_exactly(tmp_path, suffix, monkeypatch):
    from hypergs_blender.io import usd
    monkeypatch.setattr(usd, "SAVE_EVERY", 8)  # a crate file is saved and its layer reloaded 8 times
    video = make_video(t=70, n=20, seed=1)
    path = tmp_path / f"clip{suffix}"
    with usd.UsdWriter(path, 320, 180, 20, 29.97, (2, 3), video.source, start_frame=5) as writer:
        for start in range(0, 70, 9):
            writer.write(video.params[start:start + 9])
        assert not path.exists()  # only a complete file appears
    out = import_usd(path)
    np.testing.assert_allclose(out.params[..., 0:2], video.params[..., 0:2], rtol=0, atol=1e-6)
    assert np.array_equal(out.params[..., 2:8], video.params[..., 2:8]) and out.source == video.source


def test_a_failed_usd_export_leaves_no_file(tmp_path):
    from hypergs_blender.io.usd import UsdWriter
    (tmp_path / "c.usd").write_bytes(b"the file before")
    with pytest.raises(RuntimeError):
        with UsdWriter(tmp_path / "c.usd", 32, 32, 20) as writer:
            writer.write(make_video(t=3, n=20).params)
            raise RuntimeError("cancelled")
    with pytest.raises(UsdError, match="expected frames"):
        with UsdWriter(tmp_path / "c.usd", 32, 32, 20) as writer:
            writer.write(np.zeros((1, 21, 8), np.float32))
    with pytest.raises(UsdError, match="empty clip"):
        with UsdWriter(tmp_path / "c.usd", 32, 32, 20):
            pass
    assert [p.name for p in tmp_path.iterdir()] == ["c.usd"] and (tmp_path / "c.usd").read_bytes() == b"the file before"


def test_crate_files_are_read_in_a_child_and_its_errors_come_back(tmp_path, monkeypatch):
    """A binary file (.usdc, or .usd holding a crate) is read in a child process: what it reads and the
    errors it raises (their type and one-line message) come back as from a read in this process."""
    from hypergs_blender.errors import LimitError
    from hypergs_blender.io import usd

    video = make_video(t=3, n=20)
    export_usd(video, tmp_path / "c.usd")  # a crate, whatever the suffix
    export_usd(video, tmp_path / "c.usda")
    children = []
    read_in_child = usd._read_in_child
    monkeypatch.setattr(usd, "_read_in_child", lambda *a: children.append(a[0].name) or read_in_child(*a))
    np.testing.assert_array_equal(import_usd(tmp_path / "c.usd").params, import_usd(tmp_path / "c.usda").params)
    assert children == ["c.usd"]  # the text file is read here
    monkeypatch.setenv("HYPERGS_LIMIT_FRAMES", "2")
    with pytest.raises(LimitError, match="HYPERGS_LIMIT_FRAMES") as error:
        import_usd(tmp_path / "c.usd")
    assert "c.usd" in str(error.value) and children == ["c.usd", "c.usd"]
    monkeypatch.delenv("HYPERGS_LIMIT_FRAMES")
    with pytest.raises(UsdError, match="no UsdGeomPoints prim at /Nothing"):
        import_usd(tmp_path / "c.usd", prim_path="/Nothing")


def test_a_python_without_pxr_gets_a_clear_error_and_no_file(tmp_path, monkeypatch):
    """The bpy 4.2 wheel's Python has no pxr: export and import say what is missing and where it comes from."""
    video = make_video()
    existing = tmp_path / "clip.usdc"
    export_usd(video, existing)
    before = existing.read_bytes()
    monkeypatch.setitem(sys.modules, "pxr", None)  # import pxr raises ModuleNotFoundError
    for call in (lambda: export_usd(video, existing), lambda: export_usd(video, tmp_path / "new.usda"),
                 lambda: import_usd(existing)):
        with pytest.raises(HyperGSError, match=r"USD files need the Python module 'pxr' \(PyPI package usd-core\)"):
            call()
    assert existing.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["clip.usdc"]
