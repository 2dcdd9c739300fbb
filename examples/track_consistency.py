"""Do the magic front-end's tracks stay one physical point through parallax, with and without following
them by Lucas-Kanade (``--follow``)? For each world and seed: the share of track observations within 2 px of
their track's point (triangulated with the true poses), the median share of a pose's usable tracks that are
its inliers, and the run's ATE as % of its path (``--scale map``).

    python examples/track_consistency.py --worlds room clutter --seeds 0 1 2
"""

from __future__ import annotations

import argparse

import numpy as np

from deepslam.backend.config import OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.runs import run_frames, simulated_frames
from deepslam.frontend.config import TrackerConfig
from deepslam.sim.scenario import Scenario, ScenarioConfig


def measure(world: str, trajectory: str, seed: int, follow: bool, frames: int) -> tuple[float, float, float]:
    """(share of consistent track observations, median inlier share, ATE % of the path) of one magic run."""
    scenario = Scenario(ScenarioConfig(world=world, trajectory=trajectory, frames=frames, seed=seed))
    config = PipelineConfig(TrackerConfig("magic", follow=follow), OdometryConfig(scale="map"))
    summary = run_frames(simulated_frames(scenario), config, progress=False).summary(timing=False)
    return summary["tracks_consistent"], summary["inlier_share"], 100 * summary["ate_se3"] / summary["path_length"]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--worlds", nargs="+", default=["room", "clutter"], choices=["plane", "room", "clutter"],
                        help="simulated worlds")  # fmt: skip
    parser.add_argument("--trajectory", default="circle", help="camera path of every run")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2], help="seeds (world, noise, textures)")
    parser.add_argument("--frames", type=int, default=60, help="frames a run")
    args = parser.parse_args()
    print("each figure snapped / followed: the paper's snapping where the homography carries a track, or --follow")
    print(f"{'world':8s} {'seed':>4s}  {'consistent':>21s}  {'inlier share':>15s}  {'ATE % path':>15s}")
    rows = []
    for world in args.worlds:
        for seed in args.seeds:
            snapped, followed = (measure(world, args.trajectory, seed, follow, args.frames) for follow in (False, True))
            rows.append((snapped, followed))
            print(
                f"{world:8s} {seed:4d}  {snapped[0]:10.3f} {followed[0]:10.3f}  {snapped[1]:7.2f} {followed[1]:7.2f}"
                f"  {snapped[2]:7.2f} {followed[2]:7.2f}",
                flush=True,
            )
    medians = np.median(np.array(rows), axis=0)  # (2, 3): snapped / followed x the three figures
    print(
        f"{'median':8s} {'':4s}  {medians[0, 0]:10.3f} {medians[1, 0]:10.3f}  {medians[0, 1]:7.2f} {medians[1, 1]:7.2f}"
        f"  {medians[0, 2]:7.2f} {medians[1, 2]:7.2f}"
    )


if __name__ == "__main__":
    main()
