"""Front-ends: turn each frame into tracked points with track ids, behind one interface.

- ``MagicTracker``: MagicPoint detections, MagicWarp between consecutive point images (refined by
  snapping and one robust homography fit over its pairs and those of the no-motion and constant-motion
  guesses), nearest-neighbour snapping to where that homography, or the caller's prediction (a map's
  landmarks), puts each track (optionally after Lucas-Kanade followed each track from the previous
  frame, and a fundamental-matrix RANSAC on top); a track the detector misses is carried on by that
  homography and aligned to the frame it was last detected in. The pairs a pose is measured from (a frame and
  its keyframe) are confirmed and polished by ``frontend.polish`` (``confirm``).
- ``ClassicalTracker``: Shi-Tomasi corners tracked with pyramidal Lucas-Kanade (forward-backward
  checked), replenished when tracks run low: what a practitioner would build.
- ``OracleTracker``: the true projections of world landmarks with pixel noise and the same
  detection budget: the limit any front-end can reach with this back-end.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field, replace
from typing import Callable

import cv2
import numpy as np

from deepslam.errors import InputError
from deepslam.frontend.config import (
    CARRY_FRAMES,
    DEFAULT_POLISH,
    DETECTOR_PRESETS,
    FOLLOW_RADIUS,
    FRONTENDS,
    POINT_BUDGET,
    PREDICTED_WITHIN,
    TOP_UP_ENOUGH_POINTS,
    TOP_UP_MIN_POINTS,
    PolishConfig,
    TrackerConfig,
)
from deepslam.frontend.magicpoint import MagicPoint
from deepslam.frontend.magicwarp import MIN_POINTS, MagicWarp, match, refine
from deepslam.frontend.nets import resolve_device
from deepslam.frontend.polish import follow, normalise_contrast, polish
from deepslam.geometry import in_image, warp_points


@dataclass
class Tracks:
    """One frame's tracked points: pixels (N, 2) float64, track ids (N,) int64, scores (N,); ``appearance``:
    the frame as the front-end compares it with later frames (``Tracker.confirm``; uint8 (H, W)), or None."""

    points: np.ndarray
    ids: np.ndarray
    scores: np.ndarray
    appearance: np.ndarray | None = None

    @staticmethod
    def empty() -> "Tracks":
        return Tracks(np.zeros((0, 2)), np.zeros(0, np.int64), np.zeros(0))


@dataclass
class Predicted:
    """Where a model of the scene expects tracks in the next frame: track ids (M,) int64 and pixels (M, 2), e.g.
    a local map's landmarks projected from the pose the camera's motion so far predicts."""

    ids: np.ndarray
    pixels: np.ndarray


@dataclass
class Truth:
    """What a simulator knows of a frame, for the oracle: visible landmark ids (N,) and pixels (N, 2)."""

    ids: np.ndarray
    pixels: np.ndarray


class Tracker:
    """Interface: ``track(image) -> Tracks`` for each frame in order (image uint8 (H, W)); ids persist while
    a point is followed. Before a frame the caller may say where it expects some of the tracks (``expect``); a
    front-end may start its search for them there (the magic one does) or ignore it."""

    def __init__(self):
        self.previous = Tracks.empty()
        self._next_id = 0
        self.timings_ms: dict[str, float] = {}  # the last frame's stages, where a front-end times them

    def _new_ids(self, count: int) -> np.ndarray:
        ids = np.arange(self._next_id, self._next_id + count, dtype=np.int64)
        self._next_id += count
        return ids

    def _link(self, points: np.ndarray, scores: np.ndarray, pairs: np.ndarray) -> Tracks:
        """Tracks for ``points`` where ``pairs`` (K, 2) links previous indices to current ones."""
        ids = np.full(len(points), -1, np.int64)
        ids[pairs[:, 1]] = self.previous.ids[pairs[:, 0]]
        fresh = ids < 0
        ids[fresh] = self._new_ids(int(fresh.sum()))
        self.previous = Tracks(np.asarray(points, np.float64), ids, np.asarray(scores, np.float64))
        return self.previous

    def track(self, image: np.ndarray) -> Tracks:
        raise NotImplementedError

    def expect(self, predicted: Predicted) -> None:
        """Where the caller expects tracks in the frame ``track`` is given next; ignored unless a front-end
        overrides this."""

    def confirm(self, reference: Tracks, current: Tracks, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The pairs (K, 2) of ``reference`` and ``current`` indices a pose may be measured from, and the
        current frame's points (K, 2) for them: all, where they were tracked (a front-end may check
        and polish them)."""
        return pairs, current.points[pairs[:, 1]]


def _subset_pairs(pairs: np.ndarray, rows: np.ndarray, columns: np.ndarray | None = None) -> np.ndarray:
    """``pairs`` (K, 2) of indices into subsets, as indices into the sets: ``rows`` (and ``columns``, where given)
    hold each subset's indices."""
    pairs = pairs.copy()
    pairs[:, 0] = rows[pairs[:, 0]]
    if columns is not None:
        pairs[:, 1] = columns[pairs[:, 1]]
    return pairs


def _ransac_filter(pairs: np.ndarray, a: np.ndarray, b: np.ndarray, threshold: float = 1.0) -> np.ndarray:
    """Keep the pairs consistent with one fundamental matrix (MAGSAC); all of them if too few."""
    if len(pairs) < 8:
        return pairs
    _, mask = cv2.findFundamentalMat(a[pairs[:, 0]], b[pairs[:, 1]], cv2.USAC_MAGSAC, threshold, 0.999)
    return pairs if mask is None else pairs[mask.ravel().astype(bool)]


class MagicTracker(Tracker):
    """MagicPoint + MagicWarp tracking. MagicWarp estimates H between consecutive point images;
    every live track's position is carried by it and snapped to the nearest new detection within
    ``max_dist`` pixels. A track missed by the detector lives on, carried by H, for ``max_age``
    frames; with ``carry`` and ``polish`` it is also reported (score 0) where Lucas-Kanade aligns it with the
    frame it was last detected in (``_align_carried``; without ``polish``, where H carries it), so that a
    keyframe keeps its tracks through the detector's misses. A frame reports at most ``budget`` points: the
    detections that continue a track, then carried tracks (the most recently detected first), then new
    detections (all of which are followed, reported or not), so that new points do not crowd out the tracks
    a keyframe shares.
    ``iterations`` applies MagicWarp iteratively; ``refine`` polishes its H by snapping and a robust
    homography fit over its pairs and those the previous H and the identity snap (``_homography``);
    ``ransac`` adds a fundamental-matrix check; ``polish`` (a ``PolishConfig``, or None for a purely
    geometric tracker) confirms and polishes the pairs a pose is measured from (``confirm``); ``follow`` (px,
    with ``polish``) finds each track where Lucas-Kanade aligns it from the previous frame before snapping
    (``_snap``). Tracks the caller ``expect``s somewhere (a map's landmarks) are looked for there instead of
    where the homography carries them (``_place``)."""

    def __init__(
        self,
        detector: MagicPoint | ToppedUpDetector,
        warp: MagicWarp,
        max_dist: float = 3.0,
        iterations: int = 1,
        ransac: bool = False,
        max_age: int = CARRY_FRAMES,
        refine: bool = True,
        carry: bool = True,
        budget: int = POINT_BUDGET,
        polish: PolishConfig | None = DEFAULT_POLISH,
        follow: float | None = None,
    ):
        super().__init__()
        if iterations < 1 or not max_dist > 0 or max_age < 0 or budget < 1:
            raise InputError(
                f"MagicWarp iterations and the budget must be at least 1, max_dist positive and max_age at "
                f"least 0, got {iterations}, {budget}, {max_dist}, {max_age}"
            )
        self.detector, self.warp = detector, warp
        self.max_dist, self.iterations, self.ransac, self.max_age = max_dist, iterations, ransac, max_age
        self.refine, self.carry, self.budget, self.polish = refine, carry, budget, polish
        self.follow = follow if polish is not None else None  # following aligns the frames polishing keeps
        self.detections = np.zeros((0, 2))  # the previous frame's detections, MagicWarp's input
        self.last_homography = np.eye(3)
        self.live = np.zeros((0, 2))  # positions of live tracks (detected or carried)
        self.live_ids = np.zeros(0, np.int64)
        self.live_age = np.zeros(0, np.int64)  # frames since last detected
        self.live_anchor = np.zeros((0, 2))  # where each live track was last detected
        self.appearances: list[np.ndarray] = []  # the last max_age + 1 frames as polishing sees them, oldest first
        self.expected: Predicted | None = None  # where the caller expects tracks in the next frame (``expect``)

    def expect(self, predicted: Predicted) -> None:
        self.expected = predicted

    def _homography(self, points: np.ndarray, image_shape: tuple[int, int]) -> np.ndarray:
        """H (3, 3) from the previous frame's detections to ``points`` (N, 2). With ``refine``: fitted robustly
        to the pairs that MagicWarp's estimate, the previous frame's H (constant motion) and the identity (no
        motion) snap (``frontend.magicwarp.refine``), so that the motion most detections agree with wins;
        without, MagicWarp's estimate as it is. With fewer than ``MIN_POINTS`` points in either frame
        MagicWarp has nothing to go on: the previous H and the identity are the only guesses."""
        enough = min(len(self.detections), len(points)) >= MIN_POINTS
        guesses = (
            [self.warp.estimate(self.detections, points, image_shape, self.iterations, min_support=0.0)]
            if enough
            else []
        )
        if not self.refine:
            return guesses[0] if guesses else self.last_homography
        return refine(self.detections, points, guesses + [self.last_homography, np.eye(3)])

    def track(self, image: np.ndarray) -> Tracks:
        started = time.perf_counter()
        detections = self.detector.detect(image)
        detected = warped = time.perf_counter()
        points = detections[:, :2].astype(np.float64)
        pairs = np.zeros((0, 2), np.int64)
        appearance = normalise_contrast(image, self.polish.sigma) if self.polish else None
        if len(self.live) and len(points):
            if len(self.detections):
                self.last_homography = self._homography(points, image.shape)
            warped = time.perf_counter()
            before = self.live
            self.live = warp_points(self.live, self.last_homography)
            self._place(self.expected)
            pairs = self._snap(before, points, appearance)
            if self.ransac:
                pairs = _ransac_filter(pairs, self.live, points)
        matched = time.perf_counter()
        self.timings_ms = {
            "magicpoint": 1e3 * (detected - started),
            "magicwarp": 1e3 * (warped - detected),
            "match": 1e3 * (matched - warped),
        }
        ids = np.full(len(points), -1, np.int64)
        ids[pairs[:, 1]] = self.live_ids[pairs[:, 0]]
        fresh = ids < 0
        ids[fresh] = self._new_ids(int(fresh.sum()))
        missed = np.ones(len(self.live), bool)
        missed[pairs[:, 0]] = False
        keep = missed & (self.live_age < self.max_age)
        continued = int((~fresh).sum())
        reported = keep & self.carry & in_image(self.live, image.shape, margin=0.5)
        if appearance is not None:
            reported &= self._align_carried(reported, appearance)
            self.timings_ms["polish_carried"] = 1e3 * (time.perf_counter() - matched)
        reported &= np.cumsum(reported) <= self.budget - continued  # live tracks are ordered by last detection
        shown = ~fresh | (np.cumsum(fresh) <= self.budget - continued - int(reported.sum()))
        self.previous = Tracks(
            np.vstack([points[shown], self.live[reported]]),
            np.concatenate([ids[shown], self.live_ids[reported]]),
            np.concatenate([detections[shown, 2], np.zeros(reported.sum())]).astype(np.float64),
            appearance,
        )
        self.detections = points
        self.live = np.vstack([points, self.live[keep]])
        self.live_ids = np.concatenate([ids, self.live_ids[keep]])
        self.live_age = np.concatenate([np.zeros(len(points), np.int64), self.live_age[keep] + 1])
        self.live_anchor = np.vstack([points, self.live_anchor[keep]])
        if appearance is not None:
            self.appearances = (self.appearances + [appearance])[-(self.max_age + 1) :]
        self.expected = None  # a prediction holds for one frame
        return self.previous

    def _place(self, predicted: Predicted | None) -> None:
        """Move the live tracks ``predicted`` holds from where the homography carried them to where it expects
        them, if within ``PREDICTED_WITHIN`` px (farther, the prediction's motion or depth is more likely off than
        the homography): a point off the homography's plane moves by its own depth, which a map knows and the
        homography does not."""
        if predicted is None or not len(predicted.ids):
            return
        _, live, expected = np.intersect1d(self.live_ids, predicted.ids, return_indices=True)
        near = np.linalg.norm(predicted.pixels[expected] - self.live[live], axis=1) <= PREDICTED_WITHIN
        self.live[live[near]] = predicted.pixels[expected[near]]

    def _snap(self, before: np.ndarray, points: np.ndarray, appearance: np.ndarray | None) -> np.ndarray:
        """Pairs (K, 2) of live tracks and ``points`` (M, 2), this frame's detections: with ``follow``, each live
        track is first found where Lucas-Kanade aligns its patch of the previous frame (around ``before`` (N, 2),
        its position there), starting from where the homography carried it (``self.live``), and snapped to a
        detection within ``follow`` px of that (``frontend.polish.follow``); the tracks it cannot follow, and
        all without ``follow``, snap to a detection within ``max_dist`` px of where the homography carried them.
        Parallax moves a point off the homography's prediction and onto a neighbour's detection; the
        image does not."""
        if self.follow is None or appearance is None or not self.appearances:
            return match(self.live, points, np.eye(3), self.max_dist)
        found, followed = follow(self.appearances[-1], appearance, before, self.live)
        self.live[followed] = found[followed]
        pairs = _subset_pairs(match(self.live[followed], points, np.eye(3), self.follow), np.nonzero(followed)[0])
        free = np.ones(len(points), bool)
        free[pairs[:, 1]] = False
        rest = _subset_pairs(
            match(self.live[~followed], points[free], np.eye(3), self.max_dist),
            np.nonzero(~followed)[0],
            np.nonzero(free)[0],
        )
        return np.vstack([pairs, rest])

    def _align_carried(self, carried: np.ndarray, appearance: np.ndarray) -> np.ndarray:
        """Move the live tracks ``carried`` (mask (N,)) from where the homography carried them to where
        Lucas-Kanade aligns the frame they were last detected in, around that detection, with this frame's
        ``appearance`` (``frontend.polish.polish``: per frame of detection, that frame warped by the pairs'
        homography first, and a second try from the confirmed ones' homography). Returns the mask (N,) of the
        tracks it confirmed (the others stay live where the homography carried them, unreported); anchoring to
        the detection keeps errors from adding up from frame to frame. Without ``confirm``'s backward check:
        checking carried tracks too measured no better (S-HA, circle, 96 runs: a draw; docs/experiments.md,
        0.11.0)."""
        config = replace(self.polish, max_return=None)
        confirmed = carried.copy()
        for age in np.unique(self.live_age[carried]):  # the detection was age + 1 frames ago
            index = np.nonzero(carried & (self.live_age == age))[0]
            detected_in = self.appearances[-1 - int(age)]
            moved, ok = polish(detected_in, appearance, self.live_anchor[index], self.live[index], config)
            self.live[index[ok]] = moved[ok]
            confirmed[index[~ok]] = False
        return confirmed

    def confirm(self, reference: Tracks, current: Tracks, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """With ``polish``: only the pairs Lucas-Kanade confirms between the two frames' contrast-normalised
        images (the reference warped by the pairs' homography), at the positions it polished them to
        (``frontend.polish.polish``)."""
        if self.polish is None or reference.appearance is None or current.appearance is None:
            return super().confirm(reference, current, pairs)
        points, confirmed = polish(
            reference.appearance,
            current.appearance,
            reference.points[pairs[:, 0]],
            current.points[pairs[:, 1]],
            self.polish,
        )
        return pairs[confirmed], points[confirmed]


class ClassicalTracker(Tracker):
    """Shi-Tomasi + pyramidal Lucas-Kanade with a forward-backward check (``fb_max`` pixels)."""

    def __init__(self, budget: int = POINT_BUDGET, min_distance: int = 6, fb_max: float = 1.0, quality: float = 0.01):
        super().__init__()
        self.budget, self.min_distance, self.fb_max, self.quality = budget, min_distance, fb_max, quality
        self.previous_image: np.ndarray | None = None
        self.lk = dict(
            winSize=(15, 15), maxLevel=2, criteria=(cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.03)
        )

    def _detect(self, image: np.ndarray, existing: np.ndarray, count: int) -> np.ndarray:
        mask = np.full(image.shape, 255, np.uint8)
        for x, y in existing:
            cv2.circle(mask, (int(round(x)), int(round(y))), self.min_distance, 0, -1)
        corners = cv2.goodFeaturesToTrack(image, count, self.quality, self.min_distance, mask=mask)
        return np.zeros((0, 2)) if corners is None else corners.reshape(-1, 2).astype(np.float64)

    def track(self, image: np.ndarray) -> Tracks:
        pairs = np.zeros((0, 2), np.int64)
        kept = np.zeros((0, 2))
        if self.previous_image is not None and len(self.previous.points):
            p0 = self.previous.points.astype(np.float32).reshape(-1, 1, 2)
            p1, status, _ = cv2.calcOpticalFlowPyrLK(self.previous_image, image, p0, None, **self.lk)
            back, status_back, _ = cv2.calcOpticalFlowPyrLK(image, self.previous_image, p1, None, **self.lk)
            good = (status.ravel() == 1) & (status_back.ravel() == 1)
            good &= np.linalg.norm((back - p0).reshape(-1, 2), axis=1) < self.fb_max
            p1 = p1.reshape(-1, 2)
            good &= in_image(p1, image.shape, margin=0.5)
            kept = p1[good].astype(np.float64)
            pairs = np.stack([np.nonzero(good)[0], np.arange(good.sum())], 1)
        fresh = (
            self._detect(image, kept, self.budget - len(kept)) if len(kept) < self.budget * 0.7 else np.zeros((0, 2))
        )
        self.previous_image = image
        points = np.vstack([kept, fresh])
        return self._link(points, np.ones(len(points)), pairs)


@dataclass
class OracleTracker(Tracker):
    """True landmark projections with Gaussian pixel noise ``noise_px`` and at most ``budget``
    points, keeping existing tracks first (ids are the landmark ids). ``landmarks`` returns the visible
    landmarks of the frame being tracked: an evaluation that has the simulator's truth hands it over
    (``deepslam.backend.evaluation.truth``)."""

    landmarks: Callable[[], Truth]
    budget: int = POINT_BUDGET
    noise_px: float = 0.5
    seed: int = 0
    rng: np.random.Generator = field(init=False)

    def __post_init__(self):
        super().__init__()
        self.rng = np.random.default_rng(self.seed)

    def track(self, image: np.ndarray) -> Tracks:
        truth = self.landmarks()
        tracked = np.isin(truth.ids, self.previous.ids)
        order = np.concatenate([np.nonzero(tracked)[0], self.rng.permutation(np.nonzero(~tracked)[0])])[: self.budget]
        points = truth.pixels[order] + self.rng.normal(0, self.noise_px, (len(order), 2))
        self.previous = Tracks(points, truth.ids[order].astype(np.int64), np.ones(len(order)))
        return self.previous


@dataclass
class ToppedUpDetector:
    """``primary``'s detections; from a frame where it finds fewer than ``min_points`` until one where it
    finds ``enough_points`` again, ``secondary``'s that lie farther than ``radius`` pixels from all of them
    follow, up to ``top_k`` in all (float32 (N, 3) [x, y, score], the primary's first). Corner-poor walls
    such as grass, where MagicPoint S finds a handful of points, then keep enough to track; the two
    thresholds keep the set of detectors from flipping frame to frame, which would break the tracks."""

    primary: MagicPoint
    secondary: MagicPoint
    min_points: int = TOP_UP_MIN_POINTS
    enough_points: int = TOP_UP_ENOUGH_POINTS
    radius: float = 4.0
    top_k: int = POINT_BUDGET
    topping_up: bool = field(default=False, init=False)  # the last frame was topped up

    def detect(self, image: np.ndarray) -> np.ndarray:
        points = self.primary.detect(image)
        self.topping_up = len(points) < (self.enough_points if self.topping_up else self.min_points)
        if not self.topping_up:
            return points
        extra = self.secondary.detect(image)
        if len(points):
            distance = np.linalg.norm(extra[:, None, :2] - points[None, :, :2], axis=2).min(axis=1)
            extra = extra[distance > self.radius]
        return np.vstack([points, extra])[: self.top_k]


def _shipped(variant: str, config: TrackerConfig) -> MagicPoint:
    """The shipped MagicPoint ``variant`` as the magic front-end runs it (``DETECTOR_PRESETS``)."""
    extraction = replace(DETECTOR_PRESETS[variant], top_k=config.budget)
    if config.detector_scale is not None:
        grid_shifts = (4 if config.detector_scale == 1 else 2) if variant == "S" else extraction.grid_shifts
        extraction = replace(extraction, upsample=config.detector_scale, grid_shifts=grid_shifts)
    return MagicPoint.pretrained(variant, extraction=extraction, device=resolve_device(config.device))


def magic_detector(config: TrackerConfig) -> MagicPoint | ToppedUpDetector:
    """The detector of the magic front-end: the shipped MagicPoint of ``config.detector``, topped up by
    S-HA (on the image as it is) where S finds too few points when ``config.top_up`` is set."""
    detector = _shipped(config.detector, config)
    if config.detector == "S" and config.top_up:
        return ToppedUpDetector(detector, _shipped("S-HA", replace(config, detector_scale=1)), top_k=config.budget)
    return detector


def _polish_config(config: TrackerConfig) -> PolishConfig | None:
    """The polishing ``config`` asks for, or None."""
    if not config.polish:
        return None
    return DEFAULT_POLISH if config.polish_warp else replace(DEFAULT_POLISH, warp_threshold=None)


def make_tracker(config: TrackerConfig, carry_default: bool = True) -> Tracker:
    """The front-end ``config`` describes, with the shipped networks for "magic"; ``carry_default`` is
    what ``config.carry`` None means (the caller knows whether poses come from the dominant plane)."""
    if config.frontend == "magic":
        from deepslam.frontend.magicwarp import MagicWarp

        detector = magic_detector(config)
        carry = carry_default if config.carry is None else config.carry
        return MagicTracker(
            detector,
            MagicWarp.pretrained(device=resolve_device(config.device)),
            iterations=config.warp_iterations,
            ransac=config.ransac,
            refine=config.refine,
            carry=carry,
            budget=config.budget,
            polish=_polish_config(config),
            follow=FOLLOW_RADIUS if config.follow else None,
        )
    if config.frontend == "classical":
        return ClassicalTracker(budget=config.budget)
    if config.frontend == "oracle":
        raise InputError("the oracle front-end needs the simulator's landmarks: evaluation runs only")
    raise InputError(f"unknown front-end {config.frontend!r}; expected one of {', '.join(FRONTENDS)}")
