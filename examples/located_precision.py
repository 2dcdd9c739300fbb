"""How precisely the map locates a frame, against what PnP could do from the frame's own observations: for each clean
oracle run with the map (``--scale map``), over the frames PnP located, the median error (mm) of the measured pose
from the keyframe (``FrameResult.T_ref_cur``) against the true one, the same with its translation at the true
length (what is left without the map's scale), and of PnP's pose on the true 3-D points of the same observations
(its inliers: the map's landmarks), and of all the frame's tracks (as the limit's adjustment takes them), each
started at the true pose; then how many of a located frame's tracks were its inliers.
The oracle's track ids name the world's landmarks, so only its tracks have true 3-D points.

    python examples/located_precision.py --worlds room clutter --trajectories forward
"""

from __future__ import annotations

import sys

import cv2
import numpy as np
import torch

from deepslam.backend.config import OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.config import GridRuns
from deepslam.backend.evaluation.runs import run_frames, simulated_frames
from deepslam.backend.scale import with_length
from deepslam.frontend.config import TrackerConfig
from deepslam.sim.scenario import Scenario, ScenarioConfig


def pnp_error_mm(world: np.ndarray, pixels: np.ndarray, K: np.ndarray, T_world_cam: np.ndarray) -> float:
    """Position error (mm) of PnP's pose (Levenberg-Marquardt from the true ``T_world_cam`` (4, 4)) of a camera
    that saw the true points ``world`` (N, 3) at ``pixels`` (N, 2)."""
    T_cam_world = np.linalg.inv(T_world_cam)
    rvec, _ = cv2.Rodrigues(T_cam_world[:3, :3])
    tvec = T_cam_world[:3, 3:].copy()
    _, rvec, tvec = cv2.solvePnP(world, pixels, K, None, rvec, tvec, useExtrinsicGuess=True)
    rotation, _ = cv2.Rodrigues(rvec)
    position = -rotation.T @ tvec.ravel()
    return 1e3 * float(np.linalg.norm(position - T_world_cam[:3, 3]))


def located(world: str, trajectory: str, seed: int, frames: int) -> np.ndarray:
    """One run's located frames (F, 6): the measured pose's error from its keyframe (mm), the same at the true
    length (mm), PnP's on the true points of its inliers and of all its tracks (mm), its inliers and its tracks."""
    scenario = Scenario(ScenarioConfig(world=world, trajectory=trajectory, frames=frames, seed=seed))
    truth, points = np.stack([frame.T_world_cam for frame in scenario]), scenario.world.landmarks
    results = []
    config = PipelineConfig(TrackerConfig("oracle"), OdometryConfig(scale="map"))
    run_frames(
        simulated_frames(scenario), config, lambda frame, result, diagnostics: results.append(result),
        total=len(scenario), progress=False, seed=seed,
    )  # fmt: skip
    rows = []
    for result in results:
        if result.relative is None or result.relative.model != "pnp":
            continue
        k, K, inliers = result.index, scenario.K, result.relative.inliers
        T_true = np.linalg.inv(truth[result.reference]) @ truth[k]
        t_true = T_true[:3, 3]
        measured = 1e3 * float(np.linalg.norm(result.T_ref_cur[:3, 3] - t_true))
        at_true_length = with_length(result.T_ref_cur, float(np.linalg.norm(t_true)))
        unscaled = 1e3 * float(np.linalg.norm(at_true_length[:3, 3] - t_true))
        ids = result.tracks.ids[result.correspondences[inliers, 1]]
        own = pnp_error_mm(points[ids], result.measured_points[inliers].astype(np.float64), K, truth[k])
        tracks = result.tracks
        every = pnp_error_mm(points[tracks.ids], tracks.points.astype(np.float64), K, truth[k])
        rows.append((measured, unscaled, own, every, int(inliers.sum()), len(tracks.ids)))
    return np.array(rows).reshape(-1, 6)


def main() -> None:
    grid = GridRuns.parse(__doc__.split("\n\n")[0], frontend="oracle")
    if grid.frontend != "oracle":
        sys.exit("located_precision.py: only the oracle's tracks have true 3-D points (--frontend oracle)")
    torch.set_num_threads(1)
    print(
        f"{'world':<7} {'path':<8} seed  located  measured mm  at true length  PnP, its inliers  PnP, all tracks  "
        "inliers / tracks"
    )
    for world, path, seed in grid.runs:
        rows = located(world, path, seed, grid.frames)
        if not len(rows):
            print(f"{world:<7} {path:<8} {seed:>4}  {0:>7}")
            continue
        measured, unscaled, own, every, inliers, tracks = np.median(rows, axis=0)
        print(
            f"{world:<7} {path:<8} {seed:>4}  {len(rows):>7}  {measured:>11.1f}  {unscaled:>14.1f}  {own:>16.1f}  "
            f"{every:>15.1f}  {inliers:>7.0f} / {tracks:<4.0f}"
        )


if __name__ == "__main__":
    main()
