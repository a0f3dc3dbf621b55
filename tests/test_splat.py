"""hypergs_blender/splat.py: what the GPU splat shader reads (no bpy; the shader itself is checked against
the numpy rasterizer in test_blender_splat.py)."""
import numpy as np
import pytest
from conftest import hard_params

from hypergs_blender.gaussians import render_inputs
from hypergs_blender.raster import box_radii
from hypergs_blender.render import render_params
from hypergs_blender.splat import CHUNK, GAUSSIANS_PER_ROW, ROW_WIDTH, TEXELS, splat_rows, texture_rows

CLIPS = [(hard_params(400, 1), 96, 64), (hard_params(300, 2), 50, 80)]
W, H = 123, 77


def box_pixels_brute_force(window):
    """Per Gaussian of CLIPS: the quad (x0, y0, x1, y1) in pixel edges around the pixels of the window whose
    centres pass the numpy rasterizer's float32 test |k + 0.5 - m| <= r (every pixel tried), or None."""
    x, y, w, h = window
    found = []
    for params, cw, ch in CLIPS:
        means, chol, _ = render_inputs(params, cw, ch, W, H)
        radii = box_radii(chol)
        for m, l, r in zip(means, chol, radii):
            cols = np.flatnonzero(np.abs((np.arange(x, x + w, dtype=np.float32) + np.float32(0.5)) - m[0]) <= r[0])
            rows = np.flatnonzero(np.abs((np.arange(y, y + h, dtype=np.float32) + np.float32(0.5)) - m[1]) <= r[1])
            # the rasterizers' invalid Gaussians: not finite, l11 = 0 or l22 = 0
            ok = len(cols) and len(rows) and np.isfinite(m).all() and np.isfinite(l).all() and l[0] and l[2]
            found.append((x + cols[0], y + rows[0], x + cols[-1] + 1, y + rows[-1] + 1) if ok else None)
    return found


def shader_emulation(rows, window):
    """What the fragment shader sums over the window (x, y, w, h), in numpy: each row's quad, exp2 of the
    scaled inverse factor at the pixel centres, times its colour. [h, w, 3], rows top-down."""
    x, y, w, h = window
    image = np.zeros((h, w, 3), np.float64)
    for x0, y0, x1, y1, mx, my, a, b, c, *colour in rows.astype(np.float64):
        dx = np.arange(x0, x1) + 0.5 - mx
        dy = np.arange(y0, y1) + 0.5 - my
        u, v = a * dx[None, :], b * dx[None, :] + c * dy[:, None]
        image[int(y0) - y:int(y1) - y, int(x0) - x:int(x1) - x] += np.exp2(-(u * u + v * v))[..., None] * colour
    return image


@pytest.mark.parametrize("window", [None, (40, 13, 50, 30), (0, 70, 123, 7)])
def test_quads_cover_exactly_the_pixels_in_the_box(window):
    rows = splat_rows(CLIPS, W, H, window)
    assert rows.dtype == np.float32 and rows.shape[1] == ROW_WIDTH and np.isfinite(rows).all()
    expected = [q for q in box_pixels_brute_force(window or (0, 0, W, H)) if q is not None]
    assert 0 < len(rows) == len(expected) < 700  # off-image and invalid Gaussians are left out
    np.testing.assert_array_equal(rows[:, 0:4], np.array(expected, np.float32))


@pytest.mark.parametrize("window", [None, (40, 13, 50, 30)])
def test_rows_draw_the_reference(window):
    x, y, w, h = window or (0, 0, W, H)
    reference = sum(render_params(p, cw, ch, W, H) for p, cw, ch in CLIPS)[y:y + h, x:x + w]
    drawn = shader_emulation(splat_rows(CLIPS, W, H, window), (x, y, w, h))
    assert np.abs(reference).mean() > 0.1
    np.testing.assert_allclose(drawn, reference, atol=2e-5)


def test_no_clips_no_rows():
    assert splat_rows([], W, H).shape == (0, ROW_WIDTH)
    assert splat_rows([(np.zeros((0, 8), np.float32), 10, 10)], W, H).shape == (0, ROW_WIDTH)


def test_texture_layout():
    rows = np.arange((GAUSSIANS_PER_ROW + 5) * ROW_WIDTH, dtype=np.float32).reshape(-1, ROW_WIDTH)
    texture = texture_rows(rows)
    assert texture.shape == (2, GAUSSIANS_PER_ROW * TEXELS, 4) and texture.dtype == np.float32
    for i in (0, 1, GAUSSIANS_PER_ROW - 1, GAUSSIANS_PER_ROW, GAUSSIANS_PER_ROW + 4):
        row, column = divmod(i, GAUSSIANS_PER_ROW)
        for t in range(TEXELS):  # the shader's texelFetch(ivec2(TEXELS * column + t, row))
            np.testing.assert_array_equal(texture[row, TEXELS * column + t], rows[i, 4 * t:4 * t + 4])
    assert not texture[1, 5 * TEXELS:].any()
    assert texture_rows(rows[:0]).shape == (1, GAUSSIANS_PER_ROW * TEXELS, 4)
    with pytest.raises(ValueError, match="at most"):
        texture_rows(np.broadcast_to(np.float32(0), (CHUNK + 1, ROW_WIDTH)))
