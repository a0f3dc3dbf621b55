"""The Gaussians drawn with Blender's gpu module, for the viewport's Rendered mode and for F12 where Blender
gives the engine a GPU context: the image of the numpy rasterizer (hypergs_blender/raster.py), on the GPU.

Instancing: Blender's Python GPUBatch has no per-instance vertex buffers, but `draw_instanced` gives the
vertex shader gl_InstanceID. So one 4-vertex quad is drawn once per Gaussian, and each instance fetches its
numbers from a float texture that hypergs_blender/splat.py lays out: the quad, in whole pixels, around
exactly the pixels of the Gaussian's box (raster.SIGMA_CUTOFF); its mean; its inverse Cholesky factor; its colour. The
fragment shader evaluates exp(-1/2 |L^-1 d|^2) at the pixel centre, and additive blending sums the
sRGB-encoded colours into an RGBA32F offscreen. A second pass converts the sum to scene-linear as
colour.srgb_image_to_linear_rgba does (negative sums clipped to 0, alpha 1) into a second RGBA32F offscreen,
which the viewport draws through the display-space shader and F12 reads back into the render result.

The shaders map image pixels (y down) to clip space (y up): the offscreens' rows run bottom-up, as Blender's
render passes and textures do.
"""
from __future__ import annotations

import sys

import gpu
import numpy as np
from gpu_extras.batch import batch_for_shader

from ..hypergs_blender import splat

_SPLAT_VERTEX = """
void main()
{
  int i = gl_InstanceID;
  ivec2 texel = ivec2(TEXELS * (i % GAUSSIANS_PER_ROW), i / GAUSSIANS_PER_ROW);
  vec4 quad = texelFetch(gaussians, texel, 0);
  vec4 mean_ab = texelFetch(gaussians, texel + ivec2(1, 0), 0);
  vec4 c_colour = texelFetch(gaussians, texel + ivec2(2, 0), 0);
  g_mean = mean_ab.xy;
  g_inverse = vec3(mean_ab.zw, c_colour.x);
  g_colour = c_colour.yzw;
  /* A corner of the quad (whole pixels) in window pixels, y down, then in clip space, y up. */
  vec2 p = mix(quad.xy, quad.zw, corner) - origin;
  gl_Position = vec4(2.0 * p.x / size.x - 1.0, 1.0 - 2.0 * p.y / size.y, 0.0, 1.0);
}
"""

_SPLAT_FRAGMENT = """
void main()
{
  /* The pixel centre in image pixels, y down: gl_FragCoord is (column + 0.5, row from the bottom + 0.5). */
  vec2 d = vec2(origin.x + gl_FragCoord.x, origin.y + size.y - gl_FragCoord.y) - g_mean;
  float u = g_inverse.x * d.x;
  float v = g_inverse.y * d.x + g_inverse.z * d.y;
  fragColor = vec4(g_colour * exp2(-(u * u + v * v)), 1.0);
}
"""

_LINEAR_VERTEX = """
void main()
{
  gl_Position = vec4(2.0 * corner - 1.0, 0.0, 1.0);
}
"""

_LINEAR_FRAGMENT = """
float srgb_to_linear(float v)
{
  return v <= 0.04045 ? v / 12.92 : pow((v + 0.055) / 1.055, 2.4);
}

void main()
{
  vec3 s = max(texelFetch(splat_sum, ivec2(gl_FragCoord.xy), 0).rgb, vec3(0.0));
  fragColor = vec4(srgb_to_linear(s.r), srgb_to_linear(s.g), srgb_to_linear(s.b), 1.0);
}
"""

_CORNERS = [(0.0, 0.0), (1.0, 0.0), (0.0, 1.0), (1.0, 1.0)]
_PROGRAMS = {}  # name -> (shader, quad batch), made on first use (shaders are not tied to one GPU context)


def _program(name):
    if name not in _PROGRAMS:
        info = gpu.types.GPUShaderCreateInfo()
        info.vertex_in(0, "VEC2", "corner")
        info.fragment_out(0, "VEC4", "fragColor")
        if name == "splat":
            interface = gpu.types.GPUStageInterfaceInfo("hypergs_splat_interface")
            for kind, member in (("VEC2", "g_mean"), ("VEC3", "g_inverse"), ("VEC3", "g_colour")):
                interface.flat(kind, member)
            info.vertex_out(interface)
            info.define("TEXELS", str(splat.TEXELS))
            info.define("GAUSSIANS_PER_ROW", str(splat.GAUSSIANS_PER_ROW))
            info.push_constant("VEC2", "size")
            info.push_constant("VEC2", "origin")
            info.sampler(0, "FLOAT_2D", "gaussians")
            info.vertex_source(_SPLAT_VERTEX)
            info.fragment_source(_SPLAT_FRAGMENT)
        else:
            info.sampler(0, "FLOAT_2D", "splat_sum")
            info.vertex_source(_LINEAR_VERTEX)
            info.fragment_source(_LINEAR_FRAGMENT)
        shader = gpu.shader.create_from_info(info)
        _PROGRAMS[name] = shader, batch_for_shader(shader, "TRI_STRIP", {"corner": _CORNERS})
    return _PROGRAMS[name]


class SplatImage:
    """Two RGBA32F offscreens of one size: the additive sum of the splats (sRGB-encoded) and its scene-linear
    conversion (`texture`: what the viewport shows and F12 reads). Raises RuntimeError when the GPU cannot
    allocate them."""

    def __init__(self, width: int, height: int):
        self.size = (width, height)
        self._sum = gpu.types.GPUOffScreen(width, height, format="RGBA32F")
        try:
            self._linear = gpu.types.GPUOffScreen(width, height, format="RGBA32F")
        except RuntimeError:
            self._sum.free()
            raise

    @property
    def texture(self):
        return self._linear.texture_color

    def draw(self, rows: np.ndarray, origin: tuple[int, int] = (0, 0)) -> None:
        """Replace the image by the sum of the Gaussians `rows` (hypergs_blender.splat.splat_rows) over the
        window of their image whose top-left pixel is `origin` and whose size is this image's."""
        width, height = self.size
        shader, quad = _program("splat")
        saved = gpu.state.blend_get(), gpu.state.depth_test_get(), gpu.state.depth_mask_get()
        gpu.state.depth_test_set("NONE")
        gpu.state.depth_mask_set(False)
        try:
            with self._sum.bind():
                gpu.state.active_framebuffer_get().clear(color=(0.0, 0.0, 0.0, 0.0))
                gpu.state.blend_set("ADDITIVE")  # src * src_alpha + dst, and the shader's alpha is 1
                for start in range(0, len(rows), splat.CHUNK):
                    chunk = rows[start:start + splat.CHUNK]
                    shader.bind()
                    shader.uniform_float("size", (width, height))
                    shader.uniform_float("origin", tuple(map(float, origin)))
                    texture = _float_texture(splat.texture_rows(chunk))  # named: uniform_sampler keeps no reference
                    shader.uniform_sampler("gaussians", texture)
                    quad.draw_instanced(shader, instance_count=len(chunk))  # len > 0: 0 means "all"
            gpu.state.blend_set("NONE")
            shader, quad = _program("linear")
            with self._linear.bind():
                shader.bind()
                shader.uniform_sampler("splat_sum", self._sum.texture_color)
                quad.draw(shader)
        finally:
            gpu.state.blend_set(saved[0])
            gpu.state.depth_test_set(saved[1])
            gpu.state.depth_mask_set(saved[2])

    def read(self) -> np.ndarray:
        """The scene-linear image, float32 [height, width, 4], rows bottom-up (a Blender render pass)."""
        width, height = self.size
        # A one-dimensional Buffer: bpy 5.0.1 reports Fortran strides for the buffer protocol of a
        # multi-dimensional one (numpy would read it transposed).
        pixels = gpu.types.Buffer("FLOAT", width * height * 4)
        with self._linear.bind():
            gpu.state.active_framebuffer_get().read_color(0, 0, width, height, 4, 0, "FLOAT", data=pixels)
        return np.asarray(pixels).reshape(height, width, 4)

    def free(self) -> None:
        self._sum.free()
        self._linear.free()


def _float_texture(array: np.ndarray):
    """An RGBA32F texture of a float32 [height, width, 4] array."""
    height, width = array.shape[:2]
    data = gpu.types.Buffer("FLOAT", array.size, np.ascontiguousarray(array, np.float32).ravel())
    return gpu.types.GPUTexture((width, height), format="RGBA32F", data=data)


def new_image(width: int, height: int) -> SplatImage | None:
    """A SplatImage, or None when the GPU cannot hold one this size (then the caller draws on the CPU)."""
    if max(width, height) > gpu.capabilities.max_texture_size_get():
        return None
    try:
        return SplatImage(width, height)
    except RuntimeError:  # "gpu.offscreen.new(...) failed": out of GPU memory
        return None


def render_clips(clips, width: int, height: int) -> np.ndarray | None:
    """What engine.geometry.render_clips gives (the clips' sum as a scene-linear RGBA pass, rows bottom-up),
    drawn on the GPU; None when the GPU cannot hold an image this size. Needs a GPU context."""
    image = new_image(width, height)
    if image is None:
        return None
    try:
        image.draw(splat.splat_rows([(params, cw, ch) for _, params, cw, ch in clips], width, height))
        return image.read()
    finally:
        image.free()


def gpu_context_possible() -> bool:
    """Whether Blender can give a render engine a GPU context (bl_use_gpu_context). With a window it can. In
    background mode on Linux it makes one with EGL on the default display, and where that fails (no EGL
    driver; on Debian: libegl1 libegl-mesa0 libgl1-mesa-dri) bpy 5.0.1 aborts the whole process at F12
    instead of rendering without one: so ask EGL first, as Blender would."""
    import bpy
    if not bpy.app.background or sys.platform != "linux":
        return True
    return _egl_display_works()


# EGL constants (EGL/egl.h, EGL/eglext.h)
_EGL_OPENGL_API = 0x30A2
_EGL_PLATFORM_SURFACELESS_MESA = 0x31DD
# What GHOST_ContextEGL asks of a config: desktop OpenGL, 8-bit RGB, a pbuffer surface.
_EGL_CONFIG = (0x3040, 0x0008, 0x3024, 8, 0x3023, 8, 0x3022, 8, 0x3033, 0x0001, 0x3038)


def _egl_display_works() -> bool:
    """Blender's way to a headless display (GHOST_ContextEGL): the default display, else Mesa's surfaceless
    platform; then desktop OpenGL and a config like Blender's."""
    import ctypes

    try:
        egl = ctypes.CDLL("libEGL.so.1")
    except OSError:
        return False
    pointer = ctypes.c_void_p
    egl.eglGetDisplay.restype = pointer
    egl.eglGetDisplay.argtypes = [pointer]
    egl.eglGetProcAddress.restype = pointer
    egl.eglGetProcAddress.argtypes = [ctypes.c_char_p]
    egl.eglInitialize.argtypes = [pointer, pointer, pointer]
    egl.eglTerminate.argtypes = [pointer]
    egl.eglChooseConfig.argtypes = [pointer, ctypes.POINTER(ctypes.c_int32), pointer, ctypes.c_int32,
                                    ctypes.POINTER(ctypes.c_int32)]
    display = egl.eglGetDisplay(None)  # EGL_DEFAULT_DISPLAY
    if not (display and egl.eglInitialize(display, None, None)):
        address = egl.eglGetProcAddress(b"eglGetPlatformDisplayEXT")
        if not address:
            return False
        get_platform_display = ctypes.CFUNCTYPE(pointer, ctypes.c_uint, pointer, pointer)(address)
        display = get_platform_display(_EGL_PLATFORM_SURFACELESS_MESA, None, None)
        if not (display and egl.eglInitialize(display, None, None)):
            return False
    try:
        attributes = (ctypes.c_int32 * len(_EGL_CONFIG))(*_EGL_CONFIG)
        count = ctypes.c_int32(0)
        return bool(egl.eglBindAPI(_EGL_OPENGL_API)
                    and egl.eglChooseConfig(display, attributes, None, 0, ctypes.byref(count)) and count.value > 0)
    finally:
        egl.eglTerminate(display)
