"""Where a linked clip's .hgs file is, as the .blend stores it (`Object.hypergs.linked_path`): relative
to the .blend's folder ("//clip.hgs") where possible, so a project folder can move, absolute otherwise.

- Linking a clip stores its path relative when the .blend is saved and Preferences > File Paths >
  Default to Relative Paths is on (Blender's default), as Blender's own file browsers do; else absolute.
- Every save keeps the paths pointing at the same files: with that preference on, absolute paths become
  relative to where the .blend is saved (what File > External Data > Make Paths Relative does for
  Blender's own paths: it walks only those, not an add-on's properties), and relative paths are
  re-based when the .blend goes to another folder (Save As; Save Copy leaves the open file's as they
  were), as Blender's `relative_remap` does for its own.
- A path typed into the panel is kept as typed; `//` works everywhere (bpy.path.abspath).
Objects linked from a library keep their paths (relative to their library, see mesh.linked_file).
"""
from __future__ import annotations

import os

import bpy
from bpy.app.handlers import persistent

from . import add_handlers, remove_handlers


def stored_path(path: str, blend: str | None = None) -> str:
    """How to store the absolute `path` in the .blend saved at `blend` (default: the open one)."""
    blend = bpy.data.filepath if blend is None else blend
    if not blend or not bpy.context.preferences.filepaths.use_relative_paths:
        return path
    return _relative(path, blend)


def _relative(path: str, blend: str) -> str:
    try:
        return bpy.path.relpath(path, start=os.path.dirname(blend))
    except ValueError:  # on another drive (Windows): only an absolute path reaches it
        return path


def _linked_objects():
    for obj in bpy.data.objects:
        if obj.library is None and obj.type == "MESH" and obj.hypergs.linked and obj.hypergs.linked_path:
            yield obj


_before_save: list = []  # (object, its stored path) changed by the save running now


def rebasing() -> bool:
    """Whether a save is re-basing paths now: each still names the same file (nothing to re-read),
    though until the save ends it resolves from the .blend's old folder."""
    return bool(_before_save)


@persistent
def _save_pre(filepath, *args):
    _before_save.clear()
    if not filepath:
        return
    relative = bpy.context.preferences.filepaths.use_relative_paths
    changes = []
    for obj in _linked_objects():
        stored = obj.hypergs.linked_path
        if not (relative or stored.startswith("//")):
            continue  # absolute by the user's choice
        new = _relative(bpy.path.abspath(stored), filepath)  # abspath: from where the .blend is now
        if new != stored:
            changes.append((obj, stored, new))
    _before_save.extend((obj, stored) for obj, stored, _ in changes)
    for obj, _, new in changes:
        obj.hypergs.linked_path = new


def _restore():
    saved = list(_before_save)
    for obj, stored in saved:
        obj.hypergs.linked_path = stored
    _before_save.clear()


@persistent
def _save_post(filepath, *args):
    if os.path.normcase(os.path.abspath(bpy.data.filepath)) != os.path.normcase(os.path.abspath(filepath)):
        _restore()  # Save Copy: the open file stays where it was, its paths as they were
    _before_save.clear()


@persistent
def _save_post_fail(filepath, *args):
    _restore()


HANDLERS = (("save_pre", _save_pre), ("save_post", _save_post), ("save_post_fail", _save_post_fail))


def register():
    add_handlers(HANDLERS)


def unregister():
    remove_handlers(HANDLERS)
