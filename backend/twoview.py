"""Two-view relative poses for the odometry: a frame seen from an earlier one by the homography or the essential
matrix of the tracks they share (``relpose.estimate``), told what the measurements before it found: the last
translation and the dominant plane's normal pick among a decomposition's solutions, and a pose that turns more than
``max_rotation_jump`` degrees away from the previous frame's estimate gives way to the homography's or the essential
matrix's where that one agrees with the estimate."""

from __future__ import annotations

from functools import partial
from typing import Callable

import numpy as np

from deepslam.backend import relpose
from deepslam.backend.config import MAX_TURN_OF_TRANSLATION
from deepslam.geometry import rotation_angle, vector_angle

FALLBACK_METHODS = ("homography", "essential")  # the poses tried when the chosen one jumps (max_rotation_jump)


def _turn(rel: relpose.RelativePose, previous: np.ndarray) -> tuple[float, float]:
    """Degrees between the pose ``rel`` measures (T_c1_c2, (4, 4)) and ``previous``, the estimate (4, 4) of the
    frame before seen from the same camera 1 (consecutive frames barely move): rotation, then translation
    direction (0 while that estimate has not moved); infinite for a failed pose."""
    if not rel.ok:
        return np.inf, np.inf
    rotation = np.degrees(rotation_angle(rel.T_c1_c2[:3, :3].T @ previous[:3, :3]))
    translation = np.degrees(vector_angle(rel.T_c1_c2[:3, 3], previous[:3, 3]))
    return float(rotation), float(translation)


class TwoView:
    """Relative poses between two frames from their matched points, each told the last translation measured and
    the dominant plane's normal last seen.

    Args:
        method: how a pose is measured (``relpose.estimate``: auto, homography, essential, pycolmap).
        max_rotation_jump: degrees a pose may turn away from the previous frame's estimate before the other
            models are tried (0: never).
        plane_lengths: translations take their length from the dominant plane (t / d): an essential matrix's pose
            takes that of the homography of the same pairs.
        min_flow_px: a pose measured over less median flow (px) tells neither the motion so far nor the plane's
            normal (a homography's decomposition is then often tens of degrees off, and the next would follow it);
            above 0, where no motion tells ambiguous pairs apart, the essential matrix's pose is taken (0: every
            pose tells, such pairs fail).
    """

    def __init__(self, method: str, max_rotation_jump: float, plane_lengths: bool, min_flow_px: float = 0.0):
        self.method, self.max_rotation_jump, self.plane_lengths = method, max_rotation_jump, plane_lengths
        self.min_flow_px = min_flow_px
        self.last_translation: np.ndarray | None = None  # (3,) the last measured non-zero translation
        self.plane_normal_world: np.ndarray | None = None  # unit normal (3,) of the dominant plane last measured

    def measure(
        self,
        p1: np.ndarray,
        p2: np.ndarray,
        K: np.ndarray,
        shape: tuple[int, int],
        R_world_1: np.ndarray,
        previous: np.ndarray,
    ) -> relpose.RelativePose:
        """Camera 2's pose from camera 1 (``T_c1_c2``, unit or plane-relative length) from the points (K, 2) ``p1``
        in image 1 and ``p2`` in image 2 (K (3, 3), image 2's shape (H, W)); ``R_world_1`` (3, 3) is camera 1's
        estimated rotation, ``previous`` (4, 4) the estimate of the frame before image 2 seen from camera 1."""
        normal = R_world_1.T @ self.plane_normal_world if self.plane_normal_world is not None else None
        estimate = partial(
            relpose.estimate, p1, p2, K, size=shape, previous_t=self.last_translation, previous_normal=normal,
            ambiguous_takes_essential=self.min_flow_px > 0,
        )  # fmt: skip
        rel = self._gated(estimate(self.method), estimate, previous)
        if rel.ok and self.plane_lengths and rel.model == "essential":
            plane = relpose.homography_pose(p1, p2, K, previous_normal=normal)  # magnitude from the plane
            rel.t_over_d, rel.plane_normal = plane.t_over_d, plane.plane_normal
        flow = float(np.median(np.linalg.norm(p2 - p1, axis=1))) if len(p1) else 0.0
        if rel.ok and rel.plane_normal is not None and not rel.rotation_only and flow >= self.min_flow_px:
            self.plane_normal_world = R_world_1 @ rel.plane_normal
        return rel

    def essential(self, p1: np.ndarray, p2: np.ndarray, K: np.ndarray, shape: tuple[int, int]) -> relpose.RelativePose:
        """Camera 2's pose from camera 1 by the essential matrix of the points (K, 2) alone."""
        return relpose.estimate(p1, p2, K, "essential", size=shape)

    def moved(self, T: np.ndarray, flow_px: float = np.inf) -> None:
        """A pose ``T`` (4, 4) measured over ``flow_px`` (median, px; infinite: located in a map) was taken: its
        translation, if any and measured over ``min_flow_px`` or more, is the last one."""
        if np.linalg.norm(T[:3, 3]) > 0 and flow_px >= self.min_flow_px:
            self.last_translation = T[:3, 3]

    def _gated(
        self, rel: relpose.RelativePose, estimate: Callable[[str], relpose.RelativePose], previous: np.ndarray
    ) -> relpose.RelativePose:
        """``rel``, unless it turns more than ``max_rotation_jump`` degrees away from ``previous`` (4, 4: the
        frame before, seen from the same camera 1) and one of ``FALLBACK_METHODS`` (``estimate`` measures by a
        method's name) agrees with it: then the one that agrees best."""
        gate = self.max_rotation_jump
        if not (gate and rel.ok) or _turn(rel, previous)[0] <= gate:
            return rel
        turns = [(_turn(other, previous), other) for other in map(estimate, FALLBACK_METHODS)]
        (rotation, translation), closest = min(turns, key=lambda turn: turn[0])
        return closest if rotation <= gate and translation <= MAX_TURN_OF_TRANSLATION else rel
