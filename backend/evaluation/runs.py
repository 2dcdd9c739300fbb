"""Running the odometry end to end on a simulated scenario (evaluation code: it uses ``sim``)."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable, Iterable

import numpy as np

from deepslam.backend import drift
from deepslam.backend.odometry import FrameResult, InputFrame, Odometry, OdometryConfig
from deepslam.frontend.tracking import Tracker, TrackerConfig, Truth, make_tracker
from deepslam.progress import progress_bar
from deepslam.sim.scenario import Scenario, ScenarioConfig


def _tracker(config: TrackerConfig, odometry: OdometryConfig, seed: int = 0) -> Tracker:
    """The front-end of ``config``; carried magic tracks sit where the dominant plane's homography puts
    them, so they are on by default only when relative poses come from that homography too."""
    return make_tracker(config, seed, carry_default=odometry.method == "homography")


def simulated_frames(scenario: Scenario) -> Iterable[InputFrame]:
    for f in scenario:
        yield InputFrame(f.image, f.K, f.stamp_ns, f.T_world_cam, Truth(f.landmark_ids, f.landmark_pixels))


Sink = Callable[[InputFrame, FrameResult], None]


def run_frames(
    frames: Iterable[InputFrame],
    odometry: Odometry,
    sink: Sink | None = None,
    total: int | None = None,
    progress: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """Process frames in order, handing each (frame, result) to ``sink`` as soon as it is done.

    Returns (online estimates (N, 4, 4): each frame's pose as the graph had it when the frame was
    done, the poses that are logged; ground truth (N, 4, 4) or None). ``odometry.poses()`` has the
    final smoothed trajectory.
    """
    truth, online = [], []
    for frame in progress_bar(frames, total=total, unit="frame", disable=not progress):
        result = odometry.process(frame)
        truth.append(frame.T_world_cam)
        online.append(result.T_world_cam)
        if sink is not None:
            sink(frame, result)
    if not online:
        raise ValueError("no frames to process")
    has_truth = all(T is not None for T in truth)
    return np.stack(online), (np.stack(truth) if has_truth else None)


def simulate(
    scenario_config: ScenarioConfig,
    tracker_config: TrackerConfig,
    odometry_config: OdometryConfig,
    out: str | Path | None = None,
    metadata: dict | None = None,
    progress: bool = True,
) -> dict:
    """Run one simulated trajectory end to end (logged to ``out`` if given).

    Returns {"estimate", "truth", "drift", "scale", "odometry"}; the drift figures say which scale was used.
    """
    if out is not None:
        from deepslam.logs.writer import check_output

        check_output(out)
    scenario = Scenario(scenario_config)
    if odometry_config.scale == "plane" and odometry_config.plane_distance is None:
        odometry_config = replace(odometry_config, plane_distance=scenario.plane_distance())
    odometry = Odometry(_tracker(tracker_config, odometry_config, scenario_config.seed), odometry_config)
    frames = simulated_frames(scenario)
    if out is None:
        estimate, truth = run_frames(frames, odometry, None, len(scenario), progress)
    else:
        meta = {
            "scenario": asdict(scenario_config),
            "odometry": asdict(odometry_config),
            "frontend": tracker_config.frontend,
            "tracker": asdict(tracker_config),
            **(metadata or {}),
        }
        estimate, truth = run_logged(frames, odometry, out, meta, len(scenario), progress)
    return {
        "estimate": estimate,
        "truth": truth,
        "drift": drift.summary(estimate, truth),
        "smoothed_ate_se3": drift.ate_rmse(odometry.poses(), truth),
        "scale": odometry_config.scale,
        "odometry": odometry,
    }


def replay(
    log: str | Path,
    tracker_config: TrackerConfig,
    odometry_config: OdometryConfig,
    out: str | Path,
    metadata: dict | None = None,
    progress: bool = True,
) -> dict:
    """Feed a log's images (camera info, ground truth) through the pipeline again into a new log
    (never over the log it reads)."""
    from deepslam.logs.reader import check_log
    from deepslam.logs.writer import check_output

    if tracker_config.frontend == "oracle":
        raise ValueError("the oracle front-end needs the simulator's landmarks, which logs do not hold")
    check_log(log)
    check_output(out, inputs=(log,))
    odometry = Odometry(_tracker(tracker_config, odometry_config), odometry_config)
    meta = {
        "replayed_from": str(log),
        "odometry": asdict(odometry_config),
        "frontend": tracker_config.frontend,
        "tracker": asdict(tracker_config),
        **(metadata or {}),
    }
    estimate, truth = run_logged(logged_frames(log), odometry, out, meta, None, progress)
    return {
        "estimate": estimate,
        "truth": truth,
        "scale": odometry_config.scale,
        "drift": drift.summary(estimate, truth) if truth is not None else None,
    }


def to_log_frame(frame: InputFrame, result: FrameResult, reference_stamp_ns: int | None):
    """The log record of one processed frame (the format lives in ``logs``; the content here)."""
    from deepslam.logs.frames import Correspondences, LogFrame

    tracks = (
        np.column_stack([result.tracks.points, result.tracks.scores, result.tracks.ids])
        if len(result.tracks.ids)
        else np.zeros((0, 4))
    )
    correspondences = None
    if result.relative is not None and reference_stamp_ns is not None:
        correspondences = Correspondences(
            reference_stamp_ns,
            result.correspondences[:, 0],
            result.correspondences[:, 1],
            result.relative.model,
            int(result.relative.inliers.sum()),
            result.T_ref_cur,
        )
    return LogFrame(
        frame.stamp_ns,
        frame.image,
        frame.K,
        frame.T_world_cam,
        result.T_world_cam,
        result.covariance,
        tracks,
        correspondences,
    )


def run_logged(
    frames: Iterable[InputFrame],
    odometry: Odometry,
    out: str | Path,
    metadata: dict,
    total: int | None = None,
    progress: bool = True,
) -> tuple[np.ndarray, np.ndarray | None]:
    """``run_frames`` writing every frame to an MCAP log at ``out`` as it is processed. The log is
    finished cleanly on Ctrl-C (and then the interruption propagates)."""
    from deepslam.logs.writer import LogWriter

    stamps: list[int] = []
    with LogWriter(out, metadata) as log:

        def sink(frame: InputFrame, result: FrameResult) -> None:
            stamps.append(frame.stamp_ns)
            log.write(to_log_frame(frame, result, stamps[result.reference]))

        return run_frames(frames, odometry, sink, total, progress)


def logged_frames(path: str | Path) -> Iterable[InputFrame]:
    """Frames of a log as odometry input (images, camera info, ground truth when logged)."""
    from deepslam.logs.reader import read_frames

    for f in read_frames(path):
        yield InputFrame(f.image, f.K, f.stamp_ns, f.T_groundtruth)
