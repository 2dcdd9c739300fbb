"""Monocular visual odometry: front-end tracks -> relative poses or a local map -> scale -> ISAM2 pose graph.

Every frame is measured against the current keyframe (a wide baseline: frame-to-frame parallax is a
pixel or two, too little for H or E), with an extra factor to the keyframe before it when they still
share tracks; a frame whose median track motion since the keyframe passes ``keyframe_parallax`` pixels,
or that shares too few tracks with it (or too few the front-end confirms: ``Tracker.confirm``), becomes the
next keyframe (``keyframes.KeyframePolicy``). Two-view poses come from ``twoview.TwoView``: one that turns more
than ``max_rotation_jump`` degrees away from the previous frame's estimate gives way to the homography's or the
essential matrix's pose where that one agrees with it.

Frames come from any source (a camera, a simulator or a replayed log) as images with their K; the odometry
needs no simulator. Monocular translation has no scale: ``scale="gt"`` takes each step's length from ground
truth that the caller passes in as ``step_lengths`` (the usual convention of monocular VO evaluation);
``scale="plane"`` keeps metric scale without ground truth from a known initial distance to the dominant plane
(like a known camera height), which homography decompositions (t / d) carry from keyframe to keyframe
(``scale.PlaneScale``); ``scale="none"`` does the same with that distance taken as the unit of length: the
trajectory up to scale.

``scale="map"`` needs no plane: once two keyframes triangulate enough landmarks (``deepslam.backend.mapping``),
each frame is located in that local map by PnP against the current keyframe's landmarks (which the front-end
looks for where the map projects them from the pose the last step, repeated, predicts), every keyframe adds
landmarks and a local bundle adjustment, and the map carries the scale of its first baseline: its true length
where the caller passes ``step_lengths`` (an input with truth), else the unit (about one keyframe's motion).
The pose graph holds the keyframes and the frames measured two-view; a frame located in the map joins it only as
a keyframe, and until then its estimate is its keyframe's composed with its measurement (``Odometry.estimate``).
Two-view poses before the first map take their lengths from that same source for at most ``map.start_within``
frames; once a map has started (where PnP finds no pose or no map holds the keyframe), from the speed of the last
step the map measured, and a lost frame goes on by that step (constant velocity): the pixels a step moves tracks
depend on their depth, which has changed since the first baseline.
While a map waits to start from the keyframe, a frame's two-view pose is adjusted together with the frames since
the keyframe (``_initialising``, ``mapping.InitialViews``): measured one by one over a few pixels of parallax,
their directions scatter. Once a map starts, the frames before it are located in it for the final trajectory
(``Odometry.poses``); their online estimates stay as they were.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Iterator

import numpy as np

from deepslam.backend import relpose
from deepslam.backend.config import OdometryConfig
from deepslam.backend.graph import PoseGraph, measurement_sigmas
from deepslam.backend.keyframes import Decision, KeyframeEvidence, KeyframePolicy, MapLocation, Phase
from deepslam.backend.mapping import InitialViews, Keyframe, LocalMap, project
from deepslam.backend.scale import MapScale, PlaneScale, StepLengths, with_length
from deepslam.backend.twoview import TwoView
from deepslam.errors import InputError
from deepslam.frontend.tracking import Predicted, Tracker, Tracks
from deepslam.geometry import constant_motion, in_image, is_pose, rotation_angle
from deepslam.interrupts import checkpoint

BUNDLE_GAIN = 3.0  # a keyframe's pose after bundle adjustment is this many times surer than one measurement
ADJUSTED_AGREEMENT = (3.0, 0.5)  # ... if within this many degrees and this share of its length of the graph's
# ISAM2 updates (each one Gauss-Newton step) a keyframe located in the map adds to the graph once its factors are in:
# the frames located in the map between keyframes, which the graph does not hold, no longer update it
KEYFRAME_UPDATES = 3


@dataclass(frozen=True)
class Measurement:
    """Frame ``index``'s pose ``T`` (4, 4) seen from keyframe ``keyframe`` (``T_kf_frame``, metric), with the
    sigmas (6,) the graph takes it with (rotation (rad) first, then translation (m))."""

    keyframe: int
    index: int
    T: np.ndarray
    sigmas: np.ndarray


@dataclass(frozen=True)
class Posed:
    """Frame k's pose from a keyframe as measured: ``rel`` (two-view, or "pnp" where the map located it), ``T``
    (4, 4) ``T_kf_k`` (metric), the pairs (K, 2) of the keyframe's and frame k's tracks it was measured from, and
    frame k's points (K, 2) of them (where the front-end confirmed them: ``Tracker.confirm``)."""

    rel: relpose.RelativePose
    T: np.ndarray
    pairs: np.ndarray
    points: np.ndarray


@dataclass(frozen=True)
class _Kept:
    """What the odometry keeps of a frame it may still measure against: K (3, 3) and the image's (H, W)."""

    K: np.ndarray
    shape: tuple[int, int]


@dataclass
class FrameResult:
    """What the odometry made of one frame: tracks, the relative pose to its reference keyframe (None for
    the first), the current estimate ``T_world_cam`` (4, 4), its covariance (6, 6) or None,
    the correspondences (K, 2) as indices into the reference keyframe's and this frame's tracks, the
    scaled measurement ``T_ref_cur`` (4, 4) of this frame from that keyframe, the index of that reference
    keyframe, stage timings, and this frame's points of the correspondences (K, 2) where the pose was
    measured from them (the front-end may have polished the tracked positions: ``Tracker.confirm``).
    A frame that is not a keyframe reports those points in its ``tracks``; a keyframe keeps the positions
    the front-end tracked, as later frames are measured against them. ``lost``: no relative pose could be
    measured (``relative.reason`` says why), so the estimate is a guess: the previous frame moved on by the last
    step the map measured, or before any map, no motion since the previous frame."""

    index: int
    tracks: Tracks
    relative: relpose.RelativePose | None
    T_world_cam: np.ndarray
    covariance: np.ndarray | None
    correspondences: np.ndarray
    T_ref_cur: np.ndarray | None = None
    reference: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)
    keyframe: bool = False  # this frame became a keyframe
    measured_points: np.ndarray | None = None  # (K, 2) this frame's points of the correspondences, as measured
    landmarks: int = 0  # the map's landmarks after this frame (scale "map"; else 0)
    shared: int = 0  # its tracks the pose could be measured from: shared with the keyframe, or landmarks
    map_points: np.ndarray | None = None  # (M, 3) the map's world points, where this frame changed the map
    phase: Phase = Phase.TRACKING  # where the odometry stands after this frame
    keyframe_reason: str = ""  # why it became a keyframe (``KeyframePolicy``); empty where it did not

    @property
    def lost(self) -> bool:
        return self.relative is not None and not self.relative.ok


def shared_tracks(a: Tracks, b: Tracks) -> np.ndarray:
    """Index pairs (K, 2) of points of ``a`` and ``b`` with the same track id."""
    common, ia, ib = np.intersect1d(a.ids, b.ids, return_indices=True)
    return np.stack([ia, ib], 1).astype(np.int64)


def _sigmas(rel: relpose.RelativePose, T: np.ndarray, parallax: float) -> np.ndarray:
    """The sigmas (6,) the graph takes a pose ``T`` (4, 4) with, measured as ``rel`` over ``parallax`` px
    (``measurement_sigmas``: from its inliers and their share, its length and the parallax)."""
    return measurement_sigmas(int(rel.inliers.sum()), rel.inlier_ratio, float(np.linalg.norm(T[:3, 3])), parallax)


def _median_motion(a: Tracks | Keyframe, b: Tracks | Keyframe, pairs: np.ndarray) -> float:
    """Median motion (px) from ``a`` to ``b`` (tracks or map keyframes: ids and points) of the pairs (K, 2) of
    their indices; 0 for no pairs."""
    if len(pairs) == 0:
        return 0.0
    return float(np.median(np.linalg.norm(b.points[pairs[:, 1]] - a.points[pairs[:, 0]], axis=1)))


class Odometry:
    """Feed frames in order with ``process``; ``poses`` holds the optimised trajectory so far.

    Args:
        tracker: the front-end.
        config: the odometry's settings.
        origin: ``T_world_cam`` (4, 4) of the first frame (default: the identity).
        step_lengths: true step lengths, for ``config.scale == "gt"`` (every step) and ``"map"`` (the first
            baseline only, where it returns one).
    """

    def __init__(
        self,
        tracker: Tracker,
        config: OdometryConfig | None = None,
        origin: np.ndarray | None = None,
        step_lengths: StepLengths | None = None,
    ):
        config = config or OdometryConfig()
        if config.scale == "plane" and not config.plane_distance:
            raise InputError("scale 'plane' needs the first camera's distance to the dominant plane")
        if step_lengths is not None and not callable(step_lengths):
            raise InputError(
                "step_lengths must be a function (i, j) -> the true distance (m) between the cameras of frames i and "
                f"j, or None; got a {type(step_lengths).__name__}"
            )
        if config.scale == "gt" and step_lengths is None:
            raise InputError(
                "scale 'gt' takes each step's length from ground truth, which an evaluation passes in "
                "(step_lengths); without it use scale 'map', 'plane' or 'none'"
            )
        if config.scale == "none":  # the dominant plane's distance is the unit of length
            config = replace(config, plane_distance=1.0)
        self.tracker, self.config, self.step_lengths = tracker, config, step_lengths
        self.policy = KeyframePolicy(config)
        if origin is not None and not is_pose(origin):
            raise InputError(
                f"origin must be a (4, 4) T_world_cam: a rotation, a translation and a last row 0 0 0 1, got "
                f"{np.asarray(origin).tolist()}"
            )
        self.origin = np.eye(4) if origin is None else np.asarray(origin, np.float64)
        self.graph: PoseGraph | None = None
        self.history: dict[int, tuple[_Kept, Tracks]] = {}  # the frames still measured against, by index
        self.frames = 0
        plane_lengths = config.scale in ("plane", "none")
        self.two_view = TwoView(config.method, config.max_rotation_jump, plane_lengths, config.vote_flow_px)
        self.plane = PlaneScale(config.plane_distance) if plane_lengths else None
        self.keyframe, self.previous_keyframe = 0, None
        self.lost_in_a_row = 0
        self.map = LocalMap(config.map) if config.scale == "map" else None
        self.scale = MapScale(step_lengths, config.map.start_within, config.keyframe_parallax)
        # (keyframe, how the last frame measured against it in the map was located): map only
        self.location: tuple[int, MapLocation] | None = None
        self.measured: dict[int, Measurement] = {}  # the frames the graph does not hold (located in the map), by index
        self.waiting = InitialViews(config.map)  # the frames a map waits through, and where it located them

    def _step_length(self, i: int, j: int, rel: relpose.RelativePose) -> float:
        """Metric length of the translation between frames i and j."""
        if self.config.scale == "gt":
            return self.step_lengths(i, j)
        if self.config.scale == "map":
            pairs = shared_tracks(self.history[i][1], self.history[j][1])
            return self.scale.two_view(i, j, self._parallax(i, j, pairs))
        return self.plane.length(rel)

    def _locate(self, kf: int, k: int) -> Posed:
        """Frame k located in the map by PnP on the landmarks among the pairs the front-end confirms with keyframe
        kf (which the map holds): the pose "pnp" from those pairs, or "failed"."""
        frame_k, tracks_k = self.history[k]
        pairs, points = self._confirmed(kf, k)
        ids = tracks_k.ids[pairs[:, 1]]
        landmark = self.map.known(ids)
        pairs, points = pairs[landmark], points[landmark]
        location = self.map.locate(ids[landmark], points, frame_k.K, self._in_map(kf, self.estimate(k - 1)))
        located, before = int(location.inliers.sum()), self._located_against(kf)
        first = before.first_located if before is not None else located
        if location.T_world_cam is None:
            self.location = (kf, MapLocation(located, first, 0.0))
            failed = relpose.RelativePose(np.eye(4), "failed", location.inliers, reason=location.reason)
            return Posed(failed, np.eye(4), pairs, points)
        T = np.linalg.inv(self.map.pose(kf)) @ location.T_world_cam
        self.location = (kf, MapLocation(located, first, self.map.baseline_px(location, frame_k.K, kf)))
        return Posed(relpose.RelativePose(T, "pnp", location.inliers), T, pairs, points)

    def _located_against(self, kf: int) -> MapLocation | None:
        """How the last frame located in the map against keyframe kf was, or None where none was."""
        return self.location[1] if self.location is not None and self.location[0] == kf else None

    def _confirmed(self, i: int, j: int) -> tuple[np.ndarray, np.ndarray]:
        """The pairs (K, 2) of stored frames i and j's shared tracks the front-end confirms, and frame j's points
        (K, 2) of them (``Tracker.confirm``)."""
        tracks_i, tracks_j = self.history[i][1], self.history[j][1]
        return self.tracker.confirm(tracks_i, tracks_j, shared_tracks(tracks_i, tracks_j))

    def _in_map(self, kf: int, T_world_cam: np.ndarray) -> np.ndarray:
        """A pose of the graph's (4, 4) in the map's world, placed by keyframe kf, which both hold (the graph's
        world and the map's drift apart)."""
        return self.map.pose(kf) @ np.linalg.inv(self.graph.pose(kf)) @ T_world_cam

    def _map_holds(self, index: int) -> bool:
        return self.map is not None and self.map.holds(index)

    def _measure(self, i: int, j: int) -> Posed:
        """Frame j's two-view pose from stored frame i < j, scaled."""
        tracks_i, frame_j = self.history[i][1], self.history[j][0]
        pairs, p2 = self._confirmed(i, j)
        T_world_i = self.graph.pose(i)
        previous = np.linalg.inv(T_world_i) @ self.estimate(j - 1)  # frame j - 1 seen from frame i
        p1 = tracks_i.points[pairs[:, 0]]
        rel = self.two_view.measure(p1, p2, frame_j.K, frame_j.shape, T_world_i[:3, :3], previous)
        T = rel.T_c1_c2.copy()
        if rel.ok and not rel.rotation_only and rel.model != "static":
            T = with_length(T, self._step_length(i, j, rel))
        return Posed(rel, T, pairs, p2)

    def process(self, image: np.ndarray, K: np.ndarray) -> FrameResult:
        """Track the next frame (image uint8 (H, W), K (3, 3)), measure its pose against the current keyframe (in
        the map where it holds the keyframe), decide whether it becomes a keyframe, update the graph and the map."""
        started = time.perf_counter()
        tracks = self._track(image, K)
        tracked = time.perf_counter()
        k, self.frames = self.frames, self.frames + 1
        self.history[k] = (_Kept(K, image.shape), tracks)
        if k == 0:
            return self._first_frame(tracks, 1e3 * (tracked - started))
        checkpoint()  # Ctrl-C and SIGTERM take effect between the stages of a frame
        kf = self._reference(k, tracks)
        posed = self._pose(kf, k)
        posed = replace(posed, T=self._initialising(kf, k, posed))
        rel, pairs, measured_points = posed.rel, posed.pairs, posed.points
        measured, shared = time.perf_counter(), self._shared(kf, k, rel)
        checkpoint()
        measurement = self._measurement(kf, k, rel, posed.T, self._parallax(kf, k, pairs))
        decision, T = self._update_keyframes(measurement, rel, len(pairs))
        T, adjusted = self._adjust_located(k, kf, replace(posed, T=T))
        self._keep(k, tracks, pairs, measured_points)
        pose = self.estimate(k)
        self._measure_velocity(k, rel)
        optimised = time.perf_counter()
        covariance = self._covariance(k) if self.config.covariance else None
        timings = {
            "frontend": 1e3 * (tracked - started),
            "relative_pose": 1e3 * (measured - tracked),
            "graph": 1e3 * (optimised - measured),
            "covariance": 1e3 * (time.perf_counter() - optimised),
        }
        landmarks, map_points = self._map_state(self.keyframe == k or adjusted)
        return FrameResult(
            k, tracks, rel, pose, covariance, pairs, T, kf, timings, self.keyframe == k, measured_points, landmarks,
            shared, map_points, self._phase(rel), decision.reason,
        )  # fmt: skip

    def _keep(self, k: int, tracks: Tracks, pairs: np.ndarray, measured_points: np.ndarray) -> None:
        """What the frames after frame k need of it and of those before, frame k measured on ``pairs`` (K, 2) with
        its ``measured_points`` (K, 2) of them: the frames later ones are measured against (frame k, the keyframe
        and the one before it); frame k's points as its pose was measured from them, unless it is a keyframe (later
        frames are measured against a keyframe's points as tracked); and while a map waits, the views since its
        keyframe, and frame k's tracks, to locate it once the map starts (``InitialViews``)."""
        self.history = {i: kept for i, kept in self.history.items() if i in (k, self.keyframe, self.previous_keyframe)}
        waits = self._map_waits()
        self.waiting.keep_after(self.keyframe if waits else None)
        if self.keyframe != k:
            tracks.points[pairs[:, 1]] = measured_points
        if waits:
            self.waiting.keep(self._keyframe(k, self.estimate(k)))

    def _adjust_located(self, k: int, kf: int, located: Posed) -> tuple[np.ndarray, bool]:
        """Frame k, ``located`` in the map against keyframe kf (PnP's inliers among its landmark pairs) and not made
        a keyframe: with ``map.adjust_frames``, its inliers join the map's bundle adjustment (``LocalMap.observe``).
        Returns frame k's pose from kf (4, 4), the adjusted one where it joined, and whether it did (the map
        moved)."""
        rel, T = located.rel, located.T
        if not (self.config.map.adjust_frames and rel.model == "pnp" and k in self.measured):
            return T, False
        (frame_k, tracks_k), inliers = self.history[k], rel.inliers
        ids = tracks_k.ids[located.pairs[inliers, 1]]
        view = Keyframe(k, self.map.pose(kf) @ T, frame_k.K, ids, located.points[inliers])
        pose = self.map.observe(view)  # moves keyframe kf too
        adjusted = np.linalg.inv(self.map.pose(kf)) @ pose
        self.measured[k] = replace(self.measured[k], T=adjusted)
        return adjusted, True

    def _measure_velocity(self, k: int, rel: relpose.RelativePose) -> None:
        """Tell the scale the step from frame k - 1 to frame k where the map located frame k (``MapScale.record``)."""
        located = rel.model == "pnp"
        self.scale.record(np.linalg.inv(self.estimate(k - 1)) @ self.estimate(k) if located else None)

    def _track(self, image: np.ndarray, K: np.ndarray) -> Tracks:
        """The front-end's tracks in the next frame, told first where the map expects its landmarks."""
        predicted = self._predicted(K, image.shape)
        if predicted is not None:
            self.tracker.expect(predicted)
        return self.tracker.track(image)

    def _first_frame(self, tracks: Tracks, frontend_ms: float) -> FrameResult:
        """The first frame: the graph's origin and the first keyframe."""
        self.graph = PoseGraph(self.origin, self.config.graph)
        no_pairs = np.zeros((0, 2), np.int64)
        timings = {"frontend": frontend_ms}
        return FrameResult(
            0, tracks, None, self.origin, None, no_pairs, None, 0, timings, keyframe=True,
            phase=Phase.INITIALISING, keyframe_reason="the first frame",
        )  # fmt: skip

    def _map_waits(self) -> bool:
        """Whether a map waits to start from the current keyframe (``scale="map"``, none holds it)."""
        return self.map is not None and not self._map_holds(self.keyframe)

    def _initialising(self, kf: int, k: int, posed: Posed) -> np.ndarray:
        """Frame k's pose from keyframe kf (4, 4) while a map waits to start from kf: its two-view pose (``posed``)
        adjusted together with the frames since kf whose tracks moved ``min_parallax`` px from it
        (``InitialViews``), each with the pairs the front-end confirmed with kf. ``posed.T`` where there is no map
        to wait for, the pose is not a translation measured two-view, or the frames triangulate too few
        landmarks."""
        rel, T = posed.rel, posed.T
        two_view = rel.model in ("homography", "essential") and not rel.rotation_only
        if kf != self.keyframe or not self._map_waits() or not two_view:
            return T
        origin, ids = self.graph.pose(kf), self.history[k][1].ids[posed.pairs[:, 1]]
        first = self._keyframe(kf, origin)
        current = Keyframe(k, origin @ T, self.history[k][0].K, ids, posed.points)
        adjusted = self.waiting.adjust(first, current, self.estimate)
        if _median_motion(first, current, shared_tracks(first, current)) >= self.config.min_parallax:
            self.waiting.add(current)
        return T if adjusted is None else np.linalg.inv(origin) @ adjusted

    def _pose(self, kf: int, k: int) -> Posed:
        """Frame k's pose from keyframe kf: located in the map where it holds kf, else (or where too few landmarks
        are found) the two-view pose."""
        if self._map_holds(kf):
            located = self._locate(kf, k)
            if located.rel.ok:
                return located
        return self._measure(kf, k)

    def _phase(self, rel: relpose.RelativePose) -> Phase:
        """Where the odometry stands after a frame measured as ``rel``."""
        if not rel.ok:
            return Phase.LOST
        if self.map is not None and not self._map_holds(self.keyframe):
            return Phase.INITIALISING
        return Phase.TRACKING

    def _predicted(self, K: np.ndarray, shape: tuple[int, int]) -> Predicted | None:
        """Where the map's landmarks should appear in the next frame (K (3, 3), image shape (H, W)): projected
        from the pose the last step, repeated, predicts (in the map's world); None without a map that holds the
        current keyframe (or with ``map.predict`` off)."""
        if not (self.config.map.predict and self._map_holds(self.keyframe) and self.frames >= 2):
            return None
        last, before = (self._in_map(self.keyframe, self.estimate(self.frames - step)) for step in (1, 2))
        ids, world = self.map.points()
        pixels, depth = project(constant_motion(before, last), K, world)
        seen = (depth > 0) & in_image(pixels, shape)
        return Predicted(ids[seen], pixels[seen])

    def _shared(self, kf: int, k: int, rel: relpose.RelativePose) -> int:
        """The tracks of frame k its pose could be measured from: landmarks of the map where it was located in
        the map, else those it shares with keyframe kf."""
        tracks = self.history[k][1]
        if rel.model == "pnp":
            return int(self.map.known(tracks.ids).sum())
        return len(shared_tracks(self.history[kf][1], tracks))

    def _map_state(self, changed: bool) -> tuple[int, np.ndarray | None]:
        """The map's landmark count, and its points (M, 3) if it ``changed`` (else None); 0 and None without one."""
        if self.map is None:
            return 0, None
        return len(self.map.landmarks), self.map.points()[1] if changed and self.map.started else None

    def _measurement(self, kf: int, k: int, rel: relpose.RelativePose, T: np.ndarray, parallax: float) -> Measurement:
        """Frame k's measured pose ``T`` (4, 4) from keyframe kf, with ``parallax`` (px), as the graph would take
        it; where no pose could be measured, very uncertain, so that the graph stays connected: frame k - 1 moved on
        by the last step the map measured (``MapScale.velocity``), or before any map, no motion since frame k - 1.
        Until it joins the graph, frame k's estimate is the keyframe's composed with it."""
        if rel.ok:
            sigmas = _sigmas(rel, T, parallax)
            self.two_view.moved(T, np.inf if rel.model == "pnp" else parallax)
        else:
            last, velocity = self.estimate(k - 1), self.scale.velocity()
            T = np.linalg.inv(self.graph.pose(kf)) @ (last if velocity is None else last @ velocity)
            sigmas = np.array([0.5] * 3 + [1.0] * 3)
        measurement = Measurement(kf, k, T, sigmas)
        self.measured[k] = measurement
        return measurement

    def _add_measurement(self, measurement: Measurement) -> None:
        """Add a measured frame to the graph, linked to its keyframe (and to the keyframe before where they share
        tracks), and update."""
        kf, k = measurement.keyframe, measurement.index
        self.graph.add_pose(k, self.graph.pose(kf) @ measurement.T)
        self.graph.add_between(kf, k, measurement.T, measurement.sigmas)
        self._link_previous_keyframe(k, kf)
        self.graph.update(keep=[key for key in (self.keyframe, self.previous_keyframe) if key is not None])
        del self.measured[k]

    def estimate(self, index: int) -> np.ndarray:
        """The latest estimate (4, 4) ``T_world_cam`` of frame ``index``: the graph's, or for a frame the graph
        does not hold (located in the map), its keyframe's composed with the measurement."""
        measurement = self.measured.get(index)
        if measurement is None:
            return self.graph.pose(index)
        return self.graph.pose(measurement.keyframe) @ measurement.T

    def _covariance(self, index: int) -> np.ndarray:
        """The marginal covariance (6, 6) of frame ``index``'s estimate, rotation first, in its tangent space: the
        graph's, or for a frame the graph does not hold, its keyframe's carried through the measurement plus the
        measurement's own (what the graph would give a pose with that one factor)."""
        measurement = self.measured.get(index)
        if measurement is None:
            return self.graph.covariance(index)
        return self.graph.covariance_through(measurement.keyframe, measurement.T, measurement.sigmas)

    def _update_keyframes(
        self, measurement: Measurement, rel: relpose.RelativePose, confirmed: int
    ) -> tuple[Decision, np.ndarray]:
        """Frame k, measured from keyframe kf (``rel``) with ``confirmed`` pairs, through the keyframe decision
        (``KeyframePolicy``); a map is tried first where none holds the keyframe (``_map_start``). Returns the
        decision and frame k's pose from its keyframe (the map's adjustment of it where it started one)."""
        k, kf = measurement.index, measurement.keyframe
        self.lost_in_a_row = 0 if rel.ok else self.lost_in_a_row + 1
        start = self._map_start(measurement, rel)
        started = start is not None
        measurement = start if started else measurement
        decision = self.policy.decide(self._evidence(k, kf, confirmed, started))
        self._follow(decision, measurement, rel, started)
        self.scale.frame_done(k, self._map_holds(self.keyframe))
        return decision, measurement.T

    def _map_start(self, measurement: Measurement, rel: relpose.RelativePose) -> Measurement | None:
        """Where a map starts from the keyframe and frame k (``_starts_map``; not after ``reinitialise_after``
        lost frames in a row): the frames it waited through located in it, and frame k's measurement as the map's
        adjustment has it (from the keyframe before it in the map); else None."""
        k, kf, T = measurement.index, measurement.keyframe, measurement.T
        if self.lost_in_a_row >= self.config.reinitialise_after or not self._starts_map(k, kf, rel, T):
            return None
        self.waiting.locate_kept(self.map, kf, lambda index: self._in_map(kf, self.estimate(index)))
        before, T_adjusted, sigmas = self._adjusted()
        self.measured[k] = replace(measurement, keyframe=before, T=T_adjusted, sigmas=sigmas)
        return self.measured[k]

    def _follow(self, decision: Decision, measurement: Measurement, rel: relpose.RelativePose, started: bool) -> None:
        """Carry out the ``decision`` on frame k (``measurement``, measured as ``rel``; ``started``: it started a
        map). Frames measured two-view join the graph, those located in the map only as keyframes. A new keyframe
        moves the plane's distance on, joins the map that located it, and where it was lost starts the map again."""
        k, located = measurement.index, rel.model == "pnp"
        if decision.keyframe or not located:
            self._add_measurement(measurement)
        if decision.restart:
            self.previous_keyframe, self.keyframe, self.lost_in_a_row = None, k, 0
        elif decision.keyframe:
            self._advance(k, measurement.keyframe, rel, measurement.T, started)
        if decision.keyframe and located:
            self.graph.refine(KEYFRAME_UPDATES)
        if self.map is not None and self.keyframe == k and not rel.ok:
            self.map = LocalMap(self.config.map)  # tracking starts again from frame k: so does the map

    def _advance(self, k: int, kf: int, rel: relpose.RelativePose, T: np.ndarray, started: bool) -> None:
        """Frame k, measured from keyframe kf as ``T`` (4, 4), becomes the keyframe after the current one: the
        plane's distance moves on to it where it was measured against the current one, and where a map located it
        (and it did not just start one), it joins that map, whose adjustment of it then joins the graph."""
        current = self.keyframe
        if rel.ok and kf == current and not started and self.plane is not None:
            self.plane.moved_on(rel, T)
        self.previous_keyframe, self.keyframe = current, k
        if rel.ok and not started and self._map_holds(kf):
            self.map.add(self._keyframe(k, self.map.pose(kf) @ T))
            self._add_adjusted(k)

    def _evidence(self, k: int, kf: int, confirmed: int, started: bool) -> KeyframeEvidence:
        """What frame k, measured from keyframe kf, showed against the current keyframe."""
        current = self.keyframe
        pairs = shared_tracks(self.history[current][1], self.history[k][1])
        location = self._located_against(current) if self._map_holds(current) else None
        return KeyframeEvidence(
            self.lost_in_a_row, started, len(pairs), self._parallax(current, k, pairs), kf == current, confirmed,
            self.map is not None and not self.map.started, len(self.history[k][1].ids), location,
        )  # fmt: skip

    def _keyframe(self, k: int, T_world_cam: np.ndarray) -> Keyframe:
        """Stored frame k as a keyframe of the map at ``T_world_cam`` (4, 4)."""
        kept, tracks = self.history[k]
        return Keyframe(k, T_world_cam, kept.K, tracks.ids.copy(), tracks.points.copy())

    def _starts_map(self, k: int, kf: int, rel: relpose.RelativePose, T: np.ndarray) -> bool:
        """Whether a map starts (again) from the current keyframe kf and frame k, measured from it as ``T``
        (4, 4): tried at every frame while there is none, so that it starts as soon as the two triangulate
        enough landmarks with a well-determined baseline (``LocalMap.start``). Where the measurement took a
        homography (a dominant plane, such as a far wall, in a scene that need not be one) the essential
        matrix's pose is tried too. The first map's baseline takes its true length where the input has one."""
        if self.map is None or self._map_holds(kf) or kf != self.keyframe or not rel.ok or rel.model == "static":
            return False
        origin = self.graph.pose(kf)
        for candidate in self._start_poses(kf, k, rel, T):
            baseline = self.scale.first_baseline(candidate, kf, k)
            if self.map.start(self._keyframe(kf, origin), self._keyframe(k, origin @ baseline)):
                self.scale.map_started()
                return True
        return False

    def _start_poses(self, kf: int, k: int, rel: relpose.RelativePose, T: np.ndarray) -> Iterator[np.ndarray]:
        """The poses (4, 4) of frame k seen from keyframe kf a map may start from: the measured ``T``, then, where
        that was a homography's, the essential matrix's (computed only if asked for)."""
        yield T
        if rel.model == "homography":
            general = self._general_pose(kf, k, T)
            if general is not None:
                yield general

    def _general_pose(self, kf: int, k: int, T: np.ndarray) -> np.ndarray | None:
        """Frame k seen from keyframe kf (4, 4) by the essential matrix of their confirmed pairs, as long as
        ``T``, or None where it finds no translation."""
        tracks_kf, frame_k = self.history[kf][1], self.history[k][0]
        pairs, points = self._confirmed(kf, k)
        rel = self.two_view.essential(tracks_kf.points[pairs[:, 0]], points, frame_k.K, frame_k.shape)
        if not rel.ok or rel.rotation_only:
            return None
        return with_length(rel.T_c1_c2, float(np.linalg.norm(T[:3, 3])))

    def _adjusted(self) -> tuple[int, np.ndarray, np.ndarray]:
        """The map's newest keyframe seen from the one before it after the bundle adjustment: the index of the one
        before, the pose (4, 4) and its sigmas (6,), ``BUNDLE_GAIN`` times surer than a measurement from as many
        landmarks."""
        before, keyframe = self.map.keyframes[-2:]
        T = np.linalg.inv(before.T_world_cam) @ keyframe.T_world_cam
        seen = int(self.map.known(keyframe.ids).sum())
        sigmas = measurement_sigmas(seen, 1.0, float(np.linalg.norm(T[:3, 3]))) / BUNDLE_GAIN
        return before.index, T, sigmas

    def _add_adjusted(self, k: int) -> None:
        """Keyframe k's pose after the map's bundle adjustment into the graph: a between factor from the keyframe
        before it in the map (``_adjusted``), unless it contradicts the graph (``ADJUSTED_AGREEMENT``: a window
        that adjusted itself away from its measurements)."""
        before, T, sigmas = self._adjusted()
        if self.graph.in_window(before) and self._agrees(before, k, T):
            self.graph.add_between(before, k, T, sigmas)
            self.graph.update(keep=[before, k])

    def _agrees(self, i: int, j: int, T: np.ndarray) -> bool:
        """Whether ``T`` (4, 4), frame j seen from frame i, lies within ``ADJUSTED_AGREEMENT`` of the graph's."""
        G = np.linalg.inv(self.graph.pose(i)) @ self.graph.pose(j)
        turn_deg, share = ADJUSTED_AGREEMENT
        moved = np.linalg.norm(T[:3, 3] - G[:3, 3]) <= share * max(np.linalg.norm(G[:3, 3]), 1e-9)
        return moved and np.degrees(rotation_angle(G[:3, :3].T @ T[:3, :3])) <= turn_deg

    def _parallax(self, i: int, j: int, pairs: np.ndarray) -> float:
        """Median motion (pixels) of the tracks shared by frames i and j."""
        return _median_motion(self.history[i][1], self.history[j][1], pairs)

    def _reference(self, k: int, tracks: Tracks) -> int:
        """The keyframe to measure frame k against: the current one, or, without a map that holds it, the one
        before it while the current one has too little parallax (and the older one still shares enough tracks)."""
        kf, older = self.keyframe, self.previous_keyframe
        if (
            older is None
            or self._map_holds(kf)  # PnP needs no parallax
            or self._parallax(kf, k, shared_tracks(self.history[kf][1], tracks)) >= self.config.min_parallax
        ):
            return kf
        return older if len(shared_tracks(self.history[older][1], tracks)) >= self.config.min_shared_tracks else kf

    def _link_previous_keyframe(self, k: int, reference: int) -> None:
        """An extra factor to the keyframe before the current one when it was not the reference and
        they share enough tracks."""
        j = self.previous_keyframe
        if (
            j is None
            or j == reference
            or self._map_holds(reference)  # located in the map, which holds keyframe j too
            or len(shared_tracks(self.history[j][1], self.history[k][1])) < self.config.min_shared_tracks
        ):
            return
        posed = self._measure(j, k)
        if posed.rel.ok and posed.rel.model != "static":
            parallax = self._parallax(j, k, posed.pairs)
            self.graph.add_between(j, k, posed.T, _sigmas(posed.rel, posed.T, parallax))

    def poses(self) -> np.ndarray:
        """The optimised trajectory (N, 4, 4) ``T_world_cam``: each frame's latest estimate, but a frame from before
        a map where that map located it once it started (its keyframe's latest estimate composed with that pose)."""
        poses = np.stack([self.estimate(index) for index in range(self.frames)])
        for index, (keyframe, T) in self.waiting.located.items():
            poses[index] = self.graph.pose(keyframe) @ T
        return poses
