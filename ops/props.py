"""HyperGS settings: per object (`Object.hypergs`: what the clip is, how it was encoded, its timing, where
its frames live) and per scene (`Scene.hypergs`: render settings)."""
import bpy
from bpy.props import (BoolProperty, CollectionProperty, FloatProperty, IntProperty, IntVectorProperty,
                       PointerProperty, StringProperty)

from ..com.compat import path_options
from .quality import EncodeOptions

def _timing_changed(self, context):
    from . import scene
    scene.sync_timing(self.id_data)


def _linked_path_changed(self, context):
    from ..com import paths
    from . import scene
    if not paths.rebasing():
        scene.refresh_linked(self.id_data)


class HyperGSOverride(bpy.types.PropertyGroup):
    """An edited frame of a clip: the mesh holding its points instead of the cache's (com/frames.py)."""
    frame: IntProperty(name="Frame", description="The clip frame (0: its first)", min=0)
    mesh: PointerProperty(name="Points", type=bpy.types.Mesh)


class HyperGSClipSettings(EncodeOptions, bpy.types.PropertyGroup):
    """A clip's settings; its encode options (EncodeOptions) are those of the next Re-encode."""
    is_clip: BoolProperty(name="HyperGS Clip", default=False)
    source: StringProperty(name="Source", subtype="FILE_PATH", description="The video the clip was encoded from")
    source_start: IntProperty(name="First Source Frame", default=0, min=0,
                              description="Index of the clip's first frame in the source video")
    num_frames: IntProperty(name="Frames", default=0, min=0)
    gaussians_per_frame: IntProperty(name="Gaussians per Frame", default=0, min=0)
    grid: IntVectorProperty(name="Cells", size=2, default=(1, 1), min=1,
                            description="Columns and rows of the cells the Gaussians were predicted on")
    psnr: FloatProperty(name="PSNR", default=0.0, precision=2,
                        description="Measured at encode time against the source, on a sample of frames spread "
                                    "over the clip (dB)")
    encoder: StringProperty(name="Encoder")
    encode_seconds: FloatProperty(name="Encode Time", default=0.0, precision=1, subtype="TIME_ABSOLUTE")
    canvas_width: IntProperty(name="Width", default=0, min=0)
    canvas_height: IntProperty(name="Height", default=0, min=0)
    fps: FloatProperty(name="Source FPS", default=24.0, min=0.001)
    frame_start: IntProperty(name="Start Frame", description="Scene frame that shows the clip's first frame",
                             default=1, update=_timing_changed)
    speed: FloatProperty(name="Speed", description="Clip frames per scene frame", default=1.0, min=0.001,
                         update=_timing_changed)
    # Where the Gaussians live: a frame cache (the mesh holds the frame shown, com/frames.py), an external
    # .hgs file (linked), or every frame in the mesh (clips embedded whole, made before frame caches).
    cache: PointerProperty(name="Frame Cache", type=bpy.types.Image,
                           description="The file holding every frame's Gaussians (an Image datablock so that "
                                       "Blender's External Data tools handle it; never shown as an image)")
    overrides: CollectionProperty(type=HyperGSOverride, name="Edited Frames")
    linked: BoolProperty(name="Linked", default=False,
                         description="The Gaussians are read from an external .hgs file at render time "
                                     "(the mesh only outlines the image plane)")
    linked_path: StringProperty(name="File", subtype="FILE_PATH", update=_linked_path_changed, options=path_options(),
                                description="The .hgs file a linked clip's Gaussians are read from "
                                            "(// at the start: relative to the .blend file's folder)")


class HyperGSSceneSettings(bpy.types.PropertyGroup):
    """Per-scene HyperGS render settings (`Scene.hypergs`; Properties > Render > HyperGS)."""
    allow_missing_clips: BoolProperty(
        name="Render Missing Clips Black", default=False,
        description="When a clip's frame cache or linked file is missing or damaged during an animation "
                    "(Ctrl-F12) or command-line render, render it black with a warning instead of stopping the render "
                    "(a single interactive F12 always goes on with a warning)")


CLASSES = [HyperGSOverride, HyperGSClipSettings, HyperGSSceneSettings]
