"""The typed frame record that is written to and read back from a log."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass
class Correspondences:
    """Matches of the reference keyframe's tracks (``reference_index``) to this frame's
    (``current_index``), the relative-pose model ("homography", "essential", "static", "failed"), its
    inlier count and ``T_ref_cur`` (4, 4), the pose of this camera in the keyframe's camera frame."""

    reference_stamp_ns: int
    reference_index: np.ndarray
    current_index: np.ndarray
    model: str
    inliers: int
    T_ref_cur: np.ndarray


@dataclass
class FrameDiagnostics:
    """How one frame went: tracks reported, inliers of its relative pose, whether it was lost (no
    relative pose: the estimate is a guess) and why, the median error (px) of its tracks against the
    simulator's truth (from the frame before), the position error (m) of its estimate, whether it became a
    keyframe, the median error (px) against truth of the pairs its pose was measured from (the
    keyframe's points and this frame's, as measured; NaN where there is no truth), the landmarks of the
    map after it (0 without a map), the odometry's phase after it (initialising, tracking, lost; empty in older
    logs) and why it became a keyframe (empty where it did not)."""

    tracks: int
    inliers: int
    lost: bool
    reason: str = ""
    correspondence_error_px: float = float("nan")
    position_error_m: float = float("nan")
    keyframe: bool = False
    pair_error_px: float = float("nan")
    landmarks: int = 0
    phase: str = ""
    keyframe_reason: str = ""


@dataclass
class LogFrame:
    """One frame of a run. Poses are 4x4 ``T_world_cam``; ``covariance`` (6, 6) is gtsam's marginal
    of the estimate (rotation first, body frame); ``tracks`` (N, 4) [x, y, score, id]; ``landmarks`` (M, 3): the
    map's points in the world frame, where the frame changed the map (a keyframe), else None."""

    stamp_ns: int
    image: np.ndarray
    K: np.ndarray
    T_groundtruth: np.ndarray | None = None
    T_estimate: np.ndarray | None = None
    covariance: np.ndarray | None = None
    tracks: np.ndarray | None = None
    correspondences: Correspondences | None = None
    diagnostics: FrameDiagnostics | None = None
    landmarks: np.ndarray | None = None
