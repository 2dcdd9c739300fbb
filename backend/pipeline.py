"""The streaming pipeline: images in, poses out, no ground truth and no simulator needed.

``Pipeline`` wires a front-end (``deepslam.frontend``) to the odometry and its pose graph; ``deepslam run``,
``deepslam replay`` and a user's own loop all go through it.
"""

from __future__ import annotations

import numpy as np

from deepslam.backend.config import PipelineConfig
from deepslam.backend.odometry import FrameResult, Odometry
from deepslam.backend.scale import StepLengths
from deepslam.errors import InputError
from deepslam.frontend.tracking import Tracker, make_tracker

CARRYING_METHODS = ("homography", "auto")  # relative-pose methods that may take the dominant plane's homography


class Pipeline:
    """Monocular visual odometry, one frame at a time.

    Args:
        config: the front-end and the odometry (``PipelineConfig``).
        tracker: a front-end of one's own instead of the one ``config.tracker`` describes.
        origin: ``T_world_cam`` (4, 4) of the first frame (default: the identity).
        step_lengths: a function (i, j) -> the true distance (m) between the cameras of frames i and j, for
            ``scale="gt"`` (evaluation only) and the first baseline of ``scale="map"`` (where the input has truth;
            without, the map's unit is its first baseline).

    Example:
        >>> import numpy as np
        >>> from deepslam import Pipeline, PipelineConfig, TrackerConfig
        >>> pipeline = Pipeline(PipelineConfig(TrackerConfig("classical")))
        >>> K = np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]])
        >>> image = np.random.default_rng(0).integers(0, 255, (120, 160), np.uint8)
        >>> result = pipeline.process(image, K, stamp_ns=0)
        >>> result.index, result.T_world_cam.shape, pipeline.trajectory().shape
        (0, (4, 4), (1, 4, 4))
    """

    def __init__(
        self,
        config: PipelineConfig | None = None,
        tracker: Tracker | None = None,
        origin: np.ndarray | None = None,
        step_lengths: StepLengths | None = None,
    ):
        if config is not None and not isinstance(config, PipelineConfig):
            raise InputError(
                f"config must be a PipelineConfig (its tracker and odometry), got {type(config).__name__}: "
                "PipelineConfig(odometry=...) or PipelineConfig(TrackerConfig(...))"
            )
        self.config = config or PipelineConfig()
        # carried tracks sit where the dominant plane's homography puts them: on by default only when
        # relative poses may come from that homography too
        carry = self.config.odometry.method in CARRYING_METHODS
        tracker = tracker or make_tracker(self.config.tracker, carry_default=carry)
        self.odometry = Odometry(tracker, self.config.odometry, origin, step_lengths)
        self.stamps_ns: list[int] = []
        self.shape: tuple[int, int] | None = None  # the first frame's image (H, W)

    @property
    def tracker(self) -> Tracker:
        return self.odometry.tracker

    def process(self, image: np.ndarray, K: np.ndarray, stamp_ns: int) -> FrameResult:
        """The next frame's tracks and pose.

        Args:
            image: uint8 (H, W) grayscale, the same size in every frame.
            K: (3, 3) camera matrix ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` at the image's size (its principal
                point within the image).
            stamp_ns: integer nanoseconds, increasing from frame to frame.

        Returns:
            ``FrameResult``: tracks, the relative pose to its keyframe, ``T_world_cam`` (4, 4) as the graph
            has it now, and diagnostics.
        """
        K = _check_frame(image, K, stamp_ns, self.stamps_ns[-1] if self.stamps_ns else None)
        if self.shape is not None and image.shape != self.shape:
            raise InputError(
                f"frame {len(self.stamps_ns)} is {image.shape[0]}x{image.shape[1]}, the first was "
                f"{self.shape[0]}x{self.shape[1]}: every frame of a run must have the same size"
            )
        result = self.odometry.process(image, K)
        self.stamps_ns.append(int(stamp_ns))
        self.shape = image.shape
        return result

    def trajectory(self) -> np.ndarray:
        """The optimised poses (N, 4, 4) ``T_world_cam`` of every frame so far (each refined by the later ones)."""
        return self.odometry.poses()


def _check_frame(image: np.ndarray, K, stamp_ns: int, previous_ns: int | None) -> np.ndarray:
    """K as a float64 (3, 3) array, or ``InputError`` naming what is wrong with a frame."""
    if not isinstance(image, np.ndarray) or image.dtype != np.uint8 or image.ndim != 2:
        kind = f"{image.dtype} {image.shape}" if isinstance(image, np.ndarray) else type(image).__name__
        raise InputError(f"the image must be uint8 (H, W) grayscale, got {kind}")
    try:
        K = np.asarray(K, np.float64)
    except (TypeError, ValueError):
        raise InputError(f"K must be a (3, 3) array of numbers, got {K!r}") from None
    if K.shape != (3, 3) or not np.all(np.isfinite(K)) or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"K must be a finite (3, 3) camera matrix with positive focal lengths, got {K.tolist()}")
    if not np.allclose([K[1, 0], *K[2]], [0, 0, 0, 1], rtol=0, atol=1e-9):
        raise InputError(f"K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] (not transposed), got {K.tolist()}")
    (h, w), (cx, cy) = image.shape, K[:2, 2]
    if not (-0.5 < cx < w - 0.5 and -0.5 < cy < h - 0.5):
        raise InputError(
            f"K's principal point ({cx:g}, {cy:g}) is not inside the {h}x{w} image: K must be the camera matrix at "
            "the images' size"
        )
    if not isinstance(stamp_ns, (int, np.integer)):
        raise InputError(f"stamp_ns must be integer nanoseconds, got {stamp_ns!r}")
    if previous_ns is not None and stamp_ns <= previous_ns:
        raise InputError(f"stamps must increase: {stamp_ns} ns after {previous_ns} ns")
    return K
