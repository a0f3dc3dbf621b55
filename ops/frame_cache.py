"""A clip's frame cache (com/cache.py): hypergs.pack_cache keeps it inside the .blend (a self-contained
file, e.g. to send), hypergs.unpack_cache writes it back beside the .blend. Blender's own File >
External Data > Pack / Unpack Resources do the same for every clip at once (the cache is an Image
datablock's file)."""
import os

import bpy

from ..com import cache as clip_cache
from ..com.frames import is_cached_clip
from .context import active_clip, reported


def _cached_clip(context):
    obj = active_clip(context)
    return obj if obj is not None and is_cached_clip(obj) and obj.hypergs.cache.library is None else None


class HYPERGS_OT_pack_cache(bpy.types.Operator):
    """Keep the clip's frame cache inside the .blend file (self-contained; the .blend grows by the
    cache's size, and every save writes it)"""

    bl_idname = "hypergs.pack_cache"
    bl_label = "Pack into .blend"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = _cached_clip(context)
        return obj is not None and obj.hypergs.cache.packed_file is None

    def execute(self, context):
        obj = _cached_clip(context)

        def pack():
            clip_cache.pack(obj)
            size = obj.hypergs.cache.packed_file.size
            return f"HyperGS: '{obj.name}': its frame cache ({size / 1e6:.1f} MB) is packed into the .blend"
        return reported(self, pack)


class HYPERGS_OT_unpack_cache(bpy.types.Operator):
    """Write the clip's packed frame cache to a file beside the .blend (its folder <blend name>_hypergs)
    and read it from there"""

    bl_idname = "hypergs.unpack_cache"
    bl_label = "Unpack"
    bl_options = {"REGISTER", "UNDO"}

    @classmethod
    def poll(cls, context):
        obj = _cached_clip(context)
        return obj is not None and obj.hypergs.cache.packed_file is not None

    def execute(self, context):
        obj = _cached_clip(context)
        return reported(self, lambda: f"HyperGS: '{obj.name}': its frame cache is unpacked to "
                                      f"{os.path.basename(clip_cache.unpack(obj))}")


CLASSES = [HYPERGS_OT_pack_cache, HYPERGS_OT_unpack_cache]
