"""Pinhole cameras and rigid transforms (OpenCV camera frame: x right, y down, z ahead)."""

from __future__ import annotations

import cv2
import numpy as np


def intrinsics(size: tuple[int, int], fov_deg: float = 70.0) -> np.ndarray:
    """Pinhole K (3, 3) for an image of ``size`` (H, W) with horizontal field of view ``fov_deg``."""
    h, w = size
    f = (w / 2) / np.tan(np.radians(fov_deg) / 2)
    return np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1]])


def pose(rotation: np.ndarray, translation: np.ndarray) -> np.ndarray:
    """A 4x4 rigid transform from a rotation (3x3, or an axis-angle 3-vector) and a translation."""
    rotation = np.asarray(rotation, np.float64)
    if rotation.shape == (3,):
        rotation = cv2.Rodrigues(rotation)[0]
    T = np.eye(4)
    T[:3, :3], T[:3, 3] = rotation, np.asarray(translation, np.float64)
    return T


def invert(T: np.ndarray) -> np.ndarray:
    """Inverse of a 4x4 rigid transform."""
    inverse = np.eye(4)
    inverse[:3, :3] = T[:3, :3].T
    inverse[:3, 3] = -T[:3, :3].T @ T[:3, 3]
    return inverse


def look_at(eye: np.ndarray, target: np.ndarray, up: tuple[float, float, float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """``T_world_cam`` of a camera at ``eye`` looking at ``target``, image "up" towards world ``up``."""
    z = np.asarray(target, np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, up)  # right = ahead x up; then y = z x x points down in the world
    if np.linalg.norm(x) < 1e-9:
        x = np.cross(z, [1.0, 0.0, 0.0])
    x /= np.linalg.norm(x)
    return pose(np.stack([x, np.cross(z, x), z], 1), eye)


def project(points_cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Project (N, 3) camera-frame points; returns ((N, 2) pixels, (N,) depths)."""
    depth = points_cam[:, 2]
    uv = points_cam @ K.T
    with np.errstate(divide="ignore", invalid="ignore"):
        return uv[:, :2] / uv[:, 2:3], depth


def transform(T: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Apply a 4x4 transform to (N, 3) points."""
    return points @ T[:3, :3].T + T[:3, 3]
