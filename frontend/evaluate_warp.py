"""MagicWarp evaluation: match repeatability and the paper's 90% breakdown-point table."""
from __future__ import annotations

import numpy as np
import torch

from frontend.magicwarp import MagicWarp, MagicWarpNet, warp_points
from sim.pointsets import PointSetPair, make_pair, motion_homography, random_direction

SIZE = (120, 160)


def match_repeatability(H: np.ndarray, pair: PointSetPair) -> float:
    """Percentage of A points (with a partner in B) whose nearest B point after warping by ``H`` is
    their true partner (the paper's MatchRep)."""
    has_partner = pair.true_index >= 0
    if not has_partner.any():
        return 100.0
    if len(pair.points_b) == 0:
        return 0.0
    moved = warp_points(pair.points_a[has_partner], H)
    nearest = np.argmin(np.linalg.norm(moved[:, None] - pair.points_b[None], axis=2), axis=1)
    return 100.0 * float(np.mean(nearest == pair.true_index[has_partner]))


def validation_set(seed: int, runs: int = 64, magnitudes: tuple[float, ...] = (10.0, 20.0, 30.0)) -> list[tuple[float, PointSetPair]]:
    """Random-homography pairs at medium density with 20% extra points, for training validation."""
    rng = np.random.default_rng(seed)
    return [(m, make_pair(rng, motion_homography("random_h", m, SIZE, random_direction(rng)),
                          int(rng.integers(25, 51)), 0.2, SIZE)) for m in magnitudes for _ in range(runs)]


def validation_figures(net: MagicWarpNet, validation: list[tuple[float, PointSetPair]]) -> dict[str, float]:
    """Mean match repeatability per magnitude ("rep@20px", ...) and their mean as "score"."""
    warp = MagicWarp(net)
    H = warp.estimate_batch([(p.points_a, p.points_b) for _, p in validation], SIZE)
    reps: dict[float, list[float]] = {}
    for (magnitude, pair), h in zip(validation, H):
        reps.setdefault(magnitude, []).append(match_repeatability(h, pair))
    figures = {f"rep@{m:g}px": float(np.mean(r)) for m, r in reps.items()}
    figures["score"] = float(np.mean(list(figures.values())))
    return figures
