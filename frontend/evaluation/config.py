"""What the front-end's evaluations cover (``deepslam eval detector / warp / realimages``): plain dataclasses
that import no network; the evaluation functions take their defaults from them."""

from __future__ import annotations

from dataclasses import dataclass, field

SEED_HELP = {"help": "seed of the evaluation data", "min": 0, "max": 2**32 - 1}


@dataclass(frozen=True)
class DetectorEvalConfig:
    per_category: int = field(
        default=1000, metadata={"help": "images per category (paper: 1000)", "min": 1, "max": 100_000}
    )
    sweep_per_category: int = field(
        default=50,
        metadata={"help": "images per category for the noise-magnitude and noise-type sweeps", "min": 1, "max": 10_000},
    )
    seed: int = field(default=0, metadata=SEED_HELP)


@dataclass(frozen=True)
class WarpEvalConfig:
    runs: int = field(default=50, metadata={"help": "random point sets per cell (paper: 50)", "min": 1, "max": 10_000})
    seed: int = field(default=0, metadata=SEED_HELP)


@dataclass(frozen=True)
class RealImagesConfig:
    frames: int = field(default=20, metadata={"help": "frames per photograph sequence", "min": 2, "max": 1000})
    jitter: float = field(
        default=0.0,
        metadata={
            "help": "also move the camera up to this many pixels a frame (0: static, as the paper's Static "
            "Corners; the files are then named realimages_jitterPX)",
            "metavar": "PX",
            "min": 0,
            "max": 64,
        },
    )
    seed: int = field(default=0, metadata=SEED_HELP)
