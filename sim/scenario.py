"""A simulated camera run: a world, a trajectory, a camera, lighting and noise, rendered frame by frame."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Iterator

import numpy as np

from deepslam.errors import InputError
from deepslam.sim import trajectories
from deepslam.sim import world as worlds
from deepslam.sim.camera import intrinsics
from deepslam.sim.shapes import check_size
from deepslam.sim.world import WorldName

START_TIME_S = 1_704_067_200.0  # 2024-01-01 00:00:00 UTC: simulated runs start there, not at 1970
MAX_FRAMES = 100_000  # the longest run (about 2 GB of log at 120x160)
MAX_SIDE = 2048  # the largest image side (px) the pipeline runs at


@dataclass(frozen=True)
class ScenarioConfig:
    """A simulated run; every documented field is a ``deepslam run`` option."""

    world: WorldName = field(
        default="plane",
        metadata={"help": "simulated world: one textured wall, a room, or boxes at many depths (clutter)"},
    )
    trajectory: trajectories.Kind = field(default="circle", metadata={"help": "camera path"})
    frames: int = field(default=60, metadata={"help": "number of frames", "min": 2, "max": MAX_FRAMES})
    size: tuple[int, int] = field(
        default=(120, 160),
        metadata={"help": "image size, multiples of 8", "metavar": ("H", "W"), "min": 8, "max": MAX_SIDE},
    )
    fov_deg: float = 70.0
    speed: float = field(default=0.5, metadata={"help": "camera speed (m/s)", "min": 0, "max": 10})
    fps: float = field(default=10.0, metadata={"help": "frame rate (frames per second)", "min": 1e-3, "max": 1000})
    noise: float = field(
        default=0.0, metadata={"help": "photometric noise magnitude s (0 clean, 1 full, 2 random)", "min": 0, "max": 2}
    )
    lighting: float = field(
        default=0.0, metadata={"help": "amplitude of a slow global brightness change (0.3 = 30%%)", "min": 0, "max": 1}
    )
    start_time: float = field(
        default=START_TIME_S,
        metadata={
            "help": "time of the first frame, in seconds since 1970-01-01 UTC (default 2024-01-01 00:00 UTC); "
            "frames follow at 1/fps",
            "min": 0,
            "max": 4e9,
        },
    )
    seed: int = field(
        default=0,
        metadata={
            "help": "seed of the world, the image noise and the random trajectory (circle, figure8 and line are "
            "fixed paths)",
            "min": 0,
            "max": 2**32 - 1,
        },
    )

    def __post_init__(self):
        check_size(self.size)
        problems = []
        if self.frames < 2:
            problems.append(f"a run needs at least 2 frames, got {self.frames}")
        if self.seed < 0:
            problems.append(f"the seed must be non-negative, got {self.seed}")
        if not 0 <= self.noise <= 2:
            problems.append(f"noise magnitude must lie in [0, 2], got {self.noise}")
        if not (math.isfinite(self.speed) and self.speed >= 0 and math.isfinite(self.fps) and self.fps > 0):
            problems.append(
                f"speed must be finite and at least 0, fps finite and positive, got {self.speed}, {self.fps}"
            )
        if not (math.isfinite(self.lighting) and 0 <= self.lighting <= 1):
            problems.append(f"lighting must lie in [0, 1], got {self.lighting}")
        if not 1 <= self.fov_deg < 180:
            problems.append(f"the field of view must lie in [1, 180) degrees, got {self.fov_deg}")
        if problems:
            raise InputError("; ".join(problems))


@dataclass
class SimFrame:
    """image uint8 (H, W); K (3, 3); stamp_ns; T_world_cam (4, 4); visible landmark ids (N,) and pixels (N, 2)."""

    image: np.ndarray
    K: np.ndarray
    stamp_ns: int
    T_world_cam: np.ndarray
    landmark_ids: np.ndarray
    landmark_pixels: np.ndarray
    depth: np.ndarray  # float32 (H, W): z of the surface seen at each pixel (inf where nothing)


class Scenario:
    """A simulated run: the world and camera path of ``config``; iterate it for ``SimFrame``s (image, K,
    stamp, true pose, visible landmarks, depth), rendered as they are drawn.

    Example:
        >>> frames = list(Scenario(ScenarioConfig(world="plane", frames=3)))
        >>> len(frames), frames[0].image.shape, frames[0].image.dtype.name
        (3, (120, 160), 'uint8')
    """

    def __init__(self, config: ScenarioConfig = ScenarioConfig()):
        self.config = config
        self.world = worlds.make(config.world, config.seed)
        self.trajectory = trajectories.make(
            config.trajectory, config.frames, config.speed, config.fps, seed=config.seed, target=self.world.target
        )
        self.K = intrinsics(config.size, config.fov_deg)

    def plane_distance(self) -> float:
        """Distance of the first camera to the world's dominant plane (the known height for scale)."""
        if self.world.dominant_plane is None:
            raise InputError(f"the {self.world.name} world has no dominant plane: use --scale map, gt or none")
        normal, offset = self.world.dominant_plane
        return float(abs(offset - normal @ self.trajectory.poses[0][:3, 3]))

    def passes_through(self) -> int | None:
        """The first frame the camera reaches by passing through one of the world's surfaces (a wall, a box),
        or None where its path keeps in front of them all."""
        return self.world.passed_through(self.trajectory.poses[:, :3, 3])

    def __len__(self) -> int:
        return self.config.frames

    def __iter__(self) -> Iterator[SimFrame]:
        c = self.config
        rng = np.random.default_rng([c.seed, 1])
        start_ns = round(c.start_time * 1e9)
        for index, (T, stamp) in enumerate(zip(self.trajectory.poses, self.trajectory.stamps_ns, strict=False)):
            light = 1.0 + c.lighting * np.sin(2 * np.pi * index / max(c.frames, 2))
            frame = self.world.render(T, self.K, c.size, rng, c.noise, light)
            yield SimFrame(
                frame.image, self.K, start_ns + int(stamp), T, frame.landmark_ids, frame.landmark_pixels, frame.depth
            )
