"""The best any back-end could do with a run's own tracks (evaluation only: it needs the true poses).

One batch bundle adjustment of every frame and every track observation of a run, started at the truth: each
camera at its true pose, each track's point triangulated from all its observations with the true poses. An
observation farther than ``max_reprojection_px`` from that point's projection is dropped (a track that jumped
to another point: a back-end that knew which ones did); tracks seen from less than ``min_triangulation_px``
apart are left out (their depth is unknown). A frame with fewer than ``min_observations`` observations left is
not adjusted (so few leave it loose, and Levenberg-Marquardt would move it metres): as a lost frame, it moves on
from the frame before by the step before that. The
first camera is held at its true pose and its distance to the first adjusted camera that sees the points
``min_initial_px`` apart keeps its true length: the gauge and the scale, as a map's first baseline takes its true
length with ``--scale map``. The drift of the adjusted poses is what the
tracks themselves allow; a pipeline's ATE over it says how much its back-end adds.

The batch adjustment places each frame with the frames after it too, which an online back-end has not seen when it
reports the frame. ``causal_adjust`` places each frame by the adjustment of the frames up to it: the causal limit,
between the two.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from deepslam.backend import drift
from deepslam.backend.evaluation.consistency import TrackObservations, triangulate
from deepslam.backend.mapping import calibration, pixel_noise, project
from deepslam.errors import InputError
from deepslam.geometry import constant_motion, vector_angle

GAUGE_SIGMA = 1e-4  # rad and m, and a share of the first baseline: tighter, and Levenberg-Marquardt stalls


@dataclass(frozen=True)
class LimitConfig:
    """The batch adjustment's settings (those of the local map's where both have one)."""

    max_reprojection_px: float = 3.0  # an observation this far from its track's true-pose point is dropped
    min_triangulation_px: float = 6.0  # tracks whose rays span less (radians x focal length) are left out
    min_initial_px: float = 10.0  # the first baseline, whose true length is kept, spans this much at the points
    huber_px: float = 1.345  # the robust loss (px, sigma 1 px)
    iterations: int = 100  # Levenberg-Marquardt's most iterations
    # a frame with fewer observations is not adjusted: they do not determine its pose (the map's PnP needs as many,
    # MapConfig.min_located), and Levenberg-Marquardt would move it anywhere; it moves on by the step before
    min_observations: int = 12


@dataclass
class Limit:
    """The adjusted poses (N, 4, 4) ``T_world_cam``, how many observations and tracks went in, and the ATE SE3
    (m) of those poses against the truth."""

    poses: np.ndarray
    observations: int
    tracks: int
    ate_se3: float


def batch_adjust(
    observations: TrackObservations, config: LimitConfig = LimitConfig(), baseline: int | None = None
) -> Limit:
    """The batch bundle adjustment of every observation in ``observations`` (each frame with its true pose),
    started at the truth. ``baseline``: the frame whose distance from frame 0 keeps its true length (the scale), if
    the adjustment places it; by default the first that spans ``min_initial_px`` (one baseline sets the scale of
    the whole adjustment to a few percent: docs/experiments.md)."""
    truth, focal = np.stack(observations.poses), float(observations.K[0][0, 0])
    if baseline is not None and not 0 < baseline < len(truth):
        raise InputError(f"the baseline must be one of frames 1 to {len(truth) - 1}, got {baseline}")
    projections = np.stack([observations.projection(frame) for frame in range(len(truth))])
    landmarks = _landmarks(observations, truth, projections, focal, config)
    placed = _placed_frames(landmarks, len(truth), config.min_observations)
    landmarks = [
        (track, frames[placed[frames]], pixels[placed[frames]], point) for track, frames, pixels, point in landmarks
    ]
    landmarks = [landmark for landmark in landmarks if len(landmark[1]) >= 2]
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    for index in np.flatnonzero(placed):
        values.insert(gtsam.symbol("x", index), gtsam.Pose3(truth[index]))
    points = np.array([point for *_, point in landmarks]).reshape(-1, 3)
    if baseline is None or not placed[baseline]:
        baseline = _first_baseline(truth, points, focal, config.min_initial_px, placed)
    _hold_gauge(graph, truth, baseline)
    noise, calibrations = pixel_noise(config.huber_px), [calibration(K) for K in observations.K]
    for track, frames, pixels, point in landmarks:
        values.insert(gtsam.symbol("l", track), gtsam.Point3(point))
        for frame, pixel in zip(frames, pixels, strict=True):
            graph.add(
                gtsam.GenericProjectionFactorCal3_S2(
                    pixel, noise, gtsam.symbol("x", frame), gtsam.symbol("l", track), calibrations[frame]
                )
            )
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(config.iterations)
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
    poses = truth.copy()  # the first frame, and the second where it is not adjusted (no step before it is known)
    for index in range(1, len(truth)):
        if placed[index]:
            poses[index] = result.atPose3(gtsam.symbol("x", index)).matrix()
        elif index > 1:  # moves on by the step before, as a lost frame does
            poses[index] = constant_motion(poses[index - 2], poses[index - 1])
    used = sum(len(frames) for _, frames, _, _ in landmarks)
    return Limit(poses, used, len(landmarks), drift.ate_rmse(poses, truth))


def _landmarks(
    observations: TrackObservations, truth: np.ndarray, projections: np.ndarray, focal: float, config: LimitConfig
) -> list[tuple[int, np.ndarray, np.ndarray, np.ndarray]]:
    """Each track that makes a landmark (``_initial_point``): its id, the frames (M,) and pixels (M, 2) of the
    observations it keeps, and its point (3,)."""
    landmarks = []
    for track, frames, pixels in observations.tracks():
        point, kept = _initial_point(pixels, projections[frames], truth[frames, :3, 3], focal, config)
        if point is not None:
            landmarks.append((track, frames[kept], pixels[kept], point))
    return landmarks


def _placed_frames(landmarks: list[tuple], frames: int, min_observations: int) -> np.ndarray:
    """Which of the ``frames`` the adjustment places (frames,) bool: those with ``min_observations`` observations of
    the ``landmarks``, and the first frame, which holds the gauge."""
    counts = np.zeros(frames, int)
    for _, seen, _, _ in landmarks:
        np.add.at(counts, seen, 1)
    placed = counts >= min_observations
    placed[0] = True
    return placed


def causal_adjust(observations: TrackObservations, config: LimitConfig = LimitConfig()) -> np.ndarray:
    """Each frame's pose (N, 4, 4) ``T_world_cam`` where ``batch_adjust`` of the frames up to it, and of them
    alone, places it (the first frame at its true pose): the best an online back-end, which reports a frame
    before it sees the next, could report with the run's tracks. N adjustments of 1 to N frames."""
    later = [batch_adjust(observations.head(end), config).poses[-1] for end in range(2, len(observations.poses) + 1)]
    return np.stack(observations.poses[:1] + later)


def over_limit(ate_se3: float, limit_ate_se3: float) -> float:
    """A run's ATE SE3 over its limit's; NaN where the limit is 0 or unknown (as where the camera only turns: its
    tracks make no landmark, and every frame keeps the first frame's true position)."""
    return ate_se3 / limit_ate_se3 if limit_ate_se3 > 0 else float("nan")


def _first_baseline(
    truth: np.ndarray, points: np.ndarray, focal: float, min_px: float, placed: np.ndarray
) -> int | None:
    """The first of the ``placed`` frames ((N,) bool) whose true distance from frame 0 spans ``min_px`` (radians x
    ``focal``) at the median depth of the ``points`` (M, 3) in frame 0, as a map's first baseline must; the
    farthest of them from frame 0 where none does; None where none moved."""
    distances = np.linalg.norm(truth[:, :3, 3] - truth[0, :3, 3], axis=1) * placed
    if not distances.max() > 0:
        return None
    depth = np.median(project(truth[0], np.eye(3), points)[1]) if len(points) else 1.0
    wide = np.flatnonzero(distances / max(depth, 1e-9) * focal >= min_px)
    return int(wide[0]) if len(wide) else int(np.argmax(distances))


def _hold_gauge(graph: gtsam.NonlinearFactorGraph, truth: np.ndarray, baseline: int | None) -> None:
    """Hold the first camera at its true pose and its distance to frame ``baseline`` at its true length."""
    first = gtsam.symbol("x", 0)
    graph.add(gtsam.PriorFactorPose3(first, gtsam.Pose3(truth[0]), gtsam.noiseModel.Isotropic.Sigma(6, GAUGE_SIGMA)))
    if baseline is not None:
        distance = float(np.linalg.norm(truth[baseline, :3, 3] - truth[0, :3, 3]))
        noise = gtsam.noiseModel.Isotropic.Sigma(1, GAUGE_SIGMA * distance)
        graph.add(gtsam.RangeFactorPose3(first, gtsam.symbol("x", baseline), distance, noise))


def _initial_point(
    pixels: np.ndarray, projections: np.ndarray, centres: np.ndarray, focal: float, config: LimitConfig
) -> tuple[np.ndarray | None, np.ndarray]:
    """A track's point (3,) triangulated from its observations (pixels (M, 2)) with their frames' true
    projections (M, 3, 4) and camera centres (M, 3), and which observations it keeps (M,) bool: the farthest
    from the point's projection is dropped, and the point triangulated again, until all lie in front of their
    camera within ``max_reprojection_px``. None where fewer than two are left or where their rays span less
    than ``min_triangulation_px`` (an angle in pixels of the ``focal`` length)."""
    kept = np.ones(len(pixels), bool)
    while kept.sum() >= 2:
        point = triangulate(pixels[kept], projections[kept])
        if point is None:
            break
        projected = projections @ np.r_[point, 1.0]
        with np.errstate(divide="ignore", invalid="ignore"):
            distances = np.linalg.norm(projected[:, :2] / projected[:, 2:] - pixels, axis=1)
        distances = np.where(kept & (projected[:, 2] > 0) & np.isfinite(distances), distances, np.inf)
        distances[~kept] = -1.0
        worst = int(np.argmax(distances))
        if distances[worst] <= config.max_reprojection_px:
            rays = point - centres[kept]
            wide = vector_angle(rays[:1], rays).max() * focal >= config.min_triangulation_px
            return (point, kept) if wide else (None, kept)
        kept[worst] = False
    return None, kept
