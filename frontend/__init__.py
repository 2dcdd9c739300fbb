"""Front-end: MagicPoint, MagicWarp, descriptor-free matching, classical baselines, tracking."""

from deepslam._lazy import lazy_exports

_EXPORTS = {  # public name: the module that defines it
    "MagicPoint": "magicpoint",
    "MagicWarp": "magicwarp",
    "match": "magicwarp",
    "refine": "magicwarp",
    "TrackerConfig": "config",
    "MagicWarpConfig": "config",
    "DETECTOR_PRESETS": "config",
    "Tracker": "tracking",
    "Tracks": "tracking",
    "MagicTracker": "tracking",
    "ClassicalTracker": "tracking",
    "OracleTracker": "tracking",
    "make_tracker": "tracking",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
