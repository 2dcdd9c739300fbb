"""MagicWarp training pairs: 3D point clouds on simple geometry seen by two virtual cameras.

Points are cast from camera A onto a scene of planes, spheres and boxes (the first hit along each
ray, so occlusion in A is right), and both cameras come from a random trajectory (piecewise-linear
translation, rotation about random axes). Pairs with less than ``min_overlap`` of A's points visible
in B are redrawn. Occlusion in camera B is not modelled.

A fifth kind, ``homography``, moves random image points by a random 2D homography (translation,
in-plane rotation, zoom and corner jitter at once): the motions of the breakdown evaluation. Its
points, and the spurious points of every kind, are drawn as a detector reports them, at most one per
8x8 cell (``sim.pointsets.detector_points``).

A ``clean_a_share`` of the pairs (of any kind) is drawn as the breakdown evaluation draws its pairs: image
A keeps every point, with no dropout and no spurious points; image B holds every point that stays in
view plus spurious ones (up to ``max_extra`` times A's point count).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from deepslam.errors import InputError
from deepslam.geometry import in_image, warp_points
from deepslam.sim.camera import intrinsics, invert, pose, project, transform
from deepslam.sim.homography import HomographyConfig, sample_homography
from deepslam.sim.pointsets import detector_points
from deepslam.sim.trajectories import random_walk

GEOMETRIES = ("plane", "sphere", "cube", "mixed", "homography")


@dataclass(frozen=True)
class PairConfig:
    """Ranges of a training pair. ``motion`` scales the camera motion (a curriculum knob, 1 = full)."""

    size: tuple[int, int] = (120, 160)
    points: tuple[int, int] = (5, 200)
    motion: float = 1.0
    max_step: float = 0.6  # translation between the two frames at motion 1, in units of scene depth
    max_rotation: float = 0.45  # radians between the two frames at motion 1, about a random axis ...
    max_roll: float = 0.6  # ... plus up to this much about the optical axis (in-plane rotation)
    min_overlap: float = 0.3
    match_dropout: float = 0.5  # fraction of matches broken by removing one side
    point_dropout: float = 0.25  # fraction of the remaining points removed in each image
    max_extra: float = 0.5  # up to this fraction of spurious points added to each image
    clean_a_share: float = 0.0  # share of pairs with a clean image A and spurious points in B only
    fov_deg: tuple[float, float] = (55.0, 85.0)
    geometry_weights: tuple[float, ...] = (0.4, 0.15, 0.15, 0.3, 0.0)  # in the order of GEOMETRIES
    homography: HomographyConfig = HomographyConfig(
        translation=0.3, rotation=np.pi / 4, scale=0.35, perspective=0.1
    )  # "homography" pairs at motion 1

    def __post_init__(self):
        weights = self.geometry_weights
        if len(weights) != len(GEOMETRIES) or min(weights) < 0 or sum(weights) <= 0:
            raise InputError(
                f"geometry_weights needs {len(GEOMETRIES)} non-negative weights, not all zero "
                f"({', '.join(GEOMETRIES)}), got {tuple(weights)}"
            )
        for name in ("max_extra", "clean_a_share"):
            if not 0 <= getattr(self, name) <= 1:
                raise InputError(f"{name} must lie in [0, 1], got {getattr(self, name)}")


@dataclass
class PointPair:
    """Two point images and the true correspondences that supervise the loss.

    points_a (Na, 2), points_b (Nb, 2): the inputs after dropout and spurious points;
    true_a (M, 2), true_b (M, 2): projections of the same 3D points in A and B (all co-visible ones).
    """

    points_a: np.ndarray
    points_b: np.ndarray
    true_a: np.ndarray
    true_b: np.ndarray


def _cast(rays: np.ndarray, rng: np.random.Generator, geometry: str, depth: float) -> np.ndarray:
    """Distances along unit rays (N, 3) from the origin to the first hit of a random scene (inf: miss)."""
    hits = np.full(len(rays), np.inf)

    def keep(t):
        np.minimum(hits, np.where((t > 1e-6) & np.isfinite(t), t, np.inf), out=hits)

    if geometry in ("plane", "mixed"):
        normal = np.array([0.0, 0.0, -1.0]) + rng.uniform(-0.8, 0.8, 3) * [1, 1, 0]
        normal /= np.linalg.norm(normal)
        point = np.array([0.0, 0.0, depth * (1.6 if geometry == "mixed" else 1.0)])
        with np.errstate(divide="ignore", invalid="ignore"):
            keep((point @ normal) / (rays @ normal))
    objects = {"sphere": ["sphere"], "cube": ["cube"], "mixed": list(rng.choice(["sphere", "cube"], 2))}.get(
        geometry, []
    )
    for kind in objects:
        centre = np.array([*rng.uniform(-0.3, 0.3, 2) * depth, depth * rng.uniform(0.8, 1.2)])
        radius = depth * rng.uniform(0.2, 0.45)
        if kind == "sphere":
            b = rays @ centre
            disc = b**2 - (centre @ centre - radius**2)
            with np.errstate(invalid="ignore"):
                keep(np.where(disc >= 0, b - np.sqrt(disc), np.inf))
        else:
            axis = rng.normal(size=3)
            R = pose(axis / np.linalg.norm(axis) * rng.uniform(0, np.pi), np.zeros(3))[:3, :3]
            local_dirs, local_origin = rays @ R, -centre @ R
            with np.errstate(divide="ignore", invalid="ignore"):
                t1 = (-radius - local_origin) / local_dirs
                t2 = (radius - local_origin) / local_dirs
            near = np.nanmax(np.minimum(t1, t2), axis=1)
            far = np.nanmin(np.maximum(t1, t2), axis=1)
            keep(np.where(near <= far, near, np.inf))
    return hits


def sample_pair(rng: np.random.Generator, config: PairConfig = PairConfig(), geometry: str | None = None) -> PointPair:
    """One training pair (see module docstring); ``geometry`` in ``GEOMETRIES`` or random."""
    weights = np.asarray(config.geometry_weights, np.float64)
    for _ in range(100):
        kind = geometry or str(rng.choice(GEOMETRIES, p=weights / weights.sum()))
        count = int(np.exp(rng.uniform(np.log(config.points[0]), np.log(config.points[1] + 1))))
        drawn = _homography_pair(rng, config, count) if kind == "homography" else _camera_pair(rng, config, kind, count)
        if drawn is None:
            continue
        uv_a, uv_b, visible = drawn
        if visible.mean() >= config.min_overlap and visible.sum() >= 4:
            strength = 1.0 if kind != "homography" else rng.uniform()
            if config.clean_a_share and rng.random() < config.clean_a_share:
                return PointPair(uv_a, _spurious(rng, config, uv_b[visible], len(uv_a)), uv_a[visible], uv_b[visible])
            return _with_dropout(rng, config, uv_a, uv_b, visible, strength)
    raise RuntimeError("could not draw a point pair with enough overlap; check PairConfig")


def _camera_pair(rng: np.random.Generator, config: PairConfig, kind: str, count: int):
    """Projections (N, 2) of a point cloud into cameras A and B, and which are visible in B."""
    size = config.size
    h, w = size
    K = intrinsics(size, rng.uniform(*config.fov_deg))
    pixels = rng.uniform([-0.5, -0.5], [w - 0.5, h - 0.5], (count * 2, 2))
    rays = np.c_[pixels, np.ones(len(pixels))] @ np.linalg.inv(K).T
    rays /= np.linalg.norm(rays, axis=1, keepdims=True)
    depth = rng.uniform(2.0, 6.0)
    distance = _cast(rays, rng, kind, depth)
    hit = np.isfinite(distance)
    if hit.sum() < max(config.points[0], 4):
        return None
    cloud = (rays * distance[:, None])[hit][:count]
    gap = int(rng.integers(1, 6))
    walk = random_walk(
        rng,
        gap + 1,
        config.motion * config.max_step * depth * rng.uniform(0, 1) / gap,
        config.motion * config.max_rotation * rng.uniform(0, 1) / gap,
        segment_frames=2,
    )
    roll = pose(np.array([0.0, 0.0, config.motion * config.max_roll * rng.uniform(-1, 1)]), np.zeros(3))
    uv_a, _ = project(cloud, K)
    uv_b, z_b = project(transform(invert(walk[-1] @ roll), cloud), K)
    return uv_a, uv_b, (z_b > 0.1) & in_image(np.nan_to_num(uv_b, nan=-1e9), size)


def _homography_pair(rng: np.random.Generator, config: PairConfig, count: int):
    """Random points of image A (N, 2), moved by a random homography into B, and which stay in B."""
    ranges = config.homography
    amount = config.motion * rng.uniform()
    H = sample_homography(
        rng,
        config.size,
        HomographyConfig(
            ranges.translation * amount, ranges.rotation * amount, ranges.scale * amount, ranges.perspective * amount
        ),
    )
    uv_a = detector_points(rng, count, config.size)
    uv_b = warp_points(uv_a, H)
    return uv_a, uv_b, in_image(uv_b, config.size)


def _with_dropout(
    rng: np.random.Generator,
    config: PairConfig,
    uv_a: np.ndarray,
    uv_b: np.ndarray,
    visible: np.ndarray,
    strength: float = 1.0,
) -> PointPair:
    """Apply match dropout, point dropout (``strength`` times the configured fractions) and spurious
    points; keep all true matches for the loss."""
    keep_a = np.ones(len(uv_a), bool)
    keep_b = visible.copy()
    broken = visible & (rng.random(len(uv_a)) < strength * config.match_dropout)
    side = rng.random(len(uv_a)) < 0.5
    keep_a &= ~(broken & side)
    keep_b &= ~(broken & ~side)
    keep_a &= rng.random(len(uv_a)) >= strength * config.point_dropout
    keep_b &= rng.random(len(uv_a)) >= strength * config.point_dropout
    kept_a, kept_b = uv_a[keep_a], uv_b[keep_b]
    return PointPair(
        _spurious(rng, config, kept_a, len(kept_a)),
        _spurious(rng, config, kept_b, len(kept_b)),
        uv_a[visible],
        uv_b[visible],
    )


def _spurious(rng: np.random.Generator, config: PairConfig, points: np.ndarray, count: int) -> np.ndarray:
    """``points`` (N, 2) with a random share, up to ``config.max_extra``, of ``count`` spurious points
    added, in random order."""
    extra = detector_points(rng, int(count * rng.uniform(0, config.max_extra)), config.size)
    merged = np.vstack([points, extra])
    return merged[rng.permutation(len(merged))]
