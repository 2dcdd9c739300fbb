"""Front-end: MagicPoint, MagicWarp, descriptor-free matching, classical baselines, tracking."""

from deepslam.frontend.magicpoint import MagicPoint
from deepslam.frontend.magicwarp import MagicWarp, match, refine

__all__ = ["MagicPoint", "MagicWarp", "match", "refine"]
