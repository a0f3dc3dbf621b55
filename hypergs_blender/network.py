"""The trained networks as encoders: weights on disk (a JSON card, .safetensors for torch, .onnx for
onnxruntime), the torch and onnxruntime backends behind one `predict(working frames, cells) ->
params` interface (encode.py), and `resolve_encoder`, the one place that picks an encoder (and says
plainly why one cannot load). The card's `arch` says which design the weights are:

- "conv" (the default, `NetworkEncoder`): large frames are encoded in tiles (`tiles`): windows of at
  most TILE working pixels a side that overlap by the network's reach, so every Gaussian is predicted
  from the same pixels as in one pass over the whole frame (seamless by construction), and memory is
  bounded.
- "transformer" (the paper's, `TransformerEncoder`): its input is a fixed canvas; a frame is encoded
  as the paper's patch grid of canvas-sized tiles (encode.TileLayout), a k x k lattice of Gaussians in
  each, through canvas-sized windows that overlap by a context margin; each window keeps the
  Gaussians of its core (`tiles` again), so every Gaussian was predicted with context on all sides,
  and those near a border between cores are the two windows' blend (SEAM_BLEND).

Memory (measured on a 1080p frame at the Standard density, a 1280 x 720 working frame): a forward
pass's activations are ~0.6 GB per working frame. onnxruntime keeps what a run allocated in its arena
for the session's life, and its memory pattern planner keeps a plan sized for every input shape it
saw: two frames per pass with the planner held 2.4 GB after a conversion. So one working frame per
pass (BATCH_PIXELS; no slower), no memory pattern (0.8 GB, no slower), and `release()` after a
conversion gives the arena back (0.3 GB).

Only the ONNX backend works without torch: inside Blender torch is usually absent (and the extension
ships no safetensors), and this module imports torch lazily.
"""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from . import optional
from .encode import BATCH_PIXELS, FloorEncoder, check_cells
from .errors import HyperGSError
from .gaussians import covariance, lattice_anchors, with_covariance
from .raster import SIGMA_CUTOFF

WEIGHTS_DIR = Path(__file__).resolve().parent / "weights"
BUNDLED_NAME = "hypergs"  # the bundled conv network, the default model
DEFAULT_NAMES = {"conv": BUNDLED_NAME, "transformer": "hypergs_transformer"}  # what `hypergs export` names each design
BACKENDS = ("auto", "torch", "onnx")
# The torch backend's arithmetic. "bfloat16" runs the convolutions and attention in bfloat16 (torch's autocast),
# the geometry and the error pass's render in float32 (model.full_precision). Measured (the model card's session
# 38; a Xeon with AMX, one thread): the conv network 1.5-1.8x faster, -0.15 to +0.002 dB per clip, most lost
# where the PSNR is highest (Aqua's 480^2 crops at 14,400 Gaussians: 52.92 -> 52.78); the transformer 2x faster,
# -0.02 to -0.08 dB. Without AMX it is slower at most sizes (1.2-5.7x; with AVX512-BF16 alone 1.35x faster at
# N = 1,024, 1.2x slower at 3,025). So float32 unless asked for: the same Gaussians on every CPU.
PRECISIONS = ("float32", "bfloat16")
TILE = 1536  # working pixels per tile side, margins included (a 720p frame at any density: one pass)
# The transformer's attention pairs (query x key tokens, all frames) per forward pass: onnxruntime holds
# each attention's scores whole (6 heads x 4 bytes each for `small`: ~200 MB), torch's kernel does not.
BATCH_PAIRS = 1 << 23
# Working pixels across which the transformer's Gaussians cross-fade from one window to the next where
# their cores meet (TransformerEncoder.predict): a Gaussian just inside a core sees less context beyond its
# border than its neighbour across it sees from inside, and a hard cut between the two shows as a seam.
# Measured (its card, session 41; grid 2, 8 frames): at N = 1000 per tile 16 px raised every clip's PSNR
# (+0.00 to +0.05 dB) and lowered the largest seam ratio (Aqua 1.097 -> 1.055); 32 px lowered it a little
# more and gave PSNR back (Aqua 39.04 -> 39.00 dB); at N = 3000, Aqua 42.92 -> 43.01 dB, seams 1.182 -> 1.105
# (32 px: 43.01, 1.099). No extra forward passes.
SEAM_BLEND = 16


def tiles(size: int, reach: int, multiple: int, tile: int = TILE) -> list[tuple[int, int, int, int]]:
    """Windows along one axis of `size` working pixels: (start, stop, core start, core stop), all of one
    length, each inside the frame, their cores covering [0, size) once, and each core at least `reach`
    pixels from its window's ends except where those are the frame's own ends. All multiples of
    `multiple`. One window when the frame fits in `tile`."""
    if size <= tile or size <= 2 * reach + multiple:
        return [(0, size, 0, size)]
    core = max(multiple, (tile - 2 * reach) // multiple * multiple)
    length = core + 2 * reach
    if length >= size:
        return [(0, size, 0, size)]
    out = []
    for c0 in range(0, size, core):
        c1 = min(size, c0 + core)
        start = min(max(0, c0 - reach), size - length)
        out.append((start, start + length, c0, c1))
    return out


def release_arena(session, tiny_inputs: dict) -> None:
    """Give back the memory onnxruntime's CPU arena kept from the passes so far: the arena frees the
    regions no tensor uses at the end of a run that asks for it, here one on `tiny_inputs`."""
    import onnxruntime as ort
    options = ort.RunOptions()
    options.add_run_config_entry("memory.enable_memory_arena_shrinkage", "cpu:0")
    session.run(None, tiny_inputs, options)


class NetworkEncoder:
    """Runs `forward(frames float32 [B, h, w, 3]) -> params [B, (h/stride)(w/stride), 8]` (a network on
    any backend) over working frames of any size, tiled (see the module doc). stride, multiple and
    reach are the network's (model.ConvConfig)."""

    def __init__(self, forward, stride: int, multiple: int, reach: int, name: str, tile: int = TILE,
                 session=None):
        self.forward, self.name, self.session = forward, name, session  # session: onnxruntime's, or None
        # What runs: onnxruntime leaves out a provider that cannot start here (a missing CUDA library).
        self.provider = session.get_providers()[0] if session is not None else None
        self.stride, self.multiple, self.reach, self.tile = int(stride), int(multiple), int(reach), int(tile)
        self.granule = self.multiple // self.stride

    def release(self) -> None:
        """Give back the memory the runtime kept from the passes so far (onnxruntime's arena; torch's
        CPU allocator keeps none): call it after a conversion. The encoder stays usable."""
        if self.session is not None:
            release_arena(self.session, {"frames": np.zeros((1, self.multiple, self.multiple, 3), np.float32)})

    def tile_borders(self, width: int, height: int) -> tuple[list[int], list[int]]:
        """Where the tiles' cores meet on a working frame of width x height: (columns, rows)."""
        return tuple([c0 for _, _, c0, _ in tiles(size, self.reach, self.multiple, self.tile)][1:]
                     for size in (width, height))

    def predict(self, frames: np.ndarray, cells: tuple[int, int] | None = None) -> np.ndarray:
        """frames float32 [B, H, W, 3] in [0, 1] (H, W multiples of the network's `multiple`) -> params
        [B, N, 8] on the W x H canvas, row-major over the (H / stride) x (W / stride) cells (`cells`,
        the layout's (cols, rows), must be those)."""
        b, h, w, _ = frames.shape
        s = self.stride
        check_cells(cells, w // s, h // s)
        out = np.empty((b, h // s, w // s, 8), np.float32)
        windows = [(y, x) for y in tiles(h, self.reach, self.multiple, self.tile)
                   for x in tiles(w, self.reach, self.multiple, self.tile)]
        (y0, y1, _, _), (x0, x1, _, _) = windows[0]
        per_call = max(1, BATCH_PIXELS // ((y1 - y0) * (x1 - x0)))
        jobs = [(i, win) for i in range(b) for win in windows]
        for k in range(0, len(jobs), per_call):
            batch = jobs[k:k + per_call]
            crops = np.stack([frames[i, ya:yb, xa:xb] for i, ((ya, yb, _, _), (xa, xb, _, _)) in batch])
            params = np.asarray(self.forward(np.ascontiguousarray(crops, np.float32)))
            wh, ww = crops.shape[1:3]
            params = params.reshape(len(batch), wh // s, ww // s, 8)
            for p, (i, ((ya, yb, ca, cb), (xa, xb, da, db))) in zip(params, batch):
                core = p[(ca - ya) // s:(cb - ya) // s, (da - xa) // s:(db - xa) // s].copy()
                # window canvas [-1, 1] -> the whole frame's canvas
                core[..., 0] = ((core[..., 0] + 1) * (0.5 * ww) + xa) * (2.0 / w) - 1
                core[..., 1] = ((core[..., 1] + 1) * (0.5 * wh) + ya) * (2.0 / h) - 1
                out[i, ca // s:cb // s, da // s:db // s] = core
        return out.reshape(b, -1, 8)


class TransformerEncoder:
    """Runs the paper's transformer, `forward(frames float32 [B, T, c, c, 3], anchors [B, N, 2], cell [1])
    -> params [B, T, N, 8]` (model.HyperGS on any backend), over working frames that are a patch grid
    of c x c tiles (c: the canvas), with a k x k lattice of Gaussians per tile (encode.TileLayout).

    The frame is covered by c x c windows whose cores partition it and which reach at least `margin`
    working pixels beyond their cores (`tiles`); every window sees the lattice points inside it (exactly
    k x k, at the window's phase: gaussians.lattice_anchors) and keeps the Gaussians of the points in
    its core. Every Gaussian thus sees context on all sides, as in training; one within SEAM_BLEND / 2
    of a border between cores is the blend of the two windows' predictions of it. With margin 0 the
    windows are the tiles themselves (the paper's patch grid; the "paper" parametrization, whose
    Gaussians are not tied to anchors, encodes so, unblended). Frames are taken in clips of
    `clip_frames` (the last one padded with its last frame), all windows of all clips in as few
    forward passes as BATCH_PAIRS allows."""

    def __init__(self, forward, canvas: int, clip_frames: int, patch: int, name: str, margin: int,
                 gaussians: tuple[int, int], session=None):
        self.forward, self.name, self.session = forward, name, session
        self.provider = session.get_providers()[0] if session is not None else None
        self.canvas, self.clip_frames, self.patch, self.margin = int(canvas), int(clip_frames), int(patch), int(margin)
        self.gaussians = tuple(int(g) for g in gaussians)  # Gaussians per tile it was trained for (min, max)

    def release(self) -> None:
        """Give back the memory the runtime kept from the passes so far (as NetworkEncoder.release)."""
        if self.session is not None:
            release_arena(self.session, {"frames": np.zeros((1, self.clip_frames, self.canvas, self.canvas, 3), np.float32),
                                         "anchors": np.zeros((1, 1, 2), np.float32),
                                         "cell": np.array([2.0], np.float32)})

    def tile_borders(self, width: int, height: int) -> tuple[list[int], list[int]]:
        """Where the windows' cores meet on a working frame of width x height: (columns, rows)."""
        return tuple([c0 for _, _, c0, _ in tiles(size, self.margin, 1, self.canvas)][1:] for size in (width, height))

    def windows(self, width: int, height: int) -> int:
        """The canvas-sized windows (forward passes per frame) covering a working frame of width x height."""
        return len(tiles(width, self.margin, 1, self.canvas)) * len(tiles(height, self.margin, 1, self.canvas))

    def _axis(self, size: int, k: int, band: float) -> list[tuple[int, float, int, int, int, np.ndarray]]:
        """Per window along an axis of `size` working pixels: (start, phase, first, lo, hi, weight): the
        window's lattice points are the axis' points first .. first + k - 1 (points j at (j + 1/2) c / k),
        at that phase in the window; those of its core are its own points lo .. hi - 1; weight [k] is its
        share of each of its points, 1 in its core, falling linearly to 0 across each border it shares
        with a neighbour's core over `band` lattice points (0: its core's points alone)."""
        c, out = self.canvas, []
        centre = np.arange(k) + 0.5  # a window's points, in lattice points from its start

        def first_at_or_after(x: int) -> int:  # the first point at or after working pixel x
            return -(-(2 * k * x - c) // (2 * c))

        for start, _, c0, c1 in tiles(size, self.margin, 1, c):
            first = first_at_or_after(start)
            lo, hi = first_at_or_after(c0) - first, first_at_or_after(c1) - first
            weight = np.ones(k)
            for inside, shared in ((centre - lo, c0 > 0), (hi - centre, c1 < size)):
                if shared:  # inside: the signed distance into the core from that border
                    weight *= np.clip(0.5 + inside / band, 0, 1) if band else inside > 0
            out.append((start, first + 0.5 - start * k / c, first, lo, hi, weight))
        return out

    def predict(self, frames: np.ndarray, cells: tuple[int, int]) -> np.ndarray:
        """frames float32 [B, H, W, 3] in [0, 1], H and W multiples of the canvas; cells: the Gaussian
        lattice (cols, rows), k per tile along each axis -> params [B, rows * cols, 8] on the W x H
        canvas, row-major over the lattice. A Gaussian within SEAM_BLEND / 2 of a border between two
        windows' cores is the windows' blend (`_axis`' weights): means, colours and covariances averaged."""
        b, h, w, _ = frames.shape
        c, t = self.canvas, self.clip_frames
        cols, rows = cells
        k = cols * c // w
        if h % c or w % c or k < 1 or cols * c != k * w or rows * c != k * h:
            raise ValueError(f"a {w}x{h} working frame of {c} px tiles cannot hold a {cols}x{rows} lattice")
        clips = -(-b // t)
        padded = np.concatenate([frames, np.repeat(frames[-1:], clips * t - b, 0)]) if clips * t > b else frames
        padded = padded.reshape(clips, t, h, w, 3)
        band = min(SEAM_BLEND, 2 * self.margin) * k / c  # in lattice points; no wider than the windows reach
        y_axis, x_axis = self._axis(h, k, band), self._axis(w, k, band)
        jobs = [(i, y, x) for i in range(clips) for y in y_axis for x in x_axis]
        (share_y, seen_y), (share_x, seen_x) = self._shares(y_axis, k, rows), self._shares(x_axis, k, cols)
        blended = (seen_y[:, None] * seen_x) > 1  # the points more than one window predicts
        blending = bool(blended.any())  # none with one window, or a band of 0
        out = np.empty((clips, t, rows, cols, 8), np.float32)
        # sums of weight x (x, y, covariance xx, xy, yy, r, g, b) over the windows
        moments = np.zeros((clips, t, rows, cols, 8), np.float32) if blending else None
        per_call = max(1, BATCH_PAIRS // (t * ((c // self.patch) ** 2 + k * k) ** 2))
        cell = np.array([2.0 / k], np.float32)
        for n in range(0, len(jobs), per_call):
            batch = jobs[n:n + per_call]
            crops = np.stack([padded[i, :, y[0]:y[0] + c, x[0]:x[0] + c] for i, y, x in batch])
            anchors = lattice_anchors(k, [(x[1], y[1]) for _, y, x in batch])
            params = np.asarray(self.forward(np.ascontiguousarray(crops, np.float32), anchors, cell))
            for p, (i, y, x) in zip(params.reshape(len(batch), t, k, k, 8), batch):
                (ya, _, fy, y0, y1, wy), (xa, _, fx, x0, x1, wx) = y, x
                p = p.copy()  # window canvas [-1, 1] -> the whole frame's canvas
                p[..., 0] = ((p[..., 0] + 1) * (0.5 * c) + xa) * (2.0 / w) - 1
                p[..., 1] = ((p[..., 1] + 1) * (0.5 * c) + ya) * (2.0 / h) - 1
                out[i, :, fy + y0:fy + y1, fx + x0:fx + x1] = p[:, y0:y1, x0:x1]
                if blending:
                    (ys, ye), (xs, xe) = (np.flatnonzero(weight)[[0, -1]] + [0, 1] for weight in (wy, wx))
                    q = p[:, ys:ye, xs:xe]
                    cov = covariance(q[..., 2:4], q[..., 4])
                    m = np.concatenate([q[..., :2], cov[..., 0, :], cov[..., 1, 1:], q[..., 5:]], -1)
                    moments[i, :, fy + ys:fy + ye, fx + xs:fx + xe] += (wy[ys:ye, None] * wx[xs:xe])[..., None] * m
        if blending:
            m = moments[:, :, blended] / (share_y[:, None] * share_x)[blended][:, None]
            cov = np.stack([np.stack([m[..., 2], m[..., 3]], -1), np.stack([m[..., 3], m[..., 4]], -1)], -2)
            out[:, :, blended] = with_covariance(m, cov)  # m's slots 2-4 are the covariance's, replaced
        return out.reshape(clips * t, rows * cols, 8)[:b]

    @staticmethod
    def _shares(axis, k: int, points: int) -> tuple[np.ndarray, np.ndarray]:
        """Per lattice point along an axis: the sum of the windows' weights, and how many windows weigh it."""
        total, seen = np.zeros(points), np.zeros(points, int)
        for _, _, first, _, _, weight in axis:
            total[first:first + k] += weight
            seen[first:first + k] += weight > 0
        return total, seen


def transformer_geometry(cfg, gaussians: tuple[int, int] | None = None) -> dict:
    """What TransformerEncoder needs of a transformer's config (model.TransformerConfig), as its card
    stores it: the canvas, clip length and patch; the context margin of its windows (5/16 of the
    canvas, in whole patches, for the "local" parametrization, whose Gaussians belong to anchors; none for "paper"); the Gaussians
    per tile it was trained for (default: up to one per 2 x 2 canvas pixels, or the "paper"
    parametrization's learned tokens). The margin is what the trained model needs: its Gaussians within
    ~30 px of a window's edge are unlike those of the same place seen from inside. Measured seam ratios
    (256², grid 2, N = 1000 per tile) of the 128-px canvas: up to 1.30 with an eighth of the canvas on
    held-out pans; 1.04, then 1.11 (the model trained longer, its frame edges right) with a quarter;
    1.01-1.05 with 5/16 for 2.25x the passes of a quarter. A whole number of patches, so that the
    windows' patch grids line up (a 36 px margin, 4.5 patches: seam ratio 1.27)."""
    local = cfg.parametrization == "local"
    most = (cfg.canvas // 2) ** 2 if local else cfg.max_gaussians
    margin = round(cfg.canvas * 5 / 16 / cfg.patch) * cfg.patch if local else 0
    return dict(canvas=cfg.canvas, clip_frames=cfg.clip_frames, patch=cfg.patch, margin=margin,
                gaussians=list(gaussians or (1, most)))


def read_card(directory=WEIGHTS_DIR, name: str = BUNDLED_NAME) -> dict:
    path = Path(directory) / f"{name}.json"
    if not path.is_file():
        models = sorted(p.stem for p in Path(directory).glob("*.json"))
        if models:  # a name mistyped, or a design's name (Blender's "transformer") for its file's
            raise HyperGSError(f"no model {name!r} in {directory}: its models are {', '.join(models)}")
        raise HyperGSError(f"no model weights at {path}: train one with `hypergs train` and `hypergs export`")
    return json.loads(path.read_text())


def card_sigma_cutoff(card: dict) -> float:
    """The box (raster.SIGMA_CUTOFF) a model's colours were trained for: cards record it since the box
    widened from 3 to 3.5 sigmas (and to 4 in session 22); every card without it was trained under 3."""
    return float(card.get("sigma_cutoff", 3.0))


def weights_name(directory, name: str | None = None) -> str:
    """The name of the model to load from a weights folder: `name`, or the bundled name when the folder
    holds that model, or the folder's only model (a <name>.json card)."""
    if name is not None:
        return name
    directory = Path(directory)
    if (directory / f"{BUNDLED_NAME}.json").is_file():
        return BUNDLED_NAME
    cards = sorted(p.stem for p in directory.glob("*.json"))
    if len(cards) == 1:
        return cards[0]
    if not cards:
        raise HyperGSError(f"no model weights in {directory}: train one with `hypergs train` and `hypergs export`")
    raise HyperGSError(f"{directory} holds several models ({', '.join(cards)}): name one")


def load_model(directory=WEIGHTS_DIR, name: str = BUNDLED_NAME):
    from safetensors.torch import load_file

    from .model import build_model
    card = read_card(directory, name)
    model = build_model(card["config"])
    model.load_state_dict(load_file(str(Path(directory) / f"{name}.safetensors")))
    return model.eval()


def _transformer_encoder(forward, card: dict, name: str, session=None) -> TransformerEncoder:
    geometry = card["geometry"]  # written by training.export from the model's config
    return TransformerEncoder(forward, geometry["canvas"], geometry["clip_frames"], geometry["patch"], name,
                              geometry["margin"], geometry["gaussians"], session)


def torch_encoder(model, device="cpu", card: dict | None = None, precision: str = "float32"):
    """The encoder running `model` (either design) with torch; card: its card (default: as exported);
    precision: one of PRECISIONS. A bfloat16 encoder's name ends in "-bfloat16"."""
    import torch
    if precision not in PRECISIONS:
        raise HyperGSError(f"unknown precision {precision!r} ({', '.join(PRECISIONS)})")
    model = model.to(device).eval()
    cfg = model.cfg
    suffix = "-bfloat16" if precision == "bfloat16" else ""
    device_type = torch.device(device).type

    def run(*inputs: np.ndarray) -> np.ndarray:
        with torch.inference_mode(), torch.autocast(device_type, dtype=torch.bfloat16, enabled=precision == "bfloat16"):
            return model(*(torch.from_numpy(a).to(device) for a in inputs)).float().cpu().numpy()

    if cfg.arch == "transformer":
        return _transformer_encoder(run, card or dict(geometry=transformer_geometry(cfg)), f"transformer-torch{suffix}")
    return NetworkEncoder(run, cfg.stride, cfg.multiple, cfg.reach, f"network-torch{suffix}")


def onnx_encoder(onnx_path, card: dict, providers: list[str] | None = None, threads: int = 0):
    """providers: onnxruntime execution providers, best first (default: the CPU's); threads: the CPU
    provider's intra-op threads (0: onnxruntime's default, one per core)."""
    import onnxruntime as ort
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    options.enable_mem_pattern = False  # a buffer plan per input shape, kept: 2x the memory, no faster
    options.intra_op_num_threads = threads
    session = ort.InferenceSession(str(onnx_path), options, providers=providers or ["CPUExecutionProvider"])
    if card.get("arch") == "transformer":
        def forward(frames: np.ndarray, anchors: np.ndarray, cell: np.ndarray) -> np.ndarray:
            return session.run(["params"], {"frames": frames, "anchors": anchors, "cell": cell})[0]

        return _transformer_encoder(forward, card, "transformer-onnx", session)

    def forward(frames: np.ndarray) -> np.ndarray:
        return session.run(["params"], {"frames": frames})[0]

    geometry = card["geometry"]  # written by training.export from the model's config
    return NetworkEncoder(forward, geometry["stride"], geometry["multiple"], geometry["reach"], "network-onnx",
                          session=session)


def resolve_encoder(kind: str = "network", backend: str = "auto", weights=None, device=None,
                    providers: list[str] | None = None, threads: int = 0, precision: str = "float32"):
    """The encoder to use. kind: "network" (a trained network: `weights` is a folder (its model, see
    weights_name) or a model's card in one, <folder>/<name>.json; default the bundled conv network; the
    card says which design it is) or "floor" (the no-learning grid floor). backend for the network: "torch" (needs torch and the .safetensors weights), "onnx"
    (needs onnxruntime and the .onnx model), or "auto": torch where both are there, else onnx.
    providers, threads: onnxruntime's execution providers and CPU threads (see onnx_encoder); precision:
    the torch backend's (PRECISIONS; onnxruntime runs float32). What
    cannot load raises HyperGSError saying why; nothing falls back to another kind of encoder."""
    if kind == "floor":
        return FloorEncoder()
    if kind != "network":
        raise HyperGSError(f"unknown encoder {kind!r} (network or floor)")
    if backend not in BACKENDS:
        raise HyperGSError(f"unknown encoder backend {backend!r} ({', '.join(BACKENDS)})")
    directory, name = Path(weights or WEIGHTS_DIR), None
    if directory.suffix == ".json":
        directory, name = directory.parent, directory.stem
    name = weights_name(directory, name)
    card = read_card(directory, name)
    trained_box = card_sigma_cutoff(card)
    if trained_box != SIGMA_CUTOFF:  # its colours would come out 0.4 % too bright
        raise HyperGSError(f"{directory / name}.json: trained for a {trained_box:g}-sigma box, and this "
                           f"HyperGS renders with {SIGMA_CUTOFF:g}: convert the weights with "
                           f"`hypergs rebox --weights {directory} --name {name}`")
    if backend == "auto":
        backend = "torch" if optional.torch_available() and (directory / f"{name}.safetensors").is_file() else "onnx"
    try:
        if backend == "torch":
            import torch
            device = device or ("cuda" if torch.cuda.is_available() else "cpu")
            return torch_encoder(load_model(directory, name), device, card, precision)
        if precision != "float32":
            raise HyperGSError(f"--precision {precision} runs in torch; onnxruntime runs float32 (--backend torch)")
        onnx_path = directory / f"{name}.onnx"
        if not onnx_path.is_file():
            raise HyperGSError(f"no ONNX model at {onnx_path}: run `hypergs export-onnx`")
        return onnx_encoder(onnx_path, card, providers, threads)
    except HyperGSError:
        raise
    except Exception as e:  # a missing package or a broken weights file, said plainly
        raise HyperGSError(f"the trained network could not be loaded with {backend} "
                           f"({type(e).__name__}: {e})") from e

