"""The extension package: manifest, build with Blender's blender_ext.py, validation, zip contents."""
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

import pytest

import build_extension

ROOT = Path(__file__).resolve().parents[1]

PLATFORMS = ["linux-x64", "windows-x64", "macos-arm64"]


@pytest.fixture(scope="module")
def manifest():
    with open(ROOT / "blender_manifest.toml", "rb") as f:
        return tomllib.load(f)


@pytest.fixture(scope="module")
def zips(tmp_path_factory):
    out = tmp_path_factory.mktemp("dist")
    combined = build_extension.build(out / "all", quiet=True)
    split = build_extension.build(out / "split", split_platforms=True, quiet=True)
    return combined, split


def test_manifest(manifest):
    assert manifest["id"] == "hypergs" and manifest["type"] == "add-on"
    assert manifest["blender_version_min"] == "4.2.0"
    assert manifest["license"] == ["SPDX:GPL-3.0-or-later"]
    assert manifest["permissions"]["files"].strip()  # a reason is given
    assert "network" not in manifest["permissions"]
    assert sorted(manifest["platforms"]) == sorted(PLATFORMS)
    tags = [build_extension.wheel_tags(w) for w in manifest["wheels"]]
    for package in ("onnxruntime", "av", "constriction"):
        for plat in ("manylinux", "win_amd64", "macosx"):
            # Blender 4.2-5.0 run Python 3.11, 5.1 and later 3.13: every platform has a wheel for each
            # (an abi3 wheel serves both, but only a cp313 tag makes Blender accept the extension on 3.13).
            pythons = {build_extension.python_version(t[2]) for t in tags if t[0] == package and plat in t[4]}
            abi3 = {t[3] for t in tags if t[0] == package and plat in t[4]} == {"abi3"}
            assert pythons == {"3.11", "3.13"} or (abi3 and pythons == {"3.11"}), (package, plat, pythons)
        assert len({t[1] for t in tags if t[0] == package}) == 1, f"one {package} version"
    assert any(t[0] == "onnxruntime" and t[2] == "cp313" for t in tags)


def test_wheel_python_version():
    assert build_extension.python_version("cp311") == "3.11"
    assert build_extension.python_version("cp313") == "3.13"
    with pytest.raises(build_extension.BuildError):
        build_extension.python_version("pp3")


def test_build_and_validate(zips):
    combined, split = zips
    assert len(combined) == 1
    assert sorted(z.stem.rsplit("-", 1)[-1] for z in split) == sorted(p.replace("-", "_") for p in PLATFORMS)
    for z in combined + split:  # build() validates; validate again here, with the same tool
        result = build_extension.run_ext("validate", str(z))
        assert result.returncode == 0, result.stdout + result.stderr


def test_validator_rejects_a_broken_manifest(zips, tmp_path):
    good = zips[1][0]
    bad = tmp_path / "broken.zip"
    with zipfile.ZipFile(good) as src, zipfile.ZipFile(bad, "w") as dst:
        for item in src.infolist():
            data = src.read(item)
            if item.filename == "blender_manifest.toml":
                data = data.replace(b'blender_version_min = "4.2.0"', b'blender_version_min = "four"')
            if not item.filename.endswith(".whl"):
                dst.writestr(item, data)
    result = build_extension.run_ext("validate", str(bad))
    assert result.returncode != 0


def test_zip_contents(zips):
    combined, split = zips
    names = set(zipfile.ZipFile(combined[0]).namelist())
    for required in ("blender_manifest.toml", "__init__.py", "ops/__init__.py", "ui/__init__.py",
                     "engine/__init__.py", "com/mesh.py", "hypergs_blender/encode.py", "hypergs_blender/points.py",
                     "hypergs_blender/raster.py", "hypergs_blender/io/hgs.py", "hypergs_blender/io/frames.py"):
        assert required in names, required
    for weight in (ROOT / "hypergs_blender" / "weights").glob("*"):
        if weight.suffix in (".onnx", ".json"):
            assert f"hypergs_blender/weights/{weight.name}" in names
    # Only what Blender runs: no training, benchmarks, command line, sample or torch weights.
    for name in names:
        assert not name.startswith(("hypergs_blender/training/", "hypergs_blender/bench/",
                                    "hypergs_blender/commands/", "hypergs_blender/samples/")), name
        assert not name.endswith((".safetensors", "__main__.py")), name
    for name in names:
        top = name.split("/")[0]
        assert top not in {".venv", "tests", "data", "runs", "docs", "tools", ".git", ".ci", "dist"}, name
        assert "__pycache__" not in name and not name.endswith(".pyc"), name
    assert sum(n.startswith("wheels/") for n in names) == 15
    linux = next(z for z in split if z.stem.endswith("linux_x64"))
    wheels = [n for n in zipfile.ZipFile(linux).namelist() if n.startswith("wheels/")]
    assert len(wheels) == 5 and all("manylinux" in w for w in wheels)


def test_a_file_git_does_not_track_is_found_in_the_zip(tmp_path):
    """A stray file in the source tree (here: a profile beside the manifest) would ship to every user;
    the build refuses such a zip. Tracked files and the manifest's wheels are what a zip may hold."""
    with open(ROOT / "blender_manifest.toml", "rb") as f:
        wheel = f"wheels/{Path(tomllib.load(f)['wheels'][0]).name}"
    made = tmp_path / "made.zip"
    with zipfile.ZipFile(made, "w") as z:
        for name in ("blender_manifest.toml", "hypergs_blender/encode.py", wheel, "ops/"):
            z.writestr(name, b"")
    assert build_extension.untracked_files([made]) == []
    with zipfile.ZipFile(made, "a") as z:
        z.writestr("onnxruntime_profile__2026-11-27.json", b"{}")
        z.writestr("hypergs_blender/scratch.py", b"")
    assert build_extension.untracked_files([made]) == ["hypergs_blender/scratch.py",
                                                     "onnxruntime_profile__2026-11-27.json"]
    assert build_extension.untracked_files([made], root=tmp_path) == []  # not a git checkout: nothing to compare


def test_build_is_idempotent(tmp_path):
    """Wheels already in wheels/ are not fetched again: a second build reuses them."""
    build_extension.build(tmp_path / "first", quiet=True)
    before = {p.name: p.stat().st_mtime_ns for p in (ROOT / "wheels").glob("*.whl")}
    build_extension.build(tmp_path / "second", quiet=True)
    after = {p.name: p.stat().st_mtime_ns for p in (ROOT / "wheels").glob("*.whl")}
    assert before == after and before


def test_command_line(tmp_path):
    result = subprocess.run([sys.executable, "-m", "hypergs_blender", "build-extension", "--output-dir",
                             str(tmp_path), "--split-platforms"], capture_output=True, text=True, cwd=ROOT)
    assert result.returncode == 0, result.stderr
    assert len(result.stdout.split()) == 3


def test_matrix_installs_the_tests_imports_at_their_pins(tmp_path):
    import blender_matrix
    requirements = tmp_path / "requirements.txt"
    requirements.write_text("# pins\nav==18.1.0  # video\npytest==9.2.0\nnumpy==1.26.4\n")
    assert blender_matrix.pinned(["pytest", "av"], requirements) == ["pytest==9.2.0", "av==18.1.0"]
    assert sorted(blender_matrix.pinned(blender_matrix.TEST_IMPORTS)) == sorted(
        line for line in (ROOT / "requirements.txt").read_text().splitlines()
        if line.split("==")[0] in blender_matrix.TEST_IMPORTS)
    with pytest.raises(SystemExit, match="pins none of \\['torch'\\]"):
        blender_matrix.pinned(["pytest", "torch"], requirements)


def test_matrix_finds_the_modules_a_bpy_lacks(monkeypatch, tmp_path):
    """A module that neither this venv nor its bpy's bundle (5.0.1: pxr, OpenImageIO, oslquery, ...) has is named (the
    4.2 and 4.3 wheels lack pxr and OpenImageIO, and the matrix then installs them for the Blender tests); one only the
    bundle has is not, as the tests' sessions put the bundle on the path; also where bpy prints a line first (4.3)."""
    import blender_matrix
    assert blender_matrix.modules_bpy_lacks(Path(sys.executable)) == []
    monkeypatch.setattr(blender_matrix, "MODULES", {"oslquery": ("OSL queries", "none on PyPI"),
                                                    "no_such_module_here": ("Nothing", "nothing")})
    talkative = tmp_path / "python"
    talkative.write_text(f'#!/bin/sh\necho "Unable to initialise audio"\nexec "{sys.executable}" "$@"\n')
    talkative.chmod(0o755)
    for python in (Path(sys.executable), talkative):
        assert blender_matrix.modules_bpy_lacks(python) == ["no_such_module_here"]
