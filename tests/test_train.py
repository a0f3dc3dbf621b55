import argparse
import json
import os

import numpy as np
import pytest
import torch

from hypergs_blender.commands import train as train_commands
from hypergs_blender.errors import HyperGSError
from hypergs_blender.metrics import psnr_from_mse
from hypergs_blender.render import render_torch
from hypergs_blender.training import train
from hypergs_blender.model import PRESETS, ConvConfig, ConvGS, HyperGS, TransformerConfig, anchor_inputs
from hypergs_blender.training.regularizers import AdaptiveRegularizer
from hypergs_blender.training.optim import Lamb, parameter_groups

from conftest import training_args

TINY = dict(canvas=32, patch=8, clip_frames=2, temporal_window=2, dim=32, heads=2, ffn=64, st_layers=1, q_layers=1)


def test_cosine_schedule():
    lrs = [train.cosine_lr(s, 1000, 100, 1.0, 0.1) for s in range(1000)]
    assert lrs[0] == pytest.approx(0.01) and lrs[99] == pytest.approx(1.0)
    assert min(lrs[100:]) == pytest.approx(0.1, abs=1e-4) and lrs[550] == pytest.approx(0.55, abs=0.01)


# The paper's parametrization (scales |h| + eps) at lr 1e-2 can collapse its Gaussians to sub-pixel scales
# within 15 steps and learn nothing: 2 of 4 seeds under the 4-sigma box, none under 3.5 (session 22); at 3e-3
# over 300 steps all 4 learn (+7.7 to +20.7 dB) under both boxes.
@pytest.mark.parametrize("parametrization, lr, steps", [("local", 1e-2, 150), ("paper", 3e-3, 300)])
def test_tiny_model_overfits_one_clip(parametrization, lr, steps):
    torch.manual_seed(0)
    # a clip with structure: two coloured blocks moving over a gradient
    clip = np.zeros((1, 2, 32, 32, 3), np.float32)
    clip[..., 0] = np.linspace(0, 1, 32)[None, None, None, :]
    for t in range(2):
        clip[0, t, 8:16, 4 + 3 * t:14 + 3 * t] = [0.9, 0.2, 0.1]
        clip[0, t, 20:28, 18:26] = [0.1, 0.3, 0.9]
    frames = torch.from_numpy(clip)
    model = HyperGS(TransformerConfig(**TINY, parametrization=parametrization, max_gaussians=64))
    optimizer = Lamb(parameter_groups(model), lr=lr)
    for group in optimizer.param_groups:
        group["lr"] = lr * group["lr_scale"]
    reg = AdaptiveRegularizer()
    anchors, cell = anchor_inputs(64)
    psnrs = []
    for step in range(steps):
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


def test_warm_start_takes_what_fits_and_keeps_new_parts_at_initialisation(tmp_path, capsys):
    from hypergs_blender.training.export import save_weights
    torch.manual_seed(0)
    teacher = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))
    with torch.no_grad():
        for p in teacher.parameters():
            p.normal_()
    save_weights(teacher, tmp_path, "teacher")
    student = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,), stem_level="cell"))
    fresh = {k: v.clone() for k, v in student.state_dict().items()}
    train.warm_start(student, tmp_path / "teacher.safetensors")
    assert "kept at initialisation: stem.1.bias, stem.1.weight, to_cell.weight" in capsys.readouterr().out
    for k, v in student.state_dict().items():
        expected = fresh[k] if k.startswith(("stem.", "to_cell.")) and k != "to_cell.bias" else teacher.state_dict()[k]
        torch.testing.assert_close(v, expected, rtol=0, atol=0, msg=k)


def test_warm_start_prunes_the_least_important_middle_channels(tmp_path, capsys):
    from hypergs_blender.training.export import save_weights
    torch.manual_seed(0)
    teacher = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))
    block = teacher.encoder[0][0]
    with torch.no_grad():
        block.b.weight.normal_()
        block.a.weight[[1, 4, 6]] *= 10  # the three middle channels that matter most
    save_weights(teacher, tmp_path, "teacher")
    student = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,), mid=3))
    train.warm_start(student, tmp_path / "teacher.safetensors")
    assert "kept at initialisation" not in capsys.readouterr().out  # every tensor came from the teacher
    pruned = student.encoder[0][0]
    torch.testing.assert_close(pruned.a.weight, block.a.weight[[1, 4, 6]], rtol=0, atol=0)
    torch.testing.assert_close(pruned.a.bias, block.a.bias[[1, 4, 6]], rtol=0, atol=0)
    torch.testing.assert_close(pruned.b.weight, block.b.weight[:, [1, 4, 6]], rtol=0, atol=0)
    torch.testing.assert_close(pruned.b.bias, block.b.bias, rtol=0, atol=0)


def test_distill_trains_all_but_the_head_towards_the_teachers_features(tmp_path, monkeypatch):
    from hypergs_blender.training.export import save_weights
    torch.manual_seed(0)
    teacher = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))
    with torch.no_grad():
        teacher.head.weight.normal_(0, 0.05)
        teacher.encoder[0][0].b.weight.normal_(0, 0.05)
    save_weights(teacher, tmp_path, "teacher")
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=16, blocks=(1,), stem_level="cell"))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    args = training_args(tmp_path / "run", 30, "conv")
    args.init_from = args.distill = tmp_path / "teacher.safetensors"
    args.lr = 1e-2
    train.run(args)
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)["model"]
    own = teacher.state_dict()
    for k, v in state.items():
        same = k in own and own[k].shape == v.shape and torch.equal(own[k], v)
        assert same == k.startswith("head."), k  # the head is kept; the rest learns
    records = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    unexplained = [r["unexplained"] for r in records if "unexplained" in r]
    assert len(unexplained) == 30 and np.mean(unexplained[-5:]) < 0.7 * np.mean(unexplained[:5])
    with pytest.raises(Exception, match="--distill needs --init-from"):
        args.out, args.init_from = tmp_path / "new", None
        train.run(args)


def test_input_noise_is_reproducible_bounded_and_eight_bit():
    frames = np.full((4, 1, 16, 16, 3), 0.5, np.float32)
    a, b = train.with_noise(frames, 2.0, 7, 3, 0), train.with_noise(frames, 2.0, 7, 3, 0)
    np.testing.assert_array_equal(a, b)  # a pure function of (seed, step, rank): resume is exact
    assert a.dtype == np.float32 and not np.array_equal(a, train.with_noise(frames, 2.0, 7, 4, 0))
    codes = a * 255
    np.testing.assert_allclose(codes, codes.round(), rtol=0, atol=1e-4)
    stds = (a - 0.5).reshape(4, -1).std(1) * 255
    assert float(stds.max()) < 2.0 * 1.25 and float(stds.max()) > 0.3


def test_config_overrides_a_new_runs_preset(tmp_path, monkeypatch, capsys):
    from hypergs_blender.commands.cli import main
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    argv = ["train", "--out", str(tmp_path / "run"), "--data", "procedural:1", "--steps", "1", "--batch", "1",
            "--size", "32", "--warmup", "1"]
    with pytest.raises(SystemExit):
        main(argv + ["--config", "wrap=1.5"])
    assert "'wrap' is not a network config field" in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main(argv + ["--config", "heads=4"])  # a transformer's field
    assert "heads not fields of the conv preset's config" in capsys.readouterr().err
    main(argv + ["--config", "mid=4", "stem_level=cell"])
    config = json.loads(torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)["config"])
    assert config["mid"] == 4 and config["stem_level"] == "cell" and config["width"] == 8


def test_a_resume_keeps_the_runs_options_but_those_given_again(tmp_path, monkeypatch, capsys):
    from hypergs_blender.commands.cli import main
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setitem(train.PRESETS, "small", TransformerConfig(**TINY))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    run = ["train", "--out", str(tmp_path / "run")]
    main(run + ["--data", "procedural:1", "--steps", "2", "--batch", "1", "--size", "32", "--warmup", "1",
                "--lr", "3e-4", "--loss", "psnr", "--seed", "5", "--threads", "1", "--precision", "bfloat16"])

    def recorded():
        state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
        return int(state["step"]), json.loads(state["args"])
    main(run + ["--steps", "3"])  # the schedule's length alone: lr, loss, data, seed and size stay the run's
    step, args = recorded()
    assert step == 3 and (args["lr"], args["loss"], args["seed"], args["size"], args["data"]) == (
        3e-4, "psnr", 5, 32, "procedural:1")
    # the sitting's speed options are its own, and said where they differ from the last sitting's
    assert ("the run's options but --steps 3 (was 2), --precision auto (the last sitting's: bfloat16), --threads unset "
            "(the last sitting's: 1)\n") in capsys.readouterr().out
    main(run + ["--steps", "4", "--lr", "1e-4", "--loss", "psnr"])
    step, args = recorded()
    assert step == 4 and args["lr"] == 1e-4 and args["loss"] == "psnr"
    assert "the run's options but --steps 4 (was 3), --lr 0.0001 (was 0.0003)\n" in capsys.readouterr().out
    with pytest.raises(SystemExit):  # a run keeps its network
        main(run + ["--steps", "5", "--preset", "small"])
    assert "--preset small: the run in" in capsys.readouterr().err and recorded()[0] == 4


def test_a_checkpoint_records_its_box_and_is_not_resumed_or_exported_under_another(tmp_path, monkeypatch):
    """The colours a run learns are for the rasterizer's box (raster.SIGMA_CUTOFF): a checkpoint records it,
    and resuming or exporting it where HyperGS renders with another box is refused, writing nothing."""
    from hypergs_blender.raster import SIGMA_CUTOFF
    from hypergs_blender.training.export import export_checkpoint
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    train.run(training_args(tmp_path / "run", 2, "conv"))
    path = tmp_path / "run" / "checkpoint.pt"
    state = torch.load(path, weights_only=True)
    assert state["sigma_cutoff"] == SIGMA_CUTOFF
    export_checkpoint(tmp_path / "run", tmp_path / "export")  # the same box: exports
    state["sigma_cutoff"] = SIGMA_CUTOFF - 0.5
    torch.save(state, path)
    with pytest.raises(HyperGSError, match=f"trained under a {SIGMA_CUTOFF - 0.5:g}-sigma box"):
        train.run(training_args(tmp_path / "run", 4, "conv"))
    with pytest.raises(HyperGSError, match="resume or export it with the HyperGS that trained it"):
        export_checkpoint(tmp_path / "run", tmp_path / "other")
    assert int(torch.load(path, weights_only=True)["step"]) == 2 and not (tmp_path / "other").exists()


def test_ema_averages_the_weights_of_every_step_across_resumes_and_is_what_export_writes(tmp_path, monkeypatch):
    """--ema D keeps avg_1 = w_1, avg_t = D avg_(t-1) + (1 - D) w_t over the weights after each step (a run
    resumed after every step, so that each step's weights are in a checkpoint); evaluated beside the weights
    (ema_* keys); `export` writes the average, `export --trained` the weights. Turned on for a resumed run
    that had none, it starts from that run's weights."""
    from hypergs_blender.training.export import export_checkpoint
    from safetensors.torch import load_file
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {"val": float(model.head.bias[5].detach())}))
    decay, weights = 0.75, []
    for step in (1, 2, 3):
        args = training_args(tmp_path / "run", step, "conv")
        args.ema, args.eval_every = decay, 3
        train.run(args)
        weights.append(torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)["model"])
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert int(state["ema"]["n_averaged"]) == 3
    for k, (w1, w2, w3) in ((k, [w[k] for w in weights]) for k in weights[0]):
        expected = decay * (decay * w1 + (1 - decay) * w2) + (1 - decay) * w3
        torch.testing.assert_close(state["ema"][f"module.{k}"], expected, msg=k)
    assert not torch.equal(weights[0]["head.bias"], weights[2]["head.bias"])  # the steps moved the weights
    evaluated = [json.loads(line)["eval"] for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()
                 if "eval" in line]
    assert evaluated[-1] == {"val": pytest.approx(float(weights[2]["head.bias"][5])),
                             "ema_val": pytest.approx(float(state["ema"]["module.head.bias"][5]))}
    _, info = export_checkpoint(tmp_path / "run", tmp_path / "average")
    assert info["ema"] == {"decay": decay, "updates": 3}
    torch.testing.assert_close(load_file(tmp_path / "average" / "hypergs.safetensors")["head.bias"],
                               state["ema"]["module.head.bias"])
    _, info = export_checkpoint(tmp_path / "run", tmp_path / "trained", trained=True)
    assert "ema" not in info
    torch.testing.assert_close(load_file(tmp_path / "trained" / "hypergs.safetensors")["head.bias"],
                               weights[2]["head.bias"])
    train.run(training_args(tmp_path / "plain", 2, "conv"))  # a run without an average...
    args = training_args(tmp_path / "plain", 3, "conv")
    args.ema, args.given = decay, args.given | {"ema"}
    train.run(args)  # ...given one on a resume: its first update copies the weights (step 3's), n_averaged 1
    plain = torch.load(tmp_path / "plain" / "checkpoint.pt", weights_only=True)
    assert int(plain["ema"]["n_averaged"]) == 1
    torch.testing.assert_close(plain["ema"]["module.head.bias"], plain["model"]["head.bias"])


def test_lr_scale_gives_a_part_its_own_learning_rate(tmp_path):
    args = training_args(tmp_path / "run", 4, "conv")
    args.lr_scale = {"head": 30.0}
    train.run(args)
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    rest, head = sorted(state["optimizer"]["param_groups"], key=lambda group: group["lr_scale"])
    assert (rest["lr_scale"], head["lr_scale"]) == (1.0, 30.0)
    assert len(head["params"]) == 2  # the head's weight and bias
    assert head["lr"] == pytest.approx(30 * rest["lr"]) and rest["lr"] > 0
    args = training_args(tmp_path / "run", 6, "conv")  # a resume keeps the groups the run started with
    train.run(args)
    state = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert int(state["step"]) == 6 and len(state["optimizer"]["param_groups"]) == 2
    args = training_args(tmp_path / "other", 2, "conv")
    args.lr_scale = {"wrap": 3.0}
    with pytest.raises(HyperGSError, match="wrap not parts of this network"):
        train.run(args)


def test_lr_scale_the_most_specific_part_decides():
    """encoder=0.1 encoder.0.1=1: one block inside a slow part at its own rate (a new block on warm-started ones)."""
    model = ConvGS(PRESETS["conv"])
    groups = train.lr_groups(model, {"encoder": 0.1, "encoder.0.1": 1.0, "head": 2.0})
    scale_of = {id(parameter): group["lr_scale"] for group in groups for parameter in group["params"]}
    scale = {name: scale_of[id(parameter)] for name, parameter in model.named_parameters()}
    assert len(scale) == len(scale_of)  # every parameter in one group
    assert scale["encoder.0.0.a.weight"] == 0.1 and scale["encoder.0.2.b.bias"] == 0.1
    assert scale["encoder.0.1.a.weight"] == 1.0 and scale["encoder.0.1.b.bias"] == 1.0
    assert scale["head.weight"] == 2.0 and scale["stem.1.weight"] == 1.0
    with pytest.raises(HyperGSError, match="encoder.0.9 not parts of this network"):
        train.lr_groups(model, {"encoder.0.9": 3.0})


def test_train_only_trains_the_parts_named_and_keeps_the_rest(tmp_path, monkeypatch):
    """--train-only error_pass: a second pass trained on a warm-started first, which stays as it came; the
    card records it."""
    from hypergs_blender.training.export import export_checkpoint, save_weights
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    first = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))
    with torch.no_grad():
        first.head.weight.normal_(0, 0.05)
    save_weights(first, tmp_path, "first")
    args = training_args(tmp_path / "run", 3, "conv")
    args.config, args.init_from, args.train_only = {"error_width": 8}, str(tmp_path / "first.safetensors"), ["error_pass"]
    train.run(args)
    trained = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)["model"]
    for k, v in first.state_dict().items():
        torch.testing.assert_close(trained[k], v, rtol=0, atol=0, msg=k)
    assert float(trained["error_pass.head.weight"].abs().max()) > 0  # it left its zero start
    _, info = export_checkpoint(tmp_path / "run", tmp_path / "export")
    assert info["train_args"]["train_only"] == ["error_pass"] and "lr_scale" not in info["train_args"]
    args.train_only = ["error_pass", "wrap"]
    args.out = str(tmp_path / "other")
    with pytest.raises(HyperGSError, match="--train-only: wrap not parts of this network"):
        train.run(args)


def test_psnr_loss_follows_the_mean_log_mse_and_keeps_an_mse_size():
    per_frame = torch.tensor([1e-4, 4e-3, 2.5e-2, 0.0], dtype=torch.float64, requires_grad=True)
    train.frame_loss(per_frame, "psnr").backward()
    shifted = per_frame.detach() + train.PSNR_LOSS_FLOOR
    # the gradient of the mean log MSE (of the frames' mean PSNR), times their harmonic mean
    torch.testing.assert_close(per_frame.grad, (1 / shifted) / len(shifted) / torch.mean(1 / shifted))
    assert per_frame.grad[0] > 30 * per_frame.grad[2]  # the smooth frame counts most
    value = train.frame_loss(per_frame.detach(), "psnr")
    assert float(per_frame.detach().min()) <= value <= float(per_frame.detach().mean())
    assert train.frame_loss(per_frame.detach(), "mse") == pytest.approx(float(per_frame.detach().mean()))


@pytest.mark.parametrize("preset", ["conv", "small"])
def test_training_loss_weighs_each_frames_own_mse(preset):
    torch.manual_seed(0)
    model = (ConvGS(ConvConfig(width=8, stem=4, blocks=(1,))) if preset == "conv"
             else HyperGS(TransformerConfig(**TINY, max_gaussians=64)))
    frames = torch.rand(2, 1 if preset == "conv" else 2, 32, 32, 3)
    frames[0] = 0.5  # a flat clip next to a noisy one
    lattice = None if preset == "conv" else train.lattice_for_step(64, 0, 0, 0, 2)
    _, mse, _ = train.training_loss(model, frames, lattice, None)
    loss, psnr_mse, _ = train.training_loss(model, frames, lattice, None, loss="psnr")
    # the slow reference: each clip encoded, each of its frames rendered and measured on its own
    per_frame = []
    for b in range(frames.shape[0]):
        if preset == "conv":
            params = model(frames[b])
        else:
            anchors = torch.from_numpy(train.lattice_anchors(lattice[0], lattice[1][b:b + 1]))
            params = model(frames[b:b + 1], anchors, torch.tensor([2.0 / lattice[0]]))[0]
        for t in range(frames.shape[1]):
            render = render_torch(params[t:t + 1], 32, 32, 32, 32)
            per_frame.append(torch.mean((render - frames[b, t:t + 1]) ** 2))
    per_frame = torch.stack(per_frame)
    torch.testing.assert_close(mse, per_frame.mean())
    torch.testing.assert_close(psnr_mse, mse)
    torch.testing.assert_close(loss, train.frame_loss(per_frame, "psnr"))
    assert loss < 0.5 * mse  # the flat clip's small error weighs most


def test_flat_pixel_weights_mark_the_flat_pixels_by_evals_criterion():
    frames = torch.full((1, 2, 40, 40, 3), 0.5)
    frames[0, 0, :, 20:] = torch.rand(40, 20, 3)  # frame 0: left half flat, right half noise
    frames[0, 1, :, :, 1] += 0.5 / 255 * torch.randn(40, 40)  # frame 1: std 0.5/255, flat by the criterion
    weights = train.flat_pixel_weights(frames, 9.0)
    assert weights.shape == (1, 2, 40, 40, 1)
    # the slow reference: each pixel's window (clipped at the frame's border), its std per channel
    half = train.FLAT_WINDOW // 2
    for t in range(2):
        for y, x in [(0, 0), (20, 10), (20, 15), (20, 16), (5, 30), (39, 39)]:
            window = frames[0, t, max(0, y - half):y + half + 1, max(0, x - half):x + half + 1].reshape(-1, 3)
            flat = bool((window.std(0, unbiased=False) < train.FLAT_STD).all())
            assert float(weights[0, t, y, x, 0]) == pytest.approx(10.0 if flat else 1.0), (t, y, x)
    assert float(weights[0, 0, 20, 15, 0]) == 10.0 and float(weights[0, 0, 20, 16, 0]) == 1.0  # 5 px from the edge
    assert bool((weights[0, 1] == 10.0).all())
    assert bool((train.flat_pixel_weights(frames, 0.0) == 1.0).all())
    # as the training step calls it, under bfloat16 autocast: a bright frame with a std of 1.5/255 is not flat
    # (in bfloat16 its sums of squares round by more than their variance: about half its windows would read flat)
    frames[0, 1] = 0.8 + 1.5 / 255 * torch.randn(40, 40, 3)
    weights = train.flat_pixel_weights(frames, 9.0)
    assert float(weights[0, 1].mean()) < 2.0
    with train.forward_autocast(torch.device("cpu"), "bfloat16"):
        assert torch.equal(train.flat_pixel_weights(frames, 9.0), weights)


def test_flat_weight_raises_the_loss_of_an_error_in_a_flat_region_only():
    torch.manual_seed(0)
    model = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))
    frames = torch.rand(2, 1, 32, 32, 3)
    frames[0] = 0.5  # a flat clip next to a noisy one
    loss, mse, _ = train.training_loss(model, frames, None, None)
    weighted, weighted_mse, _ = train.training_loss(model, frames, None, None, flat_weight=3.0)
    torch.testing.assert_close(weighted_mse, mse)  # the log's mse is the plain one
    # the slow reference: the flat clip's pixels weigh 4 (all flat), the noisy clip's 1 (none flat)
    with torch.no_grad():
        error = (render_torch(model(frames.reshape(2, 32, 32, 3)), 32, 32, 32, 32) - frames.reshape(2, 32, 32, 3)) ** 2
    per_frame = error.mean(dim=(1, 2, 3))
    torch.testing.assert_close(weighted.detach(), per_frame.mean())  # each frame's own mean: uniform weights cancel
    frames[0, 0, :16] = torch.rand(16, 32, 3)  # half of the flat clip detailed: its flat half now counts 4x
    flat_half = train.training_loss(model, frames, None, None, flat_weight=3.0)[0]
    with torch.no_grad():
        error = (render_torch(model(frames.reshape(2, 32, 32, 3)), 32, 32, 32, 32) - frames.reshape(2, 32, 32, 3)) ** 2
        weights = train.flat_pixel_weights(frames.reshape(2, 32, 32, 3), 3.0)
    assert 1.0 < float(weights[0].mean()) < 4.0
    expected = torch.stack([(weights[i] * error[i]).sum() / (3 * weights[i].sum()) for i in range(2)]).mean()
    torch.testing.assert_close(flat_half.detach(), expected)


def test_loss_option_defaults_per_design_and_refuses_others():
    parser = argparse.ArgumentParser()
    train_commands.add_commands(parser.add_subparsers())
    assert parser.parse_args(["train", "--loss", "psnr"]).loss == "psnr"
    assert parser.parse_args(["train"]).loss is None  # train.ARCH_DEFAULTS decides
    assert {d["loss"] for d in train.ARCH_DEFAULTS.values()} <= set(train.LOSSES)
    with pytest.raises(SystemExit):
        parser.parse_args(["train", "--loss", "l1"])


def test_profile_writes_the_steps_phases_and_ops(tmp_path, monkeypatch):
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    args = training_args(tmp_path / "run", 4, "conv")
    args.profile, args.input_noise = 2, 2.0
    train.run(args)
    table = (tmp_path / "run" / "profile.txt").read_text()
    assert table.startswith("2 training steps on cpu")
    for phase in ("data", "forward", "backward", "optimizer", "ProfilerStep"):
        assert phase in table, phase
    assert torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)["step"] == 4  # it trained on


def test_an_export_records_the_weights_its_run_started_from(tmp_path, monkeypatch):
    """A warm-started run's card names its --init-from weights with their own card's record, so a bundled
    model's chain of runs can be read back from its card."""
    from hypergs_blender.training.export import export_checkpoint
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    train.run(training_args(tmp_path / "first", 2, "conv"))
    export_checkpoint(tmp_path / "first", tmp_path / "first" / "export")
    args = training_args(tmp_path / "second", 3, "conv")
    args.init_from = str(tmp_path / "first" / "export" / "hypergs.safetensors")
    train.run(args)
    export_checkpoint(tmp_path / "second", tmp_path / "second" / "export")
    card = json.loads((tmp_path / "second" / "export" / "hypergs.json").read_text())
    parent = card["info"]["train_args"]["init_from"]
    assert parent["path"] == args.init_from and parent["info"]["step"] == 2 and card["info"]["step"] == 3
    assert "init_from" not in parent["info"]["train_args"]  # the first run started from nothing


def test_steps_auto_fits_the_schedule_to_the_sitting(tmp_path, monkeypatch):
    """--steps auto --minutes 1: the warm-up's rate (a clock at one second per step) sizes the cosine to
    AUTO_TIME_SHARE of the time left, so the run ends at its schedule's end, at the lowest learning rate,
    before the minute is out; the checkpoint records the number, so a resume keeps that schedule."""
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    ticks = iter(range(10 ** 6))
    monkeypatch.setattr(train.time, "perf_counter", lambda: 0.5 * next(ticks))  # two readings per step
    args = training_args(tmp_path / "run", "auto", "conv", minutes=1)
    args.warmup = 10
    train.run(args)
    checkpoint = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    steps = json.loads(checkpoint["args"])["steps"]
    assert 40 <= steps <= 57 and checkpoint["step"] == steps
    records = [json.loads(line) for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()]
    lrs = [r["lr"] for r in records if "lr" in r]
    assert len(lrs) == steps and lrs[-1] == pytest.approx(args.lr * args.min_lr_ratio, rel=0.02)
    assert [r["step"] for r in records if "eval" in r] == [steps]


def test_steps_auto_needs_minutes_a_warmup_and_a_run_in_its_warmup(tmp_path, monkeypatch):
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    with pytest.raises(HyperGSError, match="--minutes"):
        train.run(training_args(tmp_path / "a", "auto", "conv"))
    args = training_args(tmp_path / "b", "auto", "conv", minutes=1)  # --warmup 2
    with pytest.raises(HyperGSError, match="--warmup of 10"):
        train.run(args)
    args = training_args(tmp_path / "c", 12, "conv")
    args.warmup = 10
    train.run(args)  # past its warm-up
    args = training_args(tmp_path / "c", "auto", "conv", minutes=1)
    args.warmup = 10
    with pytest.raises(HyperGSError, match="past its warm-up"):
        train.run(args)


def test_precision_runs_the_convolutions_in_bfloat16_where_asked_and_the_rest_in_float32(tmp_path, monkeypatch):
    """--precision: auto is float32 on a CPU; bfloat16 runs the network's convolutions in bfloat16 while
    its output (geometry, colours) and the weights stay float32, and a run trains with it."""
    model = ConvGS(ConvConfig(width=8, stem=4, blocks=(1,)))
    frames = torch.rand(2, 32, 32, 3)
    seen = []
    model.head.register_forward_hook(lambda module, inputs, output: seen.append(output.dtype))
    cpu = torch.device("cpu")
    for precision, dtype in (("auto", torch.float32), ("float32", torch.float32), ("bfloat16", torch.bfloat16)):
        with train.forward_autocast(cpu, precision):
            params = model(frames)
        assert seen.pop() == dtype and params.dtype == torch.float32, precision
    with pytest.raises(ValueError, match="unknown precision"):
        train.forward_autocast(cpu, "float16")
    monkeypatch.setitem(train.PRESETS, "conv", ConvConfig(width=8, stem=4, blocks=(1,)))
    monkeypatch.setattr(train, "Evaluator", lambda *a, **k: (lambda model, device: {}))
    args = training_args(tmp_path / "run", 4, "conv")
    args.precision = "bfloat16"
    # the run caps oneDNN's cache through the environment: set here so that it is undone after the test
    monkeypatch.setenv("ONEDNN_PRIMITIVE_CACHE_CAPACITY", str(train.BFLOAT16_CPU_KERNEL_CACHE))
    train.run(args)
    checkpoint = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=True)
    assert checkpoint["step"] == 4 and json.loads(checkpoint["args"])["precision"] == "bfloat16"
    assert all(v.dtype == torch.float32 for v in checkpoint["model"].values())
    losses = [json.loads(line)["loss"] for line in (tmp_path / "run" / "log.jsonl").read_text().splitlines()
              if "loss" in line]
    assert len(losses) == 4 and all(np.isfinite(losses))


def test_a_bfloat16_run_on_a_cpu_bounds_onednns_kernel_cache_unless_the_user_set_it(monkeypatch):
    # oneDNN compiles a kernel per input shape; with the Gaussian count changing each step its cache grew by GBs
    variable = "ONEDNN_PRIMITIVE_CACHE_CAPACITY"
    # set, then deleted: monkeypatch then restores the variable's state before the test (a delenv of an unset
    # variable records nothing, and the value the helper sets would outlive the test)
    monkeypatch.setenv(variable, "0")
    monkeypatch.delenv(variable)
    for device, precision in (("cpu", "float32"), ("cpu", "auto"), ("cuda", "bfloat16")):
        train.bound_kernel_cache(torch.device(device), precision)
        assert variable not in os.environ, (device, precision)
    train.bound_kernel_cache(torch.device("cpu"), "bfloat16")
    assert os.environ[variable] == str(train.BFLOAT16_CPU_KERNEL_CACHE)
    monkeypatch.setenv(variable, "256")
    train.bound_kernel_cache(torch.device("cpu"), "bfloat16")
    assert os.environ[variable] == "256"
