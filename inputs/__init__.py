"""Camera data from outside: ROS 2 bags, TUM RGB-D and EuRoC/ASL folders, deepslam's own logs.

``open_source(path, options)`` recognises what ``path`` is, checks it before any work starts (topics,
encodings, calibration, timestamps in order, one image size), and yields ``SourceFrame``s: grayscale
images undistorted (plumb_bob / radtan or equidistant, with OpenCV) and resized to the pipeline's size,
with the K that goes with them, and ground truth where the input has it (associated by time, within
``MAX_TIME_GAP_NS``).
"""

from deepslam._lazy import lazy_exports

_EXPORTS = {  # public name: the module that defines it
    "Calibration": "calibration",
    "Rectifier": "calibration",
    "Source": "source",
    "SourceError": "source",
    "SourceFrame": "source",
    "SourceOptions": "source",
    "associate": "timing",
    "open_source": "source",
}
__all__ = list(_EXPORTS)
__getattr__, __dir__ = lazy_exports(__name__, _EXPORTS)
