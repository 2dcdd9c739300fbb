"""A gtsam pose graph over camera poses, solved incrementally with ISAM2.

One ``Pose3`` per frame (key = frame index), a prior on the first, a robust ``BetweenFactorPose3``
per relative-pose measurement (consecutive or between non-consecutive keyframes).
Noise sigmas are ordered as gtsam wants them: rotation (rad) first, then translation.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np


@dataclass(frozen=True)
class GraphConfig:
    prior_sigmas: tuple[float, ...] = (1e-4,) * 6
    huber_k: float = 1.345
    relinearize_threshold: float = 0.001


def measurement_sigmas(
    inliers: int,
    inlier_ratio: float,
    step_length: float,
    parallax_px: float = np.inf,
    base_rotation: float = 0.01,
    base_translation: float = 0.05,
) -> np.ndarray:
    """Sigmas [rx, ry, rz, tx, ty, tz] for a relative pose estimated from ``inliers`` matches.

    Uncertainty shrinks with the square root of the inlier count and grows as the inlier ratio
    drops; translation sigma is relative to the step length (monocular: scale error dominates) and
    grows when the median parallax is below 5 px (the direction of a short baseline is poorly known).
    """
    quality = min(np.sqrt(max(inliers, 1) / 50.0) * max(inlier_ratio, 0.05), 4.0)
    rotation = base_rotation / quality
    translation = base_translation * max(step_length, 0.02) / quality * max(1.0, 5.0 / max(parallax_px, 0.5))
    return np.array([rotation] * 3 + [translation] * 3)


class PoseGraph:
    """Incremental pose graph: ``add_pose`` per frame, ``add_between`` per measurement, ``update``."""

    def __init__(self, first_pose: np.ndarray, config: GraphConfig = GraphConfig()):
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(config.relinearize_threshold)
        params.relinearizeSkip = 1  # check every update (gtsam's default skips 10)
        self.isam = gtsam.ISAM2(params)
        self.config = config
        self.graph = gtsam.NonlinearFactorGraph()  # every factor, for batch re-solves
        self.initial = gtsam.Values()  # every initial guess
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._add_factor(
            gtsam.PriorFactorPose3(
                0, gtsam.Pose3(first_pose), gtsam.noiseModel.Diagonal.Sigmas(np.array(config.prior_sigmas))
            )
        )
        self._insert(0, first_pose)
        self.count = 1
        self.update()

    def _add_factor(self, factor) -> None:
        self.graph.add(factor)
        self._new_factors.add(factor)

    def _insert(self, key: int, T: np.ndarray) -> None:
        self.initial.insert(key, gtsam.Pose3(T))
        self._new_values.insert(key, gtsam.Pose3(T))

    def add_pose(self, key: int, guess: np.ndarray) -> None:
        """A new pose variable with an initial guess ``T_world_cam``."""
        self._insert(key, guess)
        self.count += 1

    def add_between(self, key_1: int, key_2: int, T_1_2: np.ndarray, sigmas: np.ndarray) -> None:
        """A robust (Huber) between factor: pose 2 seen from pose 1 is ``T_1_2``."""
        noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(self.config.huber_k),
            gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, np.float64)),
        )
        self._add_factor(gtsam.BetweenFactorPose3(key_1, key_2, gtsam.Pose3(T_1_2), noise))

    def update(self) -> None:
        """Fold the new factors and values into ISAM2."""
        self.isam.update(self._new_factors, self._new_values)
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()

    def refine(self, iterations: int = 3) -> None:
        """Extra ISAM2 iterations with no new factors (relinearises what moved beyond the threshold)."""
        for _ in range(iterations):
            self.isam.update()

    def pose(self, key: int) -> np.ndarray:
        return self.isam.calculateEstimatePose3(key).matrix()

    def poses(self) -> np.ndarray:
        estimate = self.isam.calculateEstimate()
        return np.stack([estimate.atPose3(k).matrix() for k in range(self.count)])

    def covariance(self, key: int) -> np.ndarray:
        """Marginal covariance (6, 6) of a pose, rotation first, in the pose's tangent space."""
        return self.isam.marginalCovariance(key)

    def batch_solve(self) -> np.ndarray:
        """Levenberg-Marquardt on the whole graph from the initial guesses, for cross-checking ISAM2."""
        result = gtsam.LevenbergMarquardtOptimizer(self.graph, self.initial).optimize()
        return np.stack([result.atPose3(k).matrix() for k in range(self.count)])
