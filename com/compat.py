"""What differs between the Blender versions the extension runs in (4.2 LTS to 5.3), feature-detected
here and nowhere else, so the rest of the glue is written once:

- Geometry Nodes modifier inputs: `modifier.properties.inputs.<identifier>.value` since 5.2 (where
  `modifier[identifier] = value` raises TypeError), `modifier[identifier]` before.
- Sequencer strips: `editor.strips` since 4.5 (`sequences` before); a strip's timing as
  `left_handle` / `right_handle` / `duration` / `content_start` / `content_trim_start` since 5.2,
  where the older `frame_final_*`, `frame_start` and `animation_offset_start` warn that they go in 6.0.
- File-path properties that accept `//` (relative to the .blend): the PATH_SUPPORTS_BLEND_RELATIVE
  option exists since 4.5; without it Blender 4.2 still resolves `//` through bpy.path.abspath.
- What a movie strip shows of a video (MOVIE_DISPLAY, by version: nothing in the API tells): the container's
  display rotation since 4.4, HDR video colour-managed since 5.0 (before, its coded values as sRGB). Measured
  with the bpy wheels on a rotated HLG video: 4.2.23 and 4.3.0 show it as stored, 4.4.0 and 4.5.15 upright with
  mid-grey 128 as 128, 5.0.1 upright with 128 as 189 (its strip's colour space "Rec.2100-HLG").
- A mesh's first entry into Edit Mode (Tab or an operator) after its attributes were made makes another
  attribute active in 5.1 (measured in 5.1.2: `rotation` or `position`); 5.0 and 5.2 keep the active one
  (EDIT_MODE_KEEPS_ACTIVE_ATTRIBUTE).
"""
from __future__ import annotations

import bpy

from ..hypergs_blender.io.video import Display

_STRIP = getattr(bpy.types, "Strip", None) or bpy.types.Sequence  # renamed in 4.5
_NEW_TIMING = "left_handle" in _STRIP.bl_rna.properties
_PATH_RELATIVE = "is_path_supports_blend_relative" in bpy.types.Property.bl_rna.properties
MOVIE_DISPLAY = Display(rotation=bpy.app.version >= (4, 4, 0), hdr=bpy.app.version >= (5, 0, 0))
EDIT_MODE_KEEPS_ACTIVE_ATTRIBUTE = not (5, 1, 0) <= bpy.app.version < (5, 2, 0)


def set_modifier_input(modifier, identifier: str, value) -> None:
    """Set the input `identifier` (e.g. "Socket_2") of a Geometry Nodes modifier."""
    properties = getattr(modifier, "properties", None)
    if properties is not None:
        getattr(properties.inputs, identifier).value = value
    else:
        modifier[identifier] = value


def modifier_input(modifier, identifier: str):
    """The value of a Geometry Nodes modifier's input `identifier`."""
    properties = getattr(modifier, "properties", None)
    if properties is not None:
        return getattr(properties.inputs, identifier).value
    return modifier[identifier]


def top_strips(editor):
    """The editor's top-level strips (the collection with new_movie, new_scene, remove, ...)."""
    return editor.strips if hasattr(editor, "strips") else editor.sequences


def strip_siblings(editor, strip):
    """The strips collection `strip` lies in: its meta strip's, or the editor's top level."""
    meta = strip.parent_meta()
    return top_strips(meta if meta is not None else editor)


def all_strips(editor):
    """Every strip, meta strips' contents included."""
    return editor.strips_all if hasattr(editor, "strips_all") else editor.sequences_all


def strip_range(strip) -> tuple[int, int]:
    """(first, end) timeline frames the strip shows: [first, end), handles applied."""
    if _NEW_TIMING:
        return int(strip.left_handle), int(strip.right_handle)
    return int(strip.frame_final_start), int(strip.frame_final_end)


def strip_source_first(strip) -> int:
    """Index in its source (movie frames, or the strip's images) of the first frame a movie or image
    strip shows: trims, held frames and the handle's offset from the content's start."""
    if _NEW_TIMING:
        first = strip.left_handle - strip.content_start + strip.content_trim_start
    else:
        first = strip.frame_final_start - strip.frame_start + strip.animation_offset_start
    return max(0, int(round(first)))


def path_options() -> set[str]:
    """StringProperty options for a file path stored in the .blend that may start with `//`."""
    return {"PATH_SUPPORTS_BLEND_RELATIVE"} if _PATH_RELATIVE else set()
