"""Build the Blender extension zip(s) with Blender's own tool, and validate them with it.

    python tools/build_extension.py [--output-dir dist] [--split-platforms]

(`hypergs build-extension` runs this script.) It prints the paths of the zips it built. The build:
1. fetches the wheels that `blender_manifest.toml` lists (`wheels = [...]`) into wheels/ with
   `pip download --no-deps --only-binary=:all: --platform ... --python-version ...`, each for the
   platform and Python version its file name names; wheels already there are kept, so re-running
   costs nothing;
2. runs `blender_ext.py build` (from the installed `bpy` wheel, or $BLENDER_EXT) on the repository root;
3. runs `blender_ext.py validate` on every zip it built, and refuses zips holding a file that git does
   not track (other than the fetched wheels): a stray file in the tree would ship to every user.
A failure ends in one line on stderr, `error: ...`, and exit status 1.
"""
from __future__ import annotations

import argparse
import glob
import importlib.util
import os
import platform
import subprocess
import sys
import tomllib
import zipfile
from pathlib import Path

from hypergs_blender.errors import one_line

ROOT = Path(__file__).resolve().parents[1]  # the repository root = the extension root
MANIFEST = ROOT / "blender_manifest.toml"


class BuildError(Exception):
    """The extension could not be built or does not validate."""


def manifest() -> dict:
    with open(MANIFEST, "rb") as f:
        return tomllib.load(f)


def blender_ext() -> Path:
    """Path of blender_ext.py: $BLENDER_EXT, else the copy inside the installed bpy wheel."""
    if os.environ.get("BLENDER_EXT"):
        return Path(os.environ["BLENDER_EXT"])
    spec = importlib.util.find_spec("bpy")  # locates the package without importing it
    if spec is None or not spec.submodule_search_locations:
        raise BuildError("bpy is not installed (pip install bpy==5.0.1), and $BLENDER_EXT is not set")
    for location in spec.submodule_search_locations:
        found = sorted(glob.glob(os.path.join(location, "*", "scripts", "addons_core", "bl_pkg", "cli",
                                              "blender_ext.py")))
        if found:
            return Path(found[-1])
    raise BuildError("blender_ext.py not found inside the bpy package")


def wheel_tags(filename: str) -> tuple[str, str, str, str, str]:
    """name, version, python tag, abi tag, platform tag of a wheel file name."""
    parts = Path(filename).name[:-len(".whl")].split("-")
    if len(parts) not in (5, 6):
        raise BuildError(f"not a wheel file name: {filename}")
    return parts[0], parts[1], parts[-3], parts[-2], parts[-1]


def python_version(python_tag: str) -> str:
    """The Python version a wheel's python tag names: "cp313" -> "3.13" (an abi3 wheel's tag is the
    oldest version it serves)."""
    digits = python_tag.removeprefix("cp").removeprefix("py")
    if not digits.isdigit() or len(digits) < 2:
        raise BuildError(f"cannot tell the Python version of the wheel tag {python_tag!r}")
    return f"{digits[0]}.{digits[1:]}"


def fetch_wheels(wheels: list[str], quiet: bool = False) -> None:
    """Download every listed wheel missing under the repository root (idempotent)."""
    for rel in wheels:
        target = (ROOT / rel).resolve()
        if target.is_file():
            continue
        target.parent.mkdir(parents=True, exist_ok=True)
        name, version, py, abi, plat = wheel_tags(target.name)
        platforms = [arg for tag in plat.split(".") for arg in ("--platform", tag)]  # a compound tag: each
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:", *platforms,
               "--python-version", python_version(py), "--implementation", "cp",
               "--abi", abi, "-d", str(target.parent), f"{name}=={version}"]
        if quiet:
            cmd.insert(4, "-q")
        print("fetching", target.name, file=sys.stderr)
        if subprocess.run(cmd, stdout=sys.stderr).returncode != 0:
            raise BuildError(f"pip download of {target.name} failed")
        if not target.is_file():
            raise BuildError(f"pip download did not produce {target.name}; update the manifest's wheels")


def run_ext(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, str(blender_ext()), *args], capture_output=True, text=True)


def untracked_files(zip_paths, root=ROOT) -> list[str]:
    """The files in these zips that git does not track and the manifest does not list as a wheel: a stray
    file in the source tree (a profile, a scratch script, a .blend) that the build would ship to every
    user. Empty outside a git checkout (a source tarball has nothing to compare with)."""
    try:
        listed = subprocess.run(["git", "-C", str(root), "ls-files", "-z"], capture_output=True)
    except OSError:  # no git on this machine
        return []
    if listed.returncode != 0:
        return []
    known = set(listed.stdout.decode().split("\0"))
    known.update(wheel.removeprefix("./") for wheel in manifest().get("wheels", []))
    stray = set()
    for zip_path in zip_paths:
        with zipfile.ZipFile(zip_path) as archive:
            stray.update(name for name in archive.namelist() if not name.endswith("/") and name not in known)
    return sorted(stray)


def validate(zip_path) -> None:
    result = run_ext("validate", str(zip_path))
    if result.returncode != 0:
        raise BuildError(f"{zip_path} does not validate:\n{result.stdout}{result.stderr}")


def build(output_dir=ROOT / "dist", split_platforms: bool = False, quiet: bool = False) -> list[Path]:
    """Fetch wheels, build, validate; returns the paths of the zips built."""
    meta = manifest()
    fetch_wheels(meta.get("wheels", []), quiet)
    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)
    args = ["build", "--source-dir", str(ROOT), "--output-dir", str(output_dir)]
    if split_platforms:
        args.append("--split-platforms")
    before = {p: p.stat().st_mtime_ns for p in output_dir.glob("*.zip")}
    result = run_ext(*args)
    if result.returncode != 0:
        raise BuildError(f"blender_ext.py build failed:\n{result.stdout}{result.stderr}")
    prefix = f"{meta['id']}-{meta['version']}"
    zips = [p for p in output_dir.glob(f"{prefix}*.zip")
            if p not in before or p.stat().st_mtime_ns != before[p]]
    if not zips:
        raise BuildError(f"blender_ext.py build made no zip in {output_dir}:\n{result.stdout}")
    for z in zips:
        validate(z)
    stray = untracked_files(zips)
    if stray:
        for z in zips:
            z.unlink()
        raise BuildError(f"the zip would ship {len(stray)} file(s) git does not track: {', '.join(stray[:5])}"
                         f"{' ...' if len(stray) > 5 else ''}; git add, ignore or remove them, then build again")
    return sorted(zips)


def this_platform() -> str:
    """Blender's name for this platform (as in the split zips' names): linux_x64, windows_x64, ..."""
    system = {"darwin": "macos", "windows": "windows", "linux": "linux"}[platform.system().lower()]
    machine = {"x86_64": "x64", "amd64": "x64", "arm64": "arm64", "aarch64": "arm64"}[platform.machine().lower()]
    return f"{system}_{machine}"


def build_zip(output_dir) -> Path:
    """Build (and validate) the split zips; return this platform's."""
    zips = build(output_dir, split_platforms=True, quiet=True)
    mine = [z for z in zips if z.stem.endswith(this_platform())]
    if not mine:
        raise BuildError(f"no zip for {this_platform()} among {[z.name for z in zips]}")
    return mine[0]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Build and validate the Blender extension zip(s).")
    parser.add_argument("--output-dir", default=str(ROOT / "dist"))
    parser.add_argument("--split-platforms", action="store_true", help="one zip per platform")
    args = parser.parse_args(argv)
    try:
        zips = build(args.output_dir, args.split_platforms)
    except BuildError as e:
        print(f"error: {one_line(e)}", file=sys.stderr)
        return 1
    for path in zips:
        print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
