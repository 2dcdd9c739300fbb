"""Back-end: relative poses, the local map, the pose graph, odometry, the streaming pipeline and drift metrics.

``odometry.Odometry`` takes a frame through parts that each live in one module:

- ``twoview``: a frame's pose from a keyframe by the homography or essential matrix of their shared tracks
  (``relpose`` fits and decomposes them with OpenCV): to start a map, and where the map cannot locate a frame;
- ``mapping``: the local map (landmarks, PnP, bundle adjustment) and the frames a map waits through: adjusted
  together until it starts, then located in it (``InitialViews``);
- ``keyframes``: the one keyframe decision (``KeyframePolicy``) and the odometry's ``Phase``;
- ``scale``: the metric length of two-view steps (``MapScale``, ``PlaneScale``);
- ``graph``: the ISAM2 pose graph of keyframes and of the frames measured two-view.
"""

from deepslam._lazy import lazy_exports

_EXPORTS = {  # public name: the module that defines it
    "Pipeline": "pipeline",
    "PipelineConfig": "config",
    "Odometry": "odometry",
    "OdometryConfig": "config",
    "GraphConfig": "config",
    "FrameResult": "odometry",
    "PoseGraph": "graph",
    "RelativePose": "relpose",
    "estimate": "relpose",
    "ate_rmse": "drift",
    "summary": "drift",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
