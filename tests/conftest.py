import av
import numpy as np
import pytest


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
