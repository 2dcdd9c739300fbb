"""Drift sweeps: every world x front-end x noise combination of simulated runs, over seeds."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np

from deepslam.backend.evaluation.runs import simulate
from deepslam.backend.odometry import OdometryConfig, Scale
from deepslam.frontend.tracking import Frontend, TrackerConfig
from deepslam.progress import progress_bar
from deepslam.sim import trajectories
from deepslam.sim.scenario import ScenarioConfig
from deepslam.sim.world import WorldName


@dataclass(frozen=True)
class SweepConfig:
    """What ``deepslam eval pipeline`` sweeps; every field is an option."""

    worlds: tuple[WorldName, ...] = field(
        default=("plane", "room"), metadata={"help": "simulated worlds: one textured wall and/or a room"}
    )
    frontends: tuple[Frontend, ...] = field(
        default=("oracle", "magic", "classical"),
        metadata={"help": "front-ends to compare (oracle: true projections with pixel noise, the reference)"},
    )
    noise: tuple[float, ...] = field(
        default=(0.0, 1.0), metadata={"help": "photometric noise magnitudes s (0 clean, 1 full)", "min": 0, "max": 2}
    )
    frames: int = field(default=60, metadata={"help": "frames per run", "min": 2})
    seeds: int = field(
        default=6,
        metadata={"help": "runs per cell, seeds 0..N-1 (the worlds differ by seed: textures, layout)", "min": 1},
    )
    scale: Scale = field(
        default="gt",
        metadata={"help": "monocular scale: gt = ground-truth step lengths; plane = known distance to the plane"},
    )
    trajectory: trajectories.Kind = field(default="circle", metadata={"help": "camera path"})


def pipeline_matrix(
    config: SweepConfig = SweepConfig(), tracker_config: TrackerConfig = TrackerConfig(), progress: bool = True
) -> list[dict]:
    """Drift of every world x front-end x noise combination, averaged over seeds (every front-end with
    the options of ``tracker_config``); each row also keeps its per-seed ATE SE3."""
    worlds, frontends, noises, seeds = config.worlds, config.frontends, config.noise, tuple(range(config.seeds))
    frames, scale, trajectory = config.frames, config.scale, config.trajectory
    if not (worlds and frontends and noises and seeds):
        raise ValueError("the drift matrix needs at least one world, front-end, noise magnitude and seed")
    cells = [(world, noise, frontend) for world in worlds for noise in noises for frontend in frontends]
    rows = []
    with progress_bar(total=len(cells) * len(seeds), unit="run", disable=not progress) as bar:
        for world, noise, frontend in cells:
            runs = []
            for seed in seeds:
                bar.set_description(f"{world} noise {noise:g} {frontend} seed {seed}")
                scenario = ScenarioConfig(world=world, trajectory=trajectory, frames=frames, noise=noise, seed=seed)
                tracker = replace(tracker_config, frontend=frontend)
                runs.append(simulate(scenario, tracker, OdometryConfig(scale=scale), progress=False)["drift"])
                bar.update(1)
            rows.append(
                {
                    "world": world,
                    "noise": noise,
                    "frontend": frontend,
                    "scale": scale,
                    **{
                        k: float(np.mean([r[k] for r in runs]))
                        for k in ("ate_se3", "ate_sim3", "rpe_trans", "rpe_rot_deg", "final_drift_pct")
                    },
                    "seeds": list(seeds),
                    "ate_se3_per_seed": [r["ate_se3"] for r in runs],
                }
            )
    return rows


def matrix_lines(rows: list[dict]) -> list[str]:
    lines = [
        f"{'world':<6} {'noise':>5} {'frontend':<9} {'scale':<5} {'ATE SE3 m':>9} {'ATE Sim3 m':>10} {'RPE t m':>8} "
        f"{'RPE deg':>8} {'final %':>8}"
    ]
    for r in rows:
        lines.append(
            f"{r['world']:<6} {r['noise']:>5.1f} {r['frontend']:<9} {r['scale']:<5} {r['ate_se3']:>9.4f} "
            f"{r['ate_sim3']:>10.4f} {r['rpe_trans']:>8.4f} {r['rpe_rot_deg']:>8.3f} {r['final_drift_pct']:>8.2f}"
        )
    lines += ["", f"ATE SE3 m per seed ({', '.join(map(str, rows[0]['seeds']))}):"]
    lines += [
        f"{r['world']:<6} {r['noise']:>5.1f} {r['frontend']:<9} " + " ".join(f"{v:7.4f}" for v in r["ate_se3_per_seed"])
        for r in rows
    ]
    return lines
