"""Point extraction from score maps: threshold, non-maximum suppression, border removal, top-k.

Shared by MagicPoint and the classical detectors, so every detector is scored the same way.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree

from deepslam.errors import InputError
from deepslam.frontend.config import SUBPIXEL, Subpixel


def check_image(image: np.ndarray, multiple_of: int = 1) -> np.ndarray:
    """Validate a grayscale uint8 HxW image (non-empty, sides divisible by ``multiple_of``)."""
    image = np.asarray(image)
    if image.ndim != 2:
        raise InputError(f"expected a grayscale HxW image, got an array of shape {image.shape}")
    if image.dtype != np.uint8:
        raise InputError(f"expected a uint8 image, got dtype {image.dtype}")
    if image.size == 0:
        raise InputError(f"expected a non-empty image, got shape {image.shape}")
    h, w = image.shape
    if h % multiple_of or w % multiple_of:
        fit = f"{max(h - h % multiple_of, multiple_of)}x{max(w - w % multiple_of, multiple_of)}"
        raise InputError(
            f"image height and width must be divisible by {multiple_of}, got {image.shape}: crop or resize it "
            f"(to {fit}, for one)"
        )
    return image


def nms_points(points: np.ndarray, radius: float) -> np.ndarray:
    """Greedy non-maximum suppression of (N, 3) [x, y, score] points: keep the best-scoring point
    and drop every other within ``radius`` pixels, in order of score. Returns the kept points sorted
    by descending score. Only points with a neighbour within ``radius`` (found by a k-d tree) are visited."""
    order = np.argsort(-points[:, 2], kind="stable")
    points = points[order]
    if radius <= 0 or len(points) < 2:
        return points
    close = cKDTree(points[:, :2].astype(np.float64)).query_pairs(radius, output_type="ndarray")  # (K, 2), i < j
    suppressed = np.zeros(len(points), bool)
    for i, j in close[np.lexsort((close[:, 1], close[:, 0]))].tolist():  # a point's fate is final before it suppresses
        if not suppressed[i]:
            suppressed[j] = True
    return points[~suppressed]


SMOOTHING_SIGMA = 1.5  # pixels, of "smoothed"; chosen on the validation photographs (S-HA model card)


def centroid(scores: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Move integer peaks (N, 3) [x, y, score] of a score map (H, W) to the score-weighted mean position
    of their 3x3 neighbourhood (a soft argmax: exact for a peak spread bilinearly over its neighbours);
    float32 copy."""
    h, w = scores.shape
    x = np.clip(points[:, 0].astype(np.int64), 1, w - 2)
    y = np.clip(points[:, 1].astype(np.int64), 1, h - 2)
    dy, dx = np.mgrid[-1:2, -1:2]
    weights = scores[y[:, None, None] + dy, x[:, None, None] + dx].astype(np.float64)  # (N, 3, 3)
    total = np.maximum(weights.sum((1, 2)), 1e-12)
    refined = points.astype(np.float32).copy()
    refined[:, 0] = x + (weights * dx).sum((1, 2)) / total
    refined[:, 1] = y + (weights * dy).sum((1, 2)) / total
    return refined


def subpixel(scores: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Move integer peaks (N, 3) [x, y, score] of a score map (H, W) to the vertex of a parabola fitted
    through each peak and its two neighbours along x and along y (at most half a pixel); float32 copy."""
    h, w = scores.shape
    x = np.clip(points[:, 0].astype(np.int64), 1, w - 2)
    y = np.clip(points[:, 1].astype(np.int64), 1, h - 2)
    centre = scores[y, x].astype(np.float64)
    refined = points.astype(np.float32).copy()
    for axis, (before, after) in enumerate(
        ((scores[y, x - 1], scores[y, x + 1]), (scores[y - 1, x], scores[y + 1, x]))
    ):
        curvature = 2 * centre - before - after
        offset = np.where(curvature > 1e-12, 0.5 * (after - before) / np.maximum(curvature, 1e-12), 0.0)
        refined[:, axis] += np.clip(offset, -0.5, 0.5)
    return refined


def smoothed_subpixel(scores: np.ndarray, points: np.ndarray) -> np.ndarray:
    """``subpixel`` on the score map (H, W) smoothed by a Gaussian of ``SMOOTHING_SIGMA`` pixels: each
    parabola then follows the peak's wider neighbourhood, not just its three sharpest pixels; float32 copy."""
    return subpixel(cv2.GaussianBlur(scores, (0, 0), SMOOTHING_SIGMA), points)


def disk(radius: int) -> np.ndarray:
    """uint8 (2r+1, 2r+1) mask of the pixels within ``radius`` of the centre (Euclidean)."""
    dy, dx = np.mgrid[-radius : radius + 1, -radius : radius + 1]
    return (dx**2 + dy**2 <= radius**2).astype(np.uint8)


def extract_points(
    scores: np.ndarray,
    threshold: float,
    nms_radius: int = 4,
    border: int = 4,
    top_k: int | None = None,
    refine: Subpixel = "none",
) -> np.ndarray:
    """Points of a score map (H, W): maxima of their disk of radius r = ``nms_radius`` pixels above
    ``threshold``, at least ``border`` pixels from the edge, then greedy NMS with the same radius (a
    weaker point within r pixels of a stronger one goes), best ``top_k`` kept; moved to sub-pixel
    positions by ``refine``: "parabola" (``subpixel``), "smoothed" (``smoothed_subpixel``), "centroid"
    (``centroid``) or "none".

    Returns float32 (N, 3) [x, y, score] sorted by descending score.
    """
    scores = np.asarray(scores, np.float32)
    if nms_radius > 0:
        peaks = (scores >= cv2.dilate(scores, disk(nms_radius))) & (scores > threshold)
    else:
        peaks = scores > threshold
    if border > 0:
        peaks[:border], peaks[-border:], peaks[:, :border], peaks[:, -border:] = False, False, False, False
    y, x = np.nonzero(peaks)
    points = nms_points(np.stack([x, y, scores[y, x]], 1).astype(np.float32), nms_radius)
    points = points[:top_k] if top_k else points
    if refine not in SUBPIXEL:
        raise InputError(f"sub-pixel refinement must be one of {', '.join(SUBPIXEL)}, got {refine!r}")
    refiners = {"none": lambda s, p: p, "parabola": subpixel, "centroid": centroid, "smoothed": smoothed_subpixel}
    return refiners[refine](scores, points)
