"""Per-frame timings of the whole pipeline on a simulated run."""

from __future__ import annotations

import numpy as np

from deepslam.backend.evaluation.runs import simulated_frames
from deepslam.backend.odometry import Odometry, OdometryConfig
from deepslam.frontend.tracking import TrackerConfig, make_tracker
from deepslam.sim.scenario import Scenario, ScenarioConfig


def bench_pipeline(
    frames: int = 60, seed: int = 0, tracker_config: TrackerConfig = TrackerConfig()
) -> dict[str, float]:
    """Mean per-frame milliseconds of each stage (rendering not counted) of the magic front-end
    ``tracker_config`` describes: the odometry's stages, and inside its front-end MagicPoint, MagicWarp
    and matching. Time it on one torch thread (the CLI sets it)."""
    rendered = list(simulated_frames(Scenario(ScenarioConfig(frames=frames, seed=seed))))
    tracker = make_tracker(tracker_config, seed)
    odometry = Odometry(tracker, OdometryConfig(covariance=False))
    stages: dict[str, list[float]] = {}
    for frame in rendered:
        timings = odometry.process(frame).timings_ms
        for name, ms in [*tracker.timings_ms.items(), *((f"odometry.{k}", v) for k, v in timings.items())]:
            stages.setdefault(name, []).append(ms)
    means = {name: float(np.mean(values)) for name, values in stages.items()}
    means["per_frame_total"] = sum(v for k, v in means.items() if k.startswith("odometry."))
    means["fps"] = 1e3 / means["per_frame_total"]
    return means
