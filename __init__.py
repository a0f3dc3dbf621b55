"""HyperGS for Blender: videos as editable 2D Gaussians (extension entry point).

The work happens in `hypergs_blender` (no bpy); `ops`, `ui` and `engine` are the Blender glue.
"""
import bpy

from . import engine, ops, ui
from .com import cache, frames, mesh, paths
from .ops.props import HyperGSClipSettings, HyperGSSceneSettings

CLASSES = [*ops.CLASSES, *ui.CLASSES, *engine.CLASSES]


def register():
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    bpy.types.Object.hypergs = bpy.props.PointerProperty(type=HyperGSClipSettings)
    bpy.types.Scene.hypergs = bpy.props.PointerProperty(type=HyperGSSceneSettings)
    engine.register()
    ui.register()
    paths.register()
    cache.register()
    frames.register()
    mesh.register()


def unregister():
    mesh.unregister()
    frames.unregister()
    cache.unregister()
    paths.unregister()
    ui.unregister()
    engine.unregister()
    del bpy.types.Scene.hypergs
    del bpy.types.Object.hypergs
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
