"""What an encode reads, from what the user picked: a video file or an image sequence (`check_video_path`),
the selected Sequencer strips (`strips_to_convert`, `strip_source`: a strip's shown frames of its
source) and a clip's own source (`reencode_source`), each as a jobs.Source whose video frames are what this
Blender's movie strips show (compat.MOVIE_DISPLAY); and the name a clip object
takes from its source (`clip_name`)."""
from __future__ import annotations

import os
import re

import bpy

from ..com.compat import MOVIE_DISPLAY, all_strips, strip_range, strip_source_first
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io import image_sequence
from .jobs import Source


def check_video_path(path: str) -> str:
    """An absolute path to a video file or an image sequence (a file of it, a frame-number pattern
    such as `shot_####.png`, or its folder); raises HyperGSError naming what is wrong."""
    if not path:
        raise HyperGSError("No video file given")
    path = bpy.path.abspath(path)
    if image_sequence.is_image_sequence(path):
        image_sequence.list_frames(path)  # VideoError: no such file / no matching files / ...
        return path
    if not os.path.isfile(path):
        raise HyperGSError(f"{path}: no such video file")
    return path


_FRAME_FIELD = re.compile(r"(#+|%0?\d*d|\{frame(:0?\d*d)?\}|\d+)$")


def clip_name(path: str) -> str:
    """Object name for a source: the file's stem; for an image sequence without its frame number."""
    p = os.path.normpath(path)
    if not image_sequence.is_image_sequence(p):
        return os.path.splitext(os.path.basename(p))[0]
    stem = os.path.basename(p) if os.path.isdir(p) else os.path.splitext(os.path.basename(p))[0]
    name = _FRAME_FIELD.sub("", stem).rstrip("._- ")
    return name or os.path.basename(os.path.dirname(p)) or "sequence"


def sequencer_scene(context):
    """The scene whose Sequencer the context shows (5.x: the sequencer scene)."""
    return getattr(context, "sequencer_scene", None) or context.scene


def strips_to_convert(editor) -> list:
    """The movie and image strips to convert: the selected ones, or the active one when none is
    selected. Raises HyperGSError when there is none."""
    chosen = [s for s in all_strips(editor) if s.select] if editor is not None else []
    if not chosen and editor is not None and editor.active_strip is not None:
        chosen = [editor.active_strip]
    if not chosen:
        raise HyperGSError("No strip selected: select movie or image-sequence strips in the Sequencer")
    strips = [s for s in chosen if s.type in ("MOVIE", "IMAGE")]
    if not strips:
        names = ", ".join(f"'{s.name}'" for s in chosen[:3]) + (", ..." if len(chosen) > 3 else "")
        raise HyperGSError(f"{names}: not a movie strip or an image sequence")
    return strips


def strip_source(strip) -> Source:
    """What a movie or image strip shows: its source's frames from the strip's first shown one on, as
    many as the strip is long. Raises HyperGSError (a missing file, images that are not a sequence)."""
    library = getattr(strip.id_data, "library", None)
    first = strip_source_first(strip)  # index of the strip's first shown frame in its source
    start, end = strip_range(strip)
    count = end - start
    if strip.type == "IMAGE":
        path, first = _image_strip_source(strip, library, first, count)
    else:
        path = check_video_path(bpy.path.abspath(strip.filepath, library=library))
    return Source(strip.name, path, first, first + count, display=MOVIE_DISPLAY)


def _image_strip_source(strip, library, first: int, count: int) -> tuple[str, int]:
    """(the sequence's first file, index of the strip's first shown image among the sequence's files)
    for an image strip. The strip's images from `first` on must be consecutive files of one
    numbered sequence (what Add > Image/Sequence makes): the encoder reads that sequence."""
    names = [element.filename for element in strip.elements]
    used = names[first:first + count]
    if len(names) < 2 or len(used) < count or not used:
        raise HyperGSError(f"The strip '{strip.name}' shows a single image, not an image sequence")
    directory = bpy.path.abspath(strip.directory, library=library)
    path = check_video_path(os.path.join(directory, used[0]))
    frames = image_sequence.list_frames(path)
    position = {os.path.normcase(f.name): i for i, (_, f) in enumerate(frames)}
    start = position.get(os.path.normcase(used[0]))
    if start is None or [position.get(os.path.normcase(n)) for n in used] != list(range(start, start + count)):
        raise HyperGSError(f"The images of the strip '{strip.name}' are not consecutive files of one numbered "
                           f"sequence in {directory} (such as {used[0]} and the files numbered after it)")
    return str(frames[0][1]), start  # the sequence's first file: `start` counts from it (as re-encode does)


def reencode_source(obj) -> Source:
    """The frames a clip was encoded from, at the clip's frame rate (what Re-encode encodes again)."""
    s = obj.hypergs
    return Source(obj.name, check_video_path(s.source), s.source_start, s.source_start + s.num_frames, s.fps,
                  MOVIE_DISPLAY)
