"""The odometry's and the pipeline's settings: plain dataclasses that import no solver, so that the command line and
``deepslam.backend`` load them fast."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig

Method = Literal["auto", "homography", "essential", "pycolmap"]
METHODS: tuple[str, ...] = get_args(Method)
MIN_MATCHES = 8  # fewer matches than this: no relative pose
Scale = Literal["map", "gt", "plane", "none"]
SCALES: tuple[str, ...] = get_args(Scale)
MAX_TURN_OF_TRANSLATION = 60.0  # degrees a fallback's translation may lie from the motion so far


@dataclass(frozen=True)
class GraphConfig:
    prior_sigmas: tuple[float, ...] = (1e-4,) * 6
    huber_k: float = 1.345
    relinearize_threshold: float = 0.001
    window: int | None = 50  # frames a pose stays after it was last used; None: never marginalised


@dataclass(frozen=True)
class MapConfig:
    """The local map of ``scale="map"`` (``deepslam.backend.mapping``): triangulation, PnP, bundle adjustment."""

    window: int = 6  # keyframes the local bundle adjustment optimises (the oldest held, its distance to the next kept)
    min_located: int = 12  # fewer landmarks matched in a frame: no PnP pose (the two-view pose is tried)
    pnp_px: float = 2.0  # PnP RANSAC's reprojection threshold (px)
    max_reprojection_px: float = 3.0  # a landmark observation farther than this from its projection is dropped
    # rays meeting at a smaller angle (in pixels: radians x focal length) make no landmark; a keyframe for what
    # the map no longer covers waits for a baseline this wide while PnP still locates min_located landmarks
    min_triangulation_px: float = 6.0
    min_initial_landmarks: int = 30  # the map starts once two keyframes triangulate this many landmarks ...
    min_initial_px: float = 10.0  # ... seen from at least this angle apart (pixels) ...
    max_start_deg: float = 3.0  # ... and the direction between the two is known to this (1 sigma, degrees)
    start_within: int = 20  # frames before the first map whose lengths come from the truth (where known)
    coverage: float = (
        0.7  # a frame locating fewer than this share of what the first frame after its keyframe located ...
    )
    min_located_share: float = 0.3  # ... or fewer than this share of its tracks makes a keyframe
    huber_px: float = 1.345  # the bundle adjustment's robust loss (px, sigma 1 px)
    iterations: int = 10  # Levenberg-Marquardt iterations a bundle adjustment takes at most
    fixed_keyframes: int = 6  # keyframes that left the window last, held fixed where they observe its landmarks
    predict: bool = True  # the front-end looks for a landmark's track where the map projects it (constant motion)
    # each frame located between keyframes joins the bundle adjustment at once (its pose: the adjusted one), with
    # the frames located since the keyframe before the current one; off: keyframes only (faster)
    adjust_frames: bool = True
    # the solver of a window adjustment (not of the first map's, whose uncertainty gtsam measures): "pycolmap" (Ceres,
    # 1.3-2x faster a window) or "gtsam" (Levenberg-Marquardt, the same problem)
    adjuster: str = "pycolmap"

    def __post_init__(self):
        if self.window < 2 or self.min_located < 6 or self.min_initial_landmarks < self.min_located:
            raise InputError(
                f"the map's window must hold at least 2 keyframes, PnP at least 6 landmarks and the first map at "
                f"least as many, got {self.window}, {self.min_located}, {self.min_initial_landmarks}"
            )
        if self.adjuster not in ("gtsam", "pycolmap"):
            raise InputError(f"the map's adjuster must be gtsam or pycolmap, got {self.adjuster!r}")
        if self.fixed_keyframes < 0:
            raise InputError(f"the map's fixed keyframes must be 0 or more, got {self.fixed_keyframes}")
        thresholds = (
            self.pnp_px,
            self.max_reprojection_px,
            self.min_triangulation_px,
            self.min_initial_px,
            self.max_start_deg,
        )
        if not (min(thresholds) > 0 and 0 < self.coverage <= 1 and 0 <= self.min_located_share <= 1):
            raise InputError(
                f"the map's pixel thresholds must be positive and its coverage in (0, 1], got {thresholds}, "
                f"{self.coverage}, {self.min_located_share}"
            )


@dataclass(frozen=True)
class OdometryConfig:
    """Every documented field is an option of ``deepslam run`` and ``deepslam replay``."""

    method: Method = field(
        default="auto",
        metadata={
            "help": "relative pose: auto (for each pair of frames, ORB-SLAM's scores choose a homography, the "
            "dominant plane, or an essential matrix, which also wins where pairs off the plane contradict the "
            "homography's pose), homography, essential, or pycolmap"
        },
    )
    scale: Scale = field(
        default="map",
        metadata={
            "help": "monocular scale: map = a local map of triangulated landmarks carries the scale of its first "
            "baseline (its true length where the input has truth, else 1); gt = ground-truth step lengths "
            "(evaluation); plane = known distance to the dominant plane; none = up to scale (the plane's distance "
            "taken as 1; drift after Sim(3) alignment only)"
        },
    )
    plane_distance: float | None = field(
        default=None,
        metadata={"help": "first camera's distance (m) to the dominant plane for --scale plane (simulation: known)"},
    )
    keyframe_parallax: float = field(
        default=10.0, metadata={"help": "median track motion (px) since the keyframe that makes a new keyframe"}
    )
    max_rotation_jump: float = field(
        default=10.0,
        metadata={
            "help": "where a measured pose turns more than this many degrees away from the previous frame's estimate "
            "(both seen from the same keyframe), the homography's or the essential matrix's pose is taken instead if "
            f"it agrees with that estimate (rotation within this, translation within {MAX_TURN_OF_TRANSLATION:g} deg); "
            "raise it for cameras that turn this fast between frames, 0 turns it off",
            "min": 0,
        },
    )
    vote_flow_px: float = field(
        default=3.0,
        metadata={
            "help": "a two-view pose measured over less median track motion (px) than this leads neither the next "
            "pose nor the plane's normal (at 1-2 px a homography's decomposition can be tens of degrees off, and the "
            "next frames would follow it), and pairs a homography and an essential matrix explain with different "
            "motions take the essential matrix's pose where no motion so far tells them apart; 0: every pose leads, "
            "such pairs are lost (docs/experiments.md: 3 drifts less)",
            "min": 0,
        },
    )
    min_parallax: float = 3.0  # below this median motion (px) to the keyframe, measure against the one before
    min_shared_tracks: int = 20  # fewer tracks shared with the keyframe make a new keyframe too
    reinitialise_after: int = 3  # this many lost frames in a row: the current frame becomes the keyframe
    covariance: bool = True  # compute the latest pose's marginal covariance every frame
    graph: GraphConfig = GraphConfig()  # the pose graph's noise and window
    map: MapConfig = MapConfig()  # the local map of scale "map"

    def __post_init__(self):
        if self.method not in METHODS:
            raise InputError(f"unknown method {self.method!r}; expected one of {', '.join(METHODS)}")
        if self.scale not in SCALES:
            raise InputError(f"unknown scale {self.scale!r}; expected one of {', '.join(SCALES)}")
        if not (self.keyframe_parallax > 0 and self.min_parallax >= 0 and self.min_shared_tracks >= MIN_MATCHES):
            raise InputError(
                f"keyframe parallax must be positive, min parallax at least 0 and min shared tracks at least "
                f"{MIN_MATCHES}, got {self.keyframe_parallax}, {self.min_parallax}, {self.min_shared_tracks}"
            )
        if self.plane_distance is not None and not self.plane_distance > 0:
            raise InputError(f"the distance to the dominant plane must be positive, got {self.plane_distance}")
        if not self.vote_flow_px >= 0:
            raise InputError(f"the flow a pose needs to lead the next must be at least 0 px, got {self.vote_flow_px}")
        if not self.max_rotation_jump >= 0:
            raise InputError(f"the largest rotation jump must be at least 0 degrees, got {self.max_rotation_jump}")
        if self.reinitialise_after < 1:
            raise InputError(f"reinitialise_after must be at least 1, got {self.reinitialise_after}")


@dataclass(frozen=True)
class PipelineConfig:
    """The front-end and the odometry. The default scale is the local map's (``scale="map"``), whose unit is the
    first baseline unless the caller passes its true length: a camera of one's own has no ground-truth step
    lengths."""

    tracker: TrackerConfig = TrackerConfig()
    odometry: OdometryConfig = OdometryConfig()
