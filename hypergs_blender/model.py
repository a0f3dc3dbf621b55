"""HyperGS networks: video frames in, 2D Gaussians out (8 numbers each, see gaussians.PARAMS), in one
forward pass. Two designs, both built from a config dataclass (`build_model`):

ConvGS (the default, preset "conv"): fully convolutional, one Gaussian per `stride` x `stride` cell of
its input. The input is the frame resized to the working size at which each cell is `stride` pixels
(encode.Layout): the Gaussian density is the input's resolution, so one model serves every count,
and more Gaussians always see more of the frame. Per frame:

    frame [B, H, W, 3]
      -> a stem to one feature per cell (`stem_level`): "pixel": two 3x3 convs at full resolution
         and a stride x stride conv down to the cells; "cell": a 3x3 conv over the cells' pixels
         (pixel-unshuffle), a GELU and a 1x1 conv, all at cell resolution (~5x cheaper: the
         full-resolution convs are memory-bound) -- plus a linear map of the cell's own pixels
      -> residual 3x3 blocks at cell resolution, then at coarser levels (x2 each, for context) and
         back up with skips (a small U-Net; `blocks` per level)
      -> a 1x1 head to 8 numbers per cell
      -> mean  = cell centre + tanh(h) x offset_range cells    (may leave its cell: no seams)
         scale = INITIAL_SIGMA x stride x exp(scale_range tanh(h / scale_range))   (bounded)
         rotation = pi h, colour = COLOUR_GAIN x the cell's mean colour + h         (signed)
      -> with an error pass (`error_width` > 0): those Gaussians rendered at error_samples^2 points per
         cell (render.local_render: each point sums the Gaussians of the cells within `error_reach`),
         the input minus that render, and a second small conv net from [cell features, head outputs,
         error] to a correction of the head outputs (its head starts at zero): what refinement does with
         the render's gradient, learned, in one step (model card: "the error pass"); `error_iterations`
         runs it again on the render of its own outputs
The head starts at zero, i.e. at the Gaussian grid floor, and training learns corrections. The
network is translation-equivariant with a finite receptive field (`ConvConfig.reach`): a frame
encoded in tiles that overlap by at least that much gives exactly the Gaussians of one pass.

HyperGS (the paper's design, presets "small" and "paper"):

    frames [B, T, c, c, 3]
      -> 3D-conv tokenizer (kernel 1 x p x p) + learnable spatio-temporal position embedding   Z^0
      -> ST-Transformer: L x (spatial attention with 2D RoPE, temporal attention with 1D RoPE
         in windows of w frames, FFN), pre-LN                                                 Z^L
      -> skip: Z = Z^L + Z^0
      -> Q-Transformer, per frame: [patch tokens; N Gaussian tokens] through self-attention blocks
      -> heads on the Gaussian tokens -> [B, T, N, 8] (see gaussians.PARAMS)

Two parametrizations of the Gaussian tokens and heads (`TransformerConfig.parametrization`):
- "paper": N learned tokens; means tanh(h), colours sigmoid(h), rotation sigmoid(h) 2 pi,
  scale |h| + eps (canvas pixels). As in the HyperGS paper.
- "local" (default): Gaussian k belongs to an anchor a_k on a regular grid (`gaussians.grid_anchors`).
  Its token is an embedding of a_k, plus the skip feature Z sampled under a_k, plus a linear
  embedding of the frame's pixels in its grid cell (a k x k bilinear sample spanning the cell: the
  Gaussian's own neighbourhood at its own scale, which makes colours a nearly local, learnable
  linear function of the pixels, as the least-squares colours are), its mean is
  a_k + cell * offset_range * tanh(h / offset_range) (an offset from the anchor of at most
  `offset_range` grid cells, as the conv network's; older weights, offset_range 0:
  tanh(atanh(a_k) + cell * h), which pins the outer ring: 1 - a_k^2 of a cell per unit of h, 6 % at
  N = 1000, so the frame's outermost pixels stayed dark), its scale is
  (|h| + eps) x the grid spacing, and its colour is signed: the mean of its cell's pixel samples
  times the gain that makes overlapping kernels sum to the image, plus h. At initialisation
  it is therefore the grid floor, and training only has to learn corrections; any N works with one
  model, and the cost of a Gaussian token does not depend on where its Gaussian lies.
  Q-Transformer attention uses 2D RoPE over patch centres and anchors, so tokens attend locally.
The anchors and the cell size are inputs, so one exported model serves every Gaussian count.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

from .gaussians import COLOUR_GAIN, INITIAL_SIGMA, grid_anchors
from .render import local_render

SCALE_EPS = 1e-2
ERROR_GAIN = 8.0  # the error pass's input: the render's error (a few /255) times this, the size of its features


@dataclass
class TransformerConfig:
    arch: str = "transformer"
    canvas: int = 128
    patch: int = 8
    clip_frames: int = 4
    temporal_window: int = 4
    dim: int = 192
    heads: int = 6
    ffn: int = 768
    st_layers: int = 2
    q_layers: int = 2
    parametrization: str = "local"
    max_gaussians: int = 3000  # learned tokens of the "paper" parametrization
    rope_base: float = 100.0
    cell_samples: int = 4  # "local": k x k pixel samples per Gaussian cell
    offset_range: float = 1.0  # "local": grid cells a mean may move from its anchor (0: the tanh map of older weights)

    @property
    def grid(self) -> int:
        return self.canvas // self.patch


@dataclass
class ConvConfig:
    arch: str = "conv"
    stride: int = 4  # input pixels per cell side: one Gaussian per stride x stride pixels
    stem: int = 24  # channels of the stem's convs (full resolution: "pixel"; cell resolution: "cell")
    stem_level: str = "pixel"  # where the stem's convs run: "pixel" (full resolution) or "cell"
    width: int = 64  # channels at cell resolution
    blocks: tuple = (4,)  # residual blocks at the cell level, then at each coarser level (x2)
    mid: int = 0  # channels between a residual block's two convs at the cell level (0: width)
    dilation: tuple = ()  # the cell level's blocks' dilations, in order (1 for the blocks not listed): context
    widen: int = 1  # channel factor per coarser level
    offset_range: float = 1.0  # cells a mean may move from its cell centre
    scale_range: float = 3.0  # |log(scale / initial scale)| bound
    error_width: int = 0  # channels of the error pass (0: none), a second pass reading the first's render error
    error_blocks: int = 1  # its residual blocks
    error_kernel: int = 3  # its first conv's kernel (1 or 3), from the features, head outputs and error
    error_samples: int = 2  # its render's samples per cell side (stride: one per input pixel)
    error_reach: int = 2  # cells around a sample's own whose Gaussians its render sums
    error_iterations: int = 1  # times the error pass runs, each on the render of the last one's outputs

    def __post_init__(self):
        self.blocks = tuple(int(b) for b in self.blocks)
        self.dilation = tuple(int(d) for d in self.dilation)
        if len(self.dilation) > self.blocks[0] or any(d < 1 for d in self.dilation):
            raise ValueError(f"dilation {list(self.dilation)}: one of 1 or more per cell-level block ({self.blocks[0]})")
        if self.error_width and self.stride % self.error_samples:
            raise ValueError(f"error_samples ({self.error_samples}) must divide the stride ({self.stride})")
        if self.error_width and self.error_iterations < 1:
            raise ValueError(f"error_iterations must be 1 or more, got {self.error_iterations}")

    @property
    def multiple(self) -> int:
        """Input sizes must be multiples of this (the coarsest level's cell)."""
        return self.stride * 2 ** (len(self.blocks) - 1)

    @property
    def dilations(self) -> list[tuple]:
        """Each level's blocks' dilations: the cell level's from `dilation`, padded with 1; 1 at coarser levels."""
        cell_level = self.dilation + (1,) * (self.blocks[0] - len(self.dilation))
        return [cell_level] + [(1,) * n for n in self.blocks[1:]]

    @property
    def reach(self) -> int:
        """Input pixels beyond which a pixel cannot change a cell's Gaussian: an upper bound of the
        receptive field's radius, rounded up to `multiple`. Tiles that overlap by this much encode
        exactly as one pass does."""
        # the stem: two full-resolution 3x3 convs and the conv down to the cell, or one 3x3 conv over cells
        radius = 2 + self.stride if self.stem_level == "pixel" else 2 * self.stride
        for level in range(len(self.blocks)):
            cell = self.stride * 2 ** level
            # the blocks' two 3x3 convs each (dilated), the conv down to (or up from) here
            radius += (2 * sum(self.dilations[level]) + 1) * cell
            if level < len(self.blocks) - 1:
                radius += 2 * cell  # the block on the way back up
        if self.error_width:  # the error reads the Gaussians error_reach cells away; then its convs
            radius += self.error_iterations * (self.error_reach + self.error_kernel // 2 + 2 * self.error_blocks) * self.stride
        return -(-radius // self.multiple) * self.multiple


PRESETS = {
    # round 3's network: ahead of round 2's from scratch at equal CPU time (model card); the bundled one is it
    # with an error pass (error_width=32 error_samples=4 error_kernel=1), trained on it with --train-only
    # error_pass, then both passes together
    "conv": ConvConfig(stem=96, stem_level="cell", mid=32),
    "conv-round2": ConvConfig(),  # round 2's: the stem at full resolution, blocks of 64 middle channels
    "small": TransformerConfig(),
    "paper": TransformerConfig(canvas=256, patch=16, clip_frames=8, temporal_window=4, dim=768, heads=12, ffn=2800,
                         st_layers=2, q_layers=4, parametrization="paper", max_gaussians=1000),
}


def rope_angles(positions: torch.Tensor, dim: int, base: float) -> torch.Tensor:
    """Rotary angles [..., L, dim / 2] for positions [..., L, k]: the dim/2 frequency slots are split
    evenly between the k coordinates (k = 1: time; k = 2: (row, column))."""
    k = positions.shape[-1]
    per = dim // 2 // k
    inv_freq = base ** (-torch.arange(per, dtype=torch.float32, device=positions.device) / per)
    return torch.cat([positions[..., i, None].float() * inv_freq for i in range(k)], dim=-1)


def apply_rope(x: torch.Tensor, angles: torch.Tensor) -> torch.Tensor:
    """Rotate feature pairs (x_i, x_{i + d/2}) of x [..., L, d] by angles [L, d/2]."""
    x1, x2 = x.chunk(2, dim=-1)
    cos, sin = angles.cos(), angles.sin()
    return torch.cat([x1 * cos - x2 * sin, x1 * sin + x2 * cos], dim=-1)


class Attention(nn.Module):
    def __init__(self, dim: int, heads: int):
        super().__init__()
        self.heads = heads
        self.qkv = nn.Linear(dim, 3 * dim)
        self.proj = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, angles: torch.Tensor | None = None) -> torch.Tensor:
        b, n, d = x.shape
        q, k, v = self.qkv(x).reshape(b, n, 3, self.heads, d // self.heads).permute(2, 0, 3, 1, 4)
        if angles is not None:
            q, k = apply_rope(q, angles), apply_rope(k, angles)
        y = F.scaled_dot_product_attention(q, k, v)
        return self.proj(y.transpose(1, 2).reshape(b, n, d))


class FeedForward(nn.Sequential):
    def __init__(self, dim: int, hidden: int):
        super().__init__(nn.Linear(dim, hidden), nn.GELU(), nn.Linear(hidden, dim))


class STBlock(nn.Module):
    """Factorized spatio-temporal block: spatial attention per frame, temporal attention per patch
    position within windows of `window` frames, then an FFN; each pre-LN with a residual."""

    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        self.window = cfg.temporal_window
        self.norm_s, self.spatial = nn.LayerNorm(cfg.dim), Attention(cfg.dim, cfg.heads)
        self.norm_t, self.temporal = nn.LayerNorm(cfg.dim), Attention(cfg.dim, cfg.heads)
        self.norm_f, self.ffn = nn.LayerNorm(cfg.dim), FeedForward(cfg.dim, cfg.ffn)

    def forward(self, z: torch.Tensor, spatial_angles: torch.Tensor, temporal_angles: torch.Tensor) -> torch.Tensor:
        b, t, p, d = z.shape
        x = z.reshape(b * t, p, d)
        x = x + self.spatial(self.norm_s(x), spatial_angles)
        w = self.window
        x = x.reshape(b, t // w, w, p, d).transpose(2, 3).reshape(b * (t // w) * p, w, d)
        x = x + self.temporal(self.norm_t(x), temporal_angles)
        x = x + self.ffn(self.norm_f(x))
        return x.reshape(b, t // w, p, w, d).transpose(2, 3).reshape(b, t, p, d)


class QBlock(nn.Module):
    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        self.norm_a, self.attn = nn.LayerNorm(cfg.dim), Attention(cfg.dim, cfg.heads)
        self.norm_f, self.ffn = nn.LayerNorm(cfg.dim), FeedForward(cfg.dim, cfg.ffn)

    def forward(self, x: torch.Tensor, angles: torch.Tensor | None) -> torch.Tensor:
        x = x + self.attn(self.norm_a(x), angles)
        return x + self.ffn(self.norm_f(x))


class HyperGS(nn.Module):
    def __init__(self, cfg: TransformerConfig):
        super().__init__()
        if cfg.clip_frames % cfg.temporal_window or cfg.canvas % cfg.patch:
            raise ValueError("clip_frames must be a multiple of temporal_window and canvas of patch")
        self.cfg = cfg
        g, d = cfg.grid, cfg.dim
        self.tokenizer = nn.Conv3d(3, d, kernel_size=(1, cfg.patch, cfg.patch), stride=(1, cfg.patch, cfg.patch))
        self.pos_embed = nn.Parameter(torch.randn(1, cfg.clip_frames, g * g, d) * 0.02)
        self.st_blocks = nn.ModuleList(STBlock(cfg) for _ in range(cfg.st_layers))
        self.q_blocks = nn.ModuleList(QBlock(cfg) for _ in range(cfg.q_layers))
        self.norm_out = nn.LayerNorm(d)
        self.head = nn.Linear(d, 8)
        rows, cols = torch.meshgrid(torch.arange(g), torch.arange(g), indexing="ij")
        self.register_buffer("patch_rc", torch.stack([rows, cols], -1).reshape(-1, 2).float() + 0.5, persistent=False)
        self.register_buffer("frame_index", torch.arange(cfg.temporal_window).float()[:, None], persistent=False)
        if cfg.parametrization == "paper":
            self.gaussian_tokens = nn.Parameter(torch.randn(cfg.max_gaussians, d) * 0.02)
        elif cfg.parametrization == "local":
            self.anchor_embed = nn.Sequential(nn.Linear(4 * 8, d), nn.GELU(), nn.Linear(d, d))
            self.cell_embed = nn.Linear(3 * cfg.cell_samples ** 2, d)
            k = cfg.cell_samples
            offsets = (torch.arange(k).float() + 0.5) / k - 0.5  # cell-relative sample positions
            oy, ox = torch.meshgrid(offsets, offsets, indexing="ij")
            self.register_buffer("cell_offsets", torch.stack([ox, oy], -1).reshape(-1, 2), persistent=False)
            # Start at the grid floor: zero offsets and colour residuals, sigma = INITIAL_SIGMA cells.
            nn.init.zeros_(self.head.weight)
            with torch.no_grad():
                self.head.weight[2:4].normal_(0, 1e-3)
                self.head.bias.copy_(torch.tensor([0, 0, INITIAL_SIGMA - SCALE_EPS, INITIAL_SIGMA - SCALE_EPS,
                                                   0, 0, 0, 0]))
        else:
            raise ValueError(f"unknown parametrization {cfg.parametrization!r}")

    def forward(self, frames: torch.Tensor, anchors: torch.Tensor, cell: torch.Tensor) -> torch.Tensor:
        """frames [B, T, c, c, 3] in [0, 1]; anchors [N, 2] or, one set per clip, [B, N, 2] in [-1, 1];
        cell [1]: the anchor grid spacing in [-1, 1] units (2 / sqrt(N) on a square grid). Returns
        params [B, T, N, 8]."""
        cfg = self.cfg
        b, t = frames.shape[:2]
        g, d = cfg.grid, cfg.dim
        x = frames.permute(0, 4, 1, 2, 3)  # [B, 3, T, c, c]
        z0 = self.tokenizer((x - 0.5) * 4).flatten(3).permute(0, 2, 3, 1) + self.pos_embed  # [B, T, P, d]
        spatial_angles = rope_angles(self.patch_rc, d // cfg.heads, cfg.rope_base)
        temporal_angles = rope_angles(self.frame_index, d // cfg.heads, cfg.rope_base)
        z = z0
        for block in self.st_blocks:
            z = block(z, spatial_angles, temporal_angles)
        z = (z + z0).reshape(b * t, g * g, d)

        n = anchors.shape[-2]
        anchors = anchors.reshape(-1, n, 2)  # [1 or B, N, 2]
        per_clip = anchors.shape[0]

        def per_frame(a: torch.Tensor) -> torch.Tensor:  # [1 or B, ...] -> [B*T, ...]
            return a[:, None].expand(b, t, *a.shape[1:]).reshape(b * t, *a.shape[1:])

        if cfg.parametrization == "paper":
            tokens = self.gaussian_tokens[:n].expand(b * t, n, d)
            angles = None
        else:
            feature_map = z.transpose(1, 2).reshape(b * t, d, g, g)
            under_anchor = F.grid_sample(feature_map, per_frame(anchors)[:, None], align_corners=False)[:, :, 0]
            cell_pixels = self.cell_pixels(x, anchors, cell)  # [B*T, N, k*k, 3]
            tokens = (under_anchor.transpose(1, 2) + per_frame(self.anchor_embed(fourier_features(anchors)))
                      + self.cell_embed((cell_pixels.flatten(2) - 0.5) * 4))
            anchor_rc = (anchors.flip(-1) + 1) * (0.5 * g)  # (row, column) in patch units
            positions = torch.cat([self.patch_rc.expand(per_clip, g * g, 2), anchor_rc], 1)
            angles = per_frame(rope_angles(positions, d // cfg.heads, cfg.rope_base))[:, None]  # [B*T, 1, L, d/2]
        h = torch.cat([z, tokens], dim=1)
        for block in self.q_blocks:
            h = block(h, angles)
        h = self.head(self.norm_out(h[:, g * g:])).reshape(b, t, n, 8)

        if cfg.parametrization == "paper":
            means = torch.tanh(h[..., 0:2])
            scales = h[..., 2:4].abs() + SCALE_EPS
            colours = torch.sigmoid(h[..., 5:8])
        else:
            if cfg.offset_range > 0:
                offset = cfg.offset_range * torch.tanh(h[..., 0:2] / cfg.offset_range)
                means = anchors[:, None] + cell * offset  # [1 or B, 1, N, 2] + [B, T, N, 2]
            else:
                base = torch.atanh(anchors.clamp(-0.999, 0.999))[:, None]
                means = torch.tanh(base + cell * h[..., 0:2])
            spacing_px = cell * (0.5 * cfg.canvas)
            scales = (h[..., 2:4].abs() + SCALE_EPS) * spacing_px
            cell_mean = cell_pixels.mean(2).reshape(b, t, n, 3)
            colours = COLOUR_GAIN * cell_mean + h[..., 5:8]
        rotation = torch.sigmoid(h[..., 4:5]) * (2 * math.pi)
        return torch.cat([means, scales, rotation, colours], dim=-1)

    def cell_pixels(self, x: torch.Tensor, anchors: torch.Tensor, cell: torch.Tensor) -> torch.Tensor:
        """Bilinear samples of the frames x [B, 3, T, c, c] on a k x k lattice spanning each anchor's
        grid cell (anchors [1 or B, N, 2]) -> [B*T, N, k*k, 3]."""
        b, _, t, c, _ = x.shape
        n = anchors.shape[1]
        points = anchors[:, :, None, :] + cell * self.cell_offsets  # [1 or B, N, k*k, 2]
        points = points[:, None].expand(b, t, n, points.shape[2], 2).reshape(b * t, n, points.shape[2], 2)
        frames = x.transpose(1, 2).reshape(b * t, 3, c, c)
        samples = F.grid_sample(frames, points, align_corners=False, padding_mode="border")  # [B*T, 3, N, k*k]
        return samples.permute(0, 2, 3, 1)


class ResBlock(nn.Module):
    """x + conv(gelu(conv(gelu(x)))), the second conv initialised to zero (the block starts as identity);
    `mid` channels between the two convs (default: as many as outside), both 3x3 convs `dilation` apart."""

    def __init__(self, channels: int, mid: int = 0, dilation: int = 1):
        super().__init__()
        mid = mid or channels
        self.a = nn.Conv2d(channels, mid, 3, padding=dilation, dilation=dilation)
        self.b = nn.Conv2d(mid, channels, 3, padding=dilation, dilation=dilation)
        nn.init.zeros_(self.b.weight)
        nn.init.zeros_(self.b.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.b(F.gelu(self.a(F.gelu(x))))


class ConvGS(nn.Module):
    def __init__(self, cfg: ConvConfig):
        super().__init__()
        self.cfg = cfg
        s, c = cfg.stride, cfg.width
        if cfg.stem_level == "pixel":
            self.stem = nn.Sequential(nn.Conv2d(3, cfg.stem, 3, padding=1), nn.GELU(),
                                      nn.Conv2d(cfg.stem, cfg.stem, 3, padding=1), nn.GELU())
            self.to_cell = nn.Conv2d(cfg.stem, c, s, stride=s)
        elif cfg.stem_level == "cell":
            self.stem = nn.Sequential(nn.PixelUnshuffle(s), nn.Conv2d(3 * s * s, cfg.stem, 3, padding=1), nn.GELU())
            self.to_cell = nn.Conv2d(cfg.stem, c, 1)
        else:
            raise ValueError(f"unknown stem level {cfg.stem_level!r} (pixel or cell)")
        self.cell_pixels = nn.Conv2d(3 * s * s, c, 1)  # the cell's own pixels, linearly
        widths = [c * cfg.widen ** level for level in range(len(cfg.blocks))]
        mids = [(cfg.mid or c) * cfg.widen ** level for level in range(len(cfg.blocks))]
        self.down = nn.ModuleList(nn.Conv2d(a, b, 2, stride=2) for a, b in zip(widths, widths[1:]))
        self.encoder = nn.ModuleList(nn.Sequential(*(ResBlock(w, m, d) for d in level))
                                     for w, m, level in zip(widths, mids, cfg.dilations))
        self.up = nn.ModuleList(nn.Conv2d(b, a, 1) for a, b in zip(widths, widths[1:]))
        for up in self.up:  # coarser levels start switched off: a warm start from fewer levels is that network
            nn.init.zeros_(up.weight)
            nn.init.zeros_(up.bias)
        self.decoder = nn.ModuleList(ResBlock(w, m) for w, m in zip(widths[:-1], mids))
        self.head = nn.Conv2d(c, 8, 1)
        nn.init.zeros_(self.head.weight)  # start at the grid floor
        nn.init.zeros_(self.head.bias)
        self.error_pass = ErrorPass(cfg) if cfg.error_width else None

    def cell_features(self, x: torch.Tensor) -> torch.Tensor:
        """Input [B, 3, H, W] (normalised) -> the stem's features [B, width, H / stride, W / stride]."""
        return self.to_cell(self.stem(x)) + self.cell_pixels(F.pixel_unshuffle(x, self.cfg.stride))

    def features(self, x: torch.Tensor) -> torch.Tensor:
        """Input [B, 3, H, W] (normalised) -> cell features [B, width, H / stride, W / stride]."""
        h = self.cell_features(x)
        skips = []
        for level, blocks in enumerate(self.encoder):
            if level:
                skips.append(h)
                h = self.down[level - 1](h)
            h = blocks(h)
        for level in reversed(range(len(self.decoder))):
            skip = skips.pop()
            h = self.decoder[level](skip + F.interpolate(self.up[level](h), scale_factor=2.0, mode="nearest"))
        return h

    def forward(self, frames: torch.Tensor) -> torch.Tensor:
        """frames [B, H, W, 3] in [0, 1], H and W multiples of cfg.multiple -> params [B, N, 8] on the
        W x H canvas (N = (H / stride) x (W / stride), row-major from the top-left cell)."""
        x = frames.permute(0, 3, 1, 2)
        features = self.features((x - 0.5) * 2)
        # [B, 8, rows, cols]; the geometry in float32 whatever precision the convolutions ran in:
        # a half-precision cell grid puts the means of a 128-px frame on a 0.5-px lattice (-0.9 dB)
        h = full_precision(self.head(features))
        if self.error_pass is not None:
            for _ in range(self.cfg.error_iterations):  # one set of weights: each run corrects the last
                h = self.error_pass(features, h, self.render_error(h, x))
        return self.geometry(h, x)

    def geometry(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """Head outputs h [B, 8, rows, cols] (full_precision) and the input x [B, 3, H, W] -> params [B, N, 8]."""
        cfg, s = self.cfg, self.cfg.stride
        height, width = x.shape[-2:]
        rows, cols = h.shape[-2:]
        ys = (torch.arange(rows, dtype=h.dtype, device=h.device) + 0.5) * s
        xs = (torch.arange(cols, dtype=h.dtype, device=h.device) + 0.5) * s
        offset = torch.tanh(h[:, 0:2]) * (cfg.offset_range * s)
        mean_x = (xs[None, :] + offset[:, 0]) * (2.0 / width) - 1
        mean_y = (ys[:, None] + offset[:, 1]) * (2.0 / height) - 1
        r = cfg.scale_range
        scale = (INITIAL_SIGMA * s) * torch.exp(r * torch.tanh(h[:, 2:4] / r))
        rotation = h[:, 4:5] * math.pi
        colour = COLOUR_GAIN * F.avg_pool2d(x, s) + h[:, 5:8]
        params = torch.cat([mean_x[:, None], mean_y[:, None], scale, rotation, colour], 1)
        return params.flatten(2).transpose(1, 2)

    def render_error(self, h: torch.Tensor, x: torch.Tensor) -> torch.Tensor:
        """The input minus the render of the Gaussians of head outputs h, at error_samples^2 points per
        cell, as [B, 3 error_samples^2, rows, cols] (times ERROR_GAIN). An observation the error pass reads
        (as refinement reads its gradient), not a path to train the first pass through: detached."""
        cfg = self.cfg
        n = cfg.error_samples
        rows, cols = h.shape[-2:]
        with torch.no_grad(), torch.autocast(x.device.type, enabled=False):
            rendered = local_render(self.geometry(h, x), rows, cols, cfg.stride, n, cfg.error_reach)
            x = full_precision(x)
            target = F.avg_pool2d(x, cfg.stride // n) if n < cfg.stride else x
            return (F.pixel_unshuffle(target, n) - rendered) * ERROR_GAIN


class ErrorPass(nn.Module):
    """The second pass (ConvConfig.error_width > 0): from the first pass's cell features, its head outputs
    and its render's error at each cell's samples to a correction of the head outputs. A conv (error_kernel),
    residual blocks, and a 1x1 head that starts at zero, so a warm start from a one-pass network starts as it."""

    def __init__(self, cfg: ConvConfig):
        super().__init__()
        c = cfg.error_width
        self.inputs = nn.Conv2d(cfg.width + 8 + 3 * cfg.error_samples ** 2, c, cfg.error_kernel,
                                padding=cfg.error_kernel // 2)
        self.blocks = nn.Sequential(*(ResBlock(c) for _ in range(cfg.error_blocks)))
        self.head = nn.Conv2d(c, 8, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, features: torch.Tensor, h: torch.Tensor, error: torch.Tensor) -> torch.Tensor:
        z = torch.cat([features, h.to(features.dtype), error.to(features.dtype)], 1)
        return h + full_precision(self.head(self.blocks(self.inputs(z))))


def full_precision(t: torch.Tensor) -> torch.Tensor:
    """t in float32, or in float64 where it is (the tests' exact comparisons): not in an autocast's half precision."""
    return t if t.dtype == torch.float64 else t.float()


def build_model(config: dict) -> nn.Module:
    """A network from its config as saved in cards and checkpoints (`model_config`)."""
    config = dict(config)
    arch = config.get("arch", "transformer")
    if arch == "conv":
        return ConvGS(ConvConfig(**config))
    if arch == "transformer":
        # cards and checkpoints from before the field: the tanh map (the caller's dict stays as it was)
        return HyperGS(TransformerConfig(**{"offset_range": 0.0, **config}))
    raise ValueError(f"unknown network architecture {arch!r}")


def model_config(model: nn.Module) -> dict:
    return asdict(model.cfg)


def fourier_features(xy: torch.Tensor, bands: int = 8) -> torch.Tensor:
    """[N, 2] -> [N, 4 * bands] sin/cos of the coordinates at octave frequencies."""
    freqs = (2.0 ** torch.arange(bands, dtype=xy.dtype, device=xy.device)) * math.pi
    angles = (xy[..., None] * freqs).flatten(-2)
    return torch.cat([angles.sin(), angles.cos()], dim=-1)


def anchor_inputs(n: int, device=None) -> tuple[torch.Tensor, torch.Tensor]:
    """The anchors and cell size the model takes for N Gaussians per frame (square canvas)."""
    anchors = torch.from_numpy(grid_anchors(n)).to(device)
    return anchors, torch.tensor([2.0 / math.sqrt(n)], device=device)


def count_parameters(model: nn.Module) -> int:
    return sum(p.numel() for p in model.parameters())
