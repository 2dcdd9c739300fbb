"""How well two views measure the frames before a map: for each frame measured two-view while a map waits to start
(phase "initialising"), the error of the rotation its model measured and of the direction of the translation the
odometry reported (after the frames before it were adjusted with it), the direction the same pairs give once the
true rotation is known (what they tell of the translation alone), and the frame's position error as reported:
medians and 90th percentiles over frames binned by the median flow (px) of their pairs since the keyframe. Clean
runs, ``--scale map``.

    python examples/first_frames.py --frontend oracle
"""

from __future__ import annotations

import numpy as np
import torch

from deepslam.backend.config import OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.config import GridRuns
from deepslam.backend.evaluation.runs import run_frames, simulated_frames
from deepslam.frontend.config import TrackerConfig
from deepslam.geometry import rotation_angle, vector_angle
from deepslam.sim.scenario import Scenario, ScenarioConfig

FLOW_BINS_PX = (0.0, 1.5, 2.0, 3.0, 5.0, np.inf)  # the edges of the flow bins


def direction_given_rotation(R_2_1: np.ndarray, rays_1: np.ndarray, rays_2: np.ndarray) -> np.ndarray:
    """The unit translation t (3,) of camera 1 into camera 2 (a point X1 in camera 1 is ``R_2_1 @ X1 + t`` in
    camera 2) that the epipolar constraints of the pairs' rays (N, 3 each, ``K^-1 [x, y, 1]``) leave, with the
    rotation known: t is orthogonal to every ``(R_2_1 @ ray_1) x ray_2``; of its two signs, the one that puts
    more points in front of both cameras."""
    turned = rays_1 @ R_2_1.T
    normals = np.cross(turned, rays_2)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True) + 1e-12
    t = np.linalg.svd(normals)[2][-1]
    return t if _in_front(turned, rays_2, t) >= _in_front(turned, rays_2, -t) else -t


def _in_front(turned: np.ndarray, rays_2: np.ndarray, t: np.ndarray) -> int:
    """How many pairs put their point in front of both cameras for the translation t: depths z1, z2 with
    ``z1 turned + t = z2 ray_2`` (least squares) both positive."""
    a, b, c = (turned * turned).sum(1), (turned * rays_2).sum(1), (rays_2 * rays_2).sum(1)
    d, e = turned @ t, rays_2 @ t
    det = a * c - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        z1, z2 = (b * e - c * d) / det, (a * e - b * d) / det
    return int(((z1 > 0) & (z2 > 0)).sum())


def measured_frames(world: str, trajectory: str, frontend: str, seed: int, frames: int) -> list[tuple]:
    """One clean run: for each frame measured two-view before the map, (median flow px, rotation error deg,
    reported direction error deg, direction error with the true rotation deg, position error mm)."""
    scenario = Scenario(ScenarioConfig(world=world, trajectory=trajectory, frames=frames, seed=seed))
    config = PipelineConfig(TrackerConfig(frontend), OdometryConfig(scale="map"))
    results = []
    output = run_frames(
        simulated_frames(scenario), config, total=len(scenario), progress=False, seed=seed,
        sink=lambda _, result, __: results.append(result),
    )  # fmt: skip
    truth, K = output.truth, output.observations.K
    measured = []
    for result in results[1:]:
        relative = result.relative
        if result.phase != "initialising" or not relative.ok or relative.model not in ("homography", "essential"):
            continue
        keyframe = results[result.reference]
        true = np.linalg.inv(truth[result.reference]) @ truth[result.index]  # T_kf_k
        first = keyframe.tracks.points[result.correspondences[:, 0]]
        flow = float(np.median(np.linalg.norm(result.measured_points - first, axis=1)))
        rays = [
            np.c_[points, np.ones(len(points))] @ np.linalg.inv(K[result.index]).T
            for points in (first, result.measured_points)
        ]
        R_true = true[:3, :3]
        given_rotation = direction_given_rotation(R_true.T, *rays)
        measured.append((
            flow,
            np.degrees(rotation_angle(relative.T_c1_c2[:3, :3].T @ R_true)),
            np.degrees(vector_angle(result.T_ref_cur[:3, 3], true[:3, 3])),
            np.degrees(vector_angle(given_rotation, -R_true.T @ true[:3, 3])),
            1e3 * np.linalg.norm(output.estimate[result.index][:3, 3] - truth[result.index][:3, 3]),
        ))  # fmt: skip
    return measured


def main() -> None:
    grid = GridRuns.parse(__doc__.split("\n\n")[0], frontend="oracle")
    torch.set_num_threads(1)  # as the sweep's runs: the same seed, the same run
    rows = [
        row for world, path, seed in grid.runs for row in measured_frames(world, path, grid.frontend, seed, grid.frames)
    ]
    table = np.array(rows).reshape(-1, 5)
    columns = ("rotation deg", "direction deg", "true rotation", "position mm")
    print("each bin's frames: median / 90th percentile; true rotation: the direction's error given the true rotation")
    print(f"{'flow px':<8} {'frames':>6}  " + "  ".join(f"{column:>15}" for column in columns))
    for low, high in zip(FLOW_BINS_PX[:-1], FLOW_BINS_PX[1:], strict=True):
        binned = table[(table[:, 0] >= low) & (table[:, 0] < high)]
        if len(binned):
            spreads = [f"{np.median(column):.1f} / {np.percentile(column, 90):.1f}" for column in binned[:, 1:].T]
            print(f"{low:>3.1f}-{high:<4.1f} {len(binned):>6}  " + "  ".join(f"{spread:>15}" for spread in spreads))


if __name__ == "__main__":
    main()
