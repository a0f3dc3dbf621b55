"""The encode options a user chooses and what they mean, in one place: the Model (the conv network, the
default, or the paper's HyperGS transformer, offered when its weights are there: runtime.model_weights),
a Quality preset (Draft / Standard / High: the core's encode.QUALITY, a cell size in source pixels and
refine steps) or Custom values (cell size or Gaussian count, per frame or, for the transformer, per
tile; refine steps), and the transformer's patch grid, read as the core's EncodeSettings; and what the
dialogs show before an encode starts: the Gaussians per frame at each source's own resolution (they
scale with it; the transformer's: tiles x Gaussians per tile), the frames, and an estimate of time and
size (encode.estimate).

The options are properties of the operators and of a clip's settings (EncodeOptions, a mixin), drawn
by `draw` in the import file browser's side panel, the Sequencer's Convert dialog and the clip panel.
"""
from __future__ import annotations

import os
from dataclasses import dataclass

from bpy.props import EnumProperty, FloatProperty, IntProperty, IntVectorProperty

from ..hypergs_blender.encode import MAX_CELL, QUALITY, EncodeSettings, Estimate, Layout, estimate
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io.frames import probe
from ..hypergs_blender.runtime import Runtime, make_encoder, transformer_available
from .jobs import Source

CUSTOM = "CUSTOM"


def _preset_item(key: str, name: str) -> tuple[str, str, str]:
    preset = QUALITY[key]
    refine = f", refined {preset['refine']} steps" if preset["refine"] else ""
    return (key.upper(), name, f"One Gaussian per {preset['cell']:g} x {preset['cell']:g} source pixels{refine}")


class EncodeOptions:
    """The encode options (a mixin for operators and the clip settings)."""
    model: EnumProperty(
        name="Model", default="CONV",
        items=[("CONV", "Conv", "The convolutional network (the default): one Gaussian per cell at a density"),
               ("TRANSFORMER", "HyperGS Transformer", "The HyperGS paper's transformer: the frame as a patch grid "
                                                     "of tiles, a Gaussian count per tile (its weights: bundled, "
                                                     "or the folder set in the add-on's preferences)")])
    quality: EnumProperty(
        name="Quality", default="STANDARD",
        items=[_preset_item("draft", "Draft"), _preset_item("standard", "Standard"), _preset_item("high", "High"),
               (CUSTOM, "Custom", "Choose the cell size (or a Gaussian count) and the refine steps")])
    cell_size: FloatProperty(name="Cell Size", default=QUALITY["standard"]["cell"], min=1.0, soft_min=4.0,
                             max=MAX_CELL, precision=1, subtype="PIXEL",
                             description="Source pixels per Gaussian along each side (smaller: more Gaussians, "
                                         "sharper, slower); the count follows the video's resolution")
    gaussian_count: IntProperty(name="Gaussians", default=0, min=0, max=10_000_000,
                                description="Gaussians per frame (the transformer: per tile) instead of a cell size "
                                            "(0: from the cell size)")
    patch_grid: IntVectorProperty(name="Patch Grid", size=2, default=(0, 0), min=0, max=64,
                                  description="The transformer's tiles, columns and rows (0: tiles of its canvas "
                                              "size at the source's resolution)")
    refine_steps: IntProperty(name="Refine Steps", default=0, min=0, max=1000,
                              description="Steps of per-frame fitting after the network (sharper, much slower; "
                                          "needs PyTorch)")


def settings(options) -> EncodeSettings:
    """The options as the encode's settings (a preset's, or the custom ones; the model, and the
    transformer's patch grid), as this Blender can run them."""
    model = options.model.lower()
    grid = tuple(options.patch_grid) if model == "transformer" and min(options.patch_grid) > 0 else None
    if options.quality == CUSTOM:
        chosen = EncodeSettings.choose(gaussians=options.gaussian_count or None, cell=options.cell_size,
                                       refine=options.refine_steps, grid=grid, model=model)
    else:
        chosen = EncodeSettings.choose(options.quality.lower(), grid=grid, model=model)
    return chosen.runnable()


def copy_options(source, target) -> None:
    """Copy the encode options (e.g. an operator's into the clip's settings, for Re-encode)."""
    for name in ("model", "quality", "cell_size", "gaussian_count", "refine_steps", "patch_grid"):
        setattr(target, name, getattr(source, name))


_probed: dict = {}


def source_info(source: Source):
    """probe() of a source's video or image sequence, kept while the file is unchanged (dialogs redraw often)."""
    path = source.path
    try:
        st = os.stat(path)
        key = (path, st.st_size, st.st_mtime_ns, source.display)
    except OSError:
        key = (path, None, None, source.display)  # an image-sequence pattern: probe says what is wrong
    if key not in _probed:
        if len(_probed) > 64:
            _probed.clear()
        _probed[key] = probe(path, source.display)
    return _probed[key]


@dataclass(frozen=True)
class Plan:
    """What the options give for one source: its size, the Gaussians' layout, frames, estimate."""
    source: Source
    width: int
    height: int
    layout: Layout
    frames: int
    estimate: Estimate


def plan(sources: list[Source], chosen: EncodeSettings, runtime: Runtime) -> list[Plan]:
    """The layout and estimate of each source. Raises HyperGSError (a source or the encoder's problem)."""
    encoder = make_encoder(runtime, chosen.model)  # loaded once; the encode uses it too
    plans = []
    for source in sources:
        info = source_info(source)
        stop = info.num_frames if source.stop is None else min(source.stop, info.num_frames)
        frames = max(0, stop - source.start)
        layout = chosen.layout(info.width, info.height, encoder)
        plans.append(Plan(source, info.width, info.height, layout, frames,
                          estimate(layout, frames, chosen.refine, encoder.name, runtime.cpu_threads,
                                   hdr=info.hdr is not None)))
    return plans


def draw(layout, options, sources, runtime: Runtime) -> None:
    """The options, then what they give for `sources` (or why it cannot be told). `sources`: a list of
    Source, or a callable returning one (it may raise HyperGSError)."""
    layout.use_property_split = True
    layout.use_property_decorate = False
    col = layout.column()
    transformer = options.model == "TRANSFORMER"
    if transformer or transformer_available(runtime):  # offered where its weights are (else: the conv network)
        col.prop(options, "model")
    col.row().prop(options, "quality", expand=True)
    if options.quality == CUSTOM:
        sub = col.column(align=True)
        sub.prop(options, "cell_size")
        sub.prop(options, "gaussian_count", text="Gaussians per Tile" if transformer else "Gaussians")
        sub.prop(options, "refine_steps")
    if transformer:
        col.prop(options, "patch_grid")
    box = layout.box().column(align=True)
    chosen = settings(options)
    try:
        plans = plan(sources() if callable(sources) else sources, chosen, runtime)
    except HyperGSError as e:
        box.alert = True
        box.label(text=str(e), icon="ERROR")
        return
    for line, icon in summary(plans, chosen):
        box.label(text=line, icon=icon)


def summary(plans: list[Plan], chosen: EncodeSettings) -> list[tuple[str, str]]:
    """The dialog's lines (text, icon): per source its Gaussians per frame, then frames, time and size."""
    lines = []
    for p in plans[:3]:
        name = f"{p.source.name}: " if len(plans) > 1 else ""
        lines.append((f"{name}{p.layout.count:,} Gaussians per frame ({_where(p.layout)} at {p.width} x {p.height})",
                      "MOD_PARTICLES"))
    if len(plans) > 3:
        lines.append((f"and {len(plans) - 3} more clips", "BLANK1"))
    frames = sum(p.frames for p in plans)
    seconds = sum(p.estimate.seconds for p in plans)
    size = sum(p.estimate.cache_bytes for p in plans)
    refine = f", refined {chosen.refine} steps" if chosen.refine else ""
    threads = plans[0].estimate.threads if plans else 1
    lines.append((f"{frames} frames{refine}: about {_duration(seconds)} on {threads} CPU thread"
                  f"{'s' if threads > 1 else ''}, {_megabytes(size)} of frame cache", "TIME"))
    for note in [p.layout.note for p in plans if p.layout.note][:1] + ([chosen.note] if chosen.note else []):
        lines.append((note, "INFO"))
    return lines


def _where(layout: Layout) -> str:
    """Where a layout puts the Gaussians: cells, or the transformer's tiles (encode.TileLayout)."""
    if hasattr(layout, "tiles"):
        columns, rows = layout.tiles
        return f"{columns} x {rows} tiles of {layout.per_tile:,}, cells of {layout.cell:.1f} px"
    return f"{layout.cols} x {layout.rows} cells of {layout.cell:.1f} px"


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{max(1, round(seconds))} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _megabytes(size: float) -> str:
    return f"{size / 1e6:.1f} MB" if size < 1e9 else f"{size / 1e9:.1f} GB"
