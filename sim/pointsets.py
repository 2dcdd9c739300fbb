"""2D point-set pairs under the paper's four test motions (the MagicWarp breakdown experiment).

Random points in image A move by a ground-truth homography into image B; points that leave B are
dropped and spurious random points are added to B. Every motion is interpolated from the identity
by its magnitude: translation to the right (px), in-plane rotation about the centre (degrees),
zoom-in scale (factor), and a random homography whose mean corner displacement is the magnitude (px).
"""
from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from sim.homography import image_corners, inside, normalize, warp_points

MOTIONS = ("translation", "rotation", "scale", "random_h")


def motion_homography(kind: str, magnitude: float, size: tuple[int, int],
                      direction: np.ndarray | None = None) -> np.ndarray:
    """Homography (3, 3) of a motion ``kind`` at ``magnitude``.

    For "random_h", ``direction`` (4, 2) holds the corner displacement pattern with mean norm 1
    (draw it with ``random_direction``); the corners move by ``magnitude * direction``.
    """
    h, w = size
    centre = np.array([(w - 1) / 2, (h - 1) / 2])
    if kind == "translation":
        return np.array([[1.0, 0, magnitude], [0, 1, 0], [0, 0, 1]])
    if kind in ("rotation", "scale"):
        angle, scale = (magnitude, 1.0) if kind == "rotation" else (0.0, magnitude)
        return normalize(np.vstack([cv2.getRotationMatrix2D(tuple(centre), angle, scale), [0, 0, 1]]))
    if kind == "random_h":
        src = image_corners(size)
        dst = src + magnitude * direction
        return normalize(cv2.getPerspectiveTransform(src.astype(np.float32), dst.astype(np.float32)))
    raise ValueError(f"unknown motion {kind!r}; expected one of {', '.join(MOTIONS)}")


def random_direction(rng: np.random.Generator) -> np.ndarray:
    """A random corner displacement pattern (4, 2) whose corner displacements have mean norm 1."""
    pattern = rng.normal(size=(4, 2))
    return pattern / np.linalg.norm(pattern, axis=1).mean()


@dataclass
class PointSetPair:
    """points_a (N1, 2); points_b (N2, 2); true_index (N1,) index into points_b of each A point's
    true partner, -1 where it left image B."""

    points_a: np.ndarray
    points_b: np.ndarray
    true_index: np.ndarray


def make_pair(rng: np.random.Generator, H: np.ndarray, count: int, extra: float,
              size: tuple[int, int] = (120, 160)) -> PointSetPair:
    """``count`` random points in A warped by ``H`` into B, plus ``extra * count`` spurious B points."""
    h, w = size
    points_a = rng.uniform([0, 0], [w - 1, h - 1], (count, 2))
    moved = warp_points(points_a, H)
    stays = inside(moved, size)
    spurious = rng.uniform([0, 0], [w - 1, h - 1], (int(round(extra * count)), 2))
    points_b = np.vstack([moved[stays], spurious])
    order = rng.permutation(len(points_b))
    true_index = np.full(count, -1)
    true_index[stays] = np.argsort(order)[: stays.sum()]
    return PointSetPair(points_a, points_b[order], true_index)
