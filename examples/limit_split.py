"""Where a front-end's drift over its limit comes from: each run's ATE over that of the batch bundle adjustment of
its own tracks started at the truth (the sweep's "/limit"), over the whole run and over the frames from the map's
first one on (each taken over those frames), over the causal limit's (``limit.causal_adjust``: each frame where
the adjustment of the frames up to it places it, as an online back-end must), and over the limit's whose scale is
held by the run's own first baseline (the frame its first map started from frame 0 with; the limit's is the first
frame that spans ``min_initial_px``; NaN where the first map started from a later keyframe). Frames before a map
are measured two-view; a front-end whose maps start late loses most of its ground there.

    python examples/limit_split.py --frontend magic
"""

from __future__ import annotations

import numpy as np
import torch

from deepslam.backend import drift
from deepslam.backend.config import OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.config import GridRuns
from deepslam.backend.evaluation.limit import batch_adjust, causal_adjust
from deepslam.backend.evaluation.runs import run_frames, simulated_frames
from deepslam.frontend.config import TrackerConfig
from deepslam.sim.scenario import Scenario, ScenarioConfig


def split(world: str, trajectory: str, frontend: str, seed: int, frames: int) -> tuple[int, float, float, float, float]:
    """One clean run with the map (``--scale map``): the first frame tracked in a map (``frames`` where none was),
    its ATE SE3 over the limit's over the whole run, the same from that frame on (NaN for fewer than 3), over the
    causal limit's over the whole run, and over the limit's held by the run's own first baseline."""
    scenario = Scenario(ScenarioConfig(world=world, trajectory=trajectory, frames=frames, seed=seed))
    config = PipelineConfig(TrackerConfig(frontend), OdometryConfig(scale="map"))
    output = run_frames(simulated_frames(scenario), config, total=len(scenario), progress=False, seed=seed)
    limit = output.limit()
    start = next((i for i, frame in enumerate(output.diagnostics) if i and frame.phase == "tracking"), frames)
    ate = drift.ate_rmse(output.estimate, output.truth)
    causal = ate / drift.ate_rmse(causal_adjust(output.observations), output.truth)
    keyframes = [i for i, frame in enumerate(output.diagnostics[:start]) if frame.keyframe]
    own = float("nan")
    if start < frames and keyframes[-1] == 0:  # the first map started from frame 0 and frame ``start``
        own = ate / batch_adjust(output.observations, baseline=start).ate_se3
    if frames - start < 3:
        return start, ate / limit.ate_se3, float("nan"), causal, own
    after = drift.ate_rmse(output.estimate[start:], output.truth[start:])
    return start, ate / limit.ate_se3, after / drift.ate_rmse(limit.poses[start:], output.truth[start:]), causal, own


def main() -> None:
    grid = GridRuns.parse(__doc__.split("\n\n")[0], frontend="magic")
    torch.set_num_threads(1)  # as the sweep's runs: the same seed, the same run
    print(
        f"{'world':<7} {'path':<8} seed  map at  /limit whole  /limit from the map on  /causal limit whole  "
        "/limit at its baseline"
    )
    splits = []
    for world, path, seed in grid.runs:
        start, whole, after, causal, own = split(world, path, grid.frontend, seed, grid.frames)
        splits.append((whole, after, causal, own))
        print(
            f"{world:<7} {path:<8} {seed:>4}  {start:>6}  {whole:>12.2f}  {after:>22.2f}  {causal:>19.2f}  {own:>21.2f}"
        )
    whole, after, causal, own = np.array(splits).T
    mapped, held = int(np.isfinite(after).sum()), int(np.isfinite(own).sum())
    print(
        f"median {np.median(whole):.2f} ({len(whole)} runs), from the map on {_median(after):.2f} ({mapped}), "
        f"over the causal limit {np.median(causal):.2f}, at its baseline {_median(own):.2f} ({held})"
    )


def _median(values: np.ndarray) -> float:
    """The median of the finite ``values``; NaN where there are none."""
    finite = values[np.isfinite(values)]
    return float(np.median(finite)) if len(finite) else float("nan")


if __name__ == "__main__":
    main()
