"""Blender from Python, headless, with the `bpy` wheel: building and validating the extension zips
with Blender's own tool, installing them into a throw-away user directory, and the main job (convert
the bundled sample strip, F12 to PNG, PSNR against the source) that `tools/blender_main_job.py` runs.
The Blender tests drive their sessions with the same helpers.

Building (`build`, also `hypergs build-extension`):
1. fetches the wheels that `blender_manifest.toml` lists (`wheels = [...]`) into wheels/ with
   `pip download --no-deps --only-binary=:all: --platform ... --python-version ...`, each for the
   platform and Python version its file name names; wheels already there are kept, so re-running
   costs nothing;
2. runs `blender_ext.py build` (from the installed `bpy` wheel, or $BLENDER_EXT) on the repository root;
3. runs `blender_ext.py validate` on every zip it built.
"""
from __future__ import annotations

import argparse
import glob
import json
import importlib.util
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
import tomllib
import warnings
from pathlib import Path

import numpy as np

from ..errors import HyperGSError

ROOT = Path(__file__).resolve().parents[2]  # the repository root = the extension root
MANIFEST = ROOT / "blender_manifest.toml"
SAMPLE = ROOT / "hypergs_blender" / "samples" / "sample.mp4"
EXTENSION_ID = "hypergs"
# The encoder the main job uses unless --encoder says otherwise: the bundled network ("floor": the
# no-learning grid floor, for comparison).
DEFAULT_ENCODER = "bundled"
# Environment for a Blender without a GPU context on a machine that has Mesa's EGL: glvnd's libEGL then finds
# no driver, as on a machine without libegl-mesa0 (the engine must take its numpy path, not abort).
NO_EGL = {"__EGL_VENDOR_LIBRARY_FILENAMES": "/nonexistent/no_egl_vendor.json"}


class BuildError(HyperGSError):
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
        raise SystemExit(f"no zip for {this_platform()} among {[z.name for z in zips]}")
    return mine[0]


def step_recorder(results: dict, out_path):
    """Decorator factory for test sessions: `@record(name)` runs the step at once and stores its
    result (or its traceback) under `name`, rewriting `out_path` as JSON after every step, so a
    session that dies still reports the steps it finished."""
    import traceback

    def record(name):
        def wrap(fn):
            try:
                results[name] = fn()
            except BaseException:
                results[name] = {"error": traceback.format_exc()}
            Path(out_path).write_text(json.dumps(results, indent=1, default=str))
            return fn
        return wrap
    return record


def start_blender(user_dir, block=("torch", "numba")):
    """Import bpy with HOME, caches and Blender's user resources in `user_dir` (must run before any
    other bpy import in the process). Modules in `block` are made unimportable first, as in a plain
    Blender (its Python has neither torch nor numba)."""
    user_dir = str(user_dir)
    for key in ("HOME", "XDG_CACHE_HOME", "XDG_CONFIG_HOME", "BLENDER_USER_RESOURCES"):
        os.environ[key] = user_dir
    for name in block:
        sys.modules[name] = None
    import bpy
    # Blender's own Python has the modules Blender bundles (OpenImageIO, pxr, ... in 5.0 and later) on
    # its path; the bpy module keeps them inside its package.
    bundled = (Path(bpy.utils.resource_path("LOCAL")) / "python" / "lib" /
               f"python{sys.version_info.major}.{sys.version_info.minor}" / "site-packages")
    if bundled.is_dir() and str(bundled) not in sys.path:
        sys.path.append(str(bundled))
    return bpy


def install_extension(bpy, zip_path):
    """Install and enable the zip in the user_default repository; returns the add-on module."""
    import importlib

    result = bpy.ops.extensions.package_install_files(filepath=str(zip_path), repo="user_default",
                                                      enable_on_install=True)
    if result != {"FINISHED"}:
        raise RuntimeError(f"installing {zip_path} failed: {result}")
    return importlib.import_module(f"bl_ext.user_default.{EXTENSION_ID}")


def add_movie_strip(bpy, scene, path, frame_start=1, name="clip"):
    """A movie strip stretched to the scene's output size (set it first), as `source_frames` resizes the
    frames it is compared with (Add > Movie's default, Scale to Fit, would letterbox another aspect)."""
    editor = scene.sequence_editor_create()
    strips = editor.strips if hasattr(editor, "strips") else editor.sequences
    strip = strips.new_movie(name=name, filepath=str(path), channel=1, frame_start=frame_start,
                             fit_method="STRETCH")
    editor.active_strip = strip
    return strip


def in_gpu_context(bpy, work) -> dict:
    """Run `work(depsgraph) -> dict` inside a render whose engine has a GPU context (bl_use_gpu_context:
    Blender has no window in background mode, so this is where the gpu module draws offscreen), with a
    throw-away 4 x 4 frame; the scene's engine and size are put back. An exception in `work` comes back as
    {"error": "Type: message"} (it cannot cross Blender's render call)."""
    found = {}

    class Probe(bpy.types.RenderEngine):
        bl_idname = "HYPERGS_GPU_PROBE"
        bl_label = "probe"
        bl_use_gpu_context = True

        def render(self, depsgraph):
            try:
                found.update(work(depsgraph))
            except Exception as e:
                found["error"] = f"{type(e).__name__}: {e}"
            self.end_result(self.begin_result(0, 0, 4, 4))

    r = bpy.context.scene.render
    saved = r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage
    bpy.utils.register_class(Probe)
    r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage = Probe.bl_idname, 4, 4, 100
    try:
        bpy.ops.render.render()
    finally:
        r.engine, r.resolution_x, r.resolution_y, r.resolution_percentage = saved
        bpy.utils.unregister_class(Probe)
    return found


def render_png(bpy, scene, frame: int, path) -> float:
    """F12 of one frame, saved as an 8-bit PNG with the scene's colour management; returns seconds."""
    scene.frame_set(frame)
    scene.render.image_settings.file_format = "PNG"
    scene.render.image_settings.color_depth = "8"
    scene.render.image_settings.color_mode = "RGB"
    scene.render.filepath = str(path)
    started = time.perf_counter()
    bpy.ops.render.render(write_still=True)
    return time.perf_counter() - started


def read_png(bpy, path) -> np.ndarray:
    """An 8-bit PNG as float32 [H, W, 3] in [0, 1] (stored bytes / 255), rows top to bottom."""
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        w, h = image.size
        pixels = np.empty(w * h * image.channels, np.float32)
        image.pixels.foreach_get(pixels)
        return pixels.reshape(h, w, image.channels)[::-1, :, :3].copy()
    finally:
        bpy.data.images.remove(image)


def source_frames(path, indices, width, height) -> dict:
    """{index: float32 [H, W, 3] in [0, 1]} source frames, resized (stretched) to width x height."""
    from ..io.frames import iter_frames
    from ..io.images import resize_exact
    return {i: resize_exact(f, width, height).astype(np.float32) / 255 for i, f in iter_frames(path, indices)}


def psnr(a, b) -> float:
    mse = float(np.mean((np.clip(a, 0, 1).astype(np.float64) - b) ** 2))
    return float("inf") if mse == 0 else 10 * np.log10(1 / mse)


def addon_module(addon, name: str):
    """A module of the installed extension (`addon`), e.g. "com.compat": reached at run time, so the
    harness works with whichever Blender's glue the zip installed."""
    import importlib
    return importlib.import_module(f"{addon.__name__}.{name}")


def main_job(argv=None) -> int:
    parser = argparse.ArgumentParser(description="The main job: the bundled sample strip converted in Blender, "
                                                 "F12 of the Sequencer's output to PNG, PSNR.")
    parser.add_argument("--video", default=str(SAMPLE), help="video to convert (default: the bundled sample)")
    parser.add_argument("--size", help="render size WxH (default: the video's)")
    parser.add_argument("--frames", help="scene frames to render, comma-separated (default: 5 spread)")
    parser.add_argument("--quality", choices=("draft", "standard", "high"), default="standard",
                        help="the Convert dialog's Quality preset")
    parser.add_argument("--gaussians", type=int, default=0, help="Gaussians per frame instead of a preset")
    parser.add_argument("--cell", type=float, default=None, help="cell size in source pixels instead of a preset")
    parser.add_argument("--encoder", choices=("floor", "bundled"),
                        default=os.environ.get("HYPERGS_ENCODER", DEFAULT_ENCODER))
    parser.add_argument("--zip", help="install this extension zip instead of building one")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    parser.add_argument("--out", default=str(ROOT / "runs" / "main_job"))
    args = parser.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    video = Path(args.video).resolve()

    started = time.perf_counter()
    if args.zip:
        zip_path = Path(args.zip)
    else:
        zip_path = build_zip(ROOT / "dist")
        print(f"built and validated {zip_path.name} ({zip_path.stat().st_size / 1e6:.0f} MB) "
              f"in {time.perf_counter() - started:.1f} s")
    os.environ["HYPERGS_ENCODER"] = args.encoder
    user_dir = tempfile.mkdtemp(prefix="hypergs-blender-user-")
    report = dict(python=platform.python_version(), encoder=args.encoder)
    try:
        bpy = start_blender(user_dir)
        report["blender"] = bpy.app.version_string
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t = time.perf_counter()
            addon = install_extension(bpy, zip_path)
            report["install_s"] = time.perf_counter() - t
            print(f"installed into {user_dir} (Blender {bpy.app.version_string}, Python {report['python']}), "
                  f"encoder: {args.encoder}")
            _main_job_scene(bpy, addon, args, video, out, report)
        here = str(Path(addon.__file__).parent)
        report["deprecations"] = sorted({f"{Path(w.filename).relative_to(here)}:{w.lineno}: {w.message}"
                                         for w in caught if issubclass(w.category, DeprecationWarning)
                                         and w.filename.startswith(here)})
        for line in report["deprecations"]:
            print("deprecated:", line)
    finally:
        shutil.rmtree(user_dir, ignore_errors=True)
        if args.json:
            Path(args.json).write_text(json.dumps(report, indent=1))
    return 0


def _main_job_scene(bpy, addon, args, video: Path, out: Path, report: dict) -> None:
    """Convert the video's strip, then F12 of the Sequencer's output (the scene strip the conversion
    added plays the clip's scene, rendered by HyperGS) at spread frames, against the source."""
    compat = addon_module(addon, "com.compat")
    scene = bpy.context.scene
    from ..io.frames import probe
    info = probe(video)
    width, height = (map(int, args.size.lower().split("x")) if args.size else (info.width, info.height))
    scene.render.resolution_x, scene.render.resolution_y = width, height  # before the strip: it fits this
    scene.render.resolution_percentage = 100
    strip = add_movie_strip(bpy, scene, video, name=video.stem)
    scene.view_settings.view_transform = "Standard"  # as in a video editing file: output = the strips' sRGB
    first, end = compat.strip_range(strip)
    scene.frame_start, scene.frame_end = first, end - 1
    t = time.perf_counter()
    if args.gaussians or args.cell:
        from ..encode import QUALITY
        options = dict(quality="CUSTOM", gaussian_count=args.gaussians or 0,
                       cell_size=args.cell or QUALITY["standard"]["cell"])
    else:
        options = dict(quality=args.quality.upper())
    bpy.ops.hypergs.convert_strip(**options)
    report["convert_s"] = convert_s = time.perf_counter() - t
    scene_strip = scene.sequence_editor.active_strip
    obj = next(o for o in scene_strip.scene.objects if o.hypergs.is_clip)
    s = obj.hypergs
    report.update(frames=s.num_frames, gaussians=s.gaussians_per_frame, encode_psnr=s.psnr,
                  scene_strip=dict(name=scene_strip.name, range=list(compat.strip_range(scene_strip)),
                                   channel=scene_strip.channel, movie_range=[first, end], movie_muted=strip.mute,
                                   engine=scene_strip.scene.render.engine))
    print(f"converted strip '{strip.name}': {s.num_frames} frames x {s.gaussians_per_frame} Gaussians "
          f"in {convert_s:.1f} s (encode-time PSNR {s.psnr:.2f} dB), played by the scene strip "
          f"'{scene_strip.name}' on channel {scene_strip.channel}")
    if args.frames:
        frames = [int(f) for f in args.frames.split(",")]
    else:
        frames = sorted(set(np.linspace(scene.frame_start, scene.frame_end, 5).round().astype(int).tolist()))
    offset = s.source_start - first  # source frame index = scene frame + offset
    truth = source_frames(video, [f + offset for f in frames], width, height)
    values, seconds = [], []
    print(f"F12 of the Sequencer at {width}x{height}:")
    for f in frames:
        png = out / f"frame_{f:04d}.png"
        seconds.append(render_png(bpy, scene, f, png))
        values.append(psnr(read_png(bpy, png), truth[f + offset]))
        shown = png.relative_to(ROOT) if png.is_relative_to(ROOT) else png
        print(f"  frame {f:4d}: PSNR {values[-1]:6.2f} dB  ({seconds[-1]:.2f} s)  {shown}")
    print(f"mean PSNR {np.mean(values):.2f} dB over {len(values)} frames")
    report.update(render_frames=frames, psnr=values, render_s=seconds, mean_psnr=float(np.mean(values)))
    # The clip exported to a .hgs file it is then linked to (the codec's bundled wheels at work): the
    # Sequencer's F12 shows it as before, up to the file's 8-bit quantization.
    clip_scene = scene_strip.scene
    with bpy.context.temp_override(scene=clip_scene, view_layer=clip_scene.view_layers[0], active_object=obj,
                                   object=obj):
        bpy.ops.hypergs.export_clip(filepath=str(out / "clip.hgs"), link=True)
    middle = frames[len(frames) // 2]
    png = out / f"linked_{middle:04d}.png"
    render_png(bpy, scene, middle, png)
    report.update(linked=obj.hypergs.linked, linked_psnr=psnr(read_png(bpy, png), truth[middle + offset]),
                  embedded_psnr=values[len(frames) // 2])
    print(f"linked to {out / 'clip.hgs'}: frame {middle} PSNR {report['linked_psnr']:.2f} dB "
          f"(embedded {report['embedded_psnr']:.2f} dB)")
