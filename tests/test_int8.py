"""The conv network's int8 ONNX model (training.int8): onnxruntime's int8 convolutions against the torch
network rounded as they round (fake_quantize), which `hypergs train --int8` trains."""
import json

import numpy as np
import onnx
import pytest
import torch

from hypergs_blender.model import ConvConfig
from hypergs_blender.network import onnx_encoder, resolve_encoder
from hypergs_blender.training import int8, train
from hypergs_blender.training.export import card_of, export_checkpoint, export_onnx

from conftest import random_conv, training_args

CONFIG = ConvConfig(width=16, stem=8, blocks=(1,), error_width=8)  # the bundled network's shape, smaller


def frames(seed: int, n: int = 2, side: int = 32) -> torch.Tensor:
    """Smooth random frames with edges: activations with a spread, as a real frame gives."""
    g = torch.Generator().manual_seed(seed)
    coarse = torch.rand(n, 3, side // 8, side // 8, generator=g)
    smooth = torch.nn.functional.interpolate(coarse, size=(side, side), mode="bilinear", align_corners=False)
    return (0.8 * smooth + 0.2 * (torch.rand(n, 3, side, side, generator=g) > 0.5)).permute(0, 2, 3, 1).contiguous()


# How far onnxruntime's int8 model is from fake_quantize's, as a share of its distance from the float network:
# where they round a value to different sides, an error pass sees that in the render it measures and carries
# it on (0.20 measured; without the error pass 0.03). Reading the error pass's shared features unrounded, as
# onnxruntime did before quantize_onnx's Identity, made it 0.39.
@pytest.mark.parametrize("error_width, bound", [(8, 0.3), (0, 0.1)])
def test_the_int8_onnx_model_rounds_as_fake_quantize_does(tmp_path, error_width, bound):
    """onnxruntime's int8 model (QLinearConv, 7-bit weights) gives what the torch network gives with
    fake_quantize's roundings, far closer than either is to the float network: what training with
    fake_quantize learns is what onnxruntime runs. Its weights are quantized to at most 64 in magnitude."""
    model = random_conv(ConvConfig(**{**CONFIG.__dict__, "error_width": error_width})).eval()
    ranges = int8.calibrate(model, [frames(s) for s in range(3)])
    export_onnx(model, tmp_path / "m.onnx", ranges)
    graph = onnx.load(str(tmp_path / "m.onnx")).graph
    quantized_weights = [onnx.numpy_helper.to_array(i) for i in graph.initializer
                         if i.data_type == onnx.TensorProto.INT8 and i.dims and len(i.dims) == 4]
    assert len(quantized_weights) == len(int8.convolutions(model))
    assert max(int(np.abs(w.astype(np.int32)).max()) for w in quantized_weights) == int8.WEIGHT_LEVELS
    test = frames(7).numpy()
    quantized = onnx_encoder(tmp_path / "m.onnx", card_of(model), threads=1).predict(test)
    with torch.no_grad():
        exact = model(torch.from_numpy(test)).numpy()
        handles = int8.fake_quantize(model, ranges)
        rounded = model(torch.from_numpy(test)).numpy()
    emulation, rounding = np.abs(quantized - rounded).mean(), np.abs(quantized - exact).mean()
    assert rounding > 1e-4 and emulation < bound * rounding, (emulation, rounding)
    for handle in handles:
        handle.remove()
    with torch.no_grad():
        np.testing.assert_array_equal(model(torch.from_numpy(test)).numpy(), exact)  # float again


def test_calibrated_ranges_hold_zero_and_the_activations():
    model = random_conv(CONFIG).eval()
    batch = frames(3)
    ranges = int8.calibrate(model, [batch])
    seen = {}
    hooks = [m.register_forward_hook(lambda m, a, o, n=n: seen.update({n: (a[0], o)}))
             for n, m in int8.convolutions(model)]
    with torch.no_grad():
        model(batch)
    for h in hooks:
        h.remove()
    assert set(ranges) == set(seen)
    for name, (into, out) in seen.items():
        for side, values in (("input", into), ("output", out)):
            low, high = ranges[name][side]
            assert low <= 0 <= high and low < high
            outside = int(((values < low) | (values > high)).sum())
            assert outside <= 2 * int8.TAIL * values.numel() + 2, (name, side, outside)  # the tails, no more
            assert high <= float(values.max()) and (low >= float(values.min()) or low == 0)


def test_train_int8_records_its_ranges_and_exports_the_int8_model(tmp_path, monkeypatch):
    """--int8: ranges calibrated once, kept by a resumed run and in the checkpoint, the card and the
    exported ONNX model (which runs on the encoders' usual path); a transformer refuses it."""
    from hypergs_blender.training.export import save_weights
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    args = training_args(tmp_path / "run", 4, "conv", minutes=0)
    args.int8 = True
    with pytest.raises(train.HyperGSError, match="--int8 needs --init-from"):
        train.run(args)
    save_weights(random_conv(ConvConfig(width=8, stem=4, blocks=(1,))), tmp_path, "trained")
    args.init_from = str(tmp_path / "trained.safetensors")
    train.run(args)
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    ranges = state["int8"]
    assert set(ranges) == {name for name, _ in int8.convolutions(train.build_model(json.loads(state["config"])))}
    train.run(training_args(tmp_path / "run", 4, "conv"))  # resumed: --int8 as the run started
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert state["step"] == 4 and state["int8"] == ranges and json.loads(state["args"])["int8"]
    export_checkpoint(tmp_path / "run", tmp_path / "export")
    assert json.loads((tmp_path / "export" / "hypergs.json").read_text())["int8"] == ranges
    ops = {node.op_type for node in onnx.load(str(tmp_path / "export" / "hypergs.onnx")).graph.node}
    assert {"QuantizeLinear", "DequantizeLinear"} <= ops
    encoder = resolve_encoder(weights=tmp_path / "export", backend="onnx", threads=1)
    assert encoder.predict(frames(1, 1).numpy()).shape == (1, 64, 8)
    args = training_args(tmp_path / "transformer", 2, "small")
    args.int8 = True
    with pytest.raises(train.HyperGSError, match="--int8 trains the conv network"):
        train.run(args)
