import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest
import torch

from hypergs_blender.training.optim import Lamb
from hypergs_blender.encode import FloorEncoder
from hypergs_blender.errors import HyperGSError
from hypergs_blender.model import (ERROR_GAIN, PRESETS, ConvConfig, ConvGS, HyperGS, TransformerConfig, anchor_inputs, apply_rope,
                                   build_model, count_parameters, model_config, rope_angles)
from hypergs_blender.network import torch_encoder
from hypergs_blender.render import local_render, render_torch
from hypergs_blender.training.regularizers import AdaptiveRegularizer, effective_rank

from conftest import random_conv

TINY = dict(canvas=32, patch=8, clip_frames=4, temporal_window=2, dim=32, heads=2, ffn=64, st_layers=1, q_layers=1)


@pytest.mark.parametrize("parametrization", ["local", "paper"])
def test_output_shapes_and_ranges(parametrization):
    torch.manual_seed(0)
    model = HyperGS(TransformerConfig(**TINY, parametrization=parametrization, max_gaussians=64))
    frames = torch.rand(2, 4, 32, 32, 3)
    anchors, cell = anchor_inputs(50)
    out = model(frames, anchors, cell)
    assert out.shape == (2, 4, 50, 8)
    assert out[..., 0:2].abs().max() < 1
    assert out[..., 2:4].min() > 0
    assert out[..., 4].min() >= 0 and out[..., 4].max() <= 2 * math.pi
    if parametrization == "paper":
        assert out[..., 5:8].min() >= 0 and out[..., 5:8].max() <= 1


def test_local_model_starts_at_the_grid_floor():
    model = HyperGS(TransformerConfig(**TINY))
    frames = torch.full((1, 4, 32, 32, 3), 0.5)
    anchors, cell = anchor_inputs(16)
    out = model(frames, anchors, cell)
    torch.testing.assert_close(out[0, 0, :, 0:2], anchors, atol=1e-3, rtol=0)
    # sigma 0.6 grid cells: the cell is 32 / 4 = 8 px
    torch.testing.assert_close(out[..., 2:4], torch.full_like(out[..., 2:4], 4.8), atol=0.15, rtol=0)


@pytest.mark.parametrize("offset_range", [1.0, 0.0])
def test_local_means_move_as_far_at_the_frames_edge_as_inside(offset_range):
    """A Gaussian of the outer ring must reach the frame's edge: an offset h moves every mean by
    cell * R tanh(h / R), at the border as in the middle. The tanh map of older weights (R = 0) moved
    the outer ring 1 - a^2 of that (the frame's outermost pixels stayed dark)."""
    model = HyperGS(TransformerConfig(**TINY, offset_range=offset_range))
    with torch.no_grad():
        model.head.bias[0:2] = 0.5
    anchors, cell = anchor_inputs(64)  # 8 x 8: the outer ring at +-7/8
    means = model(torch.full((1, 4, 32, 32, 3), 0.5), anchors, cell)[0, 0, :, 0:2]
    moved = (means - anchors) / cell  # in grid cells, towards +x and +y
    if offset_range:
        torch.testing.assert_close(moved, torch.full_like(moved, math.tanh(0.5)))
    else:  # the right column, moving out towards the frame's edge, against the middle ones
        outward, inner = moved[anchors[:, 0] > 0.8, 0], moved[anchors[:, 0].abs() < 0.5, 0]
        assert outward.max() < 0.5 * inner.min()


def test_cards_from_before_offset_range_load_with_the_tanh_map():
    config = dataclasses.asdict(TransformerConfig(**TINY))
    assert config.pop("offset_range") == 1.0  # new runs reach the edge
    assert build_model(config).cfg.offset_range == 0.0


def test_presets():
    assert 40e6 < count_parameters(HyperGS(PRESETS["paper"])) < 55e6
    assert count_parameters(HyperGS(PRESETS["small"])) < 5e6
    assert count_parameters(ConvGS(PRESETS["conv"])) < 2e6
    for name, cfg in PRESETS.items():  # what cards and checkpoints store builds the same network
        model = build_model(model_config(build_model(dataclasses.asdict(cfg))))
        assert model.cfg == cfg, name


@pytest.mark.parametrize("k", [1, 2])
def test_rope_depends_only_on_relative_position(k):
    torch.manual_seed(0)
    dim = 16
    q, key = torch.randn(dim), torch.randn(dim)
    shift = torch.tensor([3.0, -2.0][:k])
    pos = torch.tensor([[1.0, 4.0][:k], [5.0, 2.0][:k]])
    a = rope_angles(pos, dim, 100.0)
    b = rope_angles(pos + shift, dim, 100.0)
    dot_a = apply_rope(q[None], a[0:1]) @ apply_rope(key[None], a[1:2]).T
    dot_b = apply_rope(q[None], b[0:1]) @ apply_rope(key[None], b[1:2]).T
    torch.testing.assert_close(dot_a, dot_b)
    # and it does depend on the relative position
    c = rope_angles(torch.tensor([[1.0, 4.0][:k], [6.0, 2.0][:k]]), dim, 100.0)
    dot_c = apply_rope(q[None], c[0:1]) @ apply_rope(key[None], c[1:2]).T
    assert not torch.allclose(dot_a, dot_c)


def test_effective_rank_of_hand_made_gaussians():
    erank = effective_rank(torch.tensor([[3.0, 3.0], [10.0, 0.01], [2.0, 1.0]]))
    assert erank[0] == pytest.approx(2.0)
    assert erank[1] == pytest.approx(1.0, abs=1e-4)
    q = torch.tensor([0.8, 0.2])
    assert erank[2] == pytest.approx(float(torch.exp(-(q * q.log()).sum())))


def test_regularizer_values_and_state():
    reg = AdaptiveRegularizer(erank_weight=1.0, scale_weight=1.0, tau0=1.05, s0=32.0)
    scales = torch.tensor([[3.0, 3.0], [10.0, 0.01], [40.0, 40.0]])
    loss, stats = reg.eval()(scales)
    # the needle pays tau - 1; the 40 px circle pays (40 - 32)^2 on both axes
    expected = (1.05 - float(effective_rank(scales[1:2])[0])) / 3 + (2 * 8.0 ** 2) / 6
    assert float(loss) == pytest.approx(expected, rel=1e-5)
    reg.train()(scales)
    assert float(reg.scale_ema) != 32.0 and "scale_ema" in reg.state_dict()
    # floor and ceiling hold however the EMAs move
    reg.erank_ema.fill_(0.5)
    reg.scale_ema.fill_(500.0)
    assert float(reg.tau) == pytest.approx(1.005) and float(reg.s_max) == pytest.approx(80.0)


def test_lamb_step_matches_hand_computation():
    w = torch.nn.Parameter(torch.tensor([[3.0, 4.0]]))
    opt = Lamb([w], lr=0.1, weight_decay=0.0)
    w.grad = torch.tensor([[1.0, -2.0]])
    opt.step()
    # first Adam step: update = sign(g) (up to eps); trust = |w| / |update| = 5 / sqrt(2)
    update = torch.tensor([[1.0, -1.0]])
    expected = torch.tensor([[3.0, 4.0]]) - 0.1 * (5 / math.sqrt(2)) * update
    torch.testing.assert_close(w.detach(), expected, atol=1e-5, rtol=0)


@pytest.mark.parametrize("preset", ["conv", "conv-round2"])
def test_conv_model_starts_at_the_grid_floor(preset):
    frames = np.random.default_rng(0).random((2, 24, 40, 3), dtype=np.float32)
    with torch.no_grad():
        out = ConvGS(PRESETS[preset]).eval()(torch.from_numpy(frames)).numpy()
    np.testing.assert_allclose(out, FloorEncoder().predict(frames), atol=1e-5)


def test_coarser_levels_start_switched_off():
    """A network with a coarser level (blocks (2, 1)) holding the weights of one without it is that
    network: `hypergs train --init-from` adds context to a trained network without losing what it learned."""
    plain = random_conv(ConvConfig(width=8, stem=4, stem_level="cell", blocks=(2,)))
    deeper = ConvGS(ConvConfig(width=8, stem=4, stem_level="cell", blocks=(2, 1))).eval()
    missing, unexpected = deeper.load_state_dict(plain.state_dict(), strict=False)
    assert {name.split(".")[0] for name in missing} == {"down", "encoder", "up", "decoder"} and not unexpected
    frames = torch.rand(2, 16, 24, 3)
    with torch.no_grad():
        torch.testing.assert_close(deeper(frames), plain(frames), rtol=0, atol=0)
        deeper.up[0].weight.normal_()
        deeper.encoder[1][0].b.weight.normal_()
        assert (deeper(frames) - plain(frames)).abs().max() > 1e-3


def test_conv_geometry_keeps_float32_under_half_precision():
    """Under bf16 autocast (a GPU's mixed precision) the means stay where float32 puts them: a bf16 cell
    grid would round them to a 0.5-px lattice at 128 px (-0.9 dB for the bundled network)."""
    model = random_conv(ConvConfig(width=8, stem=4, stem_level="cell", blocks=(2,)))
    frames = torch.rand(2, 128, 128, 3)
    with torch.no_grad():
        exact = model(frames)
        with torch.autocast("cpu", dtype=torch.bfloat16):
            half = model(frames)
    assert half.dtype == torch.float32
    error_px = (half[..., :2] - exact[..., :2]).abs().max() * 128 / 2
    assert error_px < 0.05, f"means moved {error_px:.3f} px under bf16"


def test_cell_stem_sees_the_pixels_of_the_cell_and_its_neighbours_only():
    """The cell stem is one 3x3 conv over cells: a cell's stem feature depends on its own pixels and
    its 8 neighbours' (a pixel two cells away changes nothing); the 'pixel' stem's reaches 2 pixels
    past the cell."""
    for stem_level, inside, outside in (("cell", 4 + 3, 4 + 4), ("pixel", 4 + 1, 4 + 2)):
        model = random_conv(ConvConfig(width=8, stem=4, stem_level=stem_level))
        x = torch.rand(1, 3, 24, 24)
        with torch.no_grad():
            base = model.cell_features(x)[0, :, 2, 2]  # the cell of pixels 8..11
            for column, changes in ((8 + inside, True), (8 + outside, False)):
                poked = x.clone()
                poked[..., column] += 1
                moved = (model.cell_features(poked)[0, :, 2, 2] - base).abs().max() > 1e-6
                assert bool(moved) == changes, (stem_level, column)


@pytest.mark.parametrize("blocks,stem_level,error_width,error_kernel,error_iterations,dilation", [
    ((2,), "pixel", 0, 3, 1, ()), ((1, 1, 1), "pixel", 0, 3, 1, ()), ((2,), "cell", 0, 3, 1, ()),
    ((1, 1, 1), "cell", 0, 3, 1, ()), ((2,), "cell", 8, 3, 1, ()), ((2,), "cell", 8, 1, 1, ()),
    ((2,), "cell", 8, 1, 2, ()), ((2,), "cell", 0, 3, 1, (1, 3)), ((2, 1), "cell", 8, 1, 1, (3,))])
def test_conv_reach_bounds_the_receptive_field(blocks, stem_level, error_width, error_kernel, error_iterations,
                                               dilation):
    """A pixel further than `reach` from a cell cannot change its Gaussian; a nearer one does."""
    cfg = ConvConfig(width=8, stem=4, blocks=blocks, stem_level=stem_level, error_width=error_width,
                     error_kernel=error_kernel, error_iterations=error_iterations, dilation=dilation)
    model = random_conv(cfg, error_strength=0.5)  # the error's far reach is faint: make it show
    size = 2 * cfg.reach + 4 * cfg.multiple
    x = torch.rand(1, size, size, 3)
    cell = size // cfg.stride // 2  # a cell in the middle
    centre = (cell + 0.5) * cfg.stride
    with torch.no_grad():
        base = model(x).reshape(size // cfg.stride, size // cfg.stride, 8)[cell, cell]
        far, near = x.clone(), x.clone()
        far[0, :, :int(centre - cfg.reach - cfg.stride)] = 0  # every column beyond the reach on the left
        near[0, :, int(centre - 2 * cfg.stride)] = 0  # one column in the next cell but one
        out_far = model(far).reshape(size // cfg.stride, size // cfg.stride, 8)[cell, cell]
        out_near = model(near).reshape(size // cfg.stride, size // cfg.stride, 8)[cell, cell]
    torch.testing.assert_close(out_far, base, atol=1e-6, rtol=0)
    assert (out_near - base).abs().max() > 1e-6


def test_a_dilated_block_sees_further_and_starts_as_the_identity():
    """A third block dilated by 3 sees a pixel 8 cells away where the network without it sees 5 (the reach grows
    by its 2 x 3 cells), and starts as the identity: a warm start from fewer blocks is that network."""
    plain = random_conv(ConvConfig(width=8, stem=4, blocks=(2,)))
    dilated = ConvGS(ConvConfig(width=8, stem=4, blocks=(3,), dilation=(1, 1, 3))).eval()
    dilated.load_state_dict(plain.state_dict(), strict=False)
    assert dilated.cfg.reach == plain.cfg.reach + 2 * 3 * 4
    x = torch.rand(1, 96, 96, 3)
    with torch.no_grad():
        torch.testing.assert_close(dilated(x), plain(x), rtol=0, atol=0)
        torch.nn.init.normal_(dilated.encoder[0][2].b.weight, std=0.1)
        cell = 12  # the middle cell's row and column; its pixels start at 48
        poked = x.clone()
        poked[0, :, 48 - 8 * 4] += 1  # 8 cells to the left: the plain network's stem and 2 blocks reach 5
        moved = lambda model: float((model(poked) - model(x)).reshape(24, 24, 8)[cell, cell].abs().max())
        assert moved(plain) == 0 and moved(dilated) > 1e-6


@pytest.mark.parametrize("fields,message", [(dict(error_samples=3), "must divide the stride"),
                                            (dict(error_iterations=0), "error_iterations must be 1 or more"),
                                            (dict(dilation=(1,) * 5), "one of 1 or more per cell-level block"),
                                            (dict(dilation=(0,)), "one of 1 or more per cell-level block")])
def test_a_config_that_cannot_run_is_refused(fields, message):
    with pytest.raises(ValueError, match=message):
        ConvConfig(error_width=8, **fields)


def test_a_new_error_pass_starts_as_the_network_it_was_added_to():
    """The error pass's head starts at zero: a two-pass network warm-started from a one-pass one gives its
    Gaussians; once its head moves, they change, and only where the error pass reads."""
    one = random_conv(ConvConfig(width=8, stem=4, blocks=(1,)))
    two = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,), error_width=8)).eval()
    assert set(two.load_state_dict(one.state_dict(), strict=False).missing_keys) == {
        k for k in two.state_dict() if k.startswith("error_pass.")}
    x = torch.rand(2, 32, 48, 3)
    with torch.no_grad():
        torch.testing.assert_close(two(x), one(x), rtol=0, atol=0)
        two.error_pass.head.bias[0] = 0.5  # every mean half a tanh to the right
        moved = two(x) - one(x)
    assert float(moved[..., 0].abs().min()) > 0 and float(moved[..., 1:].abs().max()) == 0


def test_local_render_sums_the_gaussians_of_the_cells_within_its_reach():
    """The error pass's render: per-cell Gaussians (moved up to a quarter cell, 0.2 to 0.5 cells wide: within
    reach 2 to 4.7 sigma) at samples^2 points per cell, against the rasterizer (which cuts them at its
    box); with reach 0 it misses the light of the neighbours' Gaussians."""
    rows, cols, stride, reach = 6, 8, 4, 2
    rng = torch.Generator().manual_seed(0)
    cy, cx = torch.meshgrid(torch.arange(rows) + 0.5, torch.arange(cols) + 0.5, indexing="ij")
    centres = torch.stack([cx / cols, cy / rows], -1).reshape(1, -1, 2) * 2 - 1
    n = rows * cols
    params = torch.cat([centres + (torch.rand(1, n, 2, generator=rng) - 0.5) * (1 / torch.tensor([cols, rows])),
                        stride * (0.2 + 0.3 * torch.rand(1, n, 2, generator=rng)),
                        torch.rand(1, n, 1, generator=rng) * math.pi, torch.rand(1, n, 3, generator=rng)], -1)
    for samples in (4, 2):
        exact = render_torch(params, cols * stride, rows * stride, cols * samples, rows * samples,
                             pixel_filter=False).permute(0, 3, 1, 2)  # point samples, as local_render's
        local = torch.nn.functional.pixel_shuffle(local_render(params, rows, cols, stride, samples, reach), samples)
        assert local.shape == (1, 3, rows * samples, cols * samples)
        torch.testing.assert_close(local, exact, atol=3e-3, rtol=0)  # the rasterizer's box
        alone = torch.nn.functional.pixel_shuffle(local_render(params, rows, cols, stride, samples, reach=0), samples)
        assert float((alone - exact).abs().max()) > 0.1
        # and without the box: a sum over the cells within reach at each point, through each Gaussian's inverse covariance
        slow = torch.zeros(3, rows * samples, cols * samples, dtype=torch.float64)
        p = params[0].double()
        for i in range(rows * samples):
            for j in range(cols * samples):
                point = (torch.tensor([j, i], dtype=torch.float64) + 0.5) * (stride / samples)
                r, c = i // samples, j // samples
                for nr in range(max(0, r - reach), min(rows, r + reach + 1)):
                    for nc in range(max(0, c - reach), min(cols, c + reach + 1)):
                        g = p[nr * cols + nc]
                        mean = (g[0:2] + 1) / 2 * torch.tensor([cols * stride, rows * stride], dtype=torch.float64)
                        rot = torch.tensor([[math.cos(g[4]), -math.sin(g[4])], [math.sin(g[4]), math.cos(g[4])]],
                                           dtype=torch.float64)
                        cov = rot @ torch.diag(g[2:4] ** 2) @ rot.T
                        d = point - mean
                        slow[:, i, j] += g[5:8] * torch.exp(-0.5 * d @ torch.linalg.solve(cov, d))
        fast = torch.nn.functional.pixel_shuffle(local_render(params.double(), rows, cols, stride, samples, reach), samples)
        torch.testing.assert_close(fast[0], slow, atol=1e-9, rtol=0)


def test_the_error_pass_reads_the_error_of_the_first_pass_render():
    """What the error pass reads: the input minus the render of the first pass's Gaussians, per sample."""
    cfg = ConvConfig(width=8, stem=4, blocks=(1,), error_width=8, error_samples=2, error_reach=2)
    model = random_conv(cfg)
    frames = torch.rand(1, 32, 48, 3)
    x = frames.permute(0, 3, 1, 2)
    with torch.no_grad():
        h = model.head(model.features((x - 0.5) * 2))
        error = model.render_error(h, x)  # [1, 3 samples^2, rows, cols]
        rendered = render_torch(model.geometry(h, x), 48, 32, 24, 16, pixel_filter=False)  # a sample per 2 x 2 pixels
    expected = (torch.nn.functional.avg_pool2d(x, 2) - rendered.permute(0, 3, 1, 2)) * ERROR_GAIN
    torch.testing.assert_close(torch.nn.functional.pixel_shuffle(error, 2), expected, atol=0.02, rtol=0)
    assert float(expected.abs().mean()) > 0.5  # a real error, well above the renders' difference


@pytest.mark.parametrize("blocks,stem_level,error_width,error_kernel,error_iterations,dilation", [
    ((4,), "pixel", 0, 3, 1, ()), ((1, 1, 1), "pixel", 0, 3, 1, ()), ((4,), "cell", 0, 3, 1, ()),
    ((2,), "cell", 8, 3, 1, ()), ((2,), "cell", 8, 1, 1, ()), ((2,), "cell", 8, 1, 2, ()),
    ((3,), "cell", 8, 1, 1, (1, 1, 4))])
def test_tiles_give_exactly_one_pass(blocks, stem_level, error_width, error_kernel, error_iterations, dilation,
                                     monkeypatch):
    """Encoding in overlapping tiles gives the Gaussians of one pass over the whole frame: no seams. In
    float64, so that what a pixel beyond a too-short reach changes (faint through the error pass: ~1e-5 a
    cell short) stands out of the sums' rounding."""
    import hypergs_blender.network as network
    cfg = ConvConfig(width=8, stem=4, blocks=blocks, stem_level=stem_level, error_width=error_width,
                     error_kernel=error_kernel, error_iterations=error_iterations, dilation=dilation)
    model = random_conv(cfg, error_strength=0.5).double()

    def forward(frames: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return model(torch.from_numpy(frames).double()).numpy()

    encoder = network.NetworkEncoder(forward, cfg.stride, cfg.multiple, cfg.reach, "float64")
    width = 5 * cfg.reach + 3 * cfg.multiple  # several tiles across, the last one shorter
    frames = np.random.default_rng(1).random((2, 8 * cfg.multiple, width, 3), dtype=np.float32)
    whole = forward(frames)
    encoder.tile = 2 * cfg.reach + 2 * cfg.multiple
    assert len(network.tiles(frames.shape[2], cfg.reach, cfg.multiple, encoder.tile)) > 2
    columns, _ = encoder.tile_borders(frames.shape[2], frames.shape[1])
    assert columns and all(c % cfg.multiple == 0 for c in columns)
    # the encoder's output is float32: the same numbers up to its last bit or two
    np.testing.assert_allclose(encoder.predict(frames), whole.astype(np.float32), rtol=2.4e-7, atol=1e-7)


@pytest.mark.parametrize("stem_level,error_width", [("pixel", 0), ("cell", 0), ("cell", 8)])
def test_onnx_matches_torch(tmp_path, stem_level, error_width):
    from hypergs_blender.network import onnx_encoder
    from hypergs_blender.training.export import card_of, export_onnx
    model = random_conv(ConvConfig(width=16, stem=8, blocks=(2,), stem_level=stem_level, error_width=error_width))
    export_onnx(model, tmp_path / "m.onnx")
    onnx, torch_ = onnx_encoder(tmp_path / "m.onnx", card_of(model)), torch_encoder(model)
    rng = np.random.default_rng(0)
    for shape in ((3, 32, 32, 3), (1, 48, 96, 3)):  # one exported graph serves any size, hence any count
        frames = rng.random(shape, dtype=np.float32)
        a, b = onnx.predict(frames), torch_.predict(frames)
        assert a.shape == (shape[0], shape[1] // 4 * shape[2] // 4, 8)
        np.testing.assert_allclose(a, b, atol=1e-4, rtol=1e-4)
    onnx.release()  # gives the arena back; the encoder stays usable and gives the same numbers
    torch_.release()
    np.testing.assert_array_equal(onnx.predict(frames), a)
    assert not onnx.session.get_session_options().enable_mem_pattern


def test_bfloat16_encoder_runs_in_bfloat16_and_stays_close():
    """--precision bfloat16: the convolutions in bfloat16 (the Gaussians differ from float32's), the geometry in
    float32 (means within a hundredth of a cell, not on bfloat16's lattice: 0.5 px at 128 px), named so; only
    torch runs it, and an unknown precision is refused."""
    from hypergs_blender.network import resolve_encoder
    model = random_conv(ConvConfig(width=16, stem=8, blocks=(2,), stem_level="cell", error_width=8))
    exact, fast = torch_encoder(model), torch_encoder(model, precision="bfloat16")
    assert (exact.name, fast.name) == ("network-torch", "network-torch-bfloat16")
    frames = np.random.default_rng(0).random((2, 128, 128, 3), dtype=np.float32)
    a, b = exact.predict(frames), fast.predict(frames)
    assert b.dtype == np.float32 and not np.array_equal(a, b)
    cell = 2 * model.cfg.stride / 128  # canvas units
    assert np.abs(a[..., :2] - b[..., :2]).max() < 0.01 * cell
    np.testing.assert_allclose(b[..., 2:], a[..., 2:], atol=0.02, rtol=0.02)
    with pytest.raises(HyperGSError, match="unknown precision 'half'"):
        torch_encoder(model, precision="half")
    with pytest.raises(HyperGSError, match="onnxruntime runs float32"):
        resolve_encoder("network", "onnx", precision="bfloat16")


def test_the_bundled_onnx_model_is_the_bundled_weights():
    """What Blender runs (hypergs.onnx, onnxruntime) gives the Gaussians that the bundled .safetensors give in
    torch on a real frame: the ONNX file was exported from these weights, at ONNX_OPSET (GELU as one op).
    Float32 sums in another order differ by ~5e-6 (canvas units, scales in cells); other weights by > 1e-2."""
    import onnx

    from hypergs_blender.io.frames import read_frames
    from hypergs_blender.network import WEIGHTS_DIR, resolve_encoder
    from hypergs_blender.training.export import ONNX_OPSET
    graph = onnx.load(str(WEIGHTS_DIR / "hypergs.onnx"))
    assert [(o.domain, o.version) for o in graph.opset_import] == [("", ONNX_OPSET)]
    assert "Gelu" in {node.op_type for node in graph.graph.node}
    frames, _, _ = read_frames(Path(__file__).resolve().parents[1] / "hypergs_blender" / "samples" / "sample.mp4", 2)
    frames = (frames[:, :frames.shape[1] // 4 * 4, :frames.shape[2] // 4 * 4] / 255).astype(np.float32)
    onnx_params = resolve_encoder("network", "onnx", threads=1).predict(frames)
    torch_params = resolve_encoder("network", "torch", device="cpu").predict(frames)
    assert onnx_params.shape == (2, frames.shape[1] * frames.shape[2] // 16, 8)
    np.testing.assert_allclose(onnx_params, torch_params, atol=2e-5, rtol=0)


def test_the_bundled_network_gives_more_for_more_gaussians():
    """The product's promise at the scene's resolution: every finer cell size gives a higher PSNR (the sample's
    frames at their own 256 x 144, what Blender's Quality presets and Custom cell sizes ask for; session 28
    measured the dev clips at 9 cell sizes from 10 to 4 px and 13 counts at 256^2: monotone everywhere)."""
    from hypergs_blender.encode import encode_frames, frames_layout
    from hypergs_blender.io.frames import read_frames
    from hypergs_blender.metrics import psnr
    from hypergs_blender.network import resolve_encoder
    from hypergs_blender.render import render_params
    frames, _, _ = read_frames(Path(__file__).resolve().parents[1] / "hypergs_blender" / "samples" / "sample.mp4", 2)
    encoder = resolve_encoder("network", "onnx", threads=1)
    h, w = frames.shape[1:3]
    scores = []
    for cell in (10, 8, 6, 5, 4):
        params = encode_frames(frames, encoder, frames_layout(frames, encoder, cell=cell))
        rendered = np.stack([render_params(p, w, h, w, h) for p in params])
        scores.append(float(psnr(rendered, frames / np.float32(255)).mean()))
    assert all(b > a + 0.1 for a, b in zip(scores, scores[1:])), scores


def test_onnx_graph_has_gelu_as_one_op(tmp_path):
    import onnx

    from hypergs_blender.training.export import export_onnx
    export_onnx(random_conv(ConvConfig(width=16, stem=8, blocks=(2,))), tmp_path / "m.onnx")
    ops = [node.op_type for node in onnx.load(tmp_path / "m.onnx").graph.node]
    assert ops.count("Gelu") == 2 + 2 * 2 and "Erf" not in ops  # the stem's two, two per block


def test_onnx_session_uses_the_providers_and_threads_asked_for():
    import onnxruntime as ort

    from hypergs_blender.network import resolve_encoder
    wanted = ["CUDAExecutionProvider", "CPUExecutionProvider"]  # CUDA where this onnxruntime has it
    encoder = resolve_encoder("network", "onnx", providers=wanted, threads=1)
    expected = next(p for p in wanted if p in ort.get_available_providers())
    assert encoder.provider == expected == encoder.session.get_providers()[0]
    assert encoder.session.get_session_options().intra_op_num_threads == 1
    assert resolve_encoder("network", "onnx").provider == "CPUExecutionProvider"  # the default


def test_rebox_scales_the_colours_to_the_new_box_and_resolve_refuses_weights_for_another(tmp_path):
    """Weights whose card records no box were trained under 3 sigma. The runtime refuses them (their colours
    would come out 0.4 % too bright) and names `hypergs rebox`; rebox makes the model give ratio x the
    colours it gave under the old box's gain, ratio = lattice_gain(new) / lattice_gain(old), with its
    means and shapes unchanged, re-exports the ONNX model (which bakes COLOUR_GAIN in) and records the box."""
    import json

    import torch.nn.functional as F

    from hypergs_blender.errors import HyperGSError
    from hypergs_blender.gaussians import COLOUR_GAIN, INITIAL_SIGMA, lattice_gain
    from hypergs_blender.network import load_model, resolve_encoder
    from hypergs_blender.raster import SIGMA_CUTOFF
    from hypergs_blender.training.export import rebox, save_weights
    model = random_conv(ConvConfig(width=16, stem=8, blocks=(2,)))
    save_weights(model, tmp_path, "old")
    card = json.loads((tmp_path / "old.json").read_text())
    assert card["sigma_cutoff"] == SIGMA_CUTOFF != 3.0
    (tmp_path / "old.json").write_text(json.dumps({k: v for k, v in card.items() if k != "sigma_cutoff"}))
    with pytest.raises(HyperGSError, match=r"trained for a 3-sigma box.*hypergs rebox --weights"):
        resolve_encoder("network", "torch", weights=tmp_path / "old.json")

    assert rebox(tmp_path, "old") == 3.0
    assert rebox(tmp_path, "old") is None  # already converted: nothing to do
    frames = torch.rand(2, 16, 24, 3)
    with torch.no_grad():
        before = model(frames)
        after = load_model(tmp_path, "old")(frames)
    cell_mean = F.avg_pool2d(frames.permute(0, 3, 1, 2), 4).flatten(2).transpose(1, 2)
    under_old_box = before[..., 5:8] + (lattice_gain(INITIAL_SIGMA, 3.0) - COLOUR_GAIN) * cell_mean
    ratio = COLOUR_GAIN / lattice_gain(INITIAL_SIGMA, 3.0)
    assert 0.99 < ratio < 0.999
    torch.testing.assert_close(after[..., 5:8], ratio * under_old_box, atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(after[..., :5], before[..., :5], atol=0, rtol=0)
    card = json.loads((tmp_path / "old.json").read_text())
    assert card["sigma_cutoff"] == SIGMA_CUTOFF and card["info"]["reboxed_from"] == 3.0
    onnx_params = resolve_encoder("network", "onnx", weights=tmp_path / "old.json", threads=1).predict(frames.numpy())
    np.testing.assert_allclose(onnx_params, after.numpy(), atol=1e-5, rtol=0)
    # a second conversion (as the 3.5-sigma weights to 4) keeps the box the colours were trained under
    (tmp_path / "old.json").write_text(json.dumps(dict(card, sigma_cutoff=3.5)))
    assert rebox(tmp_path, "old") == 3.5
    assert json.loads((tmp_path / "old.json").read_text())["info"]["reboxed_from"] == 3.0


def test_rebox_refuses_weights_with_an_error_pass_and_leaves_them_as_they_were(tmp_path):
    """The error pass reads the error of a render of the first pass's colours: scaling them changes what it
    reads, so no rescale gives the old image; rebox says so and writes nothing."""
    import json

    from hypergs_blender.errors import HyperGSError
    from hypergs_blender.training.export import rebox, save_weights
    save_weights(random_conv(ConvConfig(width=8, stem=4, blocks=(1,), error_width=8)), tmp_path, "old")
    card = json.loads((tmp_path / "old.json").read_text())
    (tmp_path / "old.json").write_text(json.dumps({k: v for k, v in card.items() if k != "sigma_cutoff"}))
    before = {p.name: p.read_bytes() for p in tmp_path.iterdir()}
    with pytest.raises(HyperGSError, match="error pass.*retrain"):
        rebox(tmp_path, "old")
    assert {p.name: p.read_bytes() for p in tmp_path.iterdir()} == before
