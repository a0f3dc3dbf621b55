"""Operators and per-object settings (Blender glue; the work is in hypergs_blender), one module per job:
encode.py (import a video, convert strips, re-encode; sources.py says what they read, jobs.py runs the
encode off the main thread, quality.py is their options), clip_files.py (Gaussian video files),
frame_cache.py (pack and unpack a clip's frame cache), edit_frame.py; scene.py writes clips into the
scene; context.py is what they share (the active clip, error reports)."""
from . import clip_files, edit_frame, encode, frame_cache, preferences, props

CLASSES = [*props.CLASSES, *preferences.CLASSES, *encode.CLASSES, *edit_frame.CLASSES, *clip_files.CLASSES,
           *frame_cache.CLASSES]
