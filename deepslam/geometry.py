"""Conventions every package shares: pixel coordinates, point warping, homography fits, path length,
rotation angles, angles between vectors and quaternions (x, y, z, w; ROS's order).

Pixels are float (x, y), x right, y down, the centre of the top-left pixel at (0, 0), so an image of
size (H, W) covers [-0.5, W - 0.5] x [-0.5, H - 0.5]. ``H_ab`` maps points of image a to image b.
"""

from __future__ import annotations

import cv2
import numpy as np


def warp_points(points: np.ndarray, H: np.ndarray) -> np.ndarray:
    """Apply a homography (3, 3) to (N, 2+) points (extra columns ignored); returns (N, 2) float64."""
    points = np.asarray(points, np.float64)
    points = points.reshape(-1, points.shape[-1] if points.ndim > 1 else 2)[:, :2]
    moved = points @ H[:, :2].T + H[:, 2]
    return moved[:, :2] / moved[:, 2:3]


def fit_homography(points_a: np.ndarray, points_b: np.ndarray, threshold: float) -> np.ndarray | None:
    """The homography (3, 3), ``H[2, 2] == 1``, that most pairs of ``points_a`` and ``points_b`` (K, 2)
    agree on (OpenCV's USAC MAGSAC, ``threshold`` pixels), or None when the fit fails (too few or
    degenerate pairs, e.g. collinear points)."""
    try:
        H, _ = cv2.findHomography(
            np.asarray(points_a, np.float64), np.asarray(points_b, np.float64), cv2.USAC_MAGSAC, threshold
        )
    except cv2.error:
        return None
    if H is None or not np.all(np.isfinite(H)) or abs(H[2, 2]) < 1e-12:
        return None
    return H / H[2, 2]


def in_image(points: np.ndarray, size: tuple[int, int], margin: float = 0.0) -> np.ndarray:
    """Mask (N,) of (N, 2+) points inside an image of ``size`` (H, W), edges inclusive, at least
    ``margin`` pixels from the image's outer edge. ``margin=0.5`` keeps the points between the
    centres of the outermost pixels, [0, W - 1] x [0, H - 1]."""
    h, w = size
    x, y = np.asarray(points, np.float64)[:, 0], np.asarray(points, np.float64)[:, 1]
    return (x >= -0.5 + margin) & (x <= w - 0.5 - margin) & (y >= -0.5 + margin) & (y <= h - 0.5 - margin)


def path_length(poses: np.ndarray) -> float:
    """Length (m) of the path through the positions of (N, 4, 4) poses."""
    return float(np.linalg.norm(np.diff(np.asarray(poses)[:, :3, 3], axis=0), axis=1).sum())


def constant_motion(before: np.ndarray, last: np.ndarray) -> np.ndarray:
    """The pose (4, 4) ``T_world_cam`` after ``last`` where the camera repeats its step from ``before`` to ``last``
    (both (4, 4)): constant motion."""
    return last @ np.linalg.inv(before) @ last


def is_pose(T: np.ndarray, tolerance: float = 1e-5) -> bool:
    """Whether ``T`` is a finite (4, 4) rigid transform: a rotation (orthonormal, determinant +1, to ``tolerance``),
    a translation and a last row 0 0 0 1."""
    T = np.asarray(T, np.float64)
    if T.shape != (4, 4) or not np.all(np.isfinite(T)) or not np.array_equal(T[3], [0, 0, 0, 1]):
        return False
    R = T[:3, :3]
    return bool(np.abs(R.T @ R - np.eye(3)).max() <= tolerance and np.linalg.det(R) > 0)


def rotation_angle(R: np.ndarray) -> np.ndarray:
    """Angle (radians) of rotation matrices (..., 3, 3)."""
    return np.arccos(np.clip((np.trace(R, axis1=-2, axis2=-1) - 1) / 2, -1, 1))


def vector_angle(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle (radians) between vectors ``a`` and ``b`` (..., 3), broadcast; 0 where either has no length."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    lengths = np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1)
    cosine = np.sum(a * b, axis=-1) / np.where(lengths > 0, lengths, 1.0)
    return np.where(lengths > 0, np.arccos(np.clip(cosine, -1, 1)), 0.0)


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
    """T (4, 4) of a position (3,) and a quaternion (x, y, z, w)."""
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = matrix_from_quaternion(quaternion), position
    return T
