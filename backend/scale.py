"""Where a two-view step's metric length comes from: with a local map (``scale="map"``, ``MapScale``, which also
keeps the camera's motion as the map measures it) or from the distance to the dominant plane (``scale="plane"`` and
``"none"``, ``PlaneScale``). Monocular geometry gives a step's direction only; the odometry asks these how long it
is."""

from __future__ import annotations

from collections import deque
from typing import Callable

import numpy as np

from deepslam.backend.relpose import RelativePose

MOTION_STEPS = 5  # the camera's speed: the median length of the last this many steps the map measured

StepLengths = Callable[[int, int], float | None]
"""The true distance (m) between the cameras of frames i and j (indices in processing order), None if unknown."""


def with_length(T: np.ndarray, length: float) -> np.ndarray:
    """A copy of the pose ``T`` (4, 4) whose translation is ``length`` long (zero stays zero)."""
    scaled = T.copy()
    scaled[:3, 3] *= length / max(float(np.linalg.norm(T[:3, 3])), 1e-12)
    return scaled


class MapScale:
    """The lengths (m, or units of the first baseline) of two-view steps while no map holds the keyframe.

    Until the first map starts (for at most ``start_within`` frames), a step takes its true length where
    ``step_lengths`` knows it (an input with truth), and so does the first map's baseline. Once the map has
    measured a step between two frames it located (``record``), a step is that speed times the frames between:
    the pixels a step moves tracks depend on their depth, which has changed since the first baseline. Else a step
    is in proportion to the median motion of its tracks: metres a pixel from the last true length, or one unit for
    ``keyframe_parallax`` pixels.

    Args:
        step_lengths: true step lengths, or None (a camera of one's own).
        start_within: frames from the first during which true lengths are taken.
        keyframe_parallax: pixels of track motion (px) that make one unit of length without truth.
    """

    def __init__(self, step_lengths: StepLengths | None, start_within: int, keyframe_parallax: float):
        self.step_lengths, self.start_within = step_lengths, start_within
        self.truth_until_map = True  # two-view lengths from the truth (no map yet, within start_within frames)
        self.first_map_waits = True  # no map has started yet (its baseline takes the true length)
        self.length_per_px = 1.0 / keyframe_parallax  # a two-view step's length per pixel of track motion
        # the last MOTION_STEPS steps (4, 4) between two consecutive frames located in the map, T_previous_current
        self.steps: deque[np.ndarray] = deque(maxlen=MOTION_STEPS)
        self.located_before = False  # the last frame was located in the map

    def two_view(self, i: int, j: int, parallax: float) -> float:
        """The length of a two-view step between frames i < j whose shared tracks moved ``parallax`` px."""
        known = self._truth(i, j, self.truth_until_map)
        if known is not None and parallax > 0:
            self.length_per_px = known / parallax
        velocity = self.velocity() if known is None else None
        if velocity is not None:
            return float(np.linalg.norm(velocity[:3, 3])) * (j - i)
        return known if known is not None else parallax * self.length_per_px

    def first_baseline(self, T: np.ndarray, i: int, j: int) -> np.ndarray:
        """``T`` (4, 4), frame j seen from keyframe i, with the true length of the first map's baseline where the
        input knows it (the scale every later map carries), else as it is."""
        known = self._truth(i, j, self.first_map_waits)
        return T if known is None else with_length(T, known)

    def _truth(self, i: int, j: int, wanted: bool) -> float | None:
        """The true distance (m) between frames i and j where it is ``wanted`` and the input knows it, else None."""
        return self.step_lengths(i, j) if wanted and self.step_lengths is not None else None

    def map_started(self) -> None:
        """A map has started: later maps carry its scale."""
        self.first_map_waits = False

    def frame_done(self, k: int, map_holds_keyframe: bool) -> None:
        """After frame k: true lengths end once a map holds the keyframe or ``start_within`` frames have passed."""
        self.truth_until_map &= not map_holds_keyframe and k < self.start_within

    def record(self, step: np.ndarray | None) -> None:
        """The step (4, 4) ``T_previous_current`` from the frame before to this one where the map located this one,
        else None; kept among ``steps`` where the map located the frame before too."""
        if step is not None and self.located_before:
            self.steps.append(step)
        self.located_before = step is not None

    def velocity(self) -> np.ndarray | None:
        """The camera's step (4, 4) from one frame to the next as the map last measured it: the last of its
        ``steps``, as long as their median (a single step is a few millimetres off); None before it measured any."""
        if not self.steps:
            return None
        return with_length(self.steps[-1], float(np.median([np.linalg.norm(step[:3, 3]) for step in self.steps])))


class PlaneScale:
    """Metric lengths of two-view steps from the camera's distance to the dominant plane (``scale="plane"``; with
    ``"none"`` that distance is the unit): a homography's decomposition measures t / d, and the distance moves on
    with every keyframe, d2 = d1 - n . t.

    Args:
        distance: the first camera's distance (m) to the dominant plane.
    """

    def __init__(self, distance: float):
        self.distance = distance

    def length(self, rel: RelativePose) -> float:
        """The metric length of the step ``rel`` measured (0 where it carries no t / d)."""
        return float(rel.t_over_d or 0.0) * self.distance

    def moved_on(self, rel: RelativePose, T: np.ndarray) -> None:
        """The next keyframe, measured from this one as ``rel`` and ``T`` (4, 4, metric), takes over: its distance
        to the plane is d - n . t (kept where the pose has no plane, or where that would not be positive)."""
        if rel.ok and rel.plane_normal is not None:
            distance = self.distance - float(rel.plane_normal @ T[:3, 3])
            if distance > 1e-3:
                self.distance = distance
