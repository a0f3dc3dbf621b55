"""Benchmarks (`hypergs bench ...`): each module measures one thing and returns a report dict; common.py
holds what they share. blender.py drives Blender headless (extension build, sessions, the main job)."""
