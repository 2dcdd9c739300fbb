"""Random homographies and warping of images with their points.

Conventions: pixel coordinates are float (x, y) with the centre of the top-left pixel at (0, 0);
``H_ab`` maps points of image a to image b and is stored with ``H[2, 2] == 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from deepslam.geometry import in_image, warp_points


@dataclass(frozen=True)
class HomographyConfig:
    """Ranges of a random homography, relative to the image size.

    The image corners are moved as a patch: scaled by up to ``scale`` (a factor in
    [1 - scale, 1 + scale]), rotated by up to ``rotation`` radians, shifted by up to
    ``translation`` of the image size, and each corner jittered by up to ``perspective``.
    """

    translation: float = 0.1
    rotation: float = np.pi / 8
    scale: float = 0.2
    perspective: float = 0.1


def normalize(H: np.ndarray) -> np.ndarray:
    """Scale a homography so that ``H[2, 2] == 1``; shape (..., 3, 3)."""
    H = np.asarray(H, dtype=np.float64)
    return H / H[..., 2:3, 2:3]


def image_corners(size: tuple[int, int]) -> np.ndarray:
    """The four outer corners of an image of ``size`` (H, W) in pixel coordinates, (4, 2)."""
    h, w = size
    return np.array([[-0.5, -0.5], [w - 0.5, -0.5], [w - 0.5, h - 0.5], [-0.5, h - 0.5]])


def sample_homography(
    rng: np.random.Generator, size: tuple[int, int], config: HomographyConfig = HomographyConfig()
) -> np.ndarray:
    """A random homography ``H`` mapping an image of ``size`` (H, W) to its warped version, (3, 3)."""
    h, w = size
    src = image_corners(size)
    centre = np.array([(w - 1) / 2, (h - 1) / 2])
    angle = rng.uniform(-config.rotation, config.rotation)
    scale = rng.uniform(1 - config.scale, 1 + config.scale)
    rotation = np.array([[np.cos(angle), -np.sin(angle)], [np.sin(angle), np.cos(angle)]])
    jitter = rng.uniform(-config.perspective, config.perspective, (4, 2)) * [w, h]
    shift = rng.uniform(-config.translation, config.translation, 2) * [w, h]
    dst = (src - centre) @ rotation.T * scale + centre + jitter + shift
    return normalize(cv2.getPerspectiveTransform(src.astype(np.float32), dst.astype(np.float32)))


def warp_image(image: np.ndarray, H: np.ndarray, border_value: int = 0) -> np.ndarray:
    """Warp a uint8 image with ``H`` (source to destination) into an image of the same size."""
    h, w = image.shape[:2]
    return cv2.warpPerspective(
        image,
        H,
        (w, h),
        flags=cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_REFLECT_101 if border_value < 0 else cv2.BORDER_CONSTANT,
        borderValue=max(border_value, 0),
    )


def warp_image_and_points(
    image: np.ndarray, points: np.ndarray, H: np.ndarray, border_value: int = -1
) -> tuple[np.ndarray, np.ndarray]:
    """Warp an image and its (N, 2) points with ``H``; points that leave the image are dropped.

    ``border_value`` < 0 reflects the image at its border (no black wedges), else fills with it.
    Returns (warped uint8 image, float32 (M, 2) points).
    """
    warped = warp_image(image, H, border_value)
    moved = warp_points(points, H)
    return warped, moved[in_image(moved, image.shape[:2])].astype(np.float32)
