"""gtsam's bundle adjustment beside pycolmap's (Ceres) on the same windows (``MapConfig.adjuster``): every window
of three or more keyframes the map adjusts in oracle runs is captured before its adjustment and solved by both,
with the same Huber loss, the same iteration cap and one thread. Prints the median time a window
and the median error of the landmarks' depths (in the oldest keyframe, against the simulator's points) before and
after.

    python examples/bundle_adjusters.py --oracle-noise 0.5
"""

from __future__ import annotations

import argparse
import copy
import time

import numpy as np

from deepslam.backend import mapping
from deepslam.backend.config import MapConfig, OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.runs import simulated_frames
from deepslam.backend.evaluation.truth import run_pipeline
from deepslam.frontend.config import TrackerConfig
from deepslam.sim.scenario import Scenario, ScenarioConfig

RUNS = [("room", "circle"), ("clutter", "circle"), ("clutter", "forward")]


def captured_windows(
    world: str, trajectory: str, seed: int, noise: float, frames: int = 60
) -> list[tuple[mapping.LocalMap, dict]]:
    """Copies of the map before each of its adjustments of three or more keyframes (not the trial adjustments of
    the frames a map waits on, ``mapping.adjust_views``, which keep another distance), with the run's true camera
    poses by frame index and world points by landmark id (``{"poses": {...}, "points": (M, 3)}``)."""
    windows, adjust = [], mapping.LocalMap.adjust

    def capture(local_map, ranged=1, converge=False):
        if len(local_map.keyframes) >= 3 and ranged == 1:
            windows.append(copy.deepcopy(local_map))
        return adjust(local_map, ranged, converge)

    scenario = Scenario(ScenarioConfig(world=world, trajectory=trajectory, frames=frames, seed=seed))
    poses = {}
    # gtsam's map, so that every window goes through LocalMap.adjust, where it is captured
    config = PipelineConfig(
        TrackerConfig("oracle", oracle_noise=noise), OdometryConfig(map=MapConfig(adjuster="gtsam"))
    )
    mapping.LocalMap.adjust = capture
    try:
        for _, frame, result in run_pipeline(simulated_frames(scenario), config):
            poses[result.index] = frame.T_world_cam
    finally:
        mapping.LocalMap.adjust = adjust
    truth = {"poses": poses, "points": scenario.world.landmarks}
    return [(window, truth) for window in windows]


def depth_error(T_world_oldest: np.ndarray, landmarks: dict[int, np.ndarray], truth: dict, oldest: int) -> float:
    """Median |estimated / true depth - 1| of ``landmarks`` in the oldest keyframe (frame index ``oldest``)."""
    ids = np.array(sorted(landmarks))
    estimated = mapping.project(T_world_oldest, np.eye(3), np.array([landmarks[i] for i in ids]))[1]
    true = mapping.project(truth["poses"][oldest], np.eye(3), truth["points"][ids])[1]
    return float(np.median(np.abs(estimated / true - 1)))


def with_pycolmap(local_map: mapping.LocalMap) -> tuple[np.ndarray, dict[int, np.ndarray], float]:
    """A copy of the window solved by the map's pycolmap adjuster (``mapping.adjust_with_pycolmap``, as
    ``MapConfig(adjuster="pycolmap")`` has it): the oldest keyframe's pose (4, 4), the landmarks it moved and the
    seconds it took, the problem's set-up included."""
    window = copy.deepcopy(local_map)
    adjusted = window.adjusted_landmarks()
    started = time.perf_counter()
    mapping.adjust_with_pycolmap(
        window.keyframes + window.frames, window.retired, window.landmarks, adjusted, window.config
    )
    seconds = time.perf_counter() - started
    return window.keyframes[0].T_world_cam, {track: window.landmarks[track] for track in adjusted.tolist()}, seconds


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--oracle-noise", type=float, default=0.5, help="pixel noise of the oracle's tracks")
    parser.add_argument("--seeds", nargs="+", type=int, default=[0, 1], help="seeds of each run")
    parser.add_argument("--frames", type=int, default=60, help="frames a run (default: 60)")
    args = parser.parse_args()
    if args.frames < 2:
        parser.error(f"--frames must be at least 2, got {args.frames}")
    rows = []
    for (world, trajectory), seed in ((run, seed) for run in RUNS for seed in args.seeds):
        for window, truth in captured_windows(world, trajectory, seed, args.oracle_noise, args.frames):
            oldest = window.keyframes[0].index
            before = depth_error(window.keyframes[0].T_world_cam, window.landmarks, truth, oldest)
            T_oldest, landmarks, colmap_seconds = with_pycolmap(window)
            started = time.perf_counter()
            window.adjust()
            gtsam_seconds = time.perf_counter() - started
            kept = {track: window.landmarks[track] for track in landmarks if track in window.landmarks}
            rows.append(
                (
                    1e3 * gtsam_seconds,
                    1e3 * colmap_seconds,
                    before,
                    depth_error(window.keyframes[0].T_world_cam, kept, truth, oldest),
                    depth_error(T_oldest, landmarks, truth, oldest),
                )
            )
    if not rows:
        parser.error(f"no run adjusted a window of three keyframes in {args.frames} frames: more --frames")
    medians = np.median(np.array(rows), axis=0)
    runs = ", ".join(f"{world} {trajectory}" for world, trajectory in RUNS)
    print(f"{len(rows)} windows of oracle runs (noise {args.oracle_noise} px, seeds {args.seeds}): {runs}")
    print(f"ms a window (median): gtsam {medians[0]:.1f}, pycolmap {medians[1]:.1f}")
    print(f"landmark depth error (median): before {medians[2]:.4f}, gtsam {medians[3]:.4f}, pycolmap {medians[4]:.4f}")


if __name__ == "__main__":
    main()
