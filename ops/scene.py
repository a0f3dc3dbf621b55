"""Writing clips into the scene (main thread only). Where a clip's Gaussians live (README, "Where a
clip's data lives"):

- In a frame cache (every clip made now): every frame in a file (hypergs_blender/io/cache.py) that an
  Image datablock holds (com/cache.py: beside the .blend, in the session's temporary folder until the
  .blend is first saved, or packed into it); the clip's mesh holds the points of the frame the scene
  shows (com/frames.py loads it on frame change), and edited frames are kept as meshes of their own
  (`overrides`). A Geometry Nodes modifier ("HyperGS Points") adds a point cloud of the mesh's points,
  so they show in Solid mode (a mesh's loose vertices show only in Edit Mode).
- Linked to an external .hgs file (`hypergs.linked`, Export > Link to File): the mesh is the image
  plane's outline; the engine reads the frames from the file (com/linked.py).
- Embedded whole (clips made before frame caches; still read and edited as then, no longer made): one
  mesh with every frame's points, a `frame` attribute, and the "HyperGS Frames" modifier that keeps the
  scene frame's points. Re-encode (or Copy to Frame Cache) turns one into a cache clip.
"""
from __future__ import annotations

import math

import bpy

from ..com import cache as clip_cache
from ..com import frames
from ..com import linked as linked_files
from ..com.compat import set_modifier_input, strip_range, strip_siblings
from ..com.mesh import linked_file, new_linked_mesh, outline
from ..com.paths import stored_path
from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.points import blender_fps

POINTS_GROUP = "HyperGS Points"
POINTS_MODIFIER = "HyperGS Points"
FRAMES_GROUP = "HyperGS Frames"  # the embedded clips' frame filter (made by earlier versions)
VIEW_TRANSFORM = "Standard"
# The points group's inputs: name -> (socket type, default)
INPUTS = {"Show Points": ("NodeSocketBool", True), "Point Size": ("NodeSocketFloat", 1.0)}


def _socket(sockets, name, kind=None):
    for s in sockets:
        if s.name == name and (kind is None or s.type == kind) and getattr(s, "enabled", True):
            return s
    for s in sockets:  # sockets hidden for the current mode still connect
        if s.name == name and (kind is None or s.type == kind):
            return s
    raise KeyError(name)


def _group_inputs(group) -> dict:
    """{name: identifier} of a node group's inputs."""
    return {item.name: item.identifier for item in group.interface.items_tree
            if item.item_type == "SOCKET" and item.in_out == "INPUT"}


def points_node_group():
    """The shared node group that shows a clip's points in Solid mode: the mesh, joined with a point
    cloud of its vertices (radius = mean sigma x Point Size) when Show Points is on."""
    group = bpy.data.node_groups.get(POINTS_GROUP)
    if group is not None and group.bl_idname == "GeometryNodeTree" and set(INPUTS) <= set(_group_inputs(group)):
        return group
    group = bpy.data.node_groups.new(POINTS_GROUP, "GeometryNodeTree")
    if hasattr(group, "is_modifier"):
        group.is_modifier = True
    iface = group.interface
    iface.new_socket("Geometry", in_out="INPUT", socket_type="NodeSocketGeometry")
    for name, (kind, default) in INPUTS.items():
        iface.new_socket(name, in_out="INPUT", socket_type=kind).default_value = default
    iface.new_socket("Geometry", in_out="OUTPUT", socket_type="NodeSocketGeometry")
    nodes, links = group.nodes, group.links

    def node(kind, x, y, **props):
        n = nodes.new(kind)
        n.location = (x, y)
        for k, v in props.items():
            setattr(n, k, v)
        return n

    gin = node("NodeGroupInput", -600, 0)
    gout = node("NodeGroupOutput", 500, 0)
    scale = node("GeometryNodeInputNamedAttribute", -600, -300, data_type="FLOAT_VECTOR")
    _socket(scale.inputs, "Name").default_value = "scale"
    dot = node("ShaderNodeVectorMath", -400, -300, operation="DOT_PRODUCT")
    links.new(_socket(scale.outputs, "Attribute"), dot.inputs[0])
    dot.inputs[1].default_value = (0.5, 0.5, 0.0)
    radius = node("ShaderNodeMath", -200, -300, operation="MULTIPLY")
    links.new(_socket(dot.outputs, "Value"), radius.inputs[0])
    links.new(_socket(gin.outputs, "Point Size"), radius.inputs[1])
    to_points = node("GeometryNodeMeshToPoints", 0, -200, mode="VERTICES")
    links.new(_socket(gin.outputs, "Geometry"), _socket(to_points.inputs, "Mesh"))
    links.new(radius.outputs[0], _socket(to_points.inputs, "Radius"))
    switch = node("GeometryNodeSwitch", 180, -200, input_type="GEOMETRY")
    links.new(_socket(gin.outputs, "Show Points"), _socket(switch.inputs, "Switch"))
    links.new(_socket(to_points.outputs, "Points"), _socket(switch.inputs, "True"))
    join = node("GeometryNodeJoinGeometry", 340, 0)
    links.new(_socket(switch.outputs, "Output"), join.inputs[0])
    links.new(_socket(gin.outputs, "Geometry"), join.inputs[0])
    links.new(join.outputs[0], _socket(gout.inputs, "Geometry"))
    return group


def _modifier(obj, group_name: str):
    for mod in obj.modifiers:
        if mod.type == "NODES" and mod.node_group is not None and mod.node_group.name.startswith(group_name):
            return mod
    return None


def frame_modifier(obj):
    """An embedded clip's frame filter (its "HyperGS Frames" modifier), or None."""
    return _modifier(obj, FRAMES_GROUP)


def add_points_modifier(obj, undo: "Undo | None" = None):
    """The "HyperGS Points" modifier, first in the stack (the user's modifiers act on the clip's points)."""
    mod = _modifier(obj, POINTS_GROUP)
    if mod is not None:
        return mod
    with Undo(undo) as undo:
        existed = bpy.data.node_groups.get(POINTS_GROUP)
        group = points_node_group()
        if group is not existed:
            undo.made(bpy.data.node_groups, group)
        mod = obj.modifiers.new(POINTS_MODIFIER, "NODES")
        mod.node_group = group
        if len(obj.modifiers) > 1 and hasattr(obj.modifiers, "move"):
            obj.modifiers.move(len(obj.modifiers) - 1, 0)
    return mod


def sync_timing(obj) -> None:
    """After the clip's frame_start or speed changed: an embedded clip's frame modifier gets them, a
    cache clip's mesh the frame the scene now shows."""
    if frames.is_cached_clip(obj):
        scene = bpy.context.scene
        try:
            frames.sync(obj, scene.frame_current + scene.frame_subframe)
        except HyperGSError:
            pass  # the panel shows what is wrong with the cache
        return
    mod = frame_modifier(obj)
    if mod is None:
        return
    ids = _group_inputs(mod.node_group)
    set_modifier_input(mod, ids["Start Frame"], int(obj.hypergs.frame_start))
    set_modifier_input(mod, ids["Speed"], float(obj.hypergs.speed))
    obj.update_tag()


def store_settings(obj, clip, *, psnr: float, seconds: float, encoder: str, source: str, source_start: int) -> None:
    """The clip's description into its settings. clip: anything with a clip's header fields (a
    GaussianVideo, an HgsReader or HgsHeader, clips.ClipFrames)."""
    s = obj.hypergs
    s.is_clip = True
    s.source = source
    s.source_start = source_start
    s.num_frames = clip.num_frames
    s.gaussians_per_frame = clip.num_gaussians
    s.grid = clip.grid
    s.psnr = psnr
    s.encoder = encoder
    s.encode_seconds = seconds
    s.canvas_width, s.canvas_height = clip.canvas_width, clip.canvas_height
    s.fps = clip.fps


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


def create_clip_object(collection, name: str, clip, *, scene, frame_start: int, speed: float,
                       cache_path: str | None = None, linked_path: str | None = None, undo: Undo | None = None,
                       **settings):
    """A new clip object in `collection` showing `scene`'s frame. Its frames are in the frame cache at
    `cache_path` (written already; `clip` is its header), or, with `linked_path`, in that .hgs file (`clip`
    its HgsReader). On any failure what it made is removed again (with `undo`: registered there), so
    the scene is left as it was."""
    if (cache_path is None) == (linked_path is None):
        raise ValueError("a clip's frames are in a cache or a linked file")
    with Undo(undo) as undo:
        if linked_path:
            mesh = new_linked_mesh(name, clip.canvas_width, clip.canvas_height)
        else:
            mesh = bpy.data.meshes.new(name)
        undo.made(bpy.data.meshes, mesh)
        obj = bpy.data.objects.new(name, mesh)
        undo.made(bpy.data.objects, obj)
        # The image plane lies in the object's XY plane; standing it up shows it in the front view.
        obj.rotation_euler = (math.pi / 2, 0.0, 0.0)
        store_settings(obj, clip, **settings)
        obj.hypergs.frame_start = frame_start  # before the cache is set: nothing to sync yet
        obj.hypergs.speed = speed
        if linked_path:
            obj.hypergs.linked = True
            obj.hypergs.linked_path = stored_path(linked_path)
        else:
            image = clip_cache.cache_image(cache_path, name)
            undo.made(bpy.data.images, image)
            obj.hypergs.cache = image
            add_points_modifier(obj, undo)
        collection.objects.link(obj)
        if cache_path:
            frames.sync(obj, scene.frame_current + scene.frame_subframe)
    return obj


def _swap_mesh(obj, mesh) -> None:
    old = obj.data
    name = old.name
    obj.data = mesh
    if old.users == 0:
        bpy.data.meshes.remove(old)
        mesh.name = name


def set_cache(obj, cache_path: str, clip, *, scene, keep_edits: bool = True, **settings) -> None:
    """Make the clip read its frames from the new frame cache at `cache_path` (`clip`: its header):
    Re-encode, and an embedded or linked clip copied into a cache. The clip's edited frames stay
    (`keep_edits`, edits in the mesh not kept yet included) or go; other modifiers and the timing stay.
    The cache it read before stays on disk (undo goes back to it)."""
    s = obj.hypergs
    if frames.is_cached_clip(obj) and keep_edits:
        try:
            frames.keep_edits(obj)
        except HyperGSError:  # the old cache is gone: edits cannot be told from its frames
            pass
    if s.linked or not frames.is_cached_clip(obj):  # the outline or every frame's points: one frame now
        _swap_mesh(obj, bpy.data.meshes.new(obj.data.name))
        mod = frame_modifier(obj)
        if mod is not None:
            obj.modifiers.remove(mod)
        s.linked, s.linked_path = False, ""
    if not keep_edits:
        drop_overrides(obj)
    s.cache = clip_cache.cache_image(cache_path, obj.name)
    store_settings(obj, clip, **settings)
    add_points_modifier(obj)
    frames.forget_frame(obj)
    frames.sync(obj, scene.frame_current + scene.frame_subframe)


def drop_overrides(obj) -> None:
    """Forget the clip's edited frames (their meshes go when nothing else uses them)."""
    items = obj.hypergs.overrides
    meshes = [item.mesh for item in items if item.mesh is not None]
    items.clear()
    for mesh in meshes:
        if mesh.users == 0:
            bpy.data.meshes.remove(mesh)


def link_clip(obj, path: str) -> None:
    """Make a clip linked to `path` (a .hgs file holding its Gaussians, edits included, already written):
    the mesh becomes the image plane's outline, the clip's own frames (cache, edited frames, frame
    filter, points modifier) go. Timing and other modifiers kept."""
    reader = linked_files.reader(path)
    _swap_mesh(obj, new_linked_mesh(obj.data.name, reader.canvas_width, reader.canvas_height))
    for mod in (frame_modifier(obj), _modifier(obj, POINTS_GROUP)):
        if mod is not None:
            obj.modifiers.remove(mod)
    drop_overrides(obj)
    obj.hypergs.cache = None
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
    settings and a camera it adds are registered there. Render > Lock Interface goes on (lock_interface):
    the frame handler (com/frames.py) writes the clips' meshes while a render runs, which Blender's
    handler documentation allows only with the interface locked."""
    changed = []
    render, vs = scene.render, scene.view_settings
    if undo is not None:
        was = render.engine, vs.view_transform, vs.look, vs.exposure, vs.gamma
        undo.call(lambda: _set_render_settings(render, vs, *was))
    if render.engine != "HYPERGS":
        render.engine = "HYPERGS"
        changed.append("render engine to HyperGS")
    changed += lock_interface(scene, undo)
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


def lock_interface(scene, undo: Undo | None = None) -> list[str]:
    """Render > Lock Interface on for a scene that renders clips (itself, or through scene strips);
    returns what was changed, to tell the user."""
    render = scene.render
    if render.use_lock_interface:
        return []
    render.use_lock_interface = True
    if undo is not None:
        undo.call(lambda: setattr(render, "use_lock_interface", False))
    return [f"Lock Interface on in '{scene.name}' (the clips' frames load while a render runs)"]


def match_scene_timing(scene, obj, undo: Undo | None = None) -> list[str]:
    """The scene's frame rate and frame range become the clip's (File > Import; a converted strip's
    scene gets them from the Sequencer); returns what was changed, to tell the user."""
    s = obj.hypergs
    render = scene.render
    fps, base = blender_fps(s.fps)
    first = s.frame_start
    last = first + max(1, math.ceil(s.num_frames / s.speed)) - 1
    if undo is not None:
        was = render.fps, render.fps_base, scene.frame_start, scene.frame_end
        undo.call(lambda: _set_timing(scene, *was))
    changed = []
    if (render.fps, render.fps_base) != (fps, base) and not math.isclose(render.fps / render.fps_base, fps / base):
        render.fps, render.fps_base = fps, base
        changed.append(f"frame rate to {fps / base:.4g} fps")
    if (scene.frame_start, scene.frame_end) != (first, last):
        _set_timing(scene, render.fps, render.fps_base, first, last)
        changed.append(f"frame range to {first}-{last}")
    return changed


def _set_timing(scene, fps, fps_base, first, last):
    scene.render.fps, scene.render.fps_base = fps, fps_base
    if first > scene.frame_end:  # Blender keeps start <= end: move the end first
        scene.frame_end = last
        scene.frame_start = first
    else:
        scene.frame_start = first
        scene.frame_end = last


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


def add_strip_scene(sequencer_scene, strip, clip, cache_path: str, *, undo: Undo, **settings):
    """Put the clip converted from a movie or image strip (its frame cache at `cache_path`, `clip` its
    header) back into the edit: a new scene holding the clip object (HyperGS engine, the clip's
    resolution, the Sequencer's frame rate, one scene frame per clip frame from frame 1), played by a
    scene strip with the original strip's timing on the first free channel above it; the original strip
    is muted (kept, so the conversion can be undone by hand). Everything made is registered with `undo`.
    Returns (clip object, scene strip)."""
    editor = sequencer_scene.sequence_editor
    first, end = strip_range(strip)
    scene = bpy.data.scenes.new(strip.name)
    undo.made(bpy.data.scenes, scene)
    r, sr = scene.render, sequencer_scene.render
    r.resolution_x, r.resolution_y, r.resolution_percentage = clip.canvas_width, clip.canvas_height, 100
    r.fps, r.fps_base = sr.fps, sr.fps_base
    scene.frame_start, scene.frame_end = 1, max(1, clip.num_frames)
    obj = create_clip_object(scene.collection, strip.name, clip, scene=scene, frame_start=1, speed=1.0,
                             cache_path=cache_path, undo=undo, **settings)
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
