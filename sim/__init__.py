"""Simulation: Synthetic Shapes, noise, homographies, point-cloud pairs, worlds, trajectories, photographs."""

from deepslam._lazy import lazy_exports

_EXPORTS = {  # public name: the module that defines it
    "Scenario": "scenario",
    "ScenarioConfig": "scenario",
    "HomographyConfig": "homography",
    "sample_homography": "homography",
    "warp_image_and_points": "homography",
    "intrinsics": "camera",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
