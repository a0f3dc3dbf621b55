"""Per-object HyperGS settings (`Object.hypergs`): what the clip is, how it was encoded, its timing."""
import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, IntVectorProperty, StringProperty

GAUSSIAN_COUNT = dict(name="Gaussians", description="Gaussians per frame (0: from the cell size; more: sharper, slower)",
                      default=0, min=0, max=1_000_000)
CELL_SIZE = dict(name="Cell Size", description="Source pixels per Gaussian (one Gaussian per cell x cell pixels; "
                 "smaller: more Gaussians, sharper, slower)", default=6.0, min=4.0, max=32.0)


def _timing_changed(self, context):
    from . import scene
    scene.sync_timing(self.id_data)


def _linked_path_changed(self, context):
    from . import scene
    scene.refresh_linked(self.id_data)


class HyperGSClipSettings(bpy.types.PropertyGroup):
    is_clip: BoolProperty(name="HyperGS Clip", default=False)
    source: StringProperty(name="Source", subtype="FILE_PATH", description="The video the clip was encoded from")
    source_start: IntProperty(name="First Source Frame", default=0, min=0,
                              description="Index of the clip's first frame in the source video")
    num_frames: IntProperty(name="Frames", default=0, min=0)
    gaussians_per_frame: IntProperty(name="Gaussians per Frame", default=0, min=0)
    grid: IntVectorProperty(name="Cells", size=2, default=(1, 1), min=1,
                            description="Columns and rows of the cells the Gaussians were predicted on")
    psnr: FloatProperty(name="PSNR", description="Measured at encode time against the source frames (dB)",
                        default=0.0, precision=2)
    encoder: StringProperty(name="Encoder")
    encode_seconds: FloatProperty(name="Encode Time", default=0.0, precision=1, subtype="TIME_ABSOLUTE")
    canvas_width: IntProperty(name="Width", default=0, min=0)
    canvas_height: IntProperty(name="Height", default=0, min=0)
    fps: FloatProperty(name="Source FPS", default=24.0, min=0.001)
    frame_start: IntProperty(name="Start Frame", description="Scene frame that shows the clip's first frame",
                             default=1, update=_timing_changed)
    speed: FloatProperty(name="Speed", description="Clip frames per scene frame", default=1.0, min=0.001,
                         update=_timing_changed)
    # Where the Gaussians live: in the mesh (embedded, the default) or in an external .hgs file.
    linked: BoolProperty(name="Linked", default=False,
                         description="The Gaussians are read from an external .hgs file at render time "
                                     "(the mesh only outlines the image plane)")
    linked_path: StringProperty(name="File", subtype="FILE_PATH", update=_linked_path_changed,
                                description="The .hgs file a linked clip's Gaussians are read from")
    # Settings for the next Re-encode.
    gaussian_count: IntProperty(**GAUSSIAN_COUNT)
    cell_size: FloatProperty(**CELL_SIZE)


CLASSES = [HyperGSClipSettings]
