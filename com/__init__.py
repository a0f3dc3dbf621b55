"""Blender data shared by the operators (ops/) and the render engine (engine/): a clip's mesh data
(mesh.py) and the cache of linked .hgs files (linked.py)."""
