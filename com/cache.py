"""Where a clip's frames live: its frame cache file (hypergs_blender/io/cache.py), held by an Image
datablock, and the session's FrameCache that reads them.

Why an Image datablock: it is Blender's own external-file reference, so everything Blender does with
external data applies to the cache with no code of ours: paths stored relative to the .blend (`//`,
re-based on Save As), File > External Data (Make Paths Relative / Absolute, Report Missing Files,
Find Missing Files, Pack Resources, Unpack Resources), `Image.pack()` / `unpack()` (Blender's
PackedFile: kept in the .blend, undo steps share it instead of copying it: measured 1-5 ms per undo
push with 300 MB packed, against 25-200 ms and a second copy in memory for the same bytes in an ID
property), and farm packers that follow a .blend's file dependencies (Blender Asset Tracer) take the
cache along. The image is never decoded (Blender loads image pixels only when something displays
them, and then finds no image in the file). Its name starts with a dot, which keeps it out of the
image menus.

Where new caches go: `<blend name>_hypergs/` beside the saved .blend; before the .blend is first saved,
the session's temporary folder (bpy.app.tempdir, removed when Blender quits, as unsaved work is), and
the first save moves them beside the .blend (`_save_pre`), as Blender does with bakes.

A packed cache is written out once per session to the temporary folder and read from there (reading
`packed_file.data` copies all of it every time: ~1 s per 300 MB).
"""
from __future__ import annotations

import os
import shutil

import bpy
from bpy.app.handlers import persistent

from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.io.cache import FrameCache
from ..hypergs_blender.io.files import AtomicOutput, write_bytes
from . import add_handlers, remove_handlers
from .paths import stored_path

FRAMES = FrameCache()
FOLDER_SUFFIX = "_hypergs"
SUFFIX = ".hgs"
_extracted: dict = {}  # (image session uid, packed size) -> the temporary file holding its bytes


def temp_folder() -> str:
    return os.path.join(bpy.app.tempdir, "hypergs")


def cache_folder(blend: str | None = None) -> str:
    """The folder new caches go to: beside the .blend saved at `blend` (default: the open one), or the
    session's temporary folder while the .blend has never been saved."""
    blend = bpy.data.filepath if blend is None else blend
    if not blend:
        return temp_folder()
    stem = os.path.splitext(os.path.basename(blend))[0]
    return os.path.join(os.path.dirname(os.path.abspath(blend)), stem + FOLDER_SUFFIX)


def is_temporary(path: str) -> bool:
    return os.path.normcase(os.path.abspath(path)).startswith(os.path.normcase(temp_folder()) + os.sep)


def new_cache_path(name: str, taken=()) -> str:
    """A path for a new cache of the clip `name` in cache_folder(), naming no file and none of `taken`
    (the folder is made by whoever writes it: jobs.EncodeJob). Every conversion gets its own file, so
    undoing one still finds the cache it replaced."""
    return _free_path(cache_folder(), bpy.path.clean_name(name) or "clip", taken)


def _free_path(folder: str, stem: str, taken=()) -> str:
    taken = {os.path.normcase(p) for p in taken}
    for i in range(10000):
        path = os.path.join(folder, f"{stem}{'.%03d' % i if i else ''}{SUFFIX}")
        if not os.path.exists(path) and os.path.normcase(path) not in taken:
            return path
    raise HyperGSError(f"{folder}: no free name for the cache of '{stem}'")


def cache_image(path: str, name: str):
    """A new Image datablock holding the cache file at `path` (not decoded), its path stored relative
    to the saved .blend where the preferences ask for it (paths.stored_path)."""
    image = bpy.data.images.load(path, check_existing=False)
    image.name = f".{name}{SUFFIX}"
    image.filepath = stored_path(path)
    return image


def clip_file(obj) -> str:
    """Absolute path of the file a clip reads its frames from: its cache image's file, or for a packed
    one a temporary copy of the packed bytes (written once per session). '' when the clip has none.
    Raises HyperGSError when a packed cache cannot be written out."""
    image = obj.hypergs.cache
    if image is None:
        return ""
    packed = image.packed_file
    if packed is None:
        return bpy.path.abspath(image.filepath, library=image.library) if image.filepath else ""
    key = (image.session_uid, packed.size)
    path = _extracted.get(key)
    if path is None or not os.path.isfile(path):
        path = _extract(key, lambda target: write_bytes(target, packed.data))
    return path


def _extract(key, write) -> str:
    """The temporary file holding the packed cache `key` ((image session uid, packed size)), written by
    write(path)."""
    path = os.path.join(temp_folder(), "packed", f"{key[0]}_{key[1]}{SUFFIX}")
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
    except OSError as e:
        raise HyperGSError(f"{os.path.dirname(path)}: cannot make the folder for a packed cache "
                           f"({e.strerror})") from None
    write(path)
    _extracted[key] = path
    return path


def pack(obj) -> None:
    """Keep the clip's cache inside the .blend (Blender's PackedFile). The file it was read from
    becomes the session's copy of the packed bytes (a hard link where it can be: caches are never
    changed in place), so reading goes on without writing them out again."""
    image = obj.hypergs.cache
    if image is None:
        raise HyperGSError(f"'{obj.name}' has no frame cache to pack")
    if image.packed_file is not None:
        return
    path = clip_file(obj)
    if not os.path.isfile(path):
        raise HyperGSError(f"{path}: no such file: nothing to pack")
    image.pack()

    def link(target):
        try:
            os.link(path, target)
        except OSError:
            with AtomicOutput(target) as temp:
                shutil.copyfile(path, temp)
    try:
        _extract((image.session_uid, image.packed_file.size), link)
    except HyperGSError:
        pass  # clip_file writes the packed bytes out when the clip next reads a frame


def unpack(obj) -> str:
    """Write a packed cache back to its file (the path it had, or a new one in cache_folder()) and read
    it from there; returns the path."""
    image = obj.hypergs.cache
    if image is None or image.packed_file is None:
        raise HyperGSError(f"'{obj.name}' has no packed cache")
    path = bpy.path.abspath(image.filepath, library=image.library) if image.filepath else ""
    if not path or is_temporary(path) and bpy.data.filepath:
        path = new_cache_path(obj.name)
    try:
        os.makedirs(os.path.dirname(path), exist_ok=True)
    except OSError as e:
        raise HyperGSError(f"{path}: cannot make its folder ({e.strerror})") from None
    with AtomicOutput(path) as temp:
        temp.write_bytes(image.packed_file.data)
    image.filepath = path
    image.unpack(method="USE_ORIGINAL")  # the file is there now: drop the packed copy
    image.filepath = stored_path(path)  # (unpack stores the path it used, absolute)
    FRAMES.forget(path)
    return path


def _clip_images():
    for obj in bpy.data.objects:
        s = getattr(obj, "hypergs", None)
        if obj.library is None and s is not None and s.is_clip and s.cache is not None:
            yield s.cache


_moved: list = []  # (image, its path before) for the save running now


@persistent
def _save_pre(filepath, *args):
    """Caches still in the temporary folder go beside the .blend being saved, as Blender does with
    bakes (a hard link where the folders share a file system, else a copy; the temporary file goes once
    the save succeeded: undo does not take an Image datablock's path back). A copy that fails leaves
    the cache where it was: the save goes on, and the clip still reads it this session."""
    _moved.clear()
    if not filepath:
        return
    folder = cache_folder(filepath)
    for image in set(_clip_images()):
        if image.packed_file is not None or not image.filepath:
            continue
        old = bpy.path.abspath(image.filepath)
        if not is_temporary(old) or not os.path.isfile(old):
            continue
        try:
            os.makedirs(folder, exist_ok=True)
            new = _free_path(folder, os.path.splitext(os.path.basename(old))[0])
            try:
                os.link(old, new)
            except OSError:  # another file system (or none that links)
                with AtomicOutput(new) as temp:
                    shutil.copyfile(old, temp)
        except (OSError, HyperGSError) as e:
            print(f"HyperGS: the cache {old} stays in the temporary folder: {e}")
            continue
        _moved.append((image, old))
        image.filepath = new  # the first save stores it relative (//...), as every path in the file


@persistent
def _save_post(filepath, *args):
    if os.path.normcase(os.path.abspath(bpy.data.filepath)) != os.path.normcase(os.path.abspath(filepath)):
        for image, old in _moved:  # Save Copy: the copy has its caches beside it; this session keeps its own
            image.filepath = old
    else:
        for _, old in _moved:
            FRAMES.forget(old)
            try:
                os.remove(old)
            except OSError:
                pass
    _moved.clear()


@persistent
def _save_post_fail(filepath, *args):
    for image, old in _moved:
        new = bpy.path.abspath(image.filepath)
        image.filepath = old
        try:
            os.remove(new)
        except OSError:
            pass
    _moved.clear()


HANDLERS = (("save_pre", _save_pre), ("save_post", _save_post), ("save_post_fail", _save_post_fail))


def register():
    add_handlers(HANDLERS)


def unregister():
    remove_handlers(HANDLERS)
