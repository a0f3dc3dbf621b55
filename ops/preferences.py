"""The add-on preferences (Edit > Preferences > Add-ons > HyperGS): where the network runs (an
onnxruntime execution provider) and how many CPU threads it uses. hypergs_blender/runtime.py turns them
into the encoder's parameters; `runtime(context)` reads them on the main thread."""
import bpy
from bpy.props import EnumProperty, IntProperty

from ..hypergs_blender.runtime import AUTO, PROVIDERS, Runtime, available_providers

ADDON = __package__.rpartition(".")[0]  # the extension's module, e.g. bl_ext.user_default.hypergs

DEVICES = [(AUTO, "Best Available", "A GPU provider when this onnxruntime has one (CUDA, DirectML, CoreML), "
                                    "else the CPU")] + [
    (provider, name, f"onnxruntime's {provider} (the CPU runs the network where it is not available)")
    for provider, name in PROVIDERS.items()]


class HyperGSPreferences(bpy.types.AddonPreferences):
    bl_idname = ADDON

    device: EnumProperty(name="Run the Network On", items=DEVICES, default=AUTO,
                         description="The onnxruntime execution provider that encodes videos")
    threads: IntProperty(name="CPU Threads", default=0, min=0, max=256,
                         description="Threads the network uses on the CPU (0: one per core)")

    def draw(self, context):
        layout = self.layout
        layout.use_property_split = True
        layout.prop(self, "device")
        layout.prop(self, "threads")
        available = available_providers()
        names = ", ".join(PROVIDERS[p] for p in available) or "none (onnxruntime is not installed)"
        layout.label(text=f"This onnxruntime has: {names}", icon="INFO")
        if self.device != AUTO and self.device not in available:
            layout.label(text=f"{PROVIDERS[self.device]} is not available here: the CPU runs the network",
                         icon="ERROR")


def runtime(context) -> Runtime:
    """The preferences as the encoder's Runtime (the defaults when the add-on has no preferences)."""
    addon = context.preferences.addons.get(ADDON)
    prefs = addon.preferences if addon is not None else None
    return Runtime(prefs.device, prefs.threads) if prefs is not None else Runtime()


CLASSES = [HyperGSPreferences]
