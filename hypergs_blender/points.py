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
"""
from __future__ import annotations

import numpy as np

from .gaussians import NUM_PARAMS, GaussianVideo
from .render import render_frames


def srgb_to_linear(v: np.ndarray) -> np.ndarray:
    """The sRGB decoding function, extended to all reals: odd, and the same formula above 1."""
    v = np.asarray(v, np.float32)
    a = np.abs(v)
    out = np.where(a <= 0.04045, a / 12.92, ((a + 0.055) / 1.055) ** 2.4)
    return (np.sign(v) * out).astype(np.float32)


def linear_to_srgb(v: np.ndarray) -> np.ndarray:
    """Inverse of `srgb_to_linear`."""
    v = np.asarray(v, np.float32)
    a = np.abs(v)
    out = np.where(a <= 0.0031308, a * 12.92, 1.055 * a ** (1 / 2.4) - 0.055)
    return (np.sign(v) * out).astype(np.float32)


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


def points_to_video(points: dict, canvas_width: int, canvas_height: int, fps: float = 24.0) -> GaussianVideo:
    """Inverse of `params_to_points` for points with the same count in every frame (as encoded)."""
    frame = np.asarray(points["frame"])
    order = np.argsort(frame, kind="stable")
    t = int(frame.max()) + 1 if len(frame) else 0
    counts = np.bincount(frame, minlength=t)
    if t == 0 or np.any(counts != counts[0]):
        raise ValueError("points_to_video needs the same number of points in every frame")
    params = points_to_params(*(np.asarray(points[k])[order] for k in ("position", "scale", "rotation", "color")),
                              canvas_width, canvas_height)
    return GaussianVideo(params.reshape(t, counts[0], NUM_PARAMS), canvas_width, canvas_height, fps)


def render_params_srgb(params: np.ndarray, canvas_width: int, canvas_height: int,
                       width: int, height: int) -> np.ndarray:
    """One frame's Gaussians [M, 8] rendered at width x height: float32 [H, W, 3], sRGB-encoded
    additive sums (rows top to bottom). The canvas stretches to the output (exact covariance)."""
    if len(params) == 0:
        return np.zeros((height, width, 3), np.float32)
    video = GaussianVideo(np.asarray(params, np.float32)[None], canvas_width, canvas_height)
    return render_frames(video, width, height)[0]


def srgb_image_to_linear_rgba(image: np.ndarray) -> np.ndarray:
    """An sRGB-encoded [H, W, 3] sum -> scene-linear RGBA float32 [H, W, 4], rows bottom to top
    (a Blender render pass). Negative sums clip to 0; values above 1 are kept."""
    h, w = image.shape[:2]
    out = np.ones((h, w, 4), np.float32)
    out[..., :3] = srgb_to_linear(np.maximum(image, 0))[::-1]
    return out
