"""A simulated camera run: a world, a trajectory, a camera, lighting and noise, rendered frame by frame."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from deepslam.sim import trajectories
from deepslam.sim import world as worlds
from deepslam.sim.camera import intrinsics
from deepslam.sim.shapes import check_size


@dataclass(frozen=True)
class ScenarioConfig:
    world: str = "plane"
    trajectory: str = "circle"
    frames: int = 60
    size: tuple[int, int] = (120, 160)
    fov_deg: float = 70.0
    speed: float = 0.5  # world units (m) per second
    fps: float = 10.0
    noise: float = 0.0  # photometric noise magnitude s (sim.noise), 0 clean, 1 full
    lighting: float = 0.0  # amplitude of a slow global brightness change (0.3 = +-30%)
    seed: int = 0


@dataclass
class SimFrame:
    """image uint8 (H, W); K (3, 3); stamp_ns; T_world_cam (4, 4); visible landmark ids (N,) and pixels (N, 2)."""

    image: np.ndarray
    K: np.ndarray
    stamp_ns: int
    T_world_cam: np.ndarray
    landmark_ids: np.ndarray
    landmark_pixels: np.ndarray


class Scenario:
    """Holds the world and trajectory of a config; iterate it for ``SimFrame``s."""

    def __init__(self, config: ScenarioConfig = ScenarioConfig()):
        check_size(config.size)
        if config.frames < 2:
            raise ValueError(f"a run needs at least 2 frames, got {config.frames}")
        if config.seed < 0:
            raise ValueError(f"the seed must be non-negative, got {config.seed}")
        if not 0 <= config.noise <= 2:
            raise ValueError(f"noise magnitude must lie in [0, 2], got {config.noise}")
        self.config = config
        self.world = worlds.make(config.world, config.seed)
        self.trajectory = trajectories.make(
            config.trajectory, config.frames, config.speed, config.fps, seed=config.seed, target=self.world.target
        )
        self.K = intrinsics(config.size, config.fov_deg)

    def plane_distance(self) -> float:
        """Distance of the first camera to the world's dominant plane (the known height for scale)."""
        normal, offset = self.world.dominant_plane
        return float(abs(offset - normal @ self.trajectory.poses[0][:3, 3]))

    def __len__(self) -> int:
        return self.config.frames

    def __iter__(self) -> Iterator[SimFrame]:
        c = self.config
        rng = np.random.default_rng([c.seed, 1])
        for index, (T, stamp) in enumerate(zip(self.trajectory.poses, self.trajectory.stamps_ns, strict=False)):
            light = 1.0 + c.lighting * np.sin(2 * np.pi * index / max(c.frames, 2))
            frame = self.world.render(T, self.K, c.size, rng, c.noise, light)
            yield SimFrame(frame.image, self.K, int(stamp), T, frame.landmark_ids, frame.landmark_pixels)
