"""HyperGS core: video -> 2D Gaussians in one forward pass. Never imports bpy."""
from .gaussians import GaussianVideo

__all__ = ["GaussianVideo"]
