"""Whether a track stays one physical point (evaluation only: it needs the true poses).

Each track seen in at least two frames is triangulated from all its observations with the true camera poses
(linear least squares); an observation that lies more than a few pixels from that point's projection belongs
to another point (the track jumped, or drifted with the parallax).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

CONSISTENT_PX = 2.0  # an observation within this many pixels of its track's point is one of that point


@dataclass
class TrackObservations:
    """Every observation of every track over a run, with the true camera of each frame."""

    ids: list[np.ndarray] = field(default_factory=list)  # per frame: track ids (N,)
    points: list[np.ndarray] = field(default_factory=list)  # per frame: pixels (N, 2)
    K: list[np.ndarray] = field(default_factory=list)  # per frame: (3, 3)
    poses: list[np.ndarray] = field(default_factory=list)  # per frame: true T_world_cam (4, 4)

    def add(self, ids: np.ndarray, points: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> None:
        """One frame's tracks (ids (N,), pixels (N, 2)) and its true pose ``T_world_cam`` (4, 4) with K (3, 3)."""
        self.ids.append(np.asarray(ids, np.int64))
        self.points.append(np.asarray(points, np.float64).reshape(-1, 2))
        self.K.append(np.asarray(K, np.float64))
        self.poses.append(np.asarray(T_world_cam, np.float64))

    def head(self, frames: int) -> TrackObservations:
        """The observations of the first ``frames`` frames only (the lists shared, not copied)."""
        return TrackObservations(self.ids[:frames], self.points[:frames], self.K[:frames], self.poses[:frames])

    def projection(self, frame: int) -> np.ndarray:
        """The true K [R | t] (3, 4) of a frame (its position in ``add`` order)."""
        return self.K[frame] @ np.linalg.inv(self.poses[frame])[:3]

    def tracks(self) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
        """Every track seen in at least two frames: (id, frames (M,), pixels (M, 2)), frames in order."""
        if not self.ids:
            return
        frame = np.concatenate([np.full(len(ids), i) for i, ids in enumerate(self.ids)])
        ids, points = np.concatenate(self.ids), np.concatenate(self.points)
        order = np.lexsort((frame, ids))
        ids, points, frame = ids[order], points[order], frame[order]
        starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
        for a, b in zip(starts, np.r_[starts[1:], len(ids)], strict=True):
            if b - a >= 2:
                yield int(ids[a]), frame[a:b], points[a:b]

    def errors(self) -> np.ndarray:
        """Pixel distances (M,) of every observation of a track seen at least twice from the projection of the
        point triangulated from all that track's observations (infinite behind a camera)."""
        projections = np.stack([self.projection(i) for i in range(len(self.ids))]) if self.ids else None
        errors = [_reprojection_errors(pixels, projections[frames]) for _, frames, pixels in self.tracks()]
        return np.concatenate(errors) if errors else np.zeros(0)


def _homogeneous_point(pixels: np.ndarray, projections: np.ndarray) -> np.ndarray:
    """The linear triangulation (4,) of pixels (M, 2) seen by the projections (M, 3, 4)."""
    rows = np.concatenate(
        [pixels[:, :1] * projections[:, 2] - projections[:, 0], pixels[:, 1:] * projections[:, 2] - projections[:, 1]]
    )
    return np.linalg.svd(rows, full_matrices=False)[2][-1]  # U (2M, 4), not (2M, 2M): linear in M


def triangulate(pixels: np.ndarray, projections: np.ndarray) -> np.ndarray | None:
    """The point (3,) whose projections by (M, 3, 4) lie nearest the pixels (M, 2) (linear least squares);
    None at infinity."""
    point = _homogeneous_point(pixels, projections)
    return point[:3] / point[3] if abs(point[3]) > 1e-12 else None


def _reprojection_errors(pixels: np.ndarray, projections: np.ndarray) -> np.ndarray:
    """Distances (M,) of pixels (M, 2) from the projections (by (M, 3, 4)) of their linear triangulation."""
    point = _homogeneous_point(pixels, projections)
    projected = projections @ point
    with np.errstate(divide="ignore", invalid="ignore"):
        distances = np.linalg.norm(projected[:, :2] / projected[:, 2:] - pixels, axis=1)
    return np.where(np.isfinite(distances) & (projected[:, 2] * point[3] > 0), distances, np.inf)


def consistent_share(errors: np.ndarray) -> float:
    """The share of observations within ``CONSISTENT_PX`` of their track's point (NaN without any)."""
    return float(np.mean(errors <= CONSISTENT_PX)) if len(errors) else float("nan")
