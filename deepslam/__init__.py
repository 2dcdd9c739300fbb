"""deepslam: the system of "Toward Geometric Deep SLAM" (DeTone, Malisiewicz, Rabinovich, 2017) with a
pose back-end. ``Pipeline`` takes images one at a time and returns poses; the subpackages hold the parts
(``frontend``, ``backend``, ``inputs``, ``logs``, ``sim``). Names load on first use."""

from deepslam._lazy import lazy_exports

_EXPORTS = {  # public name: the module that defines it
    "Pipeline": "backend.pipeline",
    "PipelineConfig": "backend.config",
    "FrameResult": "backend.odometry",
    "TrackerConfig": "frontend.config",
    "OdometryConfig": "backend.config",
    "DeepslamError": "errors",
    "InputError": "errors",
    "Result": "results",
    "open_source": "inputs.source",
    "SourceOptions": "inputs.source",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
