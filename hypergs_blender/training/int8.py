"""The conv network's int8 ONNX model: every convolution as onnxruntime's QDQ int8 runs it (QLinearConv:
uint8 activations in and out, one scale and zero point per tensor; int8 weights, one scale per output
channel, symmetric), with 7-bit weights (onnxruntime's reduce_range) so that no CPU saturates: without
VNNI, x86's u8 x s8 pair sums (vpmaddubsw) saturate past 32,767, and 2 x 255 x 64 stays below it.

The activation ranges are fixed per convolution (`calibrate`: the 1e-4 and 1 - 1e-4 quantiles of its
input and output over training batches, widened to hold 0) and recorded in the card (`int8`), so that
`export_onnx` rebuilds the same model from the weights. `fake_quantize` runs the torch model with those
very roundings (straight-through gradients): training with it (`hypergs train --int8`) teaches the
network the quantization noise onnxruntime will add."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ..errors import HyperGSError

TAIL = 1e-4  # the share of an activation's values left outside its range at each end
WEIGHT_LEVELS = 64  # a weight's quantized magnitude is at most this (onnxruntime's reduce_range for int8)
SAMPLE = 1 << 21  # values per tensor a quantile is taken over


def convolutions(model) -> list[tuple[str, object]]:
    import torch.nn as nn
    return [(name, m) for name, m in model.named_modules() if isinstance(m, nn.Conv2d)]


def scale_zero_point(low: float, high: float) -> tuple[float, int]:
    """uint8's scale and zero point for [low, high] (low <= 0 <= high), as onnxruntime computes them."""
    scale = (high - low) / 255.0
    return scale, int(round(-low / scale))


def calibrate(model, batches) -> dict:
    """{convolution's name: {"input": [low, high], "output": [low, high]}} over `batches` (network inputs
    [B, H, W, 3]): each end the mean over batches of its TAIL quantile, widened to hold 0."""
    import torch
    ends = {name: {"input": [], "output": []} for name, _ in convolutions(model)}
    generator = torch.Generator().manual_seed(0)

    def quantiles(t):
        t = t.detach().flatten().float()
        if t.numel() > SAMPLE:
            t = t[torch.randint(t.numel(), (SAMPLE,), generator=generator)]
        return torch.quantile(t, torch.tensor([TAIL, 1 - TAIL])).tolist()

    def record(name):
        def hook(module, args, output):
            ends[name]["input"].append(quantiles(args[0]))
            ends[name]["output"].append(quantiles(output))
        return hook

    handles = [m.register_forward_hook(record(name)) for name, m in convolutions(model)]
    try:
        with torch.no_grad():
            for frames in batches:
                model(frames)
    finally:
        for h in handles:
            h.remove()
    ranges = {name: {side: [min(0.0, float(np.mean([e[0] for e in values]))),
                            max(0.0, float(np.mean([e[1] for e in values])))]
                     for side, values in sides.items()} for name, sides in ends.items()}
    for name, sides in ranges.items():
        for side, (low, high) in sides.items():
            if not high > low:  # a convolution at its zero initialisation
                raise HyperGSError(f"the convolution {name} has an {side} of zeros only: no range to quantize it "
                                   "over (an untrained part of the network)")
    return ranges


def fake_quantize(model, ranges: dict) -> list:
    """Run `model`'s convolutions as the int8 model does (`ranges`: calibrate's); returns the hooks'
    handles (remove them to run in float again)."""
    import torch
    import torch.nn as nn

    def activation(low_high):
        scale, zero = scale_zero_point(*low_high)
        return lambda t: torch.fake_quantize_per_tensor_affine(t.float(), scale, zero, 0, 255)

    def weights(module):
        def conv(x, w, b):
            scale = (w.detach().abs().amax(dim=(1, 2, 3)) / WEIGHT_LEVELS).clamp_min(1e-12)
            zeros = torch.zeros_like(scale, dtype=torch.int32)
            w = torch.fake_quantize_per_channel_affine(w, scale, zeros, 0, -WEIGHT_LEVELS, WEIGHT_LEVELS)
            return nn.Conv2d._conv_forward(module, x, w, b)
        return conv

    handles = []
    for name, m in convolutions(model):
        into, out = activation(ranges[name]["input"]), activation(ranges[name]["output"])
        handles.append(m.register_forward_pre_hook(lambda module, args, into=into: (into(args[0]),)))
        handles.append(m.register_forward_hook(lambda module, args, output, out=out: out(output)))
        m._conv_forward = weights(m)  # the instance's, so the state dict keeps its names
        handles.append(_Restore(m))
    return handles


class _Restore:
    """A handle that gives a convolution back its class's _conv_forward."""

    def __init__(self, module):
        self.module = module

    def remove(self) -> None:
        self.module.__dict__.pop("_conv_forward", None)


def quantize_onnx(model, ranges: dict, float_path, path) -> None:
    """The float ONNX model of `model` at float_path -> the int8 one at `path` (`ranges`: calibrate's)."""
    import onnx
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static
    float_model = onnx.load(str(float_path))
    graph = float_model.graph
    # onnxruntime quantizes a tensor for all its readers, and fake_quantize a convolution's input for the
    # convolution only: where another node reads it too (the features the error pass also reads), the
    # convolution reads it through an Identity (which onnxruntime's optimizer takes out after quantization)
    readers = {}
    for node in graph.node:
        for name in node.input:
            readers[name] = readers.get(name, 0) + 1
    for position, node in reversed(list(enumerate(graph.node))):
        if node.op_type == "Conv" and readers[node.input[0]] > 1:
            alias = f"{node.name}_input"
            graph.node.insert(position, onnx.helper.make_node("Identity", [node.input[0]], [alias], name=alias))
            node.input[0] = alias
    aliased = Path(float_path).with_name(Path(float_path).stem + ".aliased.onnx")
    onnx.save(float_model, str(aliased))
    weights = {i.name: onnx.numpy_helper.to_array(i) for i in graph.initializer}
    modules = convolutions(model)
    overrides, matched = {}, set()

    def put(tensor, low_high):
        scale, zero = scale_zero_point(*low_high)
        if tensor in overrides and not np.isclose(float(overrides[tensor][0]["scale"]), scale, rtol=1e-6):
            raise ValueError(f"{tensor}: two convolutions read or write it with different ranges")
        overrides[tensor] = [{"scale": np.array(scale, np.float32), "zero_point": np.array(zero, np.uint8)}]

    for node in (n for n in graph.node if n.op_type == "Conv"):
        w = weights[node.input[1]]  # the graph's names are the exporter's: its convolutions are found by their weights
        name = [n for n, m in modules if n not in matched and tuple(m.weight.shape) == w.shape
                and np.array_equal(m.weight.detach().float().numpy(), w)]
        if len(name) != 1:
            raise ValueError(f"{node.name}: {len(name)} of the model's convolutions have its weights")
        matched.add(name[0])
        put(node.input[0], ranges[name[0]]["input"])
        put(node.output[0], ranges[name[0]]["output"])
    if len(matched) != len(modules):
        raise ValueError(f"the ONNX graph lacks {sorted(set(n for n, _ in modules) - matched)}")

    class Unused(CalibrationDataReader):  # every range is given; quantize_static still wants a pass to observe
        frames = [{"frames": np.zeros((1, model.cfg.multiple, model.cfg.multiple, 3), np.float32)}]

        def get_next(self):
            return self.frames.pop() if self.frames else None

    quantize_static(str(aliased), str(path), Unused(), quant_format=QuantFormat.QDQ, per_channel=True,
                    reduce_range=True, op_types_to_quantize=["Conv"], activation_type=QuantType.QUInt8,
                    weight_type=QuantType.QInt8, extra_options={"TensorQuantOverrides": overrides})
    aliased.unlink()
