"""Detector metrics of the paper: average precision (eps=4), localization error, repeatability (eps=2).

Detections are float (N, 3) [x, y, score] arrays; ground truth float (K, 2) [x, y] arrays.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepslam.geometry import in_image, warp_points


@dataclass
class DetectionScores:
    """Per-detection outcome over a set: score (N,), is_true_positive (N,), distance (N,) to the
    matched corner (NaN for false positives), and the number of ground-truth corners."""

    score: np.ndarray
    correct: np.ndarray
    distance: np.ndarray
    positives: int


def match_detections(detections: np.ndarray, corners: np.ndarray, eps: float = 4.0) -> DetectionScores:
    """Greedily match one image's detections, in order of score, to unmatched corners within ``eps``."""
    detections = np.asarray(detections, np.float64).reshape(-1, 3)
    corners = np.asarray(corners, np.float64).reshape(-1, 2)
    order = np.argsort(-detections[:, 2], kind="stable")
    detections = detections[order]
    correct = np.zeros(len(detections), bool)
    distance = np.full(len(detections), np.nan)
    if len(corners):
        gaps = np.linalg.norm(detections[:, None, :2] - corners[None], axis=2)
        free = np.ones(len(corners), bool)
        for i, row in enumerate(gaps):
            candidates = np.where(free & (row <= eps))[0]
            if len(candidates):
                j = candidates[np.argmin(row[candidates])]
                free[j], correct[i], distance[i] = False, True, row[j]
    return DetectionScores(detections[:, 2], correct, distance, len(corners))


def merge(results: list[DetectionScores]) -> DetectionScores:
    """Pool per-image outcomes into one set."""
    return DetectionScores(
        np.concatenate([r.score for r in results] + [np.zeros(0)]),
        np.concatenate([r.correct for r in results] + [np.zeros(0, bool)]),
        np.concatenate([r.distance for r in results] + [np.zeros(0)]),
        sum(r.positives for r in results),
    )


def average_precision(result: DetectionScores) -> float:
    """Area under the precision-recall curve over the whole set, detections ranked by score and
    precision made monotone (non-increasing in recall) before integration. 0 if there are no corners."""
    if result.positives == 0:
        return 0.0
    order = np.argsort(-result.score, kind="stable")
    tp = np.cumsum(result.correct[order])
    precision = tp / np.arange(1, len(order) + 1)
    recall = tp / result.positives
    precision = np.maximum.accumulate(precision[::-1])[::-1]
    recall_steps = np.diff(np.concatenate([[0.0], recall]))
    return float(np.sum(precision * recall_steps))


def localization_error(result: DetectionScores) -> float:
    """Mean pixel distance of the correct detections to their corners (NaN if none)."""
    return float(np.nanmean(result.distance[result.correct])) if result.correct.any() else float("nan")


def repeated(
    points_1: np.ndarray, points_2: np.ndarray, H_12: np.ndarray, size: tuple[int, int], eps: float = 2.0
) -> tuple[float, np.ndarray]:
    """(repeatability, distances): the share of points, in both images, with a detection of the other
    image within ``eps`` pixels after warping by the known homography ``H_12`` (only points seen by both
    views count), and those repeated points' distances (K,) to their nearest detection, in pixels."""
    p1, p2 = np.asarray(points_1, np.float64)[:, :2], np.asarray(points_2, np.float64)[:, :2]
    p1_in_2, p2_in_1 = warp_points(p1, H_12), warp_points(p2, np.linalg.inv(H_12))
    p1_in_2 = p1_in_2[in_image(p1_in_2, size, margin=0.5)]
    p2 = p2[in_image(p2_in_1, size, margin=0.5)]
    if len(p1_in_2) == 0 or len(p2) == 0:
        return 0.0, np.zeros(0)
    gaps = np.linalg.norm(p1_in_2[:, None] - p2[None], axis=2)
    nearest = np.concatenate([gaps.min(1), gaps.min(0)])
    return float((nearest <= eps).sum() / len(nearest)), nearest[nearest <= eps]


def repeatability(
    points_1: np.ndarray, points_2: np.ndarray, H_12: np.ndarray, size: tuple[int, int], eps: float = 2.0
) -> float:
    """Share of points, in both images, with a detection of the other image within ``eps`` after
    warping by the known homography ``H_12``; only points seen by both views count."""
    return repeated(points_1, points_2, H_12, size, eps)[0]


def repeatability_at_n(
    pairs: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
    size: tuple[int, int],
    counts: tuple[int, ...] = (10, 20, 30, 50, 75, 100, 150, 200, 300),
    eps: float = 2.0,
) -> tuple[float, float, float]:
    """The paper's repeatability@N: mean repeatability over (points_1, points_2, H_12) pairs for the
    best ``n`` detections of each image, maximised over ``n``. Returns (repeatability, N, localisation
    error): N the mean detection count at the maximum, the error the mean distance (pixels) between
    repeated points there. Points must be sorted by descending score."""
    best = (0.0, 0.0, float("nan"))
    for n in counts:
        results = [repeated(p1[:n], p2[:n], H, size, eps) for p1, p2, H in pairs]
        mean_count = float(np.mean([(min(n, len(p1)) + min(n, len(p2))) / 2 for p1, p2, _ in pairs]))
        rep = float(np.mean([r for r, _ in results]))
        if rep > best[0]:
            distances = np.concatenate([d for _, d in results])
            best = (rep, mean_count, float(distances.mean()) if len(distances) else float("nan"))
    return best
