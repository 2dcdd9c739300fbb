"""Back-end: relative poses, the pose graph, odometry, the streaming pipeline and drift metrics."""

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
