"""`hypergs train`: LAMB, cosine schedule, checkpoints with exact resume, periodic evaluation.

The same script runs on one CPU process or under `torchrun --nproc_per_node=K` (DDP, NCCL on
GPUs, gloo on CPUs): every rank draws different clips (sources.make_batch is a pure function of
(seed, step, rank)), rank 0 logs, evaluates and writes checkpoints.

The run folder holds `checkpoint.pt` (written atomically every --checkpoint-every steps and at
the end), `log.jsonl` (one line per logged step and per evaluation, with wall time: the
PSNR-vs-training-time curve) and, from `hypergs export`, the weights.
"""
from __future__ import annotations

import json
import math
import os
import threading
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist

from ..io.frames import read_frames
from ..model import PRESETS, HyperGS, ModelConfig, anchor_inputs
from ..render import render_torch
from . import data
from .export import load_checkpoint
from .optim import Lamb, parameter_groups
from .regularizers import AdaptiveRegularizer
from .sources import make_batch


def cosine_lr(step: int, total: int, warmup: int, base: float, min_ratio: float) -> float:
    if step < warmup:
        return base * (step + 1) / warmup
    t = min(1.0, (step - warmup) / max(1, total - warmup))
    return base * (min_ratio + (1 - min_ratio) * 0.5 * (1 + math.cos(math.pi * t)))


def gaussians_for_step(spec: str, seed: int, step: int) -> int:
    lo, hi = (int(v) for v in spec.split(":")) if ":" in spec else (int(spec),) * 2
    rng = np.random.default_rng([seed, step, 7919])
    return int(round(math.exp(rng.uniform(math.log(lo), math.log(hi)))))


def psnr_db(mse: float) -> float:
    return 10 * math.log10(1 / max(mse, 1e-12))


class Prefetcher:
    """Builds the next batch in a thread while the current step runs (numpy releases the GIL)."""

    def __init__(self, make):
        self.make, self.thread, self.result = make, None, None

    def start(self, step: int):
        def work():
            self.result = (step, self.make(step))
        self.thread = threading.Thread(target=work, daemon=True)
        self.thread.start()

    def get(self, step: int):
        self.thread.join()
        got_step, batch = self.result
        assert got_step == step
        return batch


def run(args) -> None:
    """Train with the options of `hypergs train` (commands/train.py), resuming from args.out."""
    distributed = "RANK" in os.environ
    if distributed:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    rank = dist.get_rank() if distributed else 0
    device = torch.device(f"cuda:{int(os.environ.get('LOCAL_RANK', 0))}" if torch.cuda.is_available() else "cpu")
    if device.type == "cuda":
        torch.cuda.set_device(device)
    if args.threads:
        torch.set_num_threads(args.threads)

    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    checkpoint_path = out / "checkpoint.pt"
    resume = load_checkpoint(checkpoint_path) if checkpoint_path.exists() else None
    if resume:
        cfg = ModelConfig(**resume["config"])
    else:
        cfg = ModelConfig(**asdict(PRESETS[args.preset]))
        if args.parametrization:
            cfg.parametrization = args.parametrization
    torch.manual_seed(args.seed)
    model = HyperGS(cfg).to(device)
    regularizer = AdaptiveRegularizer().to(device)
    optimizer = Lamb(parameter_groups(model), lr=args.lr, weight_decay=0.01)
    step, wall = 0, 0.0
    if resume:
        model.load_state_dict(resume["model"])
        regularizer.load_state_dict(resume["regularizer"])
        optimizer.load_state_dict(resume["optimizer"])
        step, wall = resume["step"], resume["wall_seconds"]
        torch.set_rng_state(resume["torch_rng"])
    train_model = torch.nn.parallel.DistributedDataParallel(model) if distributed else model

    sources = data.build_sources(args.data, args.data_root)
    size, frames_per_clip = cfg.canvas, cfg.clip_frames
    prefetch = Prefetcher(lambda s: make_batch(sources, args.seed, s, rank, args.batch, frames_per_clip, size))
    evaluator = Evaluator(cfg, args.data_root, args.eval_videos) if rank == 0 else None
    log = open(out / "log.jsonl", "a") if rank == 0 else None
    if rank == 0:
        print(f"training {cfg.parametrization} model, {sum(p.numel() for p in model.parameters()) / 1e6:.2f}M "
              f"parameters, from step {step} of {args.steps} -> {out}", flush=True)

    def save():
        state = dict(model=model.state_dict(), regularizer=regularizer.state_dict(), optimizer=optimizer.state_dict(),
                     step=step, wall_seconds=wall, config=asdict(cfg), args=vars(args) | {"func": None},
                     torch_rng=torch.get_rng_state())
        tmp = checkpoint_path.with_suffix(".tmp")
        torch.save(state, tmp)
        os.replace(tmp, checkpoint_path)

    from tqdm import tqdm
    bar = tqdm(total=args.steps, initial=step, disable=rank != 0, dynamic_ncols=True, mininterval=5)
    started = time.perf_counter() - wall
    run_started = time.perf_counter()
    prefetch.start(step)
    amp = torch.autocast("cuda", dtype=torch.bfloat16) if device.type == "cuda" else torch.autocast("cpu", enabled=False)
    while step < args.steps:
        frames = torch.from_numpy(prefetch.get(step)).to(device)
        n = gaussians_for_step(args.gaussians, args.seed, step)
        if step + 1 < args.steps:
            prefetch.start(step + 1)
        lr = cosine_lr(step, args.steps, args.warmup, args.lr, args.min_lr_ratio)
        for group in optimizer.param_groups:
            group["lr"] = lr * group.get("lr_scale", 1.0)
        anchors, cell = anchor_inputs(n, device)
        with amp:
            params = train_model(frames, anchors, cell)
        params = params.float()
        render = render_torch(params, size, size, size, size)
        mse = torch.mean((render - frames) ** 2)
        reg_loss, reg_stats = regularizer(params[..., 2:4])
        loss = mse + reg_loss
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        step += 1
        wall = time.perf_counter() - started
        if rank == 0:
            train_psnr = psnr_db(mse.item())
            bar.set_postfix(loss=f"{loss.item():.4f}", psnr=f"{train_psnr:.2f}", erank_min=f"{reg_stats['erank_min']:.3f}",
                            n=n, refresh=False)
            bar.update(1)
            if step % args.log_every == 0:
                log.write(json.dumps(dict(step=step, wall=round(wall, 1), lr=lr, n=n, loss=float(loss),
                                          psnr=train_psnr, **reg_stats)) + "\n")
                log.flush()
            if step % args.checkpoint_every == 0 or step == args.steps:
                save()
            if step % args.eval_every == 0 or step == args.steps:
                model.eval()
                record = dict(step=step, wall=round(wall, 1), eval=evaluator(model, device))
                model.train()
                log.write(json.dumps(record) + "\n")
                log.flush()
                bar.write(f"step {step} wall {wall / 60:.1f} min eval {json.dumps(record['eval'])}")
        if args.minutes is not None and time.perf_counter() - run_started > args.minutes * 60:
            break
    if rank == 0:
        save()
        bar.close()
        print(f"stopped at step {step}, {wall / 60:.1f} min of training; checkpoint {checkpoint_path}", flush=True)
    if distributed:
        dist.destroy_process_group()


class Evaluator:
    """PSNR at the canvas size on fixed held-out clips (photos + procedural) and, for reporting only
    (never for training decisions), on the videos given with --eval-videos."""

    def __init__(self, cfg: ModelConfig, data_root: str, videos=(), counts=(250, 1000)):
        self.cfg, self.counts = cfg, counts
        self.clips = {"val": data.validation_clips(data_root, cfg.clip_frames, cfg.canvas, 8)}
        for path in map(Path, videos):
            frames, _, _ = read_frames(path, cfg.clip_frames, size=cfg.canvas)
            self.clips[f"video_{path.stem}"] = (frames[None] / 255.0).astype(np.float32)

    @torch.no_grad()
    def __call__(self, model, device) -> dict:
        results = {}
        for name, clips in self.clips.items():
            for n in self.counts:
                # Gaussian density as at 256 x 256 with N per frame: the canvas holds N * (c/256)^2.
                n_canvas = max(16, round(n * (self.cfg.canvas / 256) ** 2))
                anchors, cell = anchor_inputs(n_canvas, device)
                frames = torch.from_numpy(clips).to(device)
                c = self.cfg.canvas
                render = render_torch(model(frames, anchors, cell).float(), c, c, c, c)
                results[f"{name}_n{n}"] = round(psnr_db(float(torch.mean((render.clamp(0, 1) - frames) ** 2))), 3)
        return results
