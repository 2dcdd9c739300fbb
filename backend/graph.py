"""A gtsam pose graph over camera poses, solved incrementally with ISAM2, in a sliding window.

One ``Pose3`` per frame (key = frame index), a prior on the first, a robust ``BetweenFactorPose3``
per relative-pose measurement (consecutive or between non-consecutive keyframes).
Noise sigmas are ordered as gtsam wants them: rotation (rad) first, then translation.

With a ``window`` (the default), a pose that no factor has used for that many frames is marginalised
out (gtsam's ``IncrementalFixedLagSmoother``): its estimate is kept as it was, its information stays in
the graph as a prior on what it was linked to, and time and memory per frame stay flat on long runs.
Keys passed to ``update(keep=...)`` (the keyframes still measured against) stay in the window.
``window=None`` keeps every pose in ISAM2 (and the whole graph, for ``batch_solve``).
"""

from __future__ import annotations

from typing import Iterable

import gtsam
import numpy as np

from deepslam.backend.config import GraphConfig
from deepslam.errors import InputError

RESTART_SIGMAS = np.array([1e-3] * 3 + [1e-2] * 3)  # rad, m: how firmly a restarted window holds its poses
# what gtsam's fixed-lag smoother says where its marginalisation fails on a sound graph (then the window restarts)
MARGINALISATION_FAILURES = ("Indeterminate linear system", "remove variables from the variable index that are not")


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
    """Incremental pose graph (gtsam's ISAM2): ``add_pose`` per frame, ``add_between`` per measurement,
    ``update``; old poses are marginalised after ``config.window`` frames.

    Args:
        first_pose: ``T_world_cam`` (4, 4) of frame 0, held by a tight prior.
        config: noise, robust loss and window (``GraphConfig``).

    Example:
        >>> import numpy as np
        >>> graph = PoseGraph(np.eye(4))
        >>> step = np.eye(4); step[0, 3] = 1.0  # 1 m along x
        >>> graph.add_pose(1, step); graph.add_between(0, 1, step, np.array([0.01] * 3 + [0.1] * 3))
        >>> graph.update(); np.round(graph.pose(1)[:3, 3], 3).tolist()
        [1.0, 0.0, 0.0]
    """

    def __init__(self, first_pose: np.ndarray, config: GraphConfig = GraphConfig()):
        if config.window is not None and config.window < 1:
            raise InputError(f"the graph's window must be at least 1 frame (or None), got {config.window}")
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(config.relinearize_threshold)
        params.relinearizeSkip = 1  # check every update (gtsam's default skips 10)
        self.config = config
        if config.window is None:
            self.solver = gtsam.ISAM2(params)
            self.graph: gtsam.NonlinearFactorGraph | None = gtsam.NonlinearFactorGraph()  # for batch re-solves
            self.initial: gtsam.Values | None = gtsam.Values()
        else:
            self.solver = gtsam.IncrementalFixedLagSmoother(float(config.window), params)
            self.graph = self.initial = None
        self._new_factors = gtsam.NonlinearFactorGraph()
        self._new_values = gtsam.Values()
        self._new_keys: list[int] = []
        self._estimates: dict[int, np.ndarray] = {}  # every pose's latest estimate, marginalised ones included
        self._add_factor(
            gtsam.PriorFactorPose3(
                0, gtsam.Pose3(first_pose), gtsam.noiseModel.Diagonal.Sigmas(np.array(config.prior_sigmas))
            )
        )
        self.add_pose(0, first_pose)
        self.update()

    @property
    def count(self) -> int:
        """Poses added so far."""
        return len(self._estimates)

    def _add_factor(self, factor) -> None:
        if self.graph is not None:
            self.graph.add(factor)
        self._new_factors.add(factor)

    def add_pose(self, key: int, guess: np.ndarray) -> None:
        """A new pose variable with an initial guess ``T_world_cam``."""
        if self.initial is not None:
            self.initial.insert(key, gtsam.Pose3(guess))
        self._new_values.insert(key, gtsam.Pose3(guess))
        self._new_keys.append(key)
        self._estimates[key] = np.asarray(guess, np.float64)

    def in_window(self, key: int) -> bool:
        """Whether ``key`` can still take factors (not marginalised out)."""
        return self.config.window is None or key in self._new_keys or self.solver.timestamps().get(key) is not None

    def add_between(self, key_1: int, key_2: int, T_1_2: np.ndarray, sigmas: np.ndarray) -> None:
        """A robust (Huber) between factor: pose 2 seen from pose 1 is ``T_1_2``. Both poses must be in the
        window (ValueError otherwise)."""
        for key in (key_1, key_2):
            if not self.in_window(key):
                raise InputError(f"pose {key} has left the graph's window; keep it with update(keep=...)")
        noise = gtsam.noiseModel.Robust.Create(
            gtsam.noiseModel.mEstimator.Huber.Create(self.config.huber_k),
            gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, np.float64)),
        )
        self._add_factor(gtsam.BetweenFactorPose3(key_1, key_2, gtsam.Pose3(T_1_2), noise))

    def update(self, keep: Iterable[int] = ()) -> None:
        """Fold the new factors and values in; with a window, the new poses and ``keep`` count as used now."""
        if self.config.window is None:
            self.solver.update(self._new_factors, self._new_values)
        else:
            now = float(max(self._estimates))
            timestamps = gtsam.FixedLagSmootherKeyTimestampMap()
            for key in {*self._new_keys, *keep}:
                timestamps.insert((key, now))
            window = dict(self.solver.timestamps())
            try:
                self.solver.update(self._new_factors, self._new_values, timestamps)
            except (RuntimeError, ValueError) as error:
                if not any(words in str(error) for words in MARGINALISATION_FAILURES):
                    raise
                self._restart(window, timestamps)
            estimate = self.solver.calculateEstimate()  # the window only: a few dozen poses
            for key in estimate.keys():
                self._estimates[key] = estimate.atPose3(key).matrix()
        self._new_factors, self._new_values, self._new_keys = gtsam.NonlinearFactorGraph(), gtsam.Values(), []

    def _restart(self, window: dict[int, float], timestamps: gtsam.FixedLagSmootherKeyTimestampMap) -> None:
        """A new fixed-lag smoother for one that failed to fold the new factors in: gtsam's marginalisation can
        raise ``IndeterminateSystemException`` on a graph that is not indeterminate, or fail to remove the variables
        it marginalises (``MARGINALISATION_FAILURES``). The poses of the ``window``
        (key -> time last used) start it at their latest estimates, each held by a prior of
        ``RESTART_SIGMAS``; then the new factors and values follow as they would have."""
        params = self.solver.params()
        self.solver = gtsam.IncrementalFixedLagSmoother(float(self.config.window), params)
        held, values, times = gtsam.NonlinearFactorGraph(), gtsam.Values(), gtsam.FixedLagSmootherKeyTimestampMap()
        for key, time in window.items():
            pose = gtsam.Pose3(self._estimates[key])
            held.add(gtsam.PriorFactorPose3(key, pose, gtsam.noiseModel.Diagonal.Sigmas(RESTART_SIGMAS)))
            values.insert(key, pose)
            times.insert((key, time))
        self.solver.update(held, values, times)
        self.solver.update(self._new_factors, self._new_values, timestamps)

    def refine(self, iterations: int = 3) -> None:
        """Extra ISAM2 iterations with no new factors (relinearises what moved beyond the threshold)."""
        for _ in range(iterations):
            self.update()

    def pose(self, key: int) -> np.ndarray:
        """The latest estimate (4, 4) of a pose (as it was when marginalised, for one out of the window)."""
        if self.config.window is None:
            return self.solver.calculateEstimatePose3(key).matrix()
        return self._estimates[key]

    def poses(self) -> np.ndarray:
        """Every pose's latest estimate (N, 4, 4), in key order."""
        if self.config.window is None:
            estimate = self.solver.calculateEstimate()
            return np.stack([estimate.atPose3(k).matrix() for k in sorted(self._estimates)])
        return np.stack([self._estimates[k] for k in sorted(self._estimates)])

    def __contains__(self, key: int) -> bool:
        """Whether the graph has a pose ``key`` (in the window or marginalised)."""
        return key in self._estimates

    def covariance(self, key: int) -> np.ndarray:
        """Marginal covariance (6, 6) of a pose in the window, rotation first, in the pose's tangent space."""
        return self.solver.marginalCovariance(key)

    def covariance_through(self, key: int, T: np.ndarray, sigmas: np.ndarray) -> np.ndarray:
        """The marginal covariance (6, 6) a pose would have, were it added seen from pose ``key`` as ``T`` (4, 4)
        with ``sigmas`` (6,) and no other factor: the key's carried through ``T`` plus the measurement's own
        (a robust factor weighs 1 at the zero residual such a pose has)."""
        adjoint = gtsam.Pose3(T).inverse().AdjointMap()
        return adjoint @ self.covariance(key) @ adjoint.T + np.diag(np.asarray(sigmas, np.float64) ** 2)

    def batch_solve(self) -> np.ndarray:
        """Levenberg-Marquardt on the whole graph from the initial guesses, for cross-checking ISAM2
        (``window=None`` only: a windowed graph no longer holds what it marginalised)."""
        if self.graph is None or self.initial is None:
            raise InputError("batch_solve needs the whole graph: make the PoseGraph with GraphConfig(window=None)")
        result = gtsam.LevenbergMarquardtOptimizer(self.graph, self.initial).optimize()
        return np.stack([result.atPose3(k).matrix() for k in range(self.count)])
