"""Monocular visual odometry: front-end tracks -> relative poses -> scale -> ISAM2 pose graph.

Frames come from any source (a simulator or a replayed log) as ``InputFrame``s; the odometry needs no
simulator. Monocular translation has no scale: ``scale="gt"`` takes each step's length from ground
truth (the usual convention of monocular VO evaluation); ``scale="plane"`` keeps metric scale without
ground truth from a known initial distance to the dominant plane (like a known camera height), which
homography decompositions (t / d) carry from frame to frame.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field

import cv2
import numpy as np

from backend import relpose
from backend.graph import PoseGraph, measurement_sigmas
from frontend.tracking import Tracker, Tracks, Truth

SCALES = ("gt", "plane")


@dataclass
class InputFrame:
    """image uint8 (H, W); K (3, 3); stamp_ns int; T_world_cam (4, 4) ground truth or None;
    truth: landmark projections for the oracle front-end, or None."""

    image: np.ndarray
    K: np.ndarray
    stamp_ns: int
    T_world_cam: np.ndarray | None = None
    truth: Truth | None = None


@dataclass
class OdometryConfig:
    method: str = "auto"               # relative pose: auto | homography | essential | pycolmap
    scale: str = "gt"                  # gt | plane
    plane_distance: float | None = None  # for scale="plane": distance of the first camera to the plane
    keyframe_gap: int = 5              # extra factor (and, for "auto", the model choice) with the frame this many back ...
    min_shared_tracks: int = 30        # ... when they share at least this many tracks
    covariance: bool = True            # compute the latest pose's marginal covariance every frame

    def __post_init__(self):
        if self.method not in relpose.METHODS:
            raise ValueError(f"unknown method {self.method!r}; expected one of {', '.join(relpose.METHODS)}")
        if self.scale not in SCALES:
            raise ValueError(f"unknown scale {self.scale!r}; expected one of {', '.join(SCALES)}")


@dataclass
class FrameResult:
    """What the odometry made of one frame: tracks, the relative pose to the previous frame (None for
    the first), the current estimate ``T_world_cam`` (4, 4), its covariance (6, 6) or None,
    the correspondences (K, 2) as indices into the previous and current tracks, the scaled
    measurement ``T_prev_cur`` (4, 4) that went into the graph, and stage timings."""

    index: int
    tracks: Tracks
    relative: relpose.RelativePose | None
    T_world_cam: np.ndarray
    covariance: np.ndarray | None
    correspondences: np.ndarray
    T_prev_cur: np.ndarray | None = None
    timings_ms: dict[str, float] = field(default_factory=dict)


def shared_tracks(a: Tracks, b: Tracks) -> np.ndarray:
    """Index pairs (K, 2) of points of ``a`` and ``b`` with the same track id."""
    common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    return np.stack([ia, ib], 1).astype(np.int64)


class Odometry:
    """Feed frames in order with ``process``; ``poses`` holds the optimised trajectory so far."""

    def __init__(self, tracker: Tracker, config: OdometryConfig = OdometryConfig()):
        if config.scale == "plane" and not config.plane_distance:
            raise ValueError("scale 'plane' needs the first camera's distance to the dominant plane")
        self.tracker, self.config = tracker, config
        cv2.setRNGSeed(0)  # OpenCV's RANSAC draws from a global generator: same input, same output
        self.graph: PoseGraph | None = None
        self.history: list[tuple[InputFrame, Tracks]] = []
        self.plane_distance = config.plane_distance
        self.last_translation: np.ndarray | None = None
        self.model = config.method  # "auto" until a wide-baseline pair has chosen H or E

    def _step_length(self, i: int, j: int, rel: relpose.RelativePose) -> float:
        """Metric length of the translation between frames i and j."""
        if self.config.scale == "gt":
            a, b = self.history[i][0].T_world_cam, self.history[j][0].T_world_cam
            if a is None or b is None:
                raise ValueError("scale 'gt' needs ground-truth poses in every frame")
            return float(np.linalg.norm(b[:3, 3] - a[:3, 3]))
        return float(rel.t_over_d or 0.0) * self.plane_distance

    def _measure(self, i: int, j: int) -> tuple[relpose.RelativePose, np.ndarray, np.ndarray]:
        """Relative pose between stored frames i < j, scaled; returns (pose, T_i_j, correspondences)."""
        (frame_i, tracks_i), (frame_j, tracks_j) = self.history[i], self.history[j]
        pairs = shared_tracks(tracks_i, tracks_j)
        p1, p2 = tracks_i.points[pairs[:, 0]], tracks_j.points[pairs[:, 1]]
        rel = relpose.estimate(p1, p2, frame_j.K, self.model, frame_j.image.shape, self.last_translation)
        if rel.ok and self.config.scale == "plane" and rel.model == "essential":
            plane = relpose.homography_pose(p1, p2, frame_j.K)  # magnitude from the dominant plane
            rel.t_over_d, rel.plane_normal = plane.t_over_d, plane.plane_normal
        T = rel.T_c1_c2.copy()
        if rel.ok and not rel.rotation_only and rel.model != "static":
            norm = np.linalg.norm(T[:3, 3])
            T[:3, 3] *= self._step_length(i, j, rel) / max(norm, 1e-12)
        return rel, T, pairs

    def _update_plane_distance(self, rel: relpose.RelativePose, T: np.ndarray) -> None:
        """Carry the camera's distance to the dominant plane into the new frame: d2 = d1 - n . c2."""
        if self.config.scale == "plane" and rel.ok and rel.plane_normal is not None:
            distance = self.plane_distance - float(rel.plane_normal @ T[:3, 3])
            if distance > 1e-3:
                self.plane_distance = distance

    def process(self, frame: InputFrame) -> FrameResult:
        started = time.perf_counter()
        tracks = self.tracker.track(frame.image, frame.truth)
        tracked = time.perf_counter()
        self.history.append((frame, tracks))
        k = len(self.history) - 1
        if k == 0:
            first = frame.T_world_cam if frame.T_world_cam is not None else np.eye(4)
            self.graph = PoseGraph(first)
            return FrameResult(0, tracks, None, first, None, np.zeros((0, 2), np.int64), None,
                               {"frontend": 1e3 * (tracked - started)})
        rel, T, pairs = self._measure(k - 1, k)
        measured = time.perf_counter()
        previous_pose = self.graph.pose(k - 1)
        if rel.ok:
            sigmas = measurement_sigmas(int(rel.inliers.sum()), rel.inlier_ratio, float(np.linalg.norm(T[:3, 3])))
            self.last_translation = T[:3, 3] if np.linalg.norm(T[:3, 3]) > 0 else self.last_translation
            self._update_plane_distance(rel, T)
        else:  # keep the graph connected: constant position, very uncertain
            sigmas = np.array([0.5] * 3 + [1.0] * 3)
        self.graph.add_pose(k, previous_pose @ T)
        self.graph.add_between(k - 1, k, T, sigmas)
        gap = self.config.keyframe_gap
        wide = shared_tracks(self.history[k - gap][1], tracks) if gap > 1 and k >= gap else np.zeros((0, 2), int)
        if self.config.method == "auto" and len(wide) >= relpose.MIN_MATCHES:
            old_tracks = self.history[k - gap][1]
            try:
                self.model = relpose.select_model(old_tracks.points[wide[:, 0]], tracks.points[wide[:, 1]])[0]
            except cv2.error:  # degenerate wide pair: keep the previous choice
                pass
        if len(wide) >= self.config.min_shared_tracks:
            rel_gap, T_gap, _ = self._measure(k - gap, k)
            if rel_gap.ok and rel_gap.model != "static":
                self.graph.add_between(k - gap, k, T_gap, measurement_sigmas(
                    int(rel_gap.inliers.sum()), rel_gap.inlier_ratio, float(np.linalg.norm(T_gap[:3, 3]))))
        self.graph.update()
        pose = self.graph.pose(k)
        optimised = time.perf_counter()
        covariance = self.graph.covariance(k) if self.config.covariance else None
        return FrameResult(k, tracks, rel, pose, covariance, pairs, T, {
            "frontend": 1e3 * (tracked - started), "relative_pose": 1e3 * (measured - tracked),
            "graph": 1e3 * (optimised - measured), "covariance": 1e3 * (time.perf_counter() - optimised)})

    def poses(self) -> np.ndarray:
        """The optimised trajectory (N, 4, 4) ``T_world_cam``."""
        return self.graph.poses()
