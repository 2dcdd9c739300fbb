"""Classical corner detectors through OpenCV, scored and suppressed the same way as MagicPoint.

Each returns float32 (N, 3) [x, y, score] sorted by score, after the shared ``extract_points``
(local maxima, greedy NMS of radius ``nms_radius`` pixels, border removal).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from deepslam.errors import InputError
from deepslam.frontend.points import check_image, extract_points


@dataclass
class ClassicalDetector:
    """``kind`` in ("fast", "harris", "shi"); ``top_k`` caps the detections (None: all)."""

    kind: str
    nms_radius: int = 4
    border: int = 4
    top_k: int | None = None

    def __post_init__(self):
        if self.kind not in DETECTORS:
            raise InputError(f"unknown classical detector {self.kind!r}; expected one of {', '.join(DETECTORS)}")

    def score_map(self, image: np.ndarray) -> np.ndarray:
        """The detector's corner response, float32 (H, W)."""
        return DETECTORS[self.kind](check_image(image))

    def detect(self, image: np.ndarray) -> np.ndarray:
        scores = self.score_map(image)
        return extract_points(scores, 1e-6 * max(float(scores.max()), 1e-12), self.nms_radius, self.border, self.top_k)


def fast_response(image: np.ndarray) -> np.ndarray:
    """FAST-9 corner scores (OpenCV threshold 1; OpenCV computes scores only with its own NMS) placed in a map."""
    fast = cv2.FastFeatureDetector_create(threshold=1, nonmaxSuppression=True)
    scores = np.zeros(image.shape, np.float32)
    for keypoint in fast.detect(image):
        x, y = int(round(keypoint.pt[0])), int(round(keypoint.pt[1]))
        scores[y, x] = max(scores[y, x], keypoint.response)
    return scores


def harris_response(image: np.ndarray) -> np.ndarray:
    """Harris corner measure (block 3, Sobel 3, k 0.04), negative values clipped."""
    return np.maximum(cv2.cornerHarris(image.astype(np.float32), 3, 3, 0.04), 0)


def shi_response(image: np.ndarray) -> np.ndarray:
    """Shi-Tomasi minimal eigenvalue (block 3, Sobel 3)."""
    return cv2.cornerMinEigenVal(image.astype(np.float32), 3, 3)


DETECTORS = {"fast": fast_response, "harris": harris_response, "shi": shi_response}
