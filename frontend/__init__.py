"""Front-end: MagicPoint, MagicWarp, descriptor-free matching, classical baselines, tracking."""
from frontend.magicpoint import MagicPoint
from frontend.magicwarp import MagicWarp, match, refine

__all__ = ["MagicPoint", "MagicWarp", "match", "refine"]
