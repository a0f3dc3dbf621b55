"""Training checkpoint of either design -> the weights the runtime loads (network.py):
<name>.safetensors (tensors, for torch), <name>.json (the card: which design (`arch`), its config, the
geometry its encoder needs, training info) and <name>.onnx (onnxruntime, dynamic batch; the conv
network: one graph for every frame size, hence every Gaussian count; the transformer: anchors and
cell size are inputs, one graph for every Gaussian count its parametrization allows)."""
from __future__ import annotations

import json
from pathlib import Path

from ..errors import HyperGSError, reason
from ..io.files import AtomicOutput, write_bytes
from ..network import DEFAULT_NAMES, card_sigma_cutoff, load_model, read_card, transformer_geometry
from ..raster import SIGMA_CUTOFF

# Opset 20 has GELU as one op (Gelu): at 18 the exporter spells it out (Erf, Mul, Add), which onnxruntime
# does not fuse back, and around each of those ops its NCHWc conv layout is reordered; the one op cuts a
# 1080p Standard frame's CPU time by 21 % (0.84 -> 0.65 s, one thread), with the same output.
ONNX_OPSET = 20


def card_of(model, info: dict | None = None, int8: dict | None = None) -> dict:
    """int8: the conv network's activation ranges, where its ONNX model runs in int8 (training.int8)."""
    from ..model import model_config
    cfg = model.cfg
    if cfg.arch == "transformer":
        trained = (info or {}).get("train_args", {}).get("gaussians")
        geometry = transformer_geometry(cfg, gaussian_range(trained) if trained else None)
    else:
        geometry = dict(stride=cfg.stride, multiple=cfg.multiple, reach=cfg.reach)
    card = dict(arch=cfg.arch, config=model_config(model), geometry=geometry, sigma_cutoff=SIGMA_CUTOFF,
                info=info or {})
    if int8:
        card["int8"] = int8
    return card


def gaussian_range(spec: str) -> tuple[int, int]:
    """'N' or 'MIN:MAX' (train --gaussians) -> (MIN, MAX)."""
    low, _, high = spec.partition(":")
    return int(low), int(high or low)


def save_weights(model, directory, name: str, info: dict | None = None, int8: dict | None = None) -> None:
    from safetensors.torch import save_file
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=True)
    with AtomicOutput(directory / f"{name}.safetensors") as temp:
        save_file({k: v.contiguous() for k, v in model.state_dict().items()}, str(temp))
    (directory / f"{name}.safetensors").chmod(0o644)  # safetensors writes 0600; the weights are for everyone
    write_bytes(directory / f"{name}.json", (json.dumps(card_of(model, info, int8), indent=2) + "\n").encode())


def export_onnx(model, path, int8: dict | None = None) -> None:
    """Either design, with a dynamic batch: the conv network with dynamic height and width (multiples
    of its `multiple`), the transformer with a dynamic Gaussian count (anchors [batch, N, 2]). int8: the
    conv network's activation ranges (its card's "int8"): its convolutions then run in int8 (training.int8)."""
    import tempfile

    import torch

    batch = torch.export.Dim("batch", max=4096)
    cfg = model.cfg
    if cfg.arch == "transformer":
        from ..gaussians import lattice_anchors
        frames = torch.rand(2, cfg.clip_frames, cfg.canvas, cfg.canvas, 3)
        k = 4
        anchors = torch.from_numpy(lattice_anchors(k, [(0.5, 0.5), (0.2, 0.7)]))
        most = 65536 if cfg.parametrization == "local" else cfg.max_gaussians  # "paper": its learned tokens
        gaussians = torch.export.Dim("gaussians", min=2, max=most)
        inputs, names = (frames, anchors, torch.tensor([2.0 / k])), ["frames", "anchors", "cell"]
        dynamic = {"frames": {0: batch}, "anchors": {0: batch, 1: gaussians}, "cell": None}
    else:
        m = cfg.multiple
        rows, cols = torch.export.Dim("rows", max=8192 // m), torch.export.Dim("cols", max=8192 // m)
        inputs, names = (torch.rand(2, 4 * m, 6 * m, 3),), ["frames"]
        dynamic = {"frames": {0: batch, 1: m * rows, 2: m * cols}}
    program = torch.onnx.export(model.eval(), inputs, input_names=names, output_names=["params"],
                                opset_version=ONNX_OPSET, dynamo=True, external_data=False, dynamic_shapes=dynamic)
    with AtomicOutput(path) as temp, tempfile.TemporaryDirectory() as folder:
        if int8:  # quantised from the float graph
            from .int8 import quantize_onnx
            program.save(str(Path(folder) / "float.onnx"))
            quantize_onnx(model, int8, Path(folder) / "float.onnx", temp)
        else:
            program.save(str(temp))


def rebox(directory, name: str) -> float | None:
    """Convert the weights <directory>/<name> trained for another box (network.card_sigma_cutoff) to this
    HyperGS's raster.SIGMA_CUTOFF, in place (safetensors, card, ONNX). Their colours c were fitted to that
    box; under this one, c x gain ratio (gaussians.lattice_gain) draws the same image up to the tails the
    boxes cut. Both designs compute c = COLOUR_GAIN x the cell's mean + the head's output, and COLOUR_GAIN
    follows the box, so scaling the head's colour rows by the ratio does it. Returns the old box, or None
    where the weights were already for this one."""
    import torch

    from ..gaussians import INITIAL_SIGMA, lattice_gain
    card = read_card(directory, name)
    old = card_sigma_cutoff(card)
    if old == SIGMA_CUTOFF:
        return None
    model = load_model(directory, name)
    if getattr(model.cfg, "parametrization", "local") != "local":
        raise HyperGSError(f"{name}: the {model.cfg.parametrization!r} parametrization's colours (a sigmoid) "
                           "cannot be rescaled; retrain it")
    if getattr(model, "error_pass", None) is not None:
        raise HyperGSError(f"{name}: its error pass reads the error of a render of these colours, which a rescale "
                           "would change; retrain it (hypergs train --init-from)")
    ratio = lattice_gain(INITIAL_SIGMA) / lattice_gain(INITIAL_SIGMA, old)
    with torch.no_grad():
        model.head.weight[5:8] *= ratio
        model.head.bias[5:8] *= ratio
    # The slow ONNX export first, the safetensors and the card (the box it records) last: stopped during the
    # export, the card and safetensors are the old ones, so the runtime refuses them and a second rebox
    # starts again from them
    # int8: the head's output range, measured before, still holds it: the rescale moves colours by under 1 %
    export_onnx(model, Path(directory) / f"{name}.onnx", card.get("int8"))
    info = card.get("info", {})  # reboxed_from: the box the colours were trained under, kept through conversions
    save_weights(model, directory, name, dict(info, reboxed_from=info.get("reboxed_from", old)), card.get("int8"))
    return old


def load_checkpoint(path) -> dict:
    """A training checkpoint, loaded with weights_only=True: tensors, numbers, strings and containers
    only, so a checkpoint from elsewhere cannot run code. Raises HyperGSError naming the file."""
    import pickle

    import torch
    try:
        state = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:
        raise HyperGSError(f"{path}: holds Python objects besides tensors and plain data; refused, as loading "
                           "it could run code") from None
    except (RuntimeError, EOFError, ValueError) as e:
        raise HyperGSError(f"{path}: not a readable checkpoint ({reason(e)})") from None
    if not isinstance(state, dict):
        raise HyperGSError(f"{path}: not a training checkpoint")
    # The colours a run learns are for the box it renders with: resumed or exported under another, they would
    # be wrong for it. Checkpoints record their box since session 22 (older ones: whatever box their code had).
    box = float(state.get("sigma_cutoff", SIGMA_CUTOFF))
    if box != SIGMA_CUTOFF:
        raise HyperGSError(f"{path}: trained under a {box:g}-sigma box, and this HyperGS renders with "
                           f"{SIGMA_CUTOFF:g}: resume or export it with the HyperGS that trained it, or start a new "
                           "run from its export (--init-from)")
    return state


def recorded_info(weights) -> dict | None:
    """The training record ("info") of the card beside exported weights (<name>.json next to
    <name>.safetensors), or None where there is no card."""
    card = Path(weights).with_suffix(".json")
    return json.loads(card.read_text()).get("info") if card.is_file() else None


def export_checkpoint(run, out, name: str | None = None, trained: bool = False) -> tuple[str, dict]:
    """Write the weights of `run`/checkpoint.pt into `out` as `name` (default: its design's name,
    network.DEFAULT_NAMES): their moving average where the run keeps one (train --ema), unless `trained`;
    returns the name and the training info recorded."""

    from ..model import build_model
    checkpoint_path = Path(run) / "checkpoint.pt"
    if not checkpoint_path.is_file():
        raise HyperGSError(f"{checkpoint_path}: no checkpoint")
    state = load_checkpoint(checkpoint_path)
    model = build_model(json.loads(state["config"]))
    args = json.loads(state["args"])
    average = state.get("ema") if not trained else None
    # AveragedModel's state: the network's tensors under "module.", and how many updates it has averaged
    model.load_state_dict({k.removeprefix("module."): v for k, v in average.items() if k.startswith("module.")}
                          if average else state["model"])
    keys = ("data", "batch", "size", "lr", "min_lr_ratio", "warmup", "clip", "steps", "seed", "preset", "config", "loss",
            "input_noise", "flat_weight")
    if model.cfg.arch == "transformer":
        keys = tuple(k for k in keys if k != "size") + ("gaussians",)  # it trains on its canvas, N per step
    train_args = {k: args[k] for k in keys if k in args}
    train_args.update({k: args[k] for k in ("lr_scale", "train_only") if args.get(k)})  # where a run used them
    for key in ("init_from", "distill"):  # the weights it started from, with their own card's record: the chain
        if args.get(key):
            train_args[key] = {"path": args[key], "info": recorded_info(args[key])}
    if "regularizer" in state:  # the transformer's adaptive thresholds, for the record
        train_args["regularizer"] = {k: round(float(v), 4) for k, v in state["regularizer"].items()}
    info = dict(step=int(state["step"]), cpu_hours=round(float(state["cpu_seconds"]) / 3600, 3),
                wall_hours=round(float(state["wall_seconds"]) / 3600, 3), train_args=train_args)
    if average:
        info["ema"] = dict(decay=args.get("ema"), updates=int(average["n_averaged"]))
    name = name or DEFAULT_NAMES[model.cfg.arch]
    save_weights(model, out, name, info, state.get("int8"))
    export_onnx(model, Path(out) / f"{name}.onnx", state.get("int8"))
    return name, info
