"""The Blender matrix: the extension zip is built once, then installed and run in every Blender it
supports, each the `bpy` wheel of that version in its own venv. In each, the main job
(tools/blender_main_job.py) converts the bundled sample as a movie strip and renders the Sequencer's
output with F12: the scene strip the conversion adds, rendered by HyperGS, against the source frames;
then a few frames converted with the HyperGS transformer (Model in the Convert dialog; the weights: a
tiny untrained transformer exported here, tools/tiny_transformer.py, or --transformer WEIGHTS).

    .venv/bin/python tools/blender_matrix.py [--versions 4.2,4.3,4.4,4.5,5.0,5.1,5.2,5.3] [--encoder bundled|floor] [--tests]

`.ci/run` runs it with --tests after the tests. With --tests, each version also runs every Blender test
(tests/test_blender_*.py, $HYPERGS_BLENDER_PYTHON set to its venv's Python, which gets the tests'
own imports, pytest and av, at requirements.txt's pins); it then fails when any of them fails.

The venvs live under .blender-matrix/ (gitignored): made once and reused (a venv is complete once its
READY file names its bpy version), and pip's cache makes a re-made one quick. The Python each bpy
needs is this one when the versions agree, else $HYPERGS_PYTHON_3_13 (for 3.13, ...), else pyenv's
newest 3.13.x, else python3.13 on the PATH.

A version fails when its session fails, its mean F12 PSNR is below MIN_PSNR or more than
PSNR_MARGIN below the PSNR the encoder measured itself (the Sequencer must show exactly the clip),
the clip exported to a .hgs file and linked to it renders worse than LINKED_MARGIN below the clip read
from its frame cache (this checks the bundled .hgs codec wheels too), or the extension's code triggers a
DeprecationWarning there, or the transformer's conversion does not give tiles x N Gaussians per frame
or its F12 is more than PSNR_MARGIN below what it measured. Exit status 1 if any version fails.
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

from blender_main_job import DEFAULT_ENCODER
from build_extension import ROOT, build_zip

from hypergs_blender.optional import MODULES

# Blender series -> (bpy wheel version, the Python it needs)
VERSIONS = {"4.2": ("4.2.23", "3.11"), "4.3": ("4.3.0", "3.11"), "4.4": ("4.4.0", "3.11"), "4.5": ("4.5.15", "3.11"),
            "5.0": ("5.0.1", "3.11"), "5.1": ("5.1.2", "3.13"), "5.2": ("5.2.4", "3.13"), "5.3": ("5.3.0", "3.13")}
MATRIX_DIR = ROOT / ".blender-matrix"
OUT_DIR = ROOT / "runs" / "blender_matrix"
MIN_PSNR = 24.0  # dB, the sample at Standard quality (1032 Gaussians): the network gives ~29.7, the floor ~25.9
PSNR_MARGIN = 1.0  # dB the Sequencer's F12 may lose to the encoder's own measurement (8-bit PNG)
LINKED_MARGIN = 2.0  # dB a clip linked to its .hgs file may lose to its frame cache (8-bit values: 0.3-1.5 dB at Standard)
INSTALL_TIMEOUT = 1800
SESSION_TIMEOUT = 900
TESTS_TIMEOUT = 3600
TEST_IMPORTS = ("pytest", "av")  # what the Blender side of tests/blender_session.py imports beyond bpy


def find_python(version: str) -> str:
    """An interpreter of Python `version` ("3.13")."""
    if f"{sys.version_info.major}.{sys.version_info.minor}" == version:
        return sys.executable
    override = os.environ.get(f"HYPERGS_PYTHON_{version.replace('.', '_')}")
    if override:
        return override
    pyenv = Path(os.environ.get("PYENV_ROOT") or Path.home() / ".pyenv") / "versions"
    installed = sorted(pyenv.glob(f"{version}.*"), key=lambda p: [int(x) for x in p.name.split(".") if x.isdigit()])
    if installed and (installed[-1] / "bin" / f"python{version}").is_file():
        return str(installed[-1] / "bin" / f"python{version}")
    found = shutil.which(f"python{version}")
    if found is None:
        raise SystemExit(f"no Python {version} for the bpy wheel: install it (pyenv install {version}) "
                         f"or set HYPERGS_PYTHON_{version.replace('.', '_')}")
    return found


def ensure_venv(series: str, root: Path = MATRIX_DIR) -> tuple[Path, float]:
    """The venv with bpy for a Blender series, made if missing or incomplete; (its python, seconds spent)."""
    bpy_version, python_version = VERSIONS[series]
    venv = root / f"bpy-{series}"
    ready = venv / "READY"
    python = venv / "bin" / "python"
    if ready.is_file() and ready.read_text().strip() == bpy_version and python.is_file():
        return python, 0.0
    started = time.perf_counter()
    shutil.rmtree(venv, ignore_errors=True)
    venv.parent.mkdir(parents=True, exist_ok=True)
    print(f"making {venv.relative_to(ROOT) if venv.is_relative_to(ROOT) else venv} "
          f"(Python {python_version}, bpy {bpy_version})", flush=True)
    subprocess.run([find_python(python_version), "-m", "venv", str(venv)], check=True, timeout=INSTALL_TIMEOUT)
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check", f"bpy=={bpy_version}"],
                   check=True, timeout=INSTALL_TIMEOUT)
    ready.write_text(bpy_version)
    return python, time.perf_counter() - started


def run_logged(command: list[str], log: Path, env: dict, timeout: float):
    """Run `command` in the repository root with its output in `log`; its exit status, or "timeout"."""
    with open(log, "w") as f:
        try:
            return subprocess.run(command, env=env, cwd=ROOT, stdout=f, stderr=subprocess.STDOUT,
                                  timeout=timeout).returncode
        except subprocess.TimeoutExpired:
            return "timeout"


def pinned(names, requirements: Path = ROOT / "requirements.txt") -> list[str]:
    """requirements.txt's pins ("pytest==9.2.0") of the packages `names`."""
    pins = {}
    for line in requirements.read_text().splitlines():
        name, sep, version = line.split("#")[0].strip().partition("==")
        if sep:
            pins[name.lower()] = f"{name}=={version}"
    missing = [n for n in names if n.lower() not in pins]
    if missing:
        raise SystemExit(f"{requirements} pins none of {missing}")
    return [pins[n.lower()] for n in names]


def modules_bpy_lacks(python: Path) -> list[str]:
    """Which of the optional modules Blender's Python bundles (hypergs_blender.optional.MODULES: pxr, OpenImageIO)
    `python` cannot import once its bpy's bundled modules are on the path, as the Blender tests' sessions put them
    (blender_headless.add_bundled_modules): the bpy wheels bundle them from 4.4 on, 4.2's and 4.3's do not. The
    answer is the last line printed, as bpy may print its own first (4.3: "Unable to initialise audio")."""
    code = ("import importlib.util, json, sys; sys.path.insert(0, sys.argv[1]); import bpy; "
            "from blender_headless import add_bundled_modules; add_bundled_modules(bpy); "
            "print(json.dumps([m for m in sys.argv[2:] if importlib.util.find_spec(m) is None]))")
    found = subprocess.run([str(python), "-c", code, str(Path(__file__).parent), *MODULES], capture_output=True,
                           text=True, check=True, timeout=INSTALL_TIMEOUT)
    return json.loads(found.stdout.splitlines()[-1])


def run_blender_tests(python: Path, out: Path) -> dict:
    """Every Blender test with its sessions in `python`'s Blender: {"rc", "summary", "seconds"}; pytest's
    own output in out/tests.txt. A bpy that lacks the modules Blender bundles (modules_bpy_lacks) gets them from
    PyPI at requirements.txt's pins, as the Blender it stands for has them; "added" names them."""
    added = [MODULES[m][1] for m in modules_bpy_lacks(python)]
    subprocess.run([str(python), "-m", "pip", "install", "-q", "--disable-pip-version-check",
                    *pinned([*TEST_IMPORTS, *added])], check=True, timeout=INSTALL_TIMEOUT)
    log = out / "tests.txt"
    started = time.perf_counter()
    rc = run_logged([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                     *sorted(str(t.relative_to(ROOT)) for t in (ROOT / "tests").glob("test_blender_*.py"))],
                    log, dict(os.environ, HYPERGS_BLENDER_PYTHON=str(python)), TESTS_TIMEOUT)
    lines = [line for line in log.read_text().splitlines() if line.strip()]
    return {"rc": rc, "summary": lines[-1] if lines else "", "seconds": time.perf_counter() - started, "added": added}


def run_series(series: str, python: Path, zip_path: Path, encoder: str, out: Path, transformer: Path) -> dict:
    """The main job in one Blender; its figures, with `failures` (empty when it passed)."""
    out.mkdir(parents=True, exist_ok=True)
    figures, log = out / "figures.json", out / "log.txt"
    figures.unlink(missing_ok=True)
    env = dict(os.environ, PYTHONPATH=str(ROOT))  # the core, for the job's comparisons (numpy only)
    started = time.perf_counter()
    rc = run_logged([str(python), str(ROOT / "tools" / "blender_main_job.py"), "--zip", str(zip_path),
                     "--encoder", encoder, "--json", str(figures), "--out", str(out), "--transformer", str(transformer)],
                    log, env, SESSION_TIMEOUT)
    report = json.loads(figures.read_text()) if figures.is_file() else {}
    report["session_s"] = time.perf_counter() - started
    failures = []
    if rc != 0:
        failures.append(f"the session ended with {rc} (see {log})")
    if "mean_psnr" not in report:
        failures.append(f"no F12 figures (see {log})")
    else:
        if report["mean_psnr"] < MIN_PSNR:
            failures.append(f"mean F12 PSNR {report['mean_psnr']:.2f} dB < {MIN_PSNR} dB")
        if report["mean_psnr"] < report["encode_psnr"] - PSNR_MARGIN:
            failures.append(f"the Sequencer's F12 ({report['mean_psnr']:.2f} dB) is worse than the clip "
                            f"({report['encode_psnr']:.2f} dB)")
        if not report.get("linked") or report["linked_psnr"] < report["cached_psnr"] - LINKED_MARGIN:
            failures.append(f"the clip linked to a .hgs file renders {report.get('linked_psnr', float('nan')):.2f} dB "
                            f"(from its frame cache {report['cached_psnr']:.2f} dB)")
        strip = report["scene_strip"]
        if strip["range"] != strip["movie_range"] or not strip["movie_muted"] or strip["engine"] != "HYPERGS":
            failures.append(f"the scene strip does not replace the movie strip: {strip}")
    t = report.get("transformer")
    if t is None:
        failures.append(f"no transformer conversion (see {log})")
    elif t["gaussians"] != t["expected"] or not t["on_top"] or t["psnr"] < t["encode_psnr"] - PSNR_MARGIN:
        failures.append(f"the transformer's conversion: {t}")
    failures += [f"deprecated: {d}" for d in report.get("deprecations", [])]
    report["failures"] = failures
    return report


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description="Install and run the extension in every supported Blender.")
    parser.add_argument("--versions", default=",".join(VERSIONS), help="Blender series, comma-separated")
    parser.add_argument("--encoder", choices=("bundled", "floor"), default=DEFAULT_ENCODER)
    parser.add_argument("--venvs", default=str(MATRIX_DIR), help="where the bpy venvs live")
    parser.add_argument("--out", default=str(OUT_DIR))
    parser.add_argument("--transformer", default=None,
                        help="transformer weights folder to convert with (default: a tiny untrained one made here)")
    parser.add_argument("--tests", action="store_true",
                        help="also run every Blender test (tests/test_blender_*.py) in each version")
    args = parser.parse_args(argv)
    series_list = [v.strip() for v in args.versions.split(",") if v.strip()]
    unknown = [v for v in series_list if v not in VERSIONS]
    if unknown:
        parser.error(f"unknown Blender series {unknown}: use {', '.join(VERSIONS)}")
    started = time.perf_counter()
    out = Path(args.out)
    zip_path = build_zip(out / "dist")
    if args.transformer:
        transformer = Path(args.transformer)
    else:
        from tiny_transformer import export_tiny_transformer
        transformer = export_tiny_transformer(out / "transformer_weights").parent
    rows, summary = [], {"build_s": time.perf_counter() - started}
    for series in series_list:
        python, venv_s = ensure_venv(series, Path(args.venvs))
        report = run_series(series, python, zip_path, args.encoder, out / series, transformer)
        report["venv_s"] = venv_s
        if args.tests:
            report["tests"] = run_blender_tests(python, out / series)
            if report["tests"]["rc"] != 0:  # pytest's 5 (nothing collected) fails too
                report["failures"].append(f"Blender tests: {report['tests']['summary']} "
                                          f"(see {out / series / 'tests.txt'})")
        summary[series] = report
        rows.append((series, report))
        status = "ok" if not report["failures"] else "FAILED: " + "; ".join(report["failures"])
        print(f"Blender {report.get('blender', series):12s} Python {report.get('python', '?'):7s} "
              f"venv {venv_s:5.0f} s  session {report['session_s']:5.1f} s  "
              f"convert {report.get('convert_s', float('nan')):5.1f} s  "
              f"F12 {max(report.get('render_s', [float('nan')])):5.2f} s  "
              f"PSNR {report.get('mean_psnr', float('nan')):5.2f} dB  "
              f"transformer {report.get('transformer', {}).get('psnr', float('nan')):5.2f} dB  "
              + (f"tests: {report['tests']['summary']}  " if "tests" in report else "")
              + (f"(with {', '.join(report['tests']['added'])} from PyPI)  " if report.get("tests", {}).get("added") else "")
              + status, flush=True)
    summary["total_s"] = time.perf_counter() - started
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    failed = [series for series, report in rows if report["failures"]]
    print(f"Blender matrix: {len(rows) - len(failed)} of {len(rows)} passed in {summary['total_s']:.0f} s"
          + (f"; failed: {', '.join(failed)}" if failed else ""))
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
