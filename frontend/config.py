"""The front-end's settings and the magic front-end's detector presets: plain dataclasses that import
no network, so that the command line and ``deepslam.frontend`` load them fast."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal, get_args

import numpy as np

from deepslam.errors import InputError

POINT_BUDGET = 150  # points a front-end reports at most, by default (the oracle's too)
CARRY_FRAMES = 20  # frames a track the detector misses is carried on (``MagicTracker.max_age``)
FOLLOW_RADIUS = 1.5  # px: a followed track snaps to a detection this close to where its patch aligned
PREDICTED_WITHIN = 4.0  # px: a track predicted farther than this from where the homography carries it stays there
TOP_UP_MIN_POINTS, TOP_UP_ENOUGH_POINTS = 40, 80  # S is topped up from below the first until it finds the second
BENCH_REPEATS = 100  # timed repetitions of a network's forward pass in its benchmark; the median is reported
Frontend = Literal["magic", "classical", "oracle"]
FRONTENDS: tuple[str, ...] = get_args(Frontend)


@dataclass(frozen=True)
class PolishConfig:
    """``sigma``: scale (px) of the local mean and deviation ``normalise_contrast`` removes; ``window``:
    Lucas-Kanade window side (px); ``max_move``: a pair whose point moves this far (px) is dropped;
    ``max_return``, ``return_scale``: so is a pair whose polished point, aligned back into the keyframe,
    lands farther from its partner than ``max_return`` px and ``return_scale`` times the pairs' median (image
    noise spreads every pair's return; ``max_return`` None: no backward check); ``warp_threshold``: inlier
    threshold (px) of the homography fitted to the pairs (MAGSAC) that warps the keyframe before aligning, or
    None to align the keyframe as it is; ``retry_gate``: a pair not confirmed from its tracked position is
    aligned again from where the confirmed pairs' homography puts it, if that lies within this many pixels of
    the tracked position (None: no second try; nor is there one without the warp, ``warp_threshold`` None)."""

    sigma: float = 3.0
    window: int = 15
    max_move: float = 1.5
    max_return: float | None = 0.25
    return_scale: float = 3.0
    warp_threshold: float | None = 3.0
    retry_gate: float | None = 3.0


DEFAULT_POLISH = PolishConfig()


@dataclass(frozen=True)
class TrackerConfig:
    """A front-end and its options. The magic front-end runs MagicPoint at the evaluation threshold 0.001
    with at most ``POINT_BUDGET`` points (the oracle's budget), then MagicWarp refined by snapping, and confirms and
    polishes the pairs each pose is measured from; its detector is one of ``DETECTOR_PRESETS`` (S-HA in
    one pass on the image enlarged 2x by default; S is topped up by S-HA on sparse frames). Every documented field
    is a ``deepslam run`` option."""

    frontend: Frontend = field(
        default="magic",
        metadata={"help": "magic: MagicPoint+MagicWarp; classical: Shi-Tomasi+Lucas-Kanade; oracle: true projections"},
    )
    detector: Literal["S", "S-HA"] = field(
        default="S-HA",
        metadata={
            "help": "MagicPoint of the magic front-end: S-HA (adapted to real photographs; one pass) or S "
            "(Synthetic Shapes only; on the image enlarged 2x with two grid shifts, topped up by S-HA)"
        },
    )
    detector_scale: Literal[1, 2] | None = field(
        default=None,
        metadata={
            "help": "MagicPoint detects on the image enlarged this many times (default: the detector's preset, 2; "
            "S at scale 1 averages four grid shifts); S-HA at 1 drifts about twice as much on clean and mildly "
            "noisy images but loses fewer frames under full noise, 10%% faster (docs/results.md)"
        },
    )
    top_up: bool = field(
        default=True,
        metadata={
            "help": f"from a frame where MagicPoint S finds fewer than {TOP_UP_MIN_POINTS} points (corner-poor walls "
            f"such as grass) until it finds {TOP_UP_ENOUGH_POINTS} again, add S-HA's detections (--detector S only)"
        },
    )
    warp_iterations: int = field(
        default=1, metadata={"help": "MagicWarp iterations (magic front-end)", "min": 1, "max": 10}
    )
    refine: bool = field(
        default=True,
        metadata={
            "help": "refine MagicWarp's homography by snapping and a robust fit over the pairs it, the no-motion "
            "and the constant-motion guess snap, so that the motion most detections agree with wins"
        },
    )
    carry: bool | None = field(
        default=None,
        metadata={
            "help": f"report a track the detector misses for up to {CARRY_FRAMES} frames, carried by MagicWarp's "
            "homography and aligned to the frame it was last detected in (default: with --method auto or homography)"
        },
    )
    follow: bool = field(
        default=False,
        metadata={
            "help": "find each track where Lucas-Kanade aligns its patch of the previous frame, starting from where "
            f"MagicWarp's homography carries it, and snap it to a detection within {FOLLOW_RADIUS:g} px of that, so "
            "that parallax does not move it onto a neighbour's detection (magic front-end; default: snapped where the "
            "homography carries it, as in the paper; needs --polish)"
        },
    )
    ransac: bool = field(default=False, metadata={"help": "fundamental-matrix RANSAC on MagicWarp matches"})
    polish: bool = field(
        default=True,
        metadata={
            "help": "confirm and polish the pairs each pose is measured from (a frame and its keyframe) by "
            f"Lucas-Kanade on contrast-normalised images, dropping those it moves {DEFAULT_POLISH.max_move:g} px or "
            "more (after a second try from where the confirmed pairs' homography puts them) or that do not align "
            "back to their keyframe point (magic front-end; --no-polish: correspondences from MagicPoint and "
            "MagicWarp alone)"
        },
    )
    polish_warp: bool = field(
        default=True,
        metadata={
            "help": "before polishing, warp the keyframe by the homography its pairs agree on, so that Lucas-Kanade "
            "compares patches seen from about the same viewpoint (--no-polish-warp: the keyframe as it is)"
        },
    )
    oracle_noise: float = field(
        default=0.5,
        metadata={
            "help": "standard deviation (px) of the Gaussian noise on the oracle's true projections",
            "min": 0,
            "max": 100,
        },
    )
    device: Literal["auto", "cpu", "cuda"] = field(
        default="cpu", metadata={"help": "where the magic front-end's networks run: cpu, cuda, or auto"}
    )
    budget: int = POINT_BUDGET  # points a front-end reports at most

    def __post_init__(self):
        if self.follow and not self.polish:
            raise InputError("following tracks (--follow) aligns the images polishing keeps: drop --no-polish")


Subpixel = Literal["none", "parabola", "centroid", "smoothed"]
SUBPIXEL: tuple[str, ...] = get_args(Subpixel)
GRID_SHIFT_COUNTS = (1, 2, 4)  # heatmaps of the image shifted against the 8-pixel cell grid that MagicPoint averages


@dataclass(frozen=True)
class ExtractionConfig:
    """How MagicPoint turns its heatmap into points.

    ``threshold`` on the heatmap, ``nms_radius`` and ``border`` (pixels), at most ``top_k`` points (None:
    all), ``subpixel`` ("none", "parabola" fit at each peak, "smoothed": the parabola on the heatmap smoothed
    first, or "centroid" of its 3x3 neighbourhood). ``grid_shifts`` 4 averages the heatmaps of the image
    shifted by 0 and 4 pixels in x and y against the cell grid (3-4x the time; 2: the diagonal shift only), so
    that detections move with the image more faithfully. ``upsample`` s > 1 detects on the image enlarged s
    times (bilinear; NMS radius and border scale with it, points come back in input pixels), at about s^2
    the time. Named presets: ``EXTRACTION_PRESETS`` (a network's own, evaluations'), ``DETECTOR_PRESETS``
    (the magic front-end's).
    """

    threshold: float = 0.015
    nms_radius: int = 4
    border: int = 4
    top_k: int | None = None
    grid_shifts: int = 1
    subpixel: Subpixel = "none"
    upsample: int = 1

    def __post_init__(self):
        if self.grid_shifts not in GRID_SHIFT_COUNTS:
            raise InputError(f"grid_shifts must be one of {list(GRID_SHIFT_COUNTS)}, got {self.grid_shifts}")
        if not isinstance(self.upsample, int) or not 1 <= self.upsample <= 4:
            raise InputError(f"upsample must be an integer from 1 to 4, got {self.upsample}")
        if (
            not np.isfinite(self.threshold)
            or self.nms_radius < 0
            or self.border < 0
            or (self.top_k is not None and self.top_k < 1)
        ):
            raise InputError(
                f"the detection threshold must be finite, nms_radius and border at least 0 and top_k at least 1, "
                f"got {self.threshold}, {self.nms_radius}, {self.border}, {self.top_k}"
            )
        if self.subpixel not in SUBPIXEL:
            raise InputError(f"subpixel must be one of {', '.join(SUBPIXEL)}, got {self.subpixel!r}")


EXTRACTION_PRESETS: dict[str, ExtractionConfig] = {
    "default": ExtractionConfig(),  # MagicPoint S and L: the paper's threshold, whole pixels
    "S-HA": ExtractionConfig(subpixel="smoothed"),  # S-HA's own: chosen on the validation photographs (model card)
    # the Synthetic Shapes table (and training's validation on it): no border removal, as the ground truth has
    # corners up to the image edge (2.6% of them lie within 4 px of it)
    "shapes": ExtractionConfig(threshold=0.001, border=0),
    "photo validation": ExtractionConfig(threshold=0.001, subpixel="centroid"),  # S-HA training's repeatability
}
"""A network's own extraction (by variant; "default" for the others) and the evaluations'."""

DETECTOR_PRESETS: dict[str, ExtractionConfig] = {
    # S needs the work-arounds on photographs: the image enlarged 2x, two grid shifts
    "S": ExtractionConfig(threshold=0.001, top_k=POINT_BUDGET, grid_shifts=2, subpixel="parabola", upsample=2),
    # one pass on the image enlarged 2x: half the drift of the image as it is, clean or mildly noisy
    "S-HA": ExtractionConfig(threshold=0.001, top_k=POINT_BUDGET, subpixel="parabola", upsample=2),
}
"""How the magic front-end runs each MagicPoint (``top_k`` becomes ``TrackerConfig.budget``);
``TrackerConfig.detector_scale`` overrides ``upsample`` (S at scale 1 then averages four grid shifts). S-HA
keeps the plain parabola here: its own default, the parabola on the smoothed heatmap, localises better alone
but drew end to end (S-HA model card)."""


@dataclass(frozen=True)
class MagicWarpConfig:
    """Encoder widths (``blocks`` VGG blocks per stage, a 2x2 max-pool after each stage), the grid
    the features are pooled to before the fully connected layers, and the hidden FC width."""

    widths: tuple[int, ...] = field(
        default=(64, 64, 128, 128, 128, 128),
        metadata={
            "help": "encoder widths, --blocks VGG blocks per 2x2 max-pool (a new run only: a resumed run keeps "
            "its checkpoint's shape)",
            "min": 1,
            "max": 4096,
        },
    )
    pooled: tuple[int, int] = (3, 5)
    hidden: int = field(
        default=512, metadata={"help": "width of the hidden fully connected layer", "min": 1, "max": 8192}
    )
    blocks: int = field(
        default=2,
        metadata={
            "help": "VGG blocks per stage of the encoder; with --init, weights of fewer blocks per stage are "
            "deepened: the new blocks start as identities",
            "min": 1,
            "max": 8,
        },
    )

    def __post_init__(self):
        if not self.widths or min(self.widths) < 1 or min(self.pooled) < 1 or self.hidden < 1:
            raise InputError(f"MagicWarp needs positive widths, pooled grid and hidden width, got {self}")
        if self.blocks < 1 or len(self.widths) % self.blocks:
            raise InputError(
                f"MagicWarp needs a whole number of stages of at least one block: {len(self.widths)} "
                f"widths do not make stages of {self.blocks} blocks"
            )
