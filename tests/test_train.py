import argparse
import json

import numpy as np
import pytest
import torch

from hypergs_blender.commands import train as train_commands
from hypergs_blender.metrics import psnr_from_mse
from hypergs_blender.render import render_torch
from hypergs_blender.training import train
from hypergs_blender.model import ConvConfig, ConvGS, HyperGS, TransformerConfig, anchor_inputs
from hypergs_blender.training.regularizers import AdaptiveRegularizer
from hypergs_blender.training.optim import Lamb, parameter_groups

TINY = dict(canvas=32, patch=8, clip_frames=2, temporal_window=2, dim=32, heads=2, ffn=64, st_layers=1, q_layers=1)


def test_cosine_schedule():
    lrs = [train.cosine_lr(s, 1000, 100, 1.0, 0.1) for s in range(1000)]
    assert lrs[0] == pytest.approx(0.01) and lrs[99] == pytest.approx(1.0)
    assert min(lrs[100:]) == pytest.approx(0.1, abs=1e-4) and lrs[550] == pytest.approx(0.55, abs=0.01)


@pytest.mark.parametrize("parametrization", ["local", "paper"])
def test_tiny_model_overfits_one_clip(parametrization):
    torch.manual_seed(0)
    # a clip with structure: two coloured blocks moving over a gradient
    clip = np.zeros((1, 2, 32, 32, 3), np.float32)
    clip[..., 0] = np.linspace(0, 1, 32)[None, None, None, :]
    for t in range(2):
        clip[0, t, 8:16, 4 + 3 * t:14 + 3 * t] = [0.9, 0.2, 0.1]
        clip[0, t, 20:28, 18:26] = [0.1, 0.3, 0.9]
    frames = torch.from_numpy(clip)
    model = HyperGS(TransformerConfig(**TINY, parametrization=parametrization, max_gaussians=64))
    optimizer = Lamb(parameter_groups(model), lr=1e-2)
    for group in optimizer.param_groups:
        group["lr"] = 1e-2 * group["lr_scale"]
    reg = AdaptiveRegularizer()
    anchors, cell = anchor_inputs(64)
    psnrs = []
    for step in range(150):
        params = model(frames, anchors, cell)
        mse = torch.mean((render_torch(params, 32, 32, 32, 32) - frames) ** 2)
        loss = mse + reg(params[..., 2:4])[0]
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        psnrs.append(float(psnr_from_mse(mse.item())))
    assert psnrs[-1] > psnrs[0] + 5, (psnrs[0], psnrs[-1])


def test_tiny_conv_model_overfits_one_frame():
    torch.manual_seed(0)
    frame = np.zeros((1, 32, 32, 3), np.float32)
    frame[..., 0] = np.linspace(0, 1, 32)[None, None, :]
    frame[0, 8:16, 4:14] = [0.9, 0.2, 0.1]
    frame[0, 20:28, 18:26] = [0.1, 0.3, 0.9]
    frames = torch.from_numpy(frame)
    model = ConvGS(ConvConfig(width=16, stem=8, blocks=(2,)))
    optimizer = torch.optim.AdamW(model.parameters(), lr=3e-3)
    psnrs = []
    for step in range(150):
        mse = torch.mean((render_torch(model(frames), 32, 32, 32, 32) - frames) ** 2)
        optimizer.zero_grad()
        mse.backward()
        optimizer.step()
        psnrs.append(float(psnr_from_mse(mse.item())))
    assert psnrs[-1] > psnrs[0] + 5, (psnrs[0], psnrs[-1])


def training_args(out, steps, preset, minutes=None, loader_threads=1):
    parser = argparse.ArgumentParser()
    train_commands.add_commands(parser.add_subparsers())
    argv = ["train", "--out", str(out), "--preset", preset, "--data", "procedural:1", "--steps", str(steps),
            "--batch", "2", "--size", "32", "--gaussians", "16:64", "--log-every", "1", "--eval-every", "1000",
            "--checkpoint-every", "2", "--warmup", "2", "--loader-threads", str(loader_threads)]
    argv += [] if minutes is None else ["--minutes", str(minutes)]
    return parser.parse_args(argv)


@pytest.mark.parametrize("preset", ["conv", "small"])
def test_resume_continues_exactly(tmp_path, monkeypatch, preset):
    monkeypatch.setitem(train.PRESETS, "small", TransformerConfig(**TINY))
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    train.run(training_args(tmp_path / "straight", 6, preset))
    train.run(training_args(tmp_path / "resumed", 6, preset, minutes=0))  # interrupted after its first step
    assert torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=True)["step"] == 1
    train.run(training_args(tmp_path / "resumed", 6, preset, loader_threads=3))  # workers change no batch
    straight = torch.load(tmp_path / "straight" / "checkpoint.pt", weights_only=True)
    resumed = torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=True)
    assert resumed["step"] == straight["step"] == 6 and resumed["cpu_seconds"] > 0
    for k, v in straight["model"].items():
        torch.testing.assert_close(resumed["model"][k], v, rtol=0, atol=0, msg=k)
    if preset == "small":
        torch.testing.assert_close(resumed["regularizer"], straight["regularizer"], rtol=0, atol=0)
    records = [json.loads(line) for line in (tmp_path / "resumed" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records if "loss" in r] == [1, 2, 3, 4, 5, 6]  # each step logged once
    assert [r["step"] for r in records if "eval" in r] == [6]
    cpu = [r["cpu"] for r in records if "loss" in r]
    assert all(r["rss_mb"] > 0 for r in records if "loss" in r) and cpu == sorted(cpu) and cpu[-1] > 0


def test_evaluator_encodes_as_the_runtime_does(tmp_path):
    """At initialisation the conv network is the grid floor: the trainer's evaluation must then give the
    floor's PSNR through encode.encode_frames (the same resize, layout and rendering)."""
    from hypergs_blender.encode import FloorEncoder, encode_frames, frames_layout
    from hypergs_blender.metrics import psnr
    from hypergs_blender.render import render_params
    with pytest.warns(UserWarning, match="prepare-data"):  # no held-out photos here: procedural clips
        model = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,))).eval()
        evaluator = train.Evaluator(model, tmp_path)
    results = evaluator(model, torch.device("cpu"))
    frames = evaluator.sets["val"][0]
    for cell, n in ((8, 1024), (4, 4096)):
        layout = frames_layout(frames, FloorEncoder(), cell=cell)
        floor = render_params(encode_frames(frames, FloorEncoder(), layout), 256, 256, 256, 256)
        assert results[f"val_n{n}"] == pytest.approx(float(np.mean(psnr(floor, frames / 255))), abs=0.01)
