"""The add-on preferences (Edit > Preferences > Add-ons > HyperGS): where the network runs (an
onnxruntime execution provider), how many CPU threads it uses, and where the HyperGS transformer's
weights are (a folder of your own; empty: the bundled ones). hypergs_blender/runtime.py turns them into the encoder's
parameters; `runtime(context)` reads them on the main thread."""
import bpy
from bpy.props import EnumProperty, IntProperty, StringProperty

from ..hypergs_blender.errors import HyperGSError
from ..hypergs_blender.runtime import AUTO, PROVIDERS, Runtime, available_providers, model_weights

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
    transformer_weights: StringProperty(
        name="Transformer Weights", subtype="DIR_PATH", default="",
        description="Folder of the HyperGS transformer's weights, as `hypergs export` writes them "
                    "(hypergs_transformer.json and .onnx; empty: the bundled ones, if any). The import and "
                    "convert dialogs offer the transformer when they are there")

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
        layout.prop(self, "transformer_weights")
        try:
            layout.label(text=f"HyperGS transformer: {model_weights(runtime_of(self), 'transformer')}", icon="CHECKMARK")
        except HyperGSError as e:
            layout.label(text=str(e), icon="INFO" if not self.transformer_weights else "ERROR")


def runtime_of(prefs) -> Runtime:
    weights = prefs.transformer_weights
    return Runtime(prefs.device, prefs.threads, bpy.path.abspath(weights) if weights else "")


def runtime(context) -> Runtime:
    """The preferences as the encoder's Runtime (the defaults when the add-on has no preferences)."""
    addon = context.preferences.addons.get(ADDON)
    prefs = addon.preferences if addon is not None else None
    return runtime_of(prefs) if prefs is not None else Runtime()


CLASSES = [HyperGSPreferences]
