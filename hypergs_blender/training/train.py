"""`hypergs train`: warm-up + cosine schedule, gradient clipping, checkpoints with exact resume,
periodic evaluation, resident memory in the log.

The conv network (the default) trains on single frames: batches of random `--size` crops (photo pans
at random scales, procedural scenes), one Gaussian per 4x4 pixels, MSE of the render against the
crop, AdamW. The paper's transformer (presets small/paper) trains on T-frame clips with a Gaussian
count drawn per step (a k x k anchor lattice at a random phase per clip, as the windows of a tiled
frame see it), MSE plus the adaptive erank/scale regularizers (on scales in grid cells), LAMB.

The same script runs on one CPU process or under `torchrun --nproc_per_node=K` (DDP, NCCL on GPUs,
gloo on CPUs): every rank draws different clips (sources.make_batch is a pure function of (seed,
step, rank)), rank 0 logs, evaluates and writes checkpoints. A run stopped at any point (Ctrl-C,
--minutes, a killed machine) continues exactly from its last checkpoint, also on another device.

The run folder holds `checkpoint.pt` (written atomically every --checkpoint-every steps and at the
end; tensors and plain values only, so it loads with weights_only=True), `log.jsonl` (one line per
logged step and per evaluation, with wall and CPU time and RSS: the PSNR-vs-CPU-hours curve) and,
from `hypergs export`, the weights.
"""
from __future__ import annotations

import json
import math
import os
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
import torch.distributed as dist
import torch.nn.functional as F
from torch.optim.swa_utils import AveragedModel, get_ema_multi_avg_fn
from torch.profiler import ProfilerActivity, profile, record_function, schedule

from ..encode import working_frames
from ..errors import HyperGSError
from ..gaussians import lattice_anchors
from ..io.frames import read_frames
from .. import raster
from ..metrics import psnr, psnr_from_mse
from ..model import PRESETS, ConvGS, anchor_inputs, build_model
from ..render import render_torch
from . import data, int8
from .export import load_checkpoint, recorded_info
from .optim import Lamb, parameter_groups
from .regularizers import AdaptiveRegularizer
from .sources import make_batch

EVAL_SIZE = 256  # evaluation frames: 256 x 256
EVAL_CELLS = (8, 4)  # source pixels per Gaussian at evaluation: 1024 and 4096 Gaussians on 256 x 256
# Options whose default depends on the design (each measured on it): learning rate, gradient clipping, clips per step.
ARCH_DEFAULTS = {"conv": dict(lr=1e-3, clip=0.5, batch=8, loss="mse"),
                 "transformer": dict(lr=2e-3, clip=1.0, batch=4, loss="mse")}
LOSSES = ("mse", "psnr")
PRECISIONS = ("auto", "float32", "bfloat16")
# psnr loss: a frame's error counts down to this MSE (50 dB; an 8-bit frame's own rounding is ~59 dB)
PSNR_LOSS_FLOOR = 1e-5
# --flat-weight: a pixel is flat where the clean frame's std over the FLAT_WINDOW x FLAT_WINDOW pixels
# around it is below FLAT_STD in every channel: eval's flat-ripple criterion (metrics.flat_ripple, 1/255)
# at the training frames' scale (two 4-px cells).
FLAT_STD = 1 / 255
FLAT_WINDOW = 9
# Options of this sitting (the machine, how long), not of the run: a resume never takes them from the checkpoint.
SITTING_OPTIONS = frozenset({"out", "minutes", "threads", "loader_threads", "precision", "profile", "given",
                             "command"})
# The sitting's own options that set how fast it runs: a resume does not keep them (another machine, another
# device) but says where they differ from the last sitting's, since a silent change costs hours (a run started
# with --precision bfloat16 on a CPU and resumed without it trains in float32).
SITTING_SPEED_OPTIONS = ("precision", "threads", "loader_threads")
# Options that built the network and its optimizer's parameter groups: a resumed run cannot change them.
FIXED_OPTIONS = ("preset", "parametrization", "config", "init_from", "distill", "lr_scale", "train_only", "int8")
# --int8: the activation ranges are calibrated on this many batches, drawn at steps no schedule reaches
INT8_CALIBRATION_BATCHES = 16
INT8_CALIBRATION_STEP = 1 << 40
# --steps auto: the schedule's length, set at the end of the warm-up (whose learning rates do not depend
# on it) from the sitting's step rate so far, for this share of the --minutes left (evaluations and
# checkpoints take the rest)
AUTO_STEPS = "auto"
AUTO_TIME_SHARE = 0.95
AUTO_MIN_WARMUP = 10


def cosine_lr(step: int, total: int, warmup: int, base: float, min_ratio: float) -> float:
    if step < warmup:
        return base * (step + 1) / warmup
    t = min(1.0, (step - warmup) / max(1, total - warmup))
    return base * (min_ratio + (1 - min_ratio) * 0.5 * (1 + math.cos(math.pi * t)))


def gaussians_for_step(spec: str, seed: int, step: int) -> int:
    lo, hi = (int(v) for v in spec.split(":")) if ":" in spec else (int(spec),) * 2
    rng = np.random.default_rng([seed, step, 7919])
    return int(round(math.exp(rng.uniform(math.log(lo), math.log(hi)))))


def rss_mb() -> float:
    """Resident memory of this process (MiB), 0 where /proc is missing."""
    try:
        with open("/proc/self/statm") as f:
            return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20
    except (OSError, ValueError):
        return 0.0


def step_profiler(steps: int, device: torch.device, out: Path):
    """torch.profiler over `steps` training steps after one warm-up step, started; when they are done it
    writes out/profile.txt: the ops and the phases (the loop's record_function labels: data, forward,
    backward, optimizer; the raster's plan) by their own time, the GPU's on a GPU."""
    cuda = device.type == "cuda"

    def write(prof):
        table = prof.key_averages().table(sort_by="self_cuda_time_total" if cuda else "self_cpu_time_total",
                                          row_limit=40)
        (out / "profile.txt").write_text(f"{steps} training steps on {device}\n{table}\n")

    profiler = profile(activities=[ProfilerActivity.CPU] + ([ProfilerActivity.CUDA] if cuda else []),
                       schedule=schedule(wait=0, warmup=1, active=steps, repeat=1), on_trace_ready=write)
    profiler.start()
    return profiler


class Prefetcher:
    """Builds the next `depth` batches in worker threads while the current step runs (the pixel work
    runs in nogil Numba kernels). make(step) is a pure function of the step, so the batches, and an
    exact resume, do not depend on how many workers there are."""

    def __init__(self, make, depth: int = 1):
        from concurrent.futures import ThreadPoolExecutor

        self.make, self.depth, self.pending = make, depth, {}
        self.pool = ThreadPoolExecutor(max_workers=depth, thread_name_prefix="prefetch")

    def get(self, step: int, last: int):
        """The batch of `step`; queues steps up to step + depth (below `last`) behind it."""
        for s in range(step, min(step + self.depth + 1, last)):
            if s not in self.pending:
                self.pending[s] = self.pool.submit(self.make, s)
        return self.pending.pop(step).result()

    def close(self):
        self.pool.shutdown(wait=False, cancel_futures=True)


def lattice_for_step(n: int, seed: int, step: int, rank: int, clips: int) -> tuple[int, np.ndarray]:
    """The transformer's anchors at a step: a k x k lattice (k = round(sqrt(n))) at a random phase per
    clip [clips, 2], as the windows of a tiled frame cut the lattice (gaussians.lattice_anchors); a pure
    function of (seed, step, rank), like the batch."""
    k = max(1, round(math.sqrt(n)))
    return k, np.random.default_rng([seed, step, rank, 104729]).random((clips, 2), dtype=np.float32)


def frame_loss(per_frame_mse: torch.Tensor, loss: str) -> torch.Tensor:
    """The data term from the frames' MSEs. mse: their mean. psnr: the gradient of the frames' mean
    PSNR (of mean log MSE): each frame's MSE weighted by the inverse of its own (fixed in the step),
    the weights normalised to mean 1 so that the loss keeps an MSE's size next to the regularizers.
    Under plain MSE a smooth frame at 40 dB weighs a tenth of a detailed one at 30 dB, so the
    network never learns to render it flat; eval reports the frames' mean PSNR."""
    if loss == "mse":
        return per_frame_mse.mean()
    weights = 1 / (per_frame_mse.detach() + PSNR_LOSS_FLOOR)
    return torch.mean(weights / weights.mean() * per_frame_mse)


def box_sum(x: torch.Tensor, window: int) -> torch.Tensor:
    """[N, C, H, W] -> the sums over the window x window pixels around each pixel (zero outside the frame;
    window odd), as two 1-D depthwise convolutions: 18x faster than avg_pool2d's 2-D window on a CPU,
    which made --flat-weight's steps 1.4-1.6x slower. In x's precision under the training step's autocast too
    (in bfloat16 a 9 x 9 sum of values near 1 is 2 % off: the flat criterion's std is 1/255)."""
    c, half = x.shape[1], window // 2
    with torch.autocast(x.device.type, enabled=False):
        x = F.conv2d(x, x.new_ones(c, 1, window, 1), padding=(half, 0), groups=c)
        return F.conv2d(x, x.new_ones(c, 1, 1, window), padding=(0, half), groups=c)


def flat_pixel_weights(frames: torch.Tensor, flat_weight: float) -> torch.Tensor:
    """[..., H, W, 3] frames -> [..., H, W, 1] weights: 1 + flat_weight where the pixel is flat (FLAT_STD,
    FLAT_WINDOW), else 1. Under plain MSE a ripple of 1/255 in a flat region costs a thousandth of a
    30-dB frame's error, so nothing teaches the network to render flat regions flat."""
    shape = frames.shape
    x = frames.reshape(-1, *shape[-3:]).permute(0, 3, 1, 2).float()
    moments = box_sum(torch.cat([x, x * x], 1), FLAT_WINDOW) / box_sum(torch.ones_like(x[:1, :1]), FLAT_WINDOW)
    mean, square = moments.chunk(2, 1)
    std = (square - mean * mean).clamp_min(0).sqrt()
    flat = (std < FLAT_STD).all(1, keepdim=True).permute(0, 2, 3, 1)
    return (1 + flat_weight * flat.to(frames.dtype)).reshape(*shape[:-1], 1)


def forward_autocast(device: torch.device, precision: str = "auto") -> torch.autocast:
    """The autocast the training step's forward pass runs in (--precision): "auto" is bfloat16 on CUDA,
    float32 on a CPU. The network's convolutions then run in bfloat16; its geometry, the render and the
    weights stay float32 (ConvGS.forward casts its head's output)."""
    if precision not in PRECISIONS:
        raise ValueError(f"unknown precision {precision!r} ({', '.join(PRECISIONS)})")
    if precision == "auto":
        precision = "bfloat16" if device.type == "cuda" else "float32"
    return torch.autocast(device.type, dtype=torch.bfloat16, enabled=precision == "bfloat16")


# oneDNN keeps up to 1,024 compiled kernels (its primitive cache), one per input shape. A bfloat16 forward on a CPU
# compiles new ones as the Gaussian count, and so the token count, changes from step to step: session 39's transformer
# run grew from 2.3 to 6.8 GB over 1,600 steps; with 16 kept it stayed at 2.1 GB over 120 steps where the default
# reached 3.4, at the same speed (the transformer's model card).
BFLOAT16_CPU_KERNEL_CACHE = 16


def bound_kernel_cache(device: torch.device, precision: str) -> None:
    """Cap oneDNN's primitive cache for a bfloat16 run on a CPU (a user's own ONEDNN_PRIMITIVE_CACHE_CAPACITY
    wins). oneDNN reads the variable at its first primitive, so this runs before the model computes anything."""
    if precision == "bfloat16" and device.type == "cpu":
        os.environ.setdefault("ONEDNN_PRIMITIVE_CACHE_CAPACITY", str(BFLOAT16_CPU_KERNEL_CACHE))


def training_loss(model, frames: torch.Tensor, lattice: tuple[int, np.ndarray] | None, regularizer,
                  inputs: torch.Tensor | None = None, loss: str = "mse",
                  flat_weight: float = 0.0) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """(loss, mse, regularizer stats) of one batch of clips [B, T, S, S, 3]; lattice: the transformer's
    (k, phase per clip), see lattice_for_step (the conv network's Gaussians are its cells). inputs: what
    the (conv) network sees instead of the frames, e.g. the frames with noise (the render is compared
    with the frames). loss: the data term, one of LOSSES (frame_loss), of the frames' MSEs weighted per pixel
    by flat_pixel_weights when flat_weight > 0 (the returned mse stays the plain one, for the log)."""
    b, t, size = frames.shape[:3]
    if isinstance(getattr(model, "module", model), ConvGS):
        frames = frames.reshape(b * t, size, size, 3)
        params = model(frames if inputs is None else inputs.reshape(b * t, size, size, 3)).float()
    else:
        k, phase = lattice
        anchors = torch.from_numpy(lattice_anchors(k, phase)).to(frames.device)
        params = model(frames, anchors, torch.tensor([2.0 / k], device=frames.device)).float()
    error = (render_torch(params, size, size, size, size) - frames) ** 2
    per_frame_mse = torch.mean(error, dim=(-3, -2, -1))
    if flat_weight > 0:
        weights = flat_pixel_weights(frames, flat_weight)
        data_loss = frame_loss(torch.sum(weights * error, dim=(-3, -2, -1)) / (3 * weights.sum(dim=(-3, -2, -1))), loss)
    else:
        data_loss = frame_loss(per_frame_mse, loss)
    mse = per_frame_mse.mean()
    if regularizer is None:
        return data_loss, mse, {}
    # Scales in grid cells (the anchor spacing, size / k canvas pixels): the thresholds then hold for
    # every Gaussian count drawn (in canvas pixels the EMA, set by the steps with many small Gaussians,
    # penalised every Gaussian of a step with few large ones).
    reg_loss, stats = regularizer(params[..., 2:4] * (lattice[0] / size))
    return data_loss + reg_loss, mse, stats


def warm_start(model, path, rank: int = 0) -> None:
    """Copy the weights of `path` (.safetensors) whose name and shape the model has: the same design
    continues, and a new part (another stem, a new branch) keeps its initialisation (new branches
    start at zero, so the warm-started network starts as the one it came from). A residual block with
    fewer middle channels than in `path` takes the most important of them (|conv a's filter| x |conv
    b's weights from it|): structured pruning, which --distill then repairs. Names what was left."""
    from safetensors.torch import load_file
    weights = load_file(str(path))
    own = model.state_dict()
    for key in [k for k in own if k.endswith(".a.weight") and k in weights]:
        block = key[:-len("a.weight")]
        a, b = weights[key], weights[block + "b.weight"]
        keep = own[key].shape[0]
        if a.shape[0] > keep and a.shape[1:] == own[key].shape[1:]:
            importance = a.flatten(1).norm(dim=1) * b.transpose(0, 1).flatten(1).norm(dim=1)
            chosen = importance.topk(keep).indices.sort().values
            weights[key], weights[block + "a.bias"] = a[chosen], weights[block + "a.bias"][chosen]
            weights[block + "b.weight"] = b[:, chosen]
    taken = {k: v for k, v in weights.items() if k in own and own[k].shape == v.shape}
    model.load_state_dict(taken, strict=False)
    left = sorted(set(own) - set(taken))
    if rank == 0 and left:
        print(f"warm start from {path}: {len(taken)} tensors; kept at initialisation: {', '.join(left)}", flush=True)


def check_parts(model, names, flag: str) -> None:
    """Raises HyperGSError, naming the network's top-level parts, where `names` holds one that is not a part
    (a module's dotted name: `encoder`, or `encoder.0.4` for one block of it)."""
    modules = {name for name, _ in model.named_modules() if name}
    unknown = sorted(set(names) - modules)
    if unknown:
        parts = sorted(name for name, _ in model.named_children())
        raise HyperGSError(f"{flag}: {', '.join(unknown)} not parts of this network ({', '.join(parts)}, "
                           "or a dotted name inside one)")


def part_of(parameter_name: str, parts) -> str | None:
    """The most specific of `parts` (dotted module names) that holds the parameter, or None."""
    holding = [part for part in parts if parameter_name.startswith(part + ".")]
    return max(holding, key=len, default=None)


def train_only(model, parts) -> None:
    """Freeze every parameter outside `parts` (--train-only)."""
    check_parts(model, parts, "--train-only")
    for name, parameter in model.named_parameters():
        parameter.requires_grad_(part_of(name, parts) is not None)


def lr_groups(model, lr_scale: dict) -> list[dict]:
    """The trainable parameters in AdamW groups: one per learning-rate factor, the parameters of each part
    named in `lr_scale` (part -> factor) with its factor, the most specific part deciding (`encoder=0.1
    encoder.0.4=1`: a new block at the full rate in a slow encoder), the rest with 1."""
    check_parts(model, lr_scale, "--lr-scale")
    groups = {}
    for name, parameter in model.named_parameters():
        if parameter.requires_grad:
            groups.setdefault(float(lr_scale.get(part_of(name, lr_scale), 1.0)), []).append(parameter)
    return [dict(params=params, lr_scale=scale) for scale, params in groups.items()]


def with_noise(frames: np.ndarray, max_std: float, seed: int, step: int, rank: int) -> np.ndarray:
    """The frames (float32 numpy, in [0, 1]) plus Gaussian noise of a standard deviation drawn per frame,
    uniformly in [0, max_std] (in 1/255), quantised to 8 bits like a video frame: what the network sees
    when it learns that a flat region with a camera's noise in it is still flat. A pure function of
    (seed, step, rank). Numpy, so that the loader threads make it beside the batch (at batch 64 it took
    60 ms of a GPU step's main thread)."""
    rng = np.random.default_rng([int(seed), int(step), int(rank), 4099])
    shape = frames.shape
    std = rng.uniform(0, max_std / 255, (shape[0],) + (1,) * (len(shape) - 1)).astype(np.float32)
    noisy = frames + rng.standard_normal(shape, dtype=np.float32) * std
    return (np.round(np.clip(noisy, 0, 1) * 255) / 255).astype(np.float32)


def distillation_loss(model, teacher, frames: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, dict]:
    """(loss, mse, stats): the network's cell features (its head's input) against the teacher's on one
    batch of frames, the mean squared difference over the teacher's feature variance (the fraction not
    reproduced); `mse` is the network's render MSE, for the log."""
    size = frames.shape[2]
    frames = frames.reshape(-1, size, size, 3)
    x = (frames.permute(0, 3, 1, 2) - 0.5) * 2
    with torch.no_grad():
        target = teacher.features(x)
    student = getattr(model, "module", model)
    loss = torch.mean((student.features(x) - target) ** 2) / target.var()
    with torch.no_grad():
        mse = torch.mean((render_torch(student(frames).float(), size, size, size, size) - frames) ** 2)
    return loss, mse, {"unexplained": round(float(loss.detach()), 5)}


def resume_options(args, recorded: dict) -> list[str]:
    """A resumed run keeps the options it started with (`recorded`, the checkpoint's), but for the sitting's
    own (SITTING_OPTIONS) and those this command line gives (`args.given`, commands/train.py; a namespace
    without it gives all): `--steps 4000` alone continues the run's schedule, data, loss and learning rate.
    Sets them on args; returns the given ones that differ from the record ("--lr 0.0005 (was 0.0003)"), and the
    SITTING_SPEED_OPTIONS left to their defaults that differ from the last sitting's ("--precision auto (the last
    sitting's: bfloat16)"). Raises HyperGSError where a given option would change the network (FIXED_OPTIONS)."""
    given = getattr(args, "given", None)
    given = set(vars(args)) if given is None else set(given)
    changed = []
    for key, was in recorded.items():
        if not hasattr(args, key):
            continue
        flag, now = "--" + key.replace("_", "-"), getattr(args, key)
        if key in SITTING_OPTIONS:
            if key in SITTING_SPEED_OPTIONS and key not in given and now != was:
                changed.append(f"{flag} {'unset' if now is None else now} (the last sitting's: {was})")
            continue
        if key not in given:
            setattr(args, key, was)
            continue
        now = json.loads(json.dumps(_plain({key: now})))[key]
        if now == was or (key in ("config", "lr_scale", "train_only") and not now and not was):
            continue
        if key in FIXED_OPTIONS:
            raise HyperGSError(f"{flag} {now}: the run in {args.out} was started with {flag} {was}, and a run keeps "
                               f"its network; start a new run (another --out), e.g. with --init-from its export")
        changed.append(f"{flag} {now} (was {was})")
    return changed


def auto_steps(step: int, steps_done: int, seconds: float, budget_seconds: float, broadcast_device=None) -> int:
    """--steps auto: the schedule's total once `steps_done` steps of this sitting took `seconds` of its
    `budget_seconds`: the steps that fit in AUTO_TIME_SHARE of the time left at that rate (at least one
    more). Under torchrun rank 0's number, broadcast (broadcast_device: the tensors' device), so that
    every rank runs the same schedule."""
    left = max(0.0, budget_seconds - seconds) * AUTO_TIME_SHARE
    total = step + max(1, int(steps_done / max(seconds, 1e-9) * left))
    if broadcast_device is not None:
        value = torch.tensor([total], device=broadcast_device)
        dist.broadcast(value, 0)
        total = int(value)
    return total


def run(args) -> None:
    """Train with the options of `hypergs train` (commands/train.py), resuming from args.out."""
    out = Path(args.out)
    checkpoint_path = out / "checkpoint.pt"
    resume = load_checkpoint(checkpoint_path) if checkpoint_path.exists() else None
    changed = resume_options(args, json.loads(resume["args"])) if resume else []
    if args.distill and not args.init_from:
        raise HyperGSError("--distill needs --init-from: a warm start whose head reads the teacher's features")
    if args.steps == AUTO_STEPS and (args.minutes is None or args.warmup < AUTO_MIN_WARMUP):
        raise HyperGSError(f"--steps auto sizes the schedule to --minutes from the step rate of the warm-up: give "
                           f"--minutes and a --warmup of {AUTO_MIN_WARMUP} steps or more")
    distributed = "RANK" in os.environ
    if distributed:
        dist.init_process_group("nccl" if torch.cuda.is_available() else "gloo")
    rank = dist.get_rank() if distributed else 0
    device = torch.device(f"cuda:{int(os.environ.get('LOCAL_RANK', 0))}" if torch.cuda.is_available() else "cpu")
    if device.type == "cuda":
        torch.cuda.set_device(device)
    if args.threads:
        torch.set_num_threads(args.threads)
        raster.set_threads(args.threads)
    bound_kernel_cache(device, args.precision)

    out.mkdir(parents=True, exist_ok=True)
    config = json.loads(resume["config"]) if resume else asdict(PRESETS[args.preset])
    if not resume and args.parametrization:
        config["parametrization"] = args.parametrization
    if not resume:
        config.update(args.config or {})
    for key, value in ARCH_DEFAULTS[config["arch"]].items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    torch.manual_seed(args.seed)
    model = build_model(config).to(device)
    conv = isinstance(model, ConvGS)
    teacher = None
    if not resume and args.init_from:  # warm start from exported weights (see warm_start)
        warm_start(model, args.init_from, rank)
    if args.distill and not conv:
        raise HyperGSError("--distill trains the conv network's cell features; this run is a transformer")
    if args.distill:  # the teacher's features, read by the warm start's head, kept as it came
        from ..network import load_model
        teacher = load_model(Path(args.distill).parent, Path(args.distill).stem).to(device)
        for name, parameter in model.named_parameters():
            parameter.requires_grad_(not name.startswith("head."))
    if args.int8 and (args.distill or not conv):
        raise HyperGSError("--int8 trains the conv network with its convolutions in int8, without --distill")
    if args.int8 and not args.init_from:
        raise HyperGSError("--int8 needs --init-from: its activation ranges are measured on a trained network")
    if args.train_only:
        if args.distill or not conv:
            raise HyperGSError("--train-only trains parts of a warm-started conv network, without --distill")
        train_only(model, args.train_only)
    # the paper's thresholds (s0 32 px, ceiling 80 px at its 8 px spacing: N = 1000 on 256^2) in grid cells
    regularizer = None if conv else AdaptiveRegularizer(s0=4.0, scale_ceiling=10.0).to(device)
    if regularizer is not None and not resume and args.init_from:
        # go on from the thresholds the warm start's own run adapted (its card records them): restarting
        # them at the paper's values would penalise its Gaussians against thresholds it had left behind
        thresholds = ((recorded_info(args.init_from) or {}).get("train_args") or {}).get("regularizer")
        if thresholds:
            regularizer.load_state_dict({k: torch.tensor(float(v)) for k, v in thresholds.items()})
    if conv:
        # a run keeps the parameter groups it started with (a checkpoint's optimizer state needs them)
        optimizer = torch.optim.AdamW(lr_groups(model, dict(args.lr_scale or {})), lr=args.lr, weight_decay=1e-4)
    else:
        optimizer = Lamb(parameter_groups(model), lr=args.lr, weight_decay=0.01)
    step, wall, cpu = 0, 0.0, 0.0
    if resume:
        model.load_state_dict(resume["model"])
        if regularizer is not None:
            regularizer.load_state_dict(resume["regularizer"])
        optimizer.load_state_dict(resume["optimizer"])
        step, wall, cpu = int(resume["step"]), float(resume["wall_seconds"]), float(resume["cpu_seconds"])
        if args.steps == AUTO_STEPS and step >= args.warmup:
            raise HyperGSError(f"--steps auto: the run in {out} is past its warm-up (step {step}), so its schedule "
                               f"is set; give --steps N to change its length")
        torch.set_rng_state(resume["torch_rng"])
    # The weights' moving average: batches of 8 make noisy steps, and the average over the last 1/(1 - decay)
    # of them sits nearer the minimum than the last step does. Turned on for a resumed run that had none,
    # its first update takes the run's weights as they are.
    averaged = None
    if args.ema:
        averaged = AveragedModel(model, multi_avg_fn=get_ema_multi_avg_fn(args.ema))
        if resume and "ema" in resume:
            averaged.load_state_dict(resume["ema"])
    train_model = torch.nn.parallel.DistributedDataParallel(model) if distributed else model

    sources = data.build_sources(args.data, args.data_root)
    frames_per_clip = 1 if conv else model.cfg.clip_frames
    size = args.size if conv else model.cfg.canvas
    noise = args.input_noise if teacher is None else 0.0

    def batch(s, r=rank):  # (clean frames, what the network sees: the frames with noise, or None)
        frames = make_batch(sources, args.seed, s, r, args.batch, frames_per_clip, size)
        return frames, with_noise(frames, noise, args.seed, s, r) if noise else None

    int8_ranges = resume.get("int8") if resume else None
    if args.int8 and int8_ranges is None:
        def calibration_batches():  # rank 0's in every process, so that all get the same ranges
            for s in range(INT8_CALIBRATION_STEP, INT8_CALIBRATION_STEP + INT8_CALIBRATION_BATCHES):
                frames, noisy = batch(s, 0)
                yield torch.from_numpy(frames if noisy is None else noisy)[:, 0].to(device)

        int8_ranges = int8.calibrate(model, calibration_batches())
    if int8_ranges:
        int8.fake_quantize(model, int8_ranges)
    prefetch = Prefetcher(batch, args.loader_threads)
    evaluator = Evaluator(model, args.data_root, args.eval_videos) if rank == 0 else None
    log = open(out / "log.jsonl", "a") if rank == 0 else None
    if rank == 0:
        print(f"training {config['arch']} model, {sum(p.numel() for p in model.parameters()) / 1e6:.2f}M "
              f"parameters, from step {step} of {args.steps} on {device} -> {out}"
              + (f"; the run's options but {', '.join(changed)}" if changed else "")
              + ("; the weights' moving average starts here" if averaged is not None and resume
                 and "ema" not in resume else ""), flush=True)

    def save():
        state = dict(model=model.state_dict(), optimizer=optimizer.state_dict(), step=step, wall_seconds=wall,
                     cpu_seconds=cpu, config=json.dumps(config), args=json.dumps(_plain(vars(args))),
                     torch_rng=torch.get_rng_state(), sigma_cutoff=raster.SIGMA_CUTOFF)
        if regularizer is not None:
            state["regularizer"] = regularizer.state_dict()
        if averaged is not None:
            state["ema"] = averaged.state_dict()
        if int8_ranges:
            state["int8"] = int8_ranges
        tmp = checkpoint_path.with_suffix(".tmp")
        torch.save(state, tmp)
        os.replace(tmp, checkpoint_path)

    from tqdm import tqdm
    bar = tqdm(total=None if args.steps == AUTO_STEPS else args.steps, initial=step, disable=rank != 0,
               dynamic_ncols=True, mininterval=5)
    started, cpu_started, run_started = time.perf_counter() - wall, time.process_time() - cpu, time.perf_counter()
    sitting_first_step = step
    amp = forward_autocast(device, args.precision)
    profiler = step_profiler(args.profile, device, out) if args.profile and rank == 0 else None
    try:
        while args.steps == AUTO_STEPS or step < args.steps:
            with record_function("data"):
                frames, inputs = (None if a is None else torch.from_numpy(a).to(device)
                                  for a in prefetch.get(step, math.inf if args.steps == AUTO_STEPS else args.steps))
            n = gaussians_for_step(args.gaussians, args.seed, step)
            lattice = None if conv else lattice_for_step(n, args.seed, step, rank, frames.shape[0])
            lr = cosine_lr(step, args.steps, args.warmup, args.lr, args.min_lr_ratio)
            for group in optimizer.param_groups:
                group["lr"] = lr * group.get("lr_scale", 1.0)
            with amp, record_function("forward"):
                if teacher is None:
                    loss, mse, stats = training_loss(train_model, frames, lattice, regularizer, inputs, args.loss,
                                                     args.flat_weight)
                else:
                    loss, mse, stats = distillation_loss(train_model, teacher, frames)
            optimizer.zero_grad(set_to_none=True)
            with record_function("backward"):
                loss.backward()
            with record_function("optimizer"):
                grad_norm = float(torch.nn.utils.clip_grad_norm_([p for p in model.parameters() if p.requires_grad],
                                                                 args.clip))
                optimizer.step()
                if averaged is not None:
                    averaged.update_parameters(model)
            if profiler is not None:
                profiler.step()
            step += 1
            wall, cpu = time.perf_counter() - started, time.process_time() - cpu_started
            if args.steps == AUTO_STEPS and step >= args.warmup:
                seconds = time.perf_counter() - run_started
                args.steps = bar.total = auto_steps(step, step - sitting_first_step, seconds, args.minutes * 60,
                                                    device if distributed else None)
                if rank == 0:  # tqdm.write prints on a disabled bar too
                    bar.write(f"--steps auto: {args.steps} steps ({(step - sitting_first_step) / seconds:.2f} "
                              f"steps/s over the warm-up)")
            if rank == 0:
                train_psnr = float(psnr_from_mse(float(mse.detach())))
                bar.set_postfix(psnr=f"{train_psnr:.2f}", refresh=False)
                bar.update(1)
                if step % args.log_every == 0:
                    record = dict(step=step, wall=round(wall, 1), cpu=round(cpu, 1), lr=lr, loss=float(loss.detach()),
                                  psnr=round(train_psnr, 3), grad_norm=round(grad_norm, 4), rss_mb=round(rss_mb()),
                                  **stats)
                    if not conv:
                        record["n"] = lattice[0] ** 2
                    log.write(json.dumps(record) + "\n")
                    log.flush()
                if step % args.checkpoint_every == 0 or step == args.steps:
                    save()
                if step % args.eval_every == 0 or step == args.steps:
                    model.eval()
                    record = dict(step=step, wall=round(wall, 1), cpu=round(cpu, 1), eval=evaluator(model, device))
                    model.train()
                    if averaged is not None:
                        record["eval"].update({f"ema_{k}": v for k, v in evaluator(averaged.module, device).items()})
                    log.write(json.dumps(record) + "\n")
                    log.flush()
                    bar.write(f"step {step} cpu {cpu / 3600:.2f} h eval {json.dumps(record['eval'])}")
            if args.minutes is not None and time.perf_counter() - run_started > args.minutes * 60:
                break
    finally:
        if profiler is not None:
            profiler.stop()
        prefetch.close()
        if rank == 0:
            save()
            bar.close()
            print(f"stopped at step {step}, {cpu / 3600:.2f} CPU hours ({wall / 3600:.2f} h wall) of training; "
                  f"checkpoint {checkpoint_path}", flush=True)
        if distributed:
            dist.destroy_process_group()


def _plain(values: dict) -> dict:
    return {k: (str(v) if isinstance(v, Path) else v) for k, v in values.items() if not callable(v) and k != "given"}


class Evaluator:
    """PSNR on fixed held-out frames at 256 x 256 at two densities (1024 and 4096 Gaussians): the held-out
    photos' pans and procedural clips (`val`), and, for reporting only (never for training decisions),
    the videos given with --eval-videos. Conv models encode the frames as encode.py does (resized to the
    working size); transformers on their canvas. The inputs are resized once, here (a machine that
    cannot resize fails at the start of a run, not at its first evaluation)."""

    def __init__(self, model, data_root: str, videos=(), frames_per_video: int = 4):
        clips = data.validation_clips(data_root, 2, EVAL_SIZE, 8)
        targets = {"val": (clips.reshape(-1, EVAL_SIZE, EVAL_SIZE, 3) * 255 + 0.5).astype(np.uint8)}
        for path in map(Path, videos):
            targets[f"video_{path.stem}"] = read_frames(path, frames_per_video, size=EVAL_SIZE)[0]
        # name -> (target frames, {cell: network input})
        self.sets = {name: (frames, {cell: self._input(model, frames, cell) for cell in EVAL_CELLS})
                     for name, frames in targets.items()}

    @staticmethod
    def _input(model, frames: np.ndarray, cell: int) -> np.ndarray:
        if isinstance(model, ConvGS):
            work = EVAL_SIZE * model.cfg.stride // cell
            return working_frames(frames, work, work)
        canvas, t = model.cfg.canvas, model.cfg.clip_frames
        clips = working_frames(frames, canvas, canvas)
        return clips.reshape(-1, t, canvas, canvas, 3)  # the evaluation sets hold multiples of 4 frames

    @torch.no_grad()
    def __call__(self, model, device) -> dict:
        results = {}
        for name, (frames, inputs) in self.sets.items():
            target = torch.from_numpy(frames).float().to(device) / 255
            for cell, cell_inputs in inputs.items():
                params = self._encode(model, cell_inputs, cell, device)
                render = render_torch(params, EVAL_SIZE, EVAL_SIZE, EVAL_SIZE, EVAL_SIZE)
                n = (EVAL_SIZE // cell) ** 2
                results[f"{name}_n{n}"] = round(float(psnr(render, target).mean()), 3)
        return results

    @staticmethod
    def _encode(model, inputs: np.ndarray, cell: int, device) -> torch.Tensor:
        n = (EVAL_SIZE // cell) ** 2
        if isinstance(model, ConvGS):
            params = model(torch.from_numpy(inputs).to(device)).float()
            params[..., 2:4] *= cell / model.cfg.stride  # working pixels -> 256 x 256 pixels
            return params
        anchors, spacing = anchor_inputs(n, device)
        params = model(torch.from_numpy(inputs).to(device), anchors, spacing).float().reshape(-1, n, 8)
        params[..., 2:4] *= EVAL_SIZE / model.cfg.canvas
        return params
