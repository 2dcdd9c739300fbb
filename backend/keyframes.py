"""The odometry's phases and its one keyframe decision.

``KeyframePolicy.decide`` takes what a frame showed against the current keyframe (``KeyframeEvidence``) and says
whether it becomes the next keyframe, and why: the reason goes into the frame's diagnostics. The rules, first
that holds wins:

1. ``reinitialise_after`` lost frames in a row: tracking starts again from this frame (no keyframe before it).
2. A map started from the current keyframe and this frame (``scale="map"``).
3. It shares fewer than ``min_shared_tracks`` tracks with the keyframe.
4. Its shared tracks moved ``keyframe_parallax`` px (median) since the keyframe; not while a map waits to start
   from the keyframe, so that the first baseline can grow.
5. Measured against the keyframe, the front-end confirmed fewer than ``min_shared_tracks`` of its pairs.
6. Located in the map against the keyframe: fewer than ``map.coverage`` of the landmarks the first frame after
   the keyframe located, fewer than ``map.min_located_share`` of its tracks, or a baseline of
   ``keyframe_parallax`` px (as an angle at the landmarks' median depth). The first two wait for a baseline of
   ``map.min_triangulation_px`` while PnP still locates ``map.min_located`` landmarks: a keyframe closer than
   that triangulates nothing new.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import Enum

from deepslam.backend.config import OdometryConfig


class Phase(str, Enum):
    """Where the odometry stands after a frame: ``initialising`` (no map yet holds the keyframe under
    ``scale="map"``, or the first frame), ``tracking``, or ``lost`` (no pose could be measured)."""

    INITIALISING = "initialising"
    TRACKING = "tracking"
    LOST = "lost"


@dataclass(frozen=True)
class Decision:
    """Whether the frame becomes the keyframe, why (empty when it does not), and whether tracking starts again
    from it (``restart``: the keyframes before it are forgotten)."""

    keyframe: bool
    reason: str = ""
    restart: bool = False


@dataclass(frozen=True)
class MapLocation:
    """How a frame was located in the map against the current keyframe: the landmarks it was located with, those
    the first frame after that keyframe was located with, and the angle (px: radians x focal length) the
    keyframe's centre and the frame's span at the landmarks' median depth."""

    located: int
    first_located: int
    baseline_px: float


@dataclass(frozen=True)
class KeyframeEvidence:
    """What a frame showed against the current keyframe.

    Attributes:
        lost_in_a_row: lost frames up to and including this one.
        map_started: a map started from the current keyframe and this frame.
        shared: tracks this frame shares with the keyframe.
        parallax_px: the median motion (px) of those tracks since the keyframe.
        against_keyframe: the pose was measured against the current keyframe (not the one before).
        confirmed: the pairs with the reference keyframe the front-end confirmed.
        map_waiting: a map waits to start from the keyframe (``scale="map"``, none yet holds it).
        tracks: this frame's tracks.
        location: how it was located in the map against the keyframe; None where it was not.
    """

    lost_in_a_row: int
    map_started: bool
    shared: int
    parallax_px: float
    against_keyframe: bool
    confirmed: int
    map_waiting: bool
    tracks: int
    location: MapLocation | None = None


class KeyframePolicy:
    """The odometry's keyframe rules (module docstring), with the settings of ``config``."""

    def __init__(self, config: OdometryConfig):
        self.config = config

    def decide(self, evidence: KeyframeEvidence) -> Decision:
        """Whether the frame that showed ``evidence`` becomes the keyframe, and why."""
        config = self.config
        if evidence.lost_in_a_row >= config.reinitialise_after:
            return Decision(True, f"lost {evidence.lost_in_a_row} frames in a row: tracking starts again", True)
        if evidence.map_started:
            return Decision(True, "a map starts")
        if evidence.shared < config.min_shared_tracks:
            return Decision(True, f"{evidence.shared} tracks shared with the keyframe")
        if not evidence.map_waiting and evidence.parallax_px >= config.keyframe_parallax:
            return Decision(True, f"tracks moved {evidence.parallax_px:.1f} px")
        if evidence.against_keyframe and evidence.confirmed < config.min_shared_tracks:
            return Decision(True, f"{evidence.confirmed} pairs confirmed")
        reason = self._map_thinning(evidence.location, evidence.tracks) if evidence.location else ""
        return Decision(bool(reason), reason)

    def _map_thinning(self, location: MapLocation, tracks: int) -> str:
        """Why a frame located in the map becomes a keyframe (rule 6), or an empty string."""
        config, baseline = self.config.map, location.baseline_px
        if baseline < config.min_triangulation_px and location.located >= config.min_located:
            return ""
        if location.located < config.coverage * location.first_located:
            return f"located {location.located} landmarks, the keyframe's first frame {location.first_located}"
        if location.located < config.min_located_share * tracks:
            return f"located {location.located} landmarks of {tracks} tracks"
        if baseline >= self.config.keyframe_parallax:
            return f"a baseline of {baseline:.1f} px at the landmarks"
        return ""
