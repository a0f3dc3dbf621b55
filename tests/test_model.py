import math

import numpy as np
import pytest
import torch

from hypergs_blender.training.optim import Lamb
from hypergs_blender.model import PRESETS, HyperGS, ModelConfig, anchor_inputs, apply_rope, count_parameters, rope_angles
from hypergs_blender.training.regularizers import AdaptiveRegularizer, effective_rank

TINY = dict(canvas=32, patch=8, clip_frames=4, temporal_window=2, dim=32, heads=2, ffn=64, st_layers=1, q_layers=1)


@pytest.mark.parametrize("parametrization", ["local", "paper"])
def test_output_shapes_and_ranges(parametrization):
    torch.manual_seed(0)
    model = HyperGS(ModelConfig(**TINY, parametrization=parametrization, max_gaussians=64))
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
    model = HyperGS(ModelConfig(**TINY))
    frames = torch.full((1, 4, 32, 32, 3), 0.5)
    anchors, cell = anchor_inputs(16)
    out = model(frames, anchors, cell)
    torch.testing.assert_close(out[0, 0, :, 0:2], anchors, atol=1e-3, rtol=0)
    # sigma 0.6 grid cells: the cell is 32 / 4 = 8 px
    torch.testing.assert_close(out[..., 2:4], torch.full_like(out[..., 2:4], 4.8), atol=0.15, rtol=0)


def test_presets():
    assert 40e6 < count_parameters(HyperGS(PRESETS["paper"])) < 55e6
    assert count_parameters(HyperGS(PRESETS["small"])) < 5e6


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


def test_onnx_matches_torch(tmp_path):
    from hypergs_blender.network import OnnxEncoder, TorchEncoder
    from hypergs_blender.training.export import export_onnx
    torch.manual_seed(0)
    model = HyperGS(ModelConfig(**TINY))
    with torch.no_grad():
        model.head.weight.normal_(0, 0.05)  # away from the zero-initialised head
    export_onnx(model, tmp_path / "m.onnx")
    onnx_encoder = OnnxEncoder(tmp_path / "m.onnx", {"config": {"canvas": 32, "clip_frames": 4}})
    torch_encoder = TorchEncoder(model)
    frames = np.random.default_rng(0).random((3, 4, 32, 32, 3), dtype=np.float32)
    for n in (20, 300):  # one exported graph serves any Gaussian count
        a, b = onnx_encoder.predict(frames, n), torch_encoder.predict(frames, n)
        assert a.shape == (3, 4, n, 8)
        np.testing.assert_allclose(a, b, atol=1e-4, rtol=1e-4)


def test_onnx_session_uses_the_providers_and_threads_asked_for():
    import onnxruntime as ort

    from hypergs_blender.network import resolve_encoder
    wanted = ["CUDAExecutionProvider", "CPUExecutionProvider"]  # CUDA where this onnxruntime has it
    encoder = resolve_encoder("network", "onnx", providers=wanted, threads=1)
    expected = next(p for p in wanted if p in ort.get_available_providers())
    assert encoder.provider == expected == encoder.session.get_providers()[0]
    assert encoder.session.get_session_options().intra_op_num_threads == 1
    assert resolve_encoder("network", "onnx").provider == "CPUExecutionProvider"  # the default
