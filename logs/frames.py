"""The typed frame record that is written to and read back from a log, and pose/quaternion helpers."""

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
    keyframe, and the median error (px) against truth of the pairs its pose was measured from (the
    keyframe's points and this frame's, as measured); NaN where there is no truth."""

    tracks: int
    inliers: int
    lost: bool
    reason: str = ""
    correspondence_error_px: float = float("nan")
    position_error_m: float = float("nan")
    keyframe: bool = False
    pair_error_px: float = float("nan")


@dataclass
class LogFrame:
    """One frame of a run. Poses are 4x4 ``T_world_cam``; ``covariance`` (6, 6) is gtsam's marginal
    of the estimate (rotation first, body frame); ``tracks`` (N, 4) [x, y, score, id]."""

    stamp_ns: int
    image: np.ndarray
    K: np.ndarray
    T_groundtruth: np.ndarray | None = None
    T_estimate: np.ndarray | None = None
    covariance: np.ndarray | None = None
    tracks: np.ndarray | None = None
    correspondences: Correspondences | None = None
    diagnostics: FrameDiagnostics | None = None


def quaternion_from_matrix(R: np.ndarray) -> np.ndarray:
    """Unit quaternion (x, y, z, w), w >= 0, of a 3x3 rotation matrix."""
    m = np.asarray(R, np.float64)
    trace = np.trace(m)
    if trace > 0:
        s = 2.0 * np.sqrt(trace + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    else:
        i = int(np.argmax(np.diag(m)))
        j, k = (i + 1) % 3, (i + 2) % 3
        s = 2.0 * np.sqrt(1.0 + m[i, i] - m[j, j] - m[k, k])
        q = [0.0, 0.0, 0.0, (m[k, j] - m[j, k]) / s]
        q[i], q[j], q[k] = 0.25 * s, (m[j, i] + m[i, j]) / s, (m[k, i] + m[i, k]) / s
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[3] >= 0 else -q


def matrix_from_quaternion(q: np.ndarray) -> np.ndarray:
    """3x3 rotation matrix of a quaternion (x, y, z, w); normalised first."""
    x, y, z, w = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose_matrix(position: np.ndarray, quaternion: np.ndarray) -> np.ndarray:
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = matrix_from_quaternion(quaternion), position
    return T
