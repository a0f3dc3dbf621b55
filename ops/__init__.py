"""Operators and per-object settings (Blender glue; the work is in hypergs_blender)."""
from . import operators, props

CLASSES = [*props.CLASSES, *operators.CLASSES]
