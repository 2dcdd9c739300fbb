"""What a drift sweep covers (``deepslam eval pipeline``), what ``bench pipeline`` times and how ``drift``
measures: plain dataclasses that import no solver; the functions take their defaults from them."""

from __future__ import annotations

import argparse
from dataclasses import dataclass, field

from deepslam.backend.config import Method, OdometryConfig, Scale
from deepslam.frontend.config import Frontend
from deepslam.sim import trajectories
from deepslam.sim.scenario import MAX_FRAMES
from deepslam.sim.world import WORLDS, WorldName

LEFT_OUT = (("plane", "forward"),)  # (world, path) a sweep does not run: the camera would hit the wall


@dataclass(frozen=True)
class SweepConfig:
    """What ``deepslam eval pipeline`` sweeps; every field is an option."""

    worlds: tuple[WorldName, ...] = field(
        default=("plane", "room", "clutter"),
        metadata={"help": "simulated worlds: one textured wall, a room, boxes at many depths (clutter)"},
    )
    trajectories: tuple[trajectories.Kind, ...] = field(
        default=("circle", "figure8", "line", "random", "forward"),
        metadata={"help": "camera paths (forward only in worlds with depth: in the plane world it would hit the wall)"},
    )
    frontends: tuple[Frontend, ...] = field(
        default=("oracle", "magic", "classical"),
        metadata={"help": "front-ends to compare (oracle: true projections with pixel noise, the reference)"},
    )
    noise: tuple[float, ...] = field(
        default=(0.0, 0.25, 0.5, 1.0),
        metadata={"help": "photometric noise magnitudes s (0 clean, 1 full)", "min": 0, "max": 2},
    )
    lighting: tuple[float, ...] = field(
        default=(0.0, 0.3), metadata={"help": "amplitudes of a slow global brightness change", "min": 0, "max": 1}
    )
    frames: int = field(default=60, metadata={"help": "frames per run", "min": 2, "max": MAX_FRAMES})
    seeds: int = field(
        default=12,
        metadata={
            "help": "runs per cell, seeds 0..N-1 (each seed its own world: textures, layout)",
            "min": 1,
            "max": 1000,
        },
    )
    first_seed: int = field(
        default=0,
        metadata={
            "help": "the first seed: the runs use seeds first-seed .. first-seed + seeds - 1 (to check a change "
            "on worlds an earlier sweep did not see)",
            "min": 0,
            "max": 1_000_000,
        },
    )
    scale: Scale = field(
        default="gt",
        metadata={
            "help": "monocular scale: gt = ground-truth step lengths; map = the local map's (first baseline from "
            "truth); plane = known distance to the plane; none = up to scale"
        },
    )
    method: Method = field(
        default=OdometryConfig().method,
        metadata={
            "help": "relative pose of the odometry, as deepslam run --method: auto, homography, essential, pycolmap"
        },
    )

    def paths(self) -> list[tuple[WorldName, trajectories.Kind]]:
        """(world, trajectory) of every row, in table order, but those of ``LEFT_OUT``."""
        return [(world, path) for world in self.worlds for path in self.trajectories if (world, path) not in LEFT_OUT]

    def cells(self) -> list[tuple]:
        """(world, trajectory, noise, lighting, front-end) of every row, in table order (``paths``)."""
        return [
            (world, path, noise, light, frontend)
            for world, path in self.paths()
            for noise in self.noise
            for light in self.lighting
            for frontend in self.frontends
        ]


@dataclass(frozen=True)
class PipelineBenchConfig:
    """What ``deepslam bench pipeline`` times."""

    frames: int = field(
        default=60, metadata={"help": "frames of the simulated run, timed once a round", "min": 2, "max": MAX_FRAMES}
    )
    rounds: int = field(
        default=5,
        metadata={
            "help": "times the run is timed, each with a fresh front-end; every stage reports the median of its "
            "per-round means (other work on the machine slows single rounds)",
            "min": 1,
            "max": 100,
        },
    )


@dataclass(frozen=True)
class DriftConfig:
    """How ``deepslam drift`` measures."""

    delta: int = field(default=1, metadata={"help": "frame delta of the RPE", "min": 1, "max": MAX_FRAMES})
    limit: bool = field(
        default=False,
        metadata={
            "help": "also adjust each log's own tracks in one batch bundle adjustment started at the truth (the "
            "best any back-end could do with them) and print its ATE and the log's ATE over it"
        },
    )


@dataclass(frozen=True)
class GridRuns:
    """Clean runs one by one over worlds x trajectories x seeds, as the examples that measure the map's grid take
    them from their command line (``parse``)."""

    frontend: Frontend
    frames: int
    runs: list[tuple[WorldName, trajectories.Kind, int]]  # (world, path, seed) in table order

    @classmethod
    def parse(cls, description: str, frontend: Frontend) -> GridRuns:
        """The runs ``--frontend`` (default ``frontend``), ``--worlds``, ``--trajectories``, ``--seeds`` and
        ``--frames`` name (no forward path in the plane world); a usage error exits with status 2."""
        parser = argparse.ArgumentParser(description=description)
        parser.add_argument(
            "--frontend",
            default=frontend,
            choices=("magic", "classical", "oracle"),
            help=f"the front-end (default: {frontend})",
        )
        parser.add_argument(
            "--worlds",
            nargs="+",
            default=["plane", "room", "clutter"],
            choices=WORLDS,
            help="simulated worlds (default: all three)",
        )
        parser.add_argument(
            "--trajectories",
            nargs="+",
            default=["circle", "forward"],
            choices=trajectories.KINDS,
            help="camera paths (default: circle forward; forward is left out in the plane world)",
        )
        parser.add_argument("--seeds", type=int, default=3, help="seeds 0 to N - 1 (default: 3)")
        parser.add_argument("--frames", type=int, default=60, help="frames a run (default: 60)")
        args = parser.parse_args()
        if args.seeds < 1 or args.frames < 3:
            parser.error(f"--seeds must be at least 1 and --frames at least 3, got {args.seeds} and {args.frames}")
        paths = SweepConfig(worlds=tuple(args.worlds), trajectories=tuple(args.trajectories)).paths()
        return cls(
            args.frontend, args.frames, [(world, path, seed) for world, path in paths for seed in range(args.seeds)]
        )
