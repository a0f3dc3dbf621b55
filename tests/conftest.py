import json
import os
import subprocess
import sys
from pathlib import Path

import av
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]


def write_video(path, frames, fps=12):
    """Lossless H.264 (yuv444p, crf 0) of uint8 RGB frames [T, H, W, 3]."""
    with av.open(str(path), "w") as container:
        stream = container.add_stream("libx264", rate=fps, options={"crf": "0"})
        stream.width, stream.height, stream.pix_fmt = frames.shape[2], frames.shape[1], "yuv444p"
        for f in frames:
            container.mux(stream.encode(av.VideoFrame.from_ndarray(np.ascontiguousarray(f), format="rgb24")))
        container.mux(stream.encode())
    return path


@pytest.fixture
def moving_video(tmp_path):
    """12 frames 64 x 48: a bright square moving right over a horizontal gradient."""
    frames = np.zeros((12, 48, 64, 3), np.uint8)
    frames[..., 0] = np.linspace(20, 200, 64, dtype=np.uint8)[None, None, :]
    for t in range(12):
        frames[t, 12:28, 4 + 3 * t:20 + 3 * t] = (250, 240, 60)
    return write_video(tmp_path / "moving.mp4", frames)


def make_pan_clip(path, width=432, height=240, frames=70):
    """A real-looking test movie: a camera pan over a procedural image (H.264 yuv420p, 24 fps, crf 18),
    the size of the DAVIS clips; its mdat comes before its moov."""
    from hypergs_blender.bench.scale import make_pan_video
    make_pan_video(path, seconds=frames / 24, width=width, height=height, fps=24, crf=18)
    return path


def run_blender_session(script, work: Path, encoder: str, timeout: float, env: dict | None = None) -> dict:
    """Build the extension zip, then run `script ZIP WORK OUT.json` in a fresh Python (bpy can be
    imported once per process) with $HYPERGS_ENCODER defaulting to `encoder` and the variables `env`
    added. Returns the steps' results, with the session's console output under "console" (Blender prints
render reports there)."""
    from hypergs_blender.bench.blender import build_zip
    zip_path = build_zip(work / "dist")
    env = dict(os.environ, PYTHONPATH=str(ROOT), HYPERGS_ENCODER=os.environ.get("HYPERGS_ENCODER", encoder),
               **(env or {}))
    out = work / "session.json"
    python = os.environ.get("HYPERGS_BLENDER_PYTHON", sys.executable)  # e.g. a venv with bpy 4.2
    proc = subprocess.run([python, str(script), str(zip_path), str(work), str(out)], env=env,
                          capture_output=True, text=True, timeout=timeout)
    if not out.is_file():
        pytest.fail(f"the Blender session died (rc {proc.returncode}):\n{proc.stdout[-3000:]}\n{proc.stderr[-3000:]}")
    return dict(json.loads(out.read_text()), console=proc.stdout + proc.stderr)


def step(session, name):
    """One recorded step of a Blender session; fails with its traceback if it raised."""
    result = session.get(name)
    assert result is not None, f"step {name} did not run"
    assert "error" not in result, result["error"]
    return result
