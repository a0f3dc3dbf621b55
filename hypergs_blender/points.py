"""GaussianVideo <-> per-frame point arrays on an image plane (the Blender extension's storage).

A clip is stored as points whose attributes describe one Gaussian each (float32 everywhere):

  position  [M, 3]  the mean on an image plane in the XY plane, z = 0: the canvas spans
                    x in [-aspect, aspect], y in [-1, 1] (aspect = canvas width / height), +y is up,
                    so canvas mean (mx, my) in [-1, 1] sits at (mx * aspect, -my, 0)
  scale     [M, 2]  standard deviations along the Gaussian's own axes, in plane units
                    (one plane unit is canvas_height / 2 pixels along both axes)
  rotation  [M]     radians in [0, 2 pi), counter-clockwise in the plane (the canvas angle negated,
                    because the canvas' y axis points down)
  color     [M, 4]  RGBA, scene-linear: the Gaussian's sRGB-encoded additive colour through the
                    sRGB transfer function extended to all reals (odd, and the standard formula
                    above 1), so a colour picked in Blender means what it shows; alpha is 1, unused
  frame     [M]     int32 index of the clip frame the Gaussian belongs to (0 .. T - 1)

Rendering sums the Gaussians in sRGB-encoded space (the model's definition) and only then decodes
the image to scene-linear, so storing colours linearly changes nothing about the picture.

Edited in Blender, frames may hold different numbers of points; `points_to_video` pads them to a
GaussianVideo's fixed N with invisible Gaussians and records the real counts in
`source["frame_counts"]`, which `video_to_points` honours (so export -> import keeps the edit).
"""
from __future__ import annotations

import math

import numpy as np

from .colour import linear_to_srgb, srgb_to_linear
from .gaussians import NUM_PARAMS, GaussianVideo


def params_to_points(params: np.ndarray, canvas_width: int, canvas_height: int) -> dict:
    """[T, N, 8] (or [N, 8]) canvas parameters -> flat point arrays (see the module docstring)."""
    params = np.asarray(params, np.float32)
    if params.ndim == 2:
        params = params[None]
    t, n = params.shape[:2]
    flat = params.reshape(-1, NUM_PARAMS)
    aspect = canvas_width / canvas_height
    unit = 2.0 / canvas_height  # plane units per canvas pixel
    position = np.zeros((t * n, 3), np.float32)
    position[:, 0] = flat[:, 0] * aspect
    position[:, 1] = -flat[:, 1]
    color = np.ones((t * n, 4), np.float32)
    color[:, :3] = srgb_to_linear(flat[:, 5:8])
    return dict(position=position,
                scale=np.ascontiguousarray(flat[:, 2:4] * unit, dtype=np.float32),
                rotation=np.mod(-flat[:, 4], 2 * np.pi).astype(np.float32),
                color=color,
                frame=np.repeat(np.arange(t, dtype=np.int32), n))


def points_to_params(position: np.ndarray, scale: np.ndarray, rotation: np.ndarray, color: np.ndarray,
                     canvas_width: int, canvas_height: int) -> np.ndarray:
    """Flat point arrays of one frame (position [M, 3], scale [M, 2], rotation [M], color [M, 3 or 4])
    -> canvas parameters [M, 8]. The plane's z is ignored."""
    m = len(position)
    aspect = canvas_width / canvas_height
    params = np.empty((m, NUM_PARAMS), np.float32)
    params[:, 0] = np.asarray(position, np.float32).reshape(m, -1)[:, 0] / aspect
    params[:, 1] = -np.asarray(position, np.float32).reshape(m, -1)[:, 1]
    params[:, 2:4] = np.asarray(scale, np.float32).reshape(m, 2) * (canvas_height / 2.0)
    params[:, 4] = np.mod(-np.asarray(rotation, np.float32).reshape(m), 2 * np.pi)
    params[:, 5:8] = linear_to_srgb(np.asarray(color, np.float32).reshape(m, -1)[:, :3])
    return params


FRAME_COUNTS = "frame_counts"  # GaussianVideo.source key: real Gaussians per frame of a padded clip


def clip_frame_index(scene_frame: float, frame_start: int, speed: float) -> int:
    """The clip frame shown at a scene frame (may be outside the clip): floor((f - start) * speed),
    with a 1e-4 margin so that a speed like 1/3 lands on whole frames (as the Geometry Nodes do)."""
    return math.floor((scene_frame - frame_start) * speed + 1e-4)


def blender_fps(fps: float) -> tuple[int, float]:
    """A frame rate as Blender's scenes store it: (fps, fps_base), an integer and a float with fps /
    fps_base the rate. Whole rates and the NTSC ones (24000/1001, 30000/1001, ...) as Blender's own
    presets write them (base 1 or 1.001), any other rate with the base making up the rest."""
    for base in (1.0, 1.001):
        whole = round(fps * base)
        if whole >= 1 and math.isclose(whole / base, fps, rel_tol=1e-4):
            return whole, base
    whole = max(1, round(fps))
    return whole, whole / fps


def points_to_video(points: dict, canvas_width: int, canvas_height: int, fps: float = 24.0, *,
                    num_frames: int | None = None, grid=(1, 1), source: dict | None = None) -> GaussianVideo:
    """Flat point arrays (position, scale, rotation, color, frame; see the module docstring) -> a clip.

    Frames may hold different numbers of points (points deleted or added in Blender): a
    GaussianVideo needs N per frame, so every frame is padded to the largest count with invisible
    Gaussians (colour 0, the clip's median scale, at the canvas centre) after its real ones, and
    `source["frame_counts"]` lists the real counts (`video_to_points` drops the padding again;
    other readers render the padding as nothing, or after 8-bit quantization as a colour within half
    a quantization step of 0). Within a frame, points keep their order.
    Points that cannot be a Gaussian are left out: a negative `frame`, non-finite values, a zero
    scale (a scale's sign does not matter: only its square enters the covariance).
    The clip has max(num_frames, largest frame + 1) frames (at least 1)."""
    frame = np.asarray(points["frame"]).astype(np.int64).reshape(-1)
    params = points_to_params(points["position"], np.abs(np.asarray(points["scale"], np.float32)),
                              points["rotation"], points["color"], canvas_width, canvas_height)
    keep = (frame >= 0) & np.all(np.isfinite(params), axis=1) & np.all(params[:, 2:4] > 0, axis=1)
    frame, params = frame[keep], params[keep]
    order = np.argsort(frame, kind="stable")
    frame, params = frame[order], params[order]
    t = max(int(num_frames or 0), int(frame.max()) + 1 if len(frame) else 0, 1)
    counts = np.bincount(frame, minlength=t)
    n = max(1, int(counts.max()))
    source = dict(source or {})
    source.pop(FRAME_COUNTS, None)
    if np.all(counts == n):
        out = params.reshape(t, n, NUM_PARAMS)
    else:
        out = np.broadcast_to(padding(params), (t, n, NUM_PARAMS)).copy()
        slot = np.arange(len(frame)) - np.repeat(np.cumsum(counts) - counts, counts)  # index within its frame
        out[frame, slot] = params
        source[FRAME_COUNTS] = counts.tolist()
    return GaussianVideo(out, canvas_width, canvas_height, fps, tuple(grid), source)


def padding(params: np.ndarray) -> np.ndarray:
    """The invisible Gaussian [8] that pads frames of a clip (`params` [..., 8]: its real ones) to N:
    colour 0, the median scale, at the canvas centre."""
    pad = np.zeros(NUM_PARAMS, np.float32)
    pad[2:4] = np.median(params[..., 2:4]) if params.size else 1.0
    return pad


def frame_counts(video: GaussianVideo) -> np.ndarray:
    """Real Gaussians per frame [T] (N everywhere unless the clip was padded by points_to_video)."""
    return source_frame_counts(video.source, *video.params.shape[:2])


def source_frame_counts(source, t: int, n: int) -> np.ndarray:
    """Real Gaussians per frame [t] of a clip of N = n Gaussians per frame described by `source` (a
    clip's metadata: its `frame_counts` entry, or N everywhere; a malformed entry is ignored)."""
    counts = source.get(FRAME_COUNTS) if isinstance(source, dict) else None
    try:
        counts = np.asarray(counts, np.int64)
        if counts.shape == (t,) and np.all((counts >= 0) & (counts <= n)):
            return counts
    except (TypeError, ValueError):
        pass
    return np.full(t, n, np.int64)


def video_to_points(video: GaussianVideo) -> dict:
    """params_to_points without the padding of a clip written by points_to_video."""
    points = params_to_points(video.params, video.canvas_width, video.canvas_height)
    t, n = video.params.shape[:2]
    counts = frame_counts(video)
    if np.all(counts == n):
        return points
    keep = (np.arange(n)[None, :] < counts[:, None]).reshape(-1)
    return {k: np.ascontiguousarray(v[keep]) for k, v in points.items()}
