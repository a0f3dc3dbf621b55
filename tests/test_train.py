import argparse
import json

import numpy as np
import pytest
import torch

from hypergs_blender.commands import train as train_commands
from hypergs_blender.render import render_torch
from hypergs_blender.training import train
from hypergs_blender.model import HyperGS, ModelConfig, anchor_inputs
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
    model = HyperGS(ModelConfig(**TINY, parametrization=parametrization, max_gaussians=64))
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
        psnrs.append(train.psnr_db(mse.item()))
    assert psnrs[-1] > psnrs[0] + 5, (psnrs[0], psnrs[-1])


def training_args(out, steps, minutes=None):
    parser = argparse.ArgumentParser()
    train_commands.add_commands(parser.add_subparsers())
    argv = ["train", "--out", str(out), "--data", "procedural:1", "--steps", str(steps), "--batch", "2",
            "--gaussians", "16:64", "--log-every", "1", "--eval-every", "1000", "--checkpoint-every", "2",
            "--warmup", "2"] + ([] if minutes is None else ["--minutes", str(minutes)])
    return parser.parse_args(argv)


def test_resume_continues_exactly(tmp_path, monkeypatch):
    monkeypatch.setitem(train.PRESETS, "small", ModelConfig(**TINY))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    train.run(training_args(tmp_path / "straight", 6))
    train.run(training_args(tmp_path / "resumed", 6, minutes=0))  # interrupted after its first step
    assert torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=True)["step"] == 1
    train.run(training_args(tmp_path / "resumed", 6))
    straight = torch.load(tmp_path / "straight" / "checkpoint.pt", weights_only=True)
    resumed = torch.load(tmp_path / "resumed" / "checkpoint.pt", weights_only=True)
    assert resumed["step"] == straight["step"] == 6
    for k, v in straight["model"].items():
        torch.testing.assert_close(resumed["model"][k], v, rtol=0, atol=0, msg=k)
    torch.testing.assert_close(resumed["regularizer"], straight["regularizer"], rtol=0, atol=0)
    records = [json.loads(line) for line in (tmp_path / "resumed" / "log.jsonl").read_text().splitlines()]
    assert [r["step"] for r in records if "loss" in r] == [1, 2, 3, 4, 5, 6]  # each step logged once
    assert [r["step"] for r in records if "eval" in r] == [6]
