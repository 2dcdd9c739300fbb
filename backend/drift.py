"""Trajectory drift metrics: ATE after SE(3)/Sim(3) Umeyama alignment, RPE, final drift.

Trajectories are (N, 4, 4) ``T_world_cam`` arrays with the same timestamps (associated frames).
"""

from __future__ import annotations

import numpy as np

from deepslam.errors import InputError
from deepslam.geometry import path_length, rotation_angle


def _check(estimate: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``estimate`` and ``truth`` as float64 arrays, or ``InputError`` unless they are finite (N, 4, 4) of the same
    N."""
    try:
        estimate, truth = np.asarray(estimate, np.float64), np.asarray(truth, np.float64)
    except (TypeError, ValueError):
        raise InputError("trajectories must be (N, 4, 4) arrays of numbers") from None
    if estimate.shape != truth.shape or estimate.ndim != 3 or estimate.shape[1:] != (4, 4):
        raise InputError(f"trajectories must both be (N, 4, 4), got {estimate.shape} and {truth.shape}")
    unknown = ~(np.isfinite(estimate).all(axis=(1, 2)) & np.isfinite(truth).all(axis=(1, 2)))
    if unknown.any():
        raise InputError(
            f"{int(unknown.sum())} of {len(unknown)} poses are not finite: leave out the frames without a pose or truth"
        )
    return estimate, truth


def umeyama(source: np.ndarray, target: np.ndarray, with_scale: bool) -> tuple[np.ndarray, np.ndarray, float]:
    """Least-squares (R, t, s) with target ~ s R source + t, for (N, 3) point sets (Umeyama 1991)."""
    mu_s, mu_t = source.mean(0), target.mean(0)
    xs, xt = source - mu_s, target - mu_t
    U, D, Vt = np.linalg.svd(xt.T @ xs / len(source))
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1
    R = U @ S @ Vt
    variance = (xs**2).sum() / len(source)
    s = float(np.trace(np.diag(D) @ S) / variance) if with_scale and variance > 0 else 1.0
    return R, mu_t - s * R @ mu_s, s


def align(estimate: np.ndarray, truth: np.ndarray, with_scale: bool) -> np.ndarray:
    """The estimate's poses moved (and scaled with Sim(3)) onto the ground truth by their positions."""
    return _aligned(*_check(estimate, truth), with_scale)


def _aligned(estimate: np.ndarray, truth: np.ndarray, with_scale: bool) -> np.ndarray:
    """``align`` of trajectories ``_check`` passed."""
    R, t, s = umeyama(estimate[:, :3, 3], truth[:, :3, 3], with_scale)
    aligned = estimate.copy()
    aligned[:, :3, :3] = R @ estimate[:, :3, :3]
    aligned[:, :3, 3] = s * estimate[:, :3, 3] @ R.T + t
    return aligned


def ate_rmse(estimate: np.ndarray, truth: np.ndarray, with_scale: bool = False) -> float:
    """Absolute trajectory error: RMSE of positions after SE(3) (or Sim(3)) alignment.

    Args:
        estimate, truth: (N, 4, 4) ``T_world_cam`` of the same frames.
        with_scale: align with a similarity (Sim(3)), for trajectories up to scale.

    Returns:
        The RMSE in the units of ``truth`` (m).

    Example:
        >>> import numpy as np
        >>> truth = np.stack([np.eye(4)] * 3); truth[:, 0, 3] = [0.0, 1.0, 2.0]
        >>> estimate = truth.copy(); estimate[:, :3, 3] *= 2  # twice as long
        >>> round(ate_rmse(estimate, truth), 3), round(ate_rmse(estimate, truth, with_scale=True), 3)
        (0.816, 0.0)
    """
    estimate, truth = _check(estimate, truth)
    aligned = _aligned(estimate, truth, with_scale)
    return float(np.sqrt(np.mean(np.sum((aligned[:, :3, 3] - truth[:, :3, 3]) ** 2, 1))))


def rpe(estimate: np.ndarray, truth: np.ndarray, delta: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Relative pose errors over frame pairs ``delta`` apart: (translation errors (M,), rotation
    errors (M,) in degrees), from E = (T_gt_i^-1 T_gt_j)^-1 (T_est_i^-1 T_est_j); none where ``delta`` is the number
    of poses or more."""
    estimate, truth = _check(estimate, truth)
    if delta < 1:
        raise InputError(f"the RPE's delta must be at least 1 frame, got {delta}")
    if len(estimate) <= delta:
        return np.zeros(0), np.zeros(0)
    rel_est = np.linalg.inv(estimate[:-delta]) @ estimate[delta:]
    rel_gt = np.linalg.inv(truth[:-delta]) @ truth[delta:]
    error = np.linalg.inv(rel_gt) @ rel_est
    return np.linalg.norm(error[:, :3, 3], axis=1), np.degrees(rotation_angle(error[:, :3, :3]))


def scale_drift(estimate: np.ndarray, truth: np.ndarray) -> float:
    """How the estimate's scale moved over the run: its path length over the true one in the last quarter of the
    frames, divided by the same in the first quarter (lengths between every quarter / 4-th frame); 1: no scale
    drift; NaN for fewer than 8 frames or a quarter where the camera stood still. ``estimate``, ``truth``:
    (N, 4, 4) ``T_world_cam`` of the same frames."""
    estimate, truth = _check(estimate, truth)
    quarter = len(truth) // 4
    if quarter < 2:
        return float("nan")
    stride = max(1, quarter // 4)  # lengths over a few frames at a time: frame-to-frame jitter does not add up
    ratios = []
    for part in (slice(0, quarter + 1, stride), slice(len(truth) - quarter - 1, None, stride)):
        true_length = path_length(truth[part])
        ratios.append(path_length(estimate[part]) / true_length if true_length > 0 else np.nan)
    return float(ratios[1] / ratios[0]) if ratios[0] > 0 else float("nan")


def summary(estimate: np.ndarray, truth: np.ndarray, delta: int = 1) -> dict[str, float]:
    """All drift figures of an estimated trajectory against the truth.

    Args:
        estimate, truth: (N, 4, 4) ``T_world_cam`` of the same frames, N >= 2.
        delta: frames apart of the relative pose errors.

    Returns:
        {"ate_se3", "ate_sim3": ATE RMSE (m) after SE(3) and Sim(3) alignment; "rpe_trans", "rpe_rot_deg": RPE
        means (m, degrees); "final_drift_pct": the final position error as % of the true path length (no
        alignment: both start together); "scale_drift" (``scale_drift``); "path_length" (m); "frames"}.
    """
    estimate, truth = _check(estimate, truth)
    if len(estimate) < 2:
        raise InputError("drift needs at least 2 poses")
    if not 1 <= delta < len(estimate):
        raise InputError(f"the RPE's delta must lie in [1, {len(estimate) - 1}] for {len(estimate)} poses, got {delta}")
    rpe_t, rpe_r = rpe(estimate, truth, delta)
    length = path_length(truth)
    final = np.linalg.norm(estimate[-1, :3, 3] - truth[-1, :3, 3])
    return {
        "ate_se3": ate_rmse(estimate, truth, False),
        "ate_sim3": ate_rmse(estimate, truth, True),
        "rpe_trans": float(rpe_t.mean()),
        "rpe_rot_deg": float(rpe_r.mean()),
        "final_drift_pct": float(100 * final / length) if length > 0 else float("nan"),
        "scale_drift": scale_drift(estimate, truth),
        "path_length": length,
        "frames": int(len(truth)),
    }
