"""Every `hypergs` argument is checked here, while the command line is parsed and before any work:
argparse types for numbers (positive counts, sizes and frames within limits.py), inputs that must
exist and outputs that must be writable (io/files.check_output), with `Parser` printing a bad value
as one line, `hypergs <command>: error: argument --x: ...`, exit status 2. `check_paths` then refuses
an output that is one of the command's inputs (also through a link).

Every argument that takes a value has a type from here or `choices` (tests/test_cli_arguments.py
checks this for every subcommand and passes each type's `refused` examples to it).
"""
from __future__ import annotations

import argparse
import json
import math
from dataclasses import replace
from pathlib import Path

from .. import limits
from ..encode import ADAPTIVE_MIN_REFINE, DEFAULT_QUALITY, QUALITY, EncodeSettings
from ..errors import HyperGSError, one_line
from ..io import files
from ..network import BACKENDS, DEFAULT_NAMES, PRECISIONS, WEIGHTS_DIR, resolve_encoder

BIGGEST = 1 << 31  # no count or size of ours goes past this: int32 everywhere


class Parser(argparse.ArgumentParser):
    """argparse with one-line errors (`hypergs encode: error: ...`, exit 2); the usage is behind -h."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {one_line(message)}\n")


class ArgType:
    """An argparse type: called with the text, returns the value or raises ArgumentTypeError.
    `refused`: texts it must refuse (the tests pass them to every argument of this type)."""

    refused: tuple[str, ...] = ()

    def __repr__(self) -> str:  # argparse names the type in some messages
        return type(self).__name__.lower()


class Integer(ArgType):
    """A whole number in [low, high], or in [low, limit] for a limits.Limit (read when parsing)."""

    def __init__(self, low: int, high: int = BIGGEST, limit: limits.Limit | None = None):
        self.low, self.high, self.limit = low, high, limit
        self.refused = ("abc", "1.5", "", str(low - 1), str(10 ** 30)) + (("-5",) if low > -5 else ())

    def __call__(self, text: str) -> int:
        try:
            value = int(text, 10)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a whole number") from None
        if value < self.low:
            raise argparse.ArgumentTypeError(f"must be at least {self.low}, got {value}")
        if self.limit is not None:
            _check_limit(self.limit, value)
        if value > self.high:
            raise argparse.ArgumentTypeError(f"must be at most {self.high}, got {value}")
        return value


class Real(ArgType):
    """A finite number above `low` (or equal to it when `inclusive`), at most `high` (below it when not
    `high_inclusive`)."""

    def __init__(self, low: float, inclusive: bool = False, high: float = math.inf, high_inclusive: bool = True):
        self.low, self.inclusive, self.high, self.high_inclusive = low, inclusive, high, high_inclusive
        below = low - 1 if inclusive else low
        above = () if high == math.inf else (repr(high * 2 + 1),) if high_inclusive else (repr(high),)
        self.refused = ("abc", "", "nan", "inf", repr(below)) + above

    def __call__(self, text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a number") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"must be a finite number, got {text!r}")
        if value < self.low or (value == self.low and not self.inclusive):
            raise argparse.ArgumentTypeError(f"must be {'at least' if self.inclusive else 'above'} {self.low:g}, "
                                             f"got {value:g}")
        if value > self.high or (value == self.high and not self.high_inclusive):
            raise argparse.ArgumentTypeError(f"must be {'at most' if self.high_inclusive else 'below'} {self.high:g}, "
                                             f"got {value:g}")
        return value


class Text(ArgType):
    """Any non-empty text (free-form: a data spec, a codec name, a prim path)."""

    refused = ("",)

    def __call__(self, text: str) -> str:
        if not text.strip():
            raise argparse.ArgumentTypeError("must not be empty")
        return text


class ConfigItem(ArgType):
    """FIELD=VALUE: a field of a network config (model.py's dataclasses) and its value, read as JSON (a
    number, a list) or else as text."""

    refused = ("", "mid", "=1", "no_such_field=1")

    def __call__(self, text: str) -> tuple[str, object]:
        from dataclasses import fields

        from ..model import ConvConfig, TransformerConfig
        field, sep, value = text.partition("=")
        if not sep or not field or not value:
            raise argparse.ArgumentTypeError(f"expected FIELD=VALUE, got {text!r}")
        known = {f.name for cls in (ConvConfig, TransformerConfig) for f in fields(cls)} - {"arch"}
        if field not in known:
            raise argparse.ArgumentTypeError(f"{field!r} is not a network config field ({', '.join(sorted(known))})")
        try:
            return field, json.loads(value)
        except ValueError:
            return field, value


class Part(ArgType):
    """A part of a network: a module's dotted name (head, error_pass, or encoder.0.4 for one block inside a
    part; checked when the run starts)."""

    refused = ("", "a..b", ".head", "head.", "=3", "head=2", "a-b")

    def __call__(self, text: str) -> str:
        if not all(piece.isidentifier() or piece.isdigit() for piece in text.split(".")):
            raise argparse.ArgumentTypeError(f"expected a part of the network (a module's dotted name), got {text!r}")
        return text


class LrScale(ArgType):
    """PART=FACTOR: a part of a network (a module's dotted name: head, stem, encoder.0.4, ...; checked when the run
    starts) and a positive learning-rate factor for its parameters."""

    refused = ("", "head", "head=", "=3", "head=0", "head=-1", "head=abc", "a..b=2")

    def __call__(self, text: str) -> tuple[str, float]:
        part, sep, value = text.partition("=")
        if not sep:
            raise argparse.ArgumentTypeError(f"expected PART=FACTOR (a part of the network), got {text!r}")
        return Part()(part), positive_float(value)


class Name(ArgType):
    """A file name without a folder (the stem of files written into a folder)."""

    refused = ("", "a/b", "..")

    def __call__(self, text: str) -> str:
        if not text.strip() or Path(text).name != text or text in (".", ".."):
            raise argparse.ArgumentTypeError(f"must be a file name without a folder, got {text!r}")
        return text


class InputFile(ArgType):
    """An existing file, with one of `suffixes` when given."""

    def __init__(self, suffixes=()):
        self.suffixes = tuple(suffixes)
        self.refused = ("", "/nonexistent/input" + (self.suffixes[0] if self.suffixes else ".bin"))

    def __call__(self, text: str) -> str:
        path = Path(text)
        if self.suffixes and path.suffix.lower() not in self.suffixes:
            raise argparse.ArgumentTypeError(f"{text}: must end in {', '.join(self.suffixes)}")
        if not text or not path.is_file():
            raise argparse.ArgumentTypeError(f"{text}: no such file")
        return text


class InputVideo(ArgType):
    """A video file, an image sequence's folder or file, or a frame-number pattern (`shot.####.exr`)
    whose folder exists (io/image_sequence.py reads the rest)."""

    refused = ("", "/nonexistent/video.mp4", "/nonexistent/shot.####.png")

    def __call__(self, text: str) -> str:
        from ..io.image_sequence import has_frame_pattern
        path = Path(text)
        if text and (path.exists() or (has_frame_pattern(path.name) and path.parent.is_dir())):
            return text
        raise argparse.ArgumentTypeError(f"{text}: no such video, image sequence or folder")


class InputFolder(ArgType):
    refused = ("", "/nonexistent/folder")

    def __call__(self, text: str) -> str:
        if not text or not Path(text).is_dir():
            raise argparse.ArgumentTypeError(f"{text}: no such folder")
        return text


class ModelWeights(ArgType):
    """A trained model: a weights folder, or a model's card in one (<folder>/<name>.json)."""

    refused = ("", "/nonexistent/folder", "/nonexistent/model.json")

    def __call__(self, text: str) -> str:
        path = Path(text)
        if text and (path.is_dir() or (path.suffix == ".json" and path.is_file())):
            return text
        raise argparse.ArgumentTypeError(f"{text}: no weights folder or model card (.json)")


class OutputFile(ArgType):
    """A file to write: one of `suffixes` (when given) in an existing, writable folder, not a folder."""

    def __init__(self, suffixes=()):
        self.suffixes = tuple(suffixes)
        suffix = self.suffixes[0] if self.suffixes else ".out"
        self.refused = ("", "/nonexistent/folder/out" + suffix, "a\0b" + suffix) + (
            ("out.bogus",) if self.suffixes else ())

    def __call__(self, text: str) -> str:
        if not text:
            raise argparse.ArgumentTypeError("must not be empty")
        try:
            files.check_output(text, self.suffixes)
        except HyperGSError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        return text


class OutputFolder(ArgType):
    """A folder to write files into: it exists, or its parent does (it is created when written); with
    `parents`, any of its ancestors may be missing (a run folder, runs/small)."""

    def __init__(self, parents: bool = False):
        self.parents = parents
        self.refused = ("", "a\0b", "/proc/version/out" if parents else "/nonexistent/folder/out")

    def __call__(self, text: str) -> str:
        if not text:
            raise argparse.ArgumentTypeError("must not be empty")
        path = Path(text)
        while self.parents and not path.parent.exists() and path.parent != path:
            path = path.parent
        try:
            files.check_output_folder(path)
        except HyperGSError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        return text


class Resolution(ArgType):
    """WIDTHxHEIGHT within the image limits -> (width, height)."""

    refused = ("abc", "", "0x10", "-5x10", "100000x10", "10x")

    def __call__(self, text: str) -> tuple[int, int]:
        try:
            width, height = (int(v, 10) for v in text.lower().split("x"))
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT (e.g. 1920x1080)") from None
        try:
            limits.check_image_size(width, height, text)
        except HyperGSError as e:
            raise argparse.ArgumentTypeError(str(e)) from None
        return width, height


class FrameSize(ArgType):
    """How a bench takes its frames: a square size N (image_side), 'cropN' (an N x N centre crop) or
    'native'; returned as text ('256', 'crop480', 'native')."""

    refused = ("abc", "", "0", "-3", "100000", "crop0", "crop")

    def __call__(self, text: str) -> str:
        if text == "native":
            return text
        if text.startswith("crop"):
            return "crop" + str(image_side(text[4:]))
        return str(image_side(text))


class GaussianRange(ArgType):
    """'N' or 'MIN:MAX' Gaussians per frame (1 <= MIN <= MAX within the limit); returned as text."""

    refused = ("abc", "", "0:10", "10:5", "1:2000000000", "5:")

    def __call__(self, text: str) -> str:
        parts = text.split(":")
        if len(parts) > 2:
            raise argparse.ArgumentTypeError(f"{text!r} is not N or MIN:MAX")
        low, high = gaussian_count(parts[0]), gaussian_count(parts[-1])
        if low > high:
            raise argparse.ArgumentTypeError(f"{text!r}: MIN is above MAX")
        return text


class PatchGrid(ArgType):
    """The transformer's patch grid: 'G' (G x G tiles) or 'COLSxROWS' -> (columns, rows)."""

    refused = ("abc", "", "0", "-2", "2x", "0x3", "3x0", "1x2x3", "99999")

    def __call__(self, text: str) -> tuple[int, int]:
        parts = text.lower().split("x")
        if len(parts) > 2:
            raise argparse.ArgumentTypeError(f"{text!r} is not G or COLSxROWS (e.g. 2 or 3x2)")
        side = Integer(1, high=1024)
        columns, rows = side(parts[0]), side(parts[-1])
        return columns, rows


class ScheduleSteps(ArgType):
    """`hypergs train --steps`: a whole number of steps, or 'auto' (the trainer sizes the schedule to
    --minutes from the warm-up's step rate; returned as the text)."""

    refused = ("abc", "", "0", "-5", "1.5", "Auto ")

    def __call__(self, text: str) -> int | str:
        return text if text == "auto" else positive_int(text)


def _check_limit(limit: limits.Limit, value) -> None:
    try:
        limit.check(value, "")
    except HyperGSError as e:
        raise argparse.ArgumentTypeError(str(e)) from None


positive_int = Integer(1)
non_negative_int = Integer(0)
gaussian_count = Integer(1, limit=limits.GAUSSIANS)
frame_count = Integer(1, limit=limits.FRAMES)
frame_index = Integer(0, limit=limits.FRAMES)
image_side = Integer(1, limit=limits.SIDE)
positive_float = Real(0.0)
non_negative_float = Real(0.0, inclusive=True)
fraction = Real(0.0, inclusive=True, high=1.0)
decay = Real(0.0, inclusive=True, high=1.0, high_inclusive=False)  # 1 would never move
text = Text()
config_item = ConfigItem()
schedule_steps = ScheduleSteps()
lr_scale = LrScale()
part = Part()
name = Name()
input_video = InputVideo()
input_folder = InputFolder()
model_weights = ModelWeights()
output_folder = OutputFolder()
run_folder = OutputFolder(parents=True)
resolution = Resolution()
frame_size = FrameSize()
gaussian_range = GaussianRange()
patch_grid = PatchGrid()


def command_parser(parser: argparse.ArgumentParser, args: argparse.Namespace) -> argparse.ArgumentParser:
    """The parser of the (sub)command `args` were parsed for."""
    while parser._subparsers is not None:
        action = next(a for a in parser._subparsers._group_actions if isinstance(a, argparse._SubParsersAction))
        parser = action.choices[getattr(args, action.dest)]
    return parser


def check_paths(parser: argparse.ArgumentParser, args: argparse.Namespace) -> None:
    """Refuse (parser.error) an output file that is one of the command's inputs, also through a link:
    `-o link.npz` where link.npz points at the input video."""
    def values(kinds):
        for action in parser._actions:
            if isinstance(action.type, kinds):
                value = getattr(args, action.dest, None)
                for v in (value if isinstance(value, list) else [value]):
                    if v is not None:
                        yield action, v
    for out_action, output in values(OutputFile):
        for in_action, source in values((InputFile, InputVideo, InputFolder)):
            if files.same_file(output, source):
                parser.error(f"argument {'/'.join(out_action.option_strings) or out_action.dest}: {output} "
                             f"is the input {source}; choose another output")


def add_encoder_arguments(parser) -> None:
    parser.add_argument("--encoder", default="network", choices=["network", "floor"],
                        help="the trained network, or the grid floor (no learning)")
    add_backend_arguments(parser)
    add_model_arguments(parser)


def add_backend_arguments(parser) -> None:
    """What runs the network: torch or onnxruntime, and torch's arithmetic (network.PRECISIONS)."""
    parser.add_argument("--backend", default="auto", choices=BACKENDS,
                        help="torch where it and the .safetensors weights are there, else onnxruntime (auto)")
    add_precision_argument(parser)


def add_precision_argument(parser) -> None:
    parser.add_argument("--precision", default="float32", choices=PRECISIONS,
                        help="the torch backend's arithmetic: bfloat16 is 1.5-2x faster on a CPU with AMX (slower "
                             "without) and up to 0.15 dB lower where the PSNR is highest")


def add_model_arguments(parser) -> None:
    """Which trained model: a weights folder (either design; its card says which), and a name."""
    parser.add_argument("--weights", default=None, type=input_folder,
                        help="folder with <name>.json/.safetensors/.onnx (default: the bundled models)")
    parser.add_argument("--model", default=None, type=name,
                        help="the model's name in that folder, e.g. hypergs_transformer, or a design as Blender's "
                             "dialogs name it (conv, transformer: the name `hypergs export` gives it) (default: "
                             "hypergs, or the folder's only model)")


def weights_from_args(args):
    """What resolve_encoder loads for --weights and --model: the folder, or the named model's card in it
    (default folder: the bundled models). A design's name (network.DEFAULT_NAMES: conv, transformer) stands
    for the name `hypergs export` gives it, unless the folder holds a model of that very name."""
    if args.model is None:
        return args.weights
    folder = Path(args.weights or WEIGHTS_DIR)
    card = folder / f"{args.model}.json"
    if not card.is_file() and args.model in DEFAULT_NAMES:
        card = folder / f"{DEFAULT_NAMES[args.model]}.json"
    return card


def add_settings_arguments(parser, default: str = DEFAULT_QUALITY) -> None:
    """What the encode is asked for (encode.EncodeSettings): a Quality preset, a Gaussian count per
    frame (the transformer: per tile) or a cell size (one Gaussian per cell x cell source pixels),
    refine steps, and the transformer's patch grid."""
    group = parser.add_mutually_exclusive_group()
    group.add_argument("--quality", choices=list(QUALITY), default=None,
                       help="a preset: " + ", ".join(f"{name} (cells of {p['cell']:g} px"
                                                      + (f", refined {p['refine']} steps)" if p["refine"] else ")")
                                                      for name, p in QUALITY.items()) + f"; default {default}")
    group.add_argument("--gaussians", type=gaussian_count, default=None,
                       help="Gaussians per frame (about; on a grid of cells); the transformer: per patch-grid tile")
    group.add_argument("--cell", type=positive_float, default=None, help="source pixels per Gaussian cell side")
    parser.add_argument("--refine", type=non_negative_int, default=None,
                        help="per-frame refinement steps after the prediction (default: the preset's, else 0)")
    parser.add_argument("--uniform-start", action="store_true",
                        help=f"refine from the network's grid of cells, not from its content-adaptive start (which a "
                             f"refinement of {ADAPTIVE_MIN_REFINE} steps or more takes where it pays; for comparisons)")
    parser.add_argument("--grid", type=patch_grid, default=None,
                        help="the transformer's patch grid, G or COLSxROWS tiles (default: tiles of its canvas size "
                             "at the frame's resolution)")
    parser.set_defaults(default_quality=default)


def settings_from_args(args) -> EncodeSettings:
    settings = EncodeSettings.choose(args.quality, args.gaussians, args.cell, args.refine,
                                     default=args.default_quality, grid=args.grid)
    return replace(settings, adaptive=not args.uniform_start)


def encoder_from_args(args, device=None):
    return resolve_encoder(args.encoder, args.backend, weights_from_args(args), device, precision=args.precision)
