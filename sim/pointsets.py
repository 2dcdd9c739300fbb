"""2D point-set pairs under the paper's four test motions (the MagicWarp breakdown experiment).

Random points in image A move by a ground-truth homography into image B; points that leave B are
dropped and spurious random points are added to B. Random points are drawn as a detector reports
them (``detector_points``): at most one per 8x8 cell, since MagicPoint's cell output (and
MagicWarp's input) holds one point per cell. Every motion is interpolated from the identity
by its magnitude: translation to the right (px), in-plane rotation about the centre (degrees),
zoom-in scale (factor), and a random homography whose mean corner displacement is the magnitude (px).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from deepslam.errors import InputError
from deepslam.geometry import in_image, warp_points
from deepslam.sim.homography import image_corners, normalize

MOTIONS = ("translation", "rotation", "scale", "random_h")


def motion_homography(
    kind: str, magnitude: float, size: tuple[int, int], direction: np.ndarray | None = None
) -> np.ndarray:
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
    raise InputError(f"unknown motion {kind!r}; expected one of {', '.join(MOTIONS)}")


def random_direction(rng: np.random.Generator) -> np.ndarray:
    """A random corner displacement pattern (4, 2) whose corner displacements have mean norm 1."""
    pattern = rng.normal(size=(4, 2))
    return pattern / np.linalg.norm(pattern, axis=1).mean()


def detector_points(rng: np.random.Generator, count: int, size: tuple[int, int], cell: int = 8) -> np.ndarray:
    """``count`` random points (count, 2) in an image of ``size`` (H, W), at most one per
    ``cell`` x ``cell`` cell (distinct cells, each point uniform in its cell's pixels)."""
    h, w = size
    rows, cols = h // cell, w // cell
    if not 0 <= count <= rows * cols:
        raise InputError(
            f"{count} points do not fit one per {cell}x{cell} cell of a {h}x{w} image ({rows * cols} cells)"
        )
    row, col = np.divmod(rng.choice(rows * cols, count, replace=False), cols)
    return np.c_[col, row] * cell + rng.uniform(-0.5, cell - 0.5, (count, 2))


@dataclass
class PointSetPair:
    """points_a (N1, 2); points_b (N2, 2); true_index (N1,) index into points_b of each A point's
    true partner, -1 where it left image B."""

    points_a: np.ndarray
    points_b: np.ndarray
    true_index: np.ndarray

    def without_spurious(self) -> PointSetPair:
        """The same pair with only B's points that are some A point's partner (its spurious points
        removed), B's order kept."""
        has_partner = self.true_index >= 0
        partnered = np.zeros(len(self.points_b), bool)
        partnered[self.true_index[has_partner]] = True
        true_index = np.full(len(self.true_index), -1)
        true_index[has_partner] = (np.cumsum(partnered) - 1)[self.true_index[has_partner]]
        return PointSetPair(self.points_a, self.points_b[partnered], true_index)


def make_pair(
    rng: np.random.Generator, H: np.ndarray, count: int, extra: float, size: tuple[int, int] = (120, 160)
) -> PointSetPair:
    """``count`` random points in A warped by ``H`` into B, plus ``extra * count`` spurious B points."""
    points_a = detector_points(rng, count, size)
    moved = warp_points(points_a, H)
    stays = in_image(moved, size)
    spurious = detector_points(rng, int(round(extra * count)), size)
    points_b = np.vstack([moved[stays], spurious])
    order = rng.permutation(len(points_b))
    true_index = np.full(count, -1)
    true_index[stays] = np.argsort(order)[: stays.sum()]
    return PointSetPair(points_a, points_b[order], true_index)
