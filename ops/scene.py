"""Writing clips into the scene (main thread only).

Storage: one mesh object per clip (com/mesh.py writes and reads its data), and a Geometry Nodes modifier built here ("HyperGS Frames") keeps only the points whose `frame` is
the clip frame for the scene frame, then adds a point cloud of them so they show in Solid mode.
Why one mesh and not one mesh per frame: it is plain data (no frame-change handler has to run, so it
renders the same with or without the add-on's handlers, on a farm too), it saves and reloads with
the .blend, Edit Mode edits and further Geometry Nodes modifiers apply per frame through the `frame`
attribute, and the render engine reads the depsgraph-evaluated mesh, i.e. exactly what is shown.

A clip linked to an external .hgs file (`hypergs.linked`, see com/linked.py for why) has a mesh with just
the image plane's outline and no frame modifier; the engine reads its Gaussians from the file.
"""
from __future__ import annotations

import math

import bpy

from ..com import linked as linked_files
from ..com.compat import set_modifier_input, strip_range, strip_siblings
from ..com.mesh import linked_file, new_clip_mesh, new_linked_mesh, outline
from ..com.paths import stored_path
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.gaussians import GaussianVideo

NODE_GROUP = "HyperGS Frames"
MODIFIER = "HyperGS Frames"
VIEW_TRANSFORM = "Standard"
# Node group inputs: name -> (socket type, default)
INPUTS = {
    "Start Frame": ("NodeSocketInt", 1),
    "Speed": ("NodeSocketFloat", 1.0),
    "Show Points": ("NodeSocketBool", True),
    "Point Size": ("NodeSocketFloat", 1.0),
}


def _socket(sockets, name, kind=None):
    for s in sockets:
        if s.name == name and (kind is None or s.type == kind) and getattr(s, "enabled", True):
            return s
    for s in sockets:  # sockets hidden for the current mode still connect
        if s.name == name and (kind is None or s.type == kind):
            return s
    raise KeyError(name)


def frame_node_group():
    """The shared node group: delete points of other frames; optionally add a point cloud to show them."""
    group = bpy.data.node_groups.get(NODE_GROUP)
    if group is not None and group.bl_idname == "GeometryNodeTree" and _group_inputs_ok(group):
        return group
    group = bpy.data.node_groups.new(NODE_GROUP, "GeometryNodeTree")
    if hasattr(group, "is_modifier"):
        group.is_modifier = True
    iface = group.interface
    iface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    for name, (kind, default) in INPUTS.items():
        socket = iface.new_socket(name, in_out="INPUT", socket_type=kind)
        socket.default_value = default
    iface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = group.nodes, group.links

    def node(kind, x, y, **props):
        n = nodes.new(kind)
        n.location = (x, y)
        for k, v in props.items():
            setattr(n, k, v)
        return n

    gin = node("NodeGroupInput", -900, 0)
    gout = node("NodeGroupOutput", 700, 0)
    time = node("GeometryNodeInputSceneTime", -900, -250)
    # clip frame = floor((scene frame - start) * speed + 1e-4)
    sub = node("ShaderNodeMath", -700, -200, operation="SUBTRACT")
    links.new(_socket(time.outputs, "Frame"), sub.inputs[0])
    links.new(_socket(gin.outputs, "Start Frame"), sub.inputs[1])
    mad = node("ShaderNodeMath", -530, -200, operation="MULTIPLY_ADD")
    links.new(sub.outputs[0], mad.inputs[0])
    links.new(_socket(gin.outputs, "Speed"), mad.inputs[1])
    mad.inputs[2].default_value = 1e-4
    flo = node("ShaderNodeMath", -360, -200, operation="FLOOR")
    links.new(mad.outputs[0], flo.inputs[0])
    attr = node("GeometryNodeInputNamedAttribute", -360, -380, data_type="FLOAT")
    _socket(attr.inputs, "Name").default_value = "frame"
    cmp = node("FunctionNodeCompare", -180, -250, data_type="FLOAT", operation="NOT_EQUAL")
    links.new(_socket(attr.outputs, "Attribute"), _socket(cmp.inputs, "A", "VALUE"))
    links.new(flo.outputs[0], _socket(cmp.inputs, "B", "VALUE"))
    _socket(cmp.inputs, "Epsilon").default_value = 0.5
    delete = node("GeometryNodeDeleteGeometry", 0, 0, domain="POINT")
    links.new(_socket(gin.outputs, "Geometry"), _socket(delete.inputs, "Geometry"))
    links.new(_socket(cmp.outputs, "Result"), _socket(delete.inputs, "Selection"))
    # Display: a point cloud of the frame's points, radius = mean sigma x Point Size.
    scale = node("GeometryNodeInputNamedAttribute", -180, -500, data_type="FLOAT_VECTOR")
    _socket(scale.inputs, "Name").default_value = "scale"
    dot = node("ShaderNodeVectorMath", 0, -450, operation="DOT_PRODUCT")
    links.new(_socket(scale.outputs, "Attribute"), dot.inputs[0])
    dot.inputs[1].default_value = (0.5, 0.5, 0.0)
    radius = node("ShaderNodeMath", 180, -450, operation="MULTIPLY")
    links.new(_socket(dot.outputs, "Value"), radius.inputs[0])
    links.new(_socket(gin.outputs, "Point Size"), radius.inputs[1])
    to_points = node("GeometryNodeMeshToPoints", 200, -200, mode="VERTICES")
    links.new(_socket(delete.outputs, "Geometry"), _socket(to_points.inputs, "Mesh"))
    links.new(radius.outputs[0], _socket(to_points.inputs, "Radius"))
    switch = node("GeometryNodeSwitch", 380, -200, input_type="GEOMETRY")
    links.new(_socket(gin.outputs, "Show Points"), _socket(switch.inputs, "Switch"))
    links.new(_socket(to_points.outputs, "Points"), _socket(switch.inputs, "True"))
    join = node("GeometryNodeJoinGeometry", 540, 0)
    links.new(_socket(switch.outputs, "Output"), join.inputs[0])
    links.new(_socket(delete.outputs, "Geometry"), join.inputs[0])
    links.new(join.outputs[0], _socket(gout.inputs, "Geometry"))
    return group


def _group_inputs_ok(group) -> bool:
    names = {item.name for item in group.interface.items_tree
             if item.item_type == "SOCKET" and item.in_out == "INPUT"}
    return set(INPUTS) <= names


def _input_ids(group) -> dict:
    return {item.name: item.identifier for item in group.interface.items_tree
            if item.item_type == "SOCKET" and item.in_out == "INPUT"}


def frame_modifier(obj):
    for mod in obj.modifiers:
        if mod.type == "NODES" and mod.node_group is not None and mod.node_group.name.startswith(NODE_GROUP):
            return mod
    return None


def sync_timing(obj) -> None:
    """Copy the object's frame_start and speed into its frame modifier."""
    mod = frame_modifier(obj)
    if mod is None:
        return
    ids = _input_ids(mod.node_group)
    set_modifier_input(mod, ids["Start Frame"], int(obj.hypergs.frame_start))
    set_modifier_input(mod, ids["Speed"], float(obj.hypergs.speed))
    obj.update_tag()


def add_frame_modifier(obj):
    mod = obj.modifiers.new(MODIFIER, "NODES")
    mod.node_group = frame_node_group()
    sync_timing(obj)
    return mod


def store_settings(obj, video: GaussianVideo, *, psnr: float, seconds: float, encoder: str,
                   source: str, source_start: int) -> None:
    s = obj.hypergs
    s.is_clip = True
    s.source = source
    s.source_start = source_start
    s.num_frames = video.num_frames
    s.gaussians_per_frame = video.num_gaussians
    s.grid = video.grid
    s.psnr = psnr
    s.encoder = encoder
    s.encode_seconds = seconds
    s.canvas_width, s.canvas_height = video.canvas_width, video.canvas_height
    s.fps = video.fps


class Undo:
    """What a change made so far, taken back if a later step fails, so a failed operator leaves the
    scene as it was. Use `with Undo() as undo:`; `made(datablocks, block)` registers a new datablock
    (removed again), `call(fn)` any other way back. Given a `parent`, it registers there instead and the
    outermost one takes everything back."""

    def __init__(self, parent: "Undo | None" = None):
        self._parent = parent
        self._steps: list = []

    def made(self, datablocks, block) -> None:
        self.call(lambda: datablocks.remove(block))

    def call(self, fn) -> None:
        if self._parent is not None:
            self._parent.call(fn)
        else:
            self._steps.append(fn)

    def __enter__(self) -> "Undo":
        return self

    def __exit__(self, exc_type, exc, tb) -> bool:
        if exc_type is not None:
            for fn in reversed(self._steps):
                fn()
        self._steps.clear()
        return False


def create_clip_object(collection, name: str, video: GaussianVideo, *, frame_start: int, speed: float,
                       linked_path: str | None = None, undo: Undo | None = None, **settings):
    """A new clip object in `collection`: mesh, settings, frame modifier. Returns it.
    linked_path: link the clip to that .hgs file instead (`video` may then be its HgsReader: only
    the header is used); the mesh is the image plane's outline and there is no frame modifier.
    On any failure what it made is removed again (with `undo`: registered there), so the scene is
    left as it was."""
    with Undo(undo) as undo:
        groups_before = set(bpy.data.node_groups.keys())
        if linked_path:
            mesh = new_linked_mesh(name, video.canvas_width, video.canvas_height)
        else:
            mesh = new_clip_mesh(name, video)
        undo.made(bpy.data.meshes, mesh)
        obj = bpy.data.objects.new(name, mesh)
        undo.made(bpy.data.objects, obj)
        # The image plane lies in the object's XY plane; standing it up shows it in the front view.
        obj.rotation_euler = (math.pi / 2, 0.0, 0.0)
        store_settings(obj, video, **settings)
        obj.hypergs.frame_start = frame_start  # before the modifier: its update has nothing to sync
        obj.hypergs.speed = speed
        if linked_path:
            obj.hypergs.linked = True
            obj.hypergs.linked_path = stored_path(linked_path)
        else:
            mod = add_frame_modifier(obj)
            if mod.node_group.name not in groups_before:
                undo.made(bpy.data.node_groups, mod.node_group)
        collection.objects.link(obj)
    return obj


def _swap_mesh(obj, mesh) -> None:
    old = obj.data
    name = old.name
    obj.data = mesh
    if old.users == 0:
        bpy.data.meshes.remove(old)
        mesh.name = name


def replace_clip_mesh(obj, video: GaussianVideo, **settings) -> None:
    """Re-encode result: a new mesh for the object (modifiers and timing kept)."""
    _swap_mesh(obj, new_clip_mesh(obj.data.name, video))
    store_settings(obj, video, **settings)
    sync_timing(obj)


def embed_clip(obj, video: GaussianVideo) -> None:
    """Make a linked clip embedded: its Gaussians (the linked file's, as `video`) go into the mesh,
    the frame modifier is added back (first in the stack), the link is dropped. Settings kept."""
    _swap_mesh(obj, new_clip_mesh(obj.data.name, video))
    s = obj.hypergs
    s.linked = False
    s.linked_path = ""
    if frame_modifier(obj) is None:
        add_frame_modifier(obj)
        index = len(obj.modifiers) - 1
        if index and hasattr(obj.modifiers, "move"):
            obj.modifiers.move(index, 0)
    sync_timing(obj)


def link_clip(obj, path: str) -> None:
    """Make a clip linked to `path` (a .hgs file holding its Gaussians, already written): the mesh
    becomes the image plane's outline, the frame modifier goes. Timing and other modifiers kept."""
    reader = linked_files.reader(path)
    _swap_mesh(obj, new_linked_mesh(obj.data.name, reader.canvas_width, reader.canvas_height))
    mod = frame_modifier(obj)
    if mod is not None:
        obj.modifiers.remove(mod)
    obj.hypergs.linked = True
    obj.hypergs.linked_path = stored_path(path)  # refresh_linked copies the file's header into the settings


def refresh_linked(obj) -> None:
    """After the linked file changed (path edited): its header into the settings, the outline to
    its aspect. A missing or damaged file changes nothing here (the panel shows the problem)."""
    s = obj.hypergs
    if not s.linked:
        return
    try:
        reader = linked_files.reader(linked_file(obj))
    except HyperGSError:
        return
    s.num_frames, s.gaussians_per_frame = reader.num_frames, reader.num_gaussians
    s.grid = [max(1, g) for g in reader.grid]
    s.canvas_width, s.canvas_height, s.fps = reader.canvas_width, reader.canvas_height, reader.fps
    mesh = obj.data
    if obj.mode == "OBJECT" and len(mesh.vertices) == 4 and not mesh.attributes.get("frame"):
        mesh.vertices.foreach_set("co", outline(reader.canvas_width, reader.canvas_height).ravel())
        mesh.update()
    obj.update_tag()


def select_only(context, obj) -> None:
    if context.mode != "OBJECT":
        return
    for other in context.view_layer.objects:
        if other.select_get():
            other.select_set(False)
    obj.select_set(True)
    context.view_layer.objects.active = obj


def prepare_scene(scene, undo: Undo | None = None) -> list[str]:
    """Render settings the clips need; returns what was changed, to tell the user. With `undo`, the
    settings and a camera it adds are registered there."""
    changed = []
    render, vs = scene.render, scene.view_settings
    if undo is not None:
        was = render.engine, vs.view_transform, vs.look, vs.exposure, vs.gamma
        undo.call(lambda: _set_render_settings(render, vs, *was))
    if render.engine != "HYPERGS":
        render.engine = "HYPERGS"
        changed.append("render engine to HyperGS")
    if vs.view_transform != VIEW_TRANSFORM or vs.look != "None" or vs.exposure != 0 or vs.gamma != 1:
        vs.view_transform = VIEW_TRANSFORM
        vs.look = "None"
        vs.exposure = 0.0
        vs.gamma = 1.0
        changed.append("view transform to Standard (so renders give back the video's colours)")
    if scene.camera is None:
        scene.camera = _new_camera(scene, undo)
        changed.append("added a camera (F12 needs one)")
    return changed


def _set_render_settings(render, view_settings, engine, view_transform, look, exposure, gamma):
    render.engine = engine
    view_settings.view_transform, view_settings.look = view_transform, look
    view_settings.exposure, view_settings.gamma = exposure, gamma


def _new_camera(scene, undo: Undo | None):
    with Undo(undo) as undo:
        cam = bpy.data.cameras.new("HyperGS Camera")
        undo.made(bpy.data.cameras, cam)
        cam.type = "ORTHO"
        aspect = scene.render.resolution_x / max(1, scene.render.resolution_y)
        cam.ortho_scale = 2.0 * max(aspect, 1.0)
        obj = bpy.data.objects.new("HyperGS Camera", cam)
        undo.made(bpy.data.objects, obj)
        obj.location = (0.0, -6.0, 0.0)
        obj.rotation_euler = (math.pi / 2, 0.0, 0.0)
        scene.collection.objects.link(obj)
    return obj


# ----------------------------------------------------------------------------------------------------
# Converted strips: a scene per clip, shown in the Sequencer by a scene strip

PREVIEW_SHADING = "RENDERED"  # the Sequencer previews scene strips with their render engine (HyperGS)
MAX_CHANNEL = 128  # the Sequencer's last channel


def add_strip_scene(sequencer_scene, strip, video: GaussianVideo, *, undo: Undo, **settings):
    """Put the clip converted from a movie or image strip back into the edit: a new scene holding the
    clip object (HyperGS engine, the clip's resolution, the Sequencer's frame rate, one scene frame per
    clip frame from frame 1), played by a scene strip with the original strip's timing on the first
    free channel above it; the original strip is muted (kept, so the conversion can be undone by
    hand). Everything made is registered with `undo`. Returns (clip object, scene strip)."""
    editor = sequencer_scene.sequence_editor
    first, end = strip_range(strip)
    scene = bpy.data.scenes.new(strip.name)
    undo.made(bpy.data.scenes, scene)
    r, sr = scene.render, sequencer_scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = video.canvas_width, video.canvas_height, 100
    r.fps, r.fps_base = sr.fps, sr.fps_base
    scene.frame_start, scene.frame_end = 1, max(1, video.num_frames)
    obj = create_clip_object(scene.collection, strip.name, video, frame_start=1, speed=1.0, undo=undo, **settings)
    prepare_scene(scene, undo)
    siblings = strip_siblings(editor, strip)
    channel = free_channel(siblings, first, end, strip.channel + 1)
    if channel > MAX_CHANNEL:
        raise HyperGSError(f"no free Sequencer channel above '{strip.name}' for its frames {first}-{end - 1}")
    scene_strip = siblings.new_scene(name=scene.name, scene=scene, channel=channel, frame_start=first)
    undo.call(lambda: siblings.remove(scene_strip))
    copy_placement(strip, scene_strip)
    was_muted = strip.mute
    strip.mute = True  # the movie would cover the scene strip's picture otherwise (or show under it)
    undo.call(lambda: setattr(strip, "mute", was_muted))
    return obj, scene_strip


PLACEMENT = {"transform": ("scale_x", "scale_y", "offset_x", "offset_y", "rotation", "origin"),
             "crop": ("min_x", "max_x", "min_y", "max_y")}


def copy_placement(source, target) -> None:
    """Show `target` where `source` shows: its transform and crop. The clip's scene renders at the
    source's own resolution, so a movie scaled to fit a smaller (or larger) Sequencer output keeps its
    framing instead of being shown at its original size, cropped."""
    for group, names in PLACEMENT.items():
        src, dst = getattr(source, group, None), getattr(target, group, None)
        if src is not None and dst is not None:
            for name in names:
                setattr(dst, name, getattr(src, name))


def free_channel(strips, first: int, end: int, lowest: int) -> int:
    """The lowest channel >= `lowest` where no strip of `strips` shows a frame of [first, end)."""
    taken = {s.channel for s in strips if strip_range(s)[0] < end and first < strip_range(s)[1]}
    channel = lowest
    while channel in taken:
        channel += 1
    return channel


def sequencer_preview_rendered(sequencer_scene, undo: Undo) -> list[str]:
    """Make the Sequencer preview scene strips with their render engine (else it shows them in Solid
    mode: the clip's points, not its picture); returns what was changed, to tell the user."""
    render = sequencer_scene.render
    was = render.sequencer_gl_preview
    if was == PREVIEW_SHADING:
        return []
    render.sequencer_gl_preview = PREVIEW_SHADING
    undo.call(lambda: setattr(render, "sequencer_gl_preview", was))
    return ["Sequencer preview of scene strips to Rendered (so they show the Gaussians)"]
