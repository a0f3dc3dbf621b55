"""Blender data shared by the operators (ops/) and the render engine (engine/): a clip's mesh data
(mesh.py), the frame a clip's mesh shows (frames.py), where its frames live (cache.py), the files of
linked clips (linked.py), stored paths (paths.py) and what differs between Blender versions (compat.py).

`add_handlers` / `remove_handlers`: the modules' bpy.app.handlers, each a list of (event, function)."""
import bpy


def add_handlers(handlers) -> None:
    for event, function in handlers:
        getattr(bpy.app.handlers, event).append(function)


def remove_handlers(handlers) -> None:
    for event, function in handlers:
        getattr(bpy.app.handlers, event).remove(function)
