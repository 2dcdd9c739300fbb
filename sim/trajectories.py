"""Camera trajectories: ground-truth ``T_world_cam`` (4x4) per frame and integer-nanosecond stamps."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal, get_args

import cv2
import numpy as np

from deepslam.errors import InputError
from deepslam.geometry import path_length
from deepslam.sim.camera import look_at, pose

Kind = Literal["circle", "figure8", "line", "random", "forward"]
KINDS: tuple[str, ...] = get_args(Kind)


@dataclass(frozen=True)
class Trajectory:
    """Poses (N, 4, 4) ``T_world_cam`` and timestamps (N,) int64 nanoseconds."""

    poses: np.ndarray
    stamps_ns: np.ndarray

    def __len__(self) -> int:
        return len(self.poses)

    def path_length(self) -> float:
        return path_length(self.poses)


def random_walk(
    rng: np.random.Generator, frames: int, step: float, angle_step: float, segment_frames: int = 10
) -> np.ndarray:
    """Piecewise-linear motion with rotation about random axes, starting at the identity.

    Each segment of ``segment_frames`` frames moves ``step`` per frame along a random direction
    (in the camera frame at the segment's start) and rotates ``angle_step`` radians per frame about
    a random axis. Returns (frames, 4, 4) ``T_world_cam``.
    """
    poses = [np.eye(4)]
    while len(poses) < frames:
        direction = rng.normal(size=3)
        axis = rng.normal(size=3)
        velocity = pose(axis / np.linalg.norm(axis) * angle_step, direction / np.linalg.norm(direction) * step)
        for _ in range(min(segment_frames, frames - len(poses))):
            poses.append(poses[-1] @ velocity)
    return np.stack(poses)


def make(
    kind: str,
    frames: int,
    speed: float = 0.5,
    fps: float = 30.0,
    radius: float = 2.0,
    seed: int = 0,
    target: tuple[float, float, float] = (0.0, 0.0, 0.0),
    height: float = 0.0,
) -> Trajectory:
    """A trajectory of ``kind`` (one of ``KINDS``) with ``frames`` frames at ``fps``.

    ``speed`` is in world units per second. circle/figure8 orbit ``target`` at about ``radius``
    looking at it; line moves sideways in front of it; forward moves towards it, swaying gently from side to
    side and up and down, looking ahead; random is a ``random_walk`` looking forward.
    """
    if kind not in KINDS:
        raise InputError(f"unknown trajectory {kind!r}; expected one of {', '.join(KINDS)}")
    if frames < 2:
        raise InputError(f"a trajectory needs at least 2 frames, got {frames}")
    if speed <= 0 or fps <= 0:
        raise InputError(f"speed and fps must be positive, got speed={speed}, fps={fps}")
    stamps = np.rint(np.arange(frames) * 1e9 / fps).astype(np.int64)
    distance = speed * np.arange(frames) / fps
    target = np.asarray(target, np.float64)
    if kind == "random":
        rng = np.random.default_rng(seed)
        walk = random_walk(rng, frames, speed / fps, np.radians(10.0) / fps, segment_frames=int(fps))
        start = look_at(target + np.array([0.0, -radius, height]), target)
        return Trajectory(np.einsum("ij,njk->nik", start, walk), stamps)
    if kind == "line":
        eyes = np.stack([distance - distance[-1] / 2, np.full(frames, -radius), np.full(frames, height)], 1) + target
        looks = eyes + np.array([0.0, radius, 0.0])
    elif kind == "forward":
        sway = distance / (0.3 * radius)  # a sideways sway every ~4 m, half as much up and down
        eyes = target + np.stack([0.2 * np.sin(sway), distance - radius, height + 0.1 * np.sin(2 * sway)], 1)
        looks = eyes + np.array([0.0, radius, 0.0])
    else:
        orbit = 0.3 * radius  # the camera circles in a plane facing the target, looking near it
        phase = distance / orbit
        if kind == "circle":
            offsets = np.stack([np.sin(phase), np.zeros(frames), 1 - np.cos(phase)], 1) * orbit
        else:  # a figure of eight (speed is exact at the crossing, approximate elsewhere)
            offsets = np.stack([np.sin(phase), np.zeros(frames), np.sin(2 * phase) / 2], 1) * orbit
        eyes = target + np.array([0.0, -radius, height]) + offsets
        looks = np.repeat(target[None], frames, 0) + offsets * 0.5
    return Trajectory(np.stack([look_at(e, t) for e, t in zip(eyes, looks, strict=False)]), stamps)


def relative_motion(rng: np.random.Generator, max_translation: float, max_rotation: float) -> np.ndarray:
    """A random rigid motion (4x4): translation up to ``max_translation`` along a random direction,
    rotation up to ``max_rotation`` radians about a random axis."""
    direction, axis = rng.normal(size=3), rng.normal(size=3)
    rotation = axis / np.linalg.norm(axis) * rng.uniform(0, max_rotation)
    return pose(cv2.Rodrigues(rotation)[0], direction / np.linalg.norm(direction) * rng.uniform(0, max_translation))
