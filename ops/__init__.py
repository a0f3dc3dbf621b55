"""Operators and per-object settings (Blender glue; the work is in hypergs_blender)."""
from . import operators, preferences, props

CLASSES = [*props.CLASSES, *preferences.CLASSES, *operators.CLASSES]
