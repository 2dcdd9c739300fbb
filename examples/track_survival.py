"""Why the magic front-end's tracks end: on a simulated run, for every track detected in one frame, does the
next frame continue it, and if not, did MagicPoint detect the point again (within 1.5 px of where it truly
is) or miss it? Prints a line per frame and the totals.

    python examples/track_survival.py --world room --path random --seed 0
"""

from __future__ import annotations

import argparse

import numpy as np

from deepslam.backend.evaluation.runs import simulated_frames, true_positions
from deepslam.frontend.config import TrackerConfig
from deepslam.frontend.tracking import MagicTracker, make_tracker
from deepslam.sim.scenario import Scenario, ScenarioConfig

NEAR_PX = 1.5  # a detection this close to a track's true position repeats it; a continuation this close is right


def survival(previous, frame, tracker: MagicTracker, live: np.ndarray, ids: np.ndarray) -> np.ndarray:
    """Counts (4,) over the tracks detected in ``previous`` at ``live`` (N, 2) with track ``ids`` (N,):
    continued, continued to within NEAR_PX of the truth, ended though a detection repeats them, ended
    with no detection near."""
    truth = true_positions(previous, live, frame)
    seen = np.isfinite(truth[:, 0])
    detections = tracker.detections
    now = dict(zip(tracker.live_ids[: len(detections)].tolist(), detections, strict=True))
    continued = np.array([i in now for i in ids.tolist()], bool)
    where = np.array([now.get(i, (np.inf, np.inf)) for i in ids.tolist()], np.float64).reshape(-1, 2)
    right = np.linalg.norm(where - truth, axis=1) < NEAR_PX
    nearest = np.linalg.norm(truth[:, None] - detections[None], axis=2).min(1) if len(detections) else np.inf
    repeated = nearest < NEAR_PX
    return np.array([(seen & m).sum() for m in (continued, right, ~continued & repeated, ~continued & ~repeated)])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--world", default="room", choices=("plane", "room"), help="simulated world")
    parser.add_argument("--path", default="random", help="camera path: circle, figure8, line or random")
    parser.add_argument("--seed", type=int, default=0, help="the world's seed (textures, layout)")
    parser.add_argument("--noise", type=float, default=0.0, help="photometric noise magnitude (0 clean, 1 full)")
    args = parser.parse_args()
    scenario = Scenario(ScenarioConfig(world=args.world, trajectory=args.path, seed=args.seed, noise=args.noise))
    tracker = make_tracker(TrackerConfig(frontend="magic"))
    totals, previous = np.zeros(4, int), None
    print("frame  detected  continued  right  ended:repeated  ended:missed")
    for index, frame in enumerate(simulated_frames(scenario)):
        just_detected = tracker.live_age == 0
        live, ids = tracker.live[just_detected], tracker.live_ids[just_detected]
        tracker.track(frame.image)
        if previous is not None and len(live):
            counts = survival(previous, frame, tracker, live, ids)
            totals += counts
            detected, continued, right, repeated, missed = sum(counts[[0, 2, 3]]), *counts
            print(f"{index:5d}  {detected:8d}  {continued:9d}  {right:5d}  {repeated:14d}  {missed:12d}")
        previous = frame
    continued, right, repeated, missed = totals / max(totals[[0, 2, 3]].sum(), 1)
    print(f"total  continued {continued:.0%} (right {right:.0%}), ended: repeated {repeated:.0%}, missed {missed:.0%}")


if __name__ == "__main__":
    main()
