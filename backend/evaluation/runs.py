"""Running the odometry end to end on a simulated scenario (evaluation code: it uses ``sim``)."""

from __future__ import annotations

import warnings
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Callable, Iterable, Iterator

import cv2
import numpy as np

from deepslam.backend import drift
from deepslam.backend.config import OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.consistency import TrackObservations, consistent_share
from deepslam.backend.evaluation.limit import Limit, batch_adjust, over_limit
from deepslam.backend.evaluation.truth import GroundTruth, TrueFrame, run_pipeline
from deepslam.backend.odometry import FrameResult
from deepslam.backend.pipeline import Pipeline
from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig
from deepslam.frontend.tracking import Tracker, Tracks, Truth
from deepslam.geometry import path_length
from deepslam.inputs import SourceOptions, open_source
from deepslam.interrupts import held_signals
from deepslam.logs.frames import Correspondences, FrameDiagnostics, LogFrame
from deepslam.progress import progress_bar
from deepslam.sim.scenario import Scenario, ScenarioConfig


def simulated_frames(scenario: Scenario) -> Iterator[TrueFrame]:
    """The scenario's frames with all the simulator knows of them."""
    for f in scenario:
        yield TrueFrame(f.image, f.K, f.stamp_ns, f.T_world_cam, Truth(f.landmark_ids, f.landmark_pixels), f.depth)


def true_positions(before: TrueFrame, points_before: np.ndarray, after: TrueFrame) -> np.ndarray:
    """Where ``points_before`` (N, 2) of frame ``before`` truly are in frame ``after``: each back-projected
    with the true depth, moved by the true poses and projected (N, 2); NaN where the depth buffer saw nothing.
    All NaN without depth or poses (real data)."""
    points_before = np.asarray(points_before, np.float64).reshape(-1, 2)
    projected = np.full((len(points_before), 2), np.nan)
    if before.depth is None or before.T_world_cam is None or after.T_world_cam is None or len(points_before) == 0:
        return projected
    inverse_depth = np.where(np.isfinite(before.depth), 1.0 / before.depth, 0.0).astype(np.float32)
    sampled = cv2.remap(
        inverse_depth, *np.asarray(points_before, np.float32).reshape(-1, 1, 2).transpose(2, 0, 1), cv2.INTER_LINEAR
    )
    seen = sampled.ravel() > 0  # 1/z is linear across a plane's pixels (z is not); 0 where nothing was hit
    z = 1.0 / np.where(seen, sampled.ravel(), 1.0).astype(np.float64)
    rays = np.c_[points_before[seen], np.ones(seen.sum())] @ np.linalg.inv(before.K).T
    world = rays * z[seen, None] @ before.T_world_cam[:3, :3].T + before.T_world_cam[:3, 3]
    T_cam_world = np.linalg.inv(after.T_world_cam)
    camera = world @ T_cam_world[:3, :3].T + T_cam_world[:3, 3]
    pixels = camera @ after.K.T
    projected[seen] = pixels[:, :2] / pixels[:, 2:3]
    return projected


def projection_errors(
    before: TrueFrame, points_before: np.ndarray, after: TrueFrame, points_after: np.ndarray
) -> np.ndarray:
    """Pixel errors (M,) of point pairs: each of ``points_before`` (N, 2) where it truly is in ``after``
    (``true_positions``) against its partner in ``points_after`` (N, 2); points where the depth buffer saw
    nothing are left out. Empty without depth or poses (real data)."""
    projected = true_positions(before, points_before, after)
    seen = np.isfinite(projected[:, 0])
    return np.linalg.norm(projected[seen] - np.asarray(points_after, np.float64).reshape(-1, 2)[seen], axis=1)


def track_errors(previous: TrueFrame, tracks_before: Tracks, frame: TrueFrame, tracks: Tracks) -> np.ndarray:
    """Pixel errors (M,) of the tracks followed from ``previous`` to ``frame``, where the front-end put them
    (``projection_errors``)."""
    _, before, after = np.intersect1d(tracks_before.ids, tracks.ids, return_indices=True)
    return projection_errors(previous, tracks_before.points[before], frame, tracks.points[after])


Sink = Callable[[TrueFrame, FrameResult, FrameDiagnostics], None]


@dataclass
class RunOutput:
    """What a run produced: online estimates (N, 4, 4), each frame's pose as the graph had it when the
    frame was done (the poses that are logged); ground truth (N, 4, 4) with NaN where a frame has none, or
    None when no frame has any; per-frame diagnostics; every track's error against truth from frame to
    frame, and the error of every pair a pose was measured from (a keyframe's point and this frame's, as
    measured), in pixels (empty without truth); the pipeline that ran; each frame's inliers over the pairs or
    landmarks it could be measured from (``FrameResult.shared``; NaN where there were none); every track
    observation's distance (px) from the projection of its track's point triangulated with the true poses
    (``consistency``; empty without truth)."""

    estimate: np.ndarray
    truth: np.ndarray | None
    diagnostics: list[FrameDiagnostics]
    track_errors: np.ndarray
    pair_errors: np.ndarray
    pipeline: Pipeline
    frame_ms: np.ndarray  # (N,) the pipeline's milliseconds per frame
    inlier_shares: np.ndarray  # (N - 1,)
    consistency_errors: np.ndarray  # (M,)
    observations: TrackObservations  # every track observation of the frames with truth

    def limit(self) -> Limit | None:
        """The batch bundle adjustment of the run's own track observations, started at the truth
        (``deepslam.backend.evaluation.limit``); None unless every frame has truth."""
        if self.truth is None or len(self.observations.poses) != len(self.estimate):
            return None
        return batch_adjust(self.observations)

    def summary(self, scale: str = "gt", timing: bool = True, limit: bool = False) -> dict:
        """What a run shows without truth: frames, keyframes, lost frames, the estimated path's length (in the
        run's units: metres, or with ``scale`` "none" the first plane distances, with "map" and no truth at the
        start the first baseline), median tracks and inliers a frame, the median share of a frame's pairs (or
        landmarks) that are inliers, the map's landmarks at the end and milliseconds a frame; then the drift over
        the frames with ground truth (up to scale, only what survives a Sim(3) alignment), the median track and
        pair errors against the simulator and the share of track observations within ``CONSISTENT_PX`` of their
        track's point, where they can be measured. ``timing`` False leaves out the milliseconds (they differ from
        run to run). ``limit``: also the ATE SE3 of the batch bundle adjustment of the run's own tracks (``limit``)
        and the run's ATE SE3 over it, where every frame has truth."""
        figures: dict = {
            "frames": len(self.estimate),
            "keyframes": sum(d.keyframe for d in self.diagnostics),
            "lost_frames": sum(d.lost for d in self.diagnostics),
            "path_length_estimate": path_length(self.estimate),
            "tracks_per_frame": _median(np.array([d.tracks for d in self.diagnostics], float)),
            "inliers_per_frame": _median(np.array([d.inliers for d in self.diagnostics[1:]], float)),  # 0: no pose
            "inlier_share": _median(self.inlier_shares[np.isfinite(self.inlier_shares)]),
            "landmarks": self.diagnostics[-1].landmarks,
        }
        if timing:
            figures["ms_per_frame"] = _median(self.frame_ms)
        if self.truth is not None:
            known = ~np.isnan(self.truth[:, 0, 0])
            if known.sum() >= 2:
                errors = drift.summary(self.estimate[known], self.truth[known])
                unit = scale == "none" or (scale == "map" and not known[0])  # no true first baseline: no metres
                keep = ("ate_sim3", "path_length") if unit else tuple(k for k in errors if k != "frames")
                figures |= {k: errors[k] for k in keep} | {"frames_with_truth": int(known.sum())}
        if len(self.track_errors):
            figures["track_error_px"] = _median(self.track_errors)
        if len(self.pair_errors):
            figures["pair_error_px"] = _median(self.pair_errors)
        if len(self.consistency_errors):
            figures["tracks_consistent"] = consistent_share(self.consistency_errors)
        best = self.limit() if limit and "ate_se3" in figures else None
        if best is not None:
            figures["limit_ate_se3"] = best.ate_se3
            figures["ate_over_limit"] = over_limit(figures["ate_se3"], best.ate_se3)
        return figures


def _median(values: np.ndarray) -> float:
    return float(np.median(values)) if len(values) else float("nan")


def _pair_errors(frame: TrueFrame, result: FrameResult, kept: dict[int, tuple[TrueFrame, Tracks]]) -> np.ndarray:
    """Pixel errors (M,) of the pairs the frame's pose was measured from (``projection_errors``), if its
    reference keyframe is among the ``kept`` frames."""
    if result.measured_points is None or result.reference not in kept:
        return np.zeros(0)
    reference, reference_tracks = kept[result.reference]
    reference_points = reference_tracks.points[result.correspondences[:, 0]]
    return projection_errors(reference, reference_points, frame, result.measured_points)


def _diagnostics(
    frame: TrueFrame, result: FrameResult, frame_errors: np.ndarray, frame_pair_errors: np.ndarray
) -> FrameDiagnostics:
    """What the log and the drift report keep of one processed frame, given its track and pair errors (px)."""
    relative = result.relative
    position_error = (
        float(np.linalg.norm(result.T_world_cam[:3, 3] - frame.T_world_cam[:3, 3]))
        if frame.T_world_cam is not None
        else float("nan")
    )
    return FrameDiagnostics(
        len(result.tracks.ids),
        int(relative.inliers.sum()) if relative is not None else 0,
        result.lost,
        relative.reason if relative is not None else "",
        _median(frame_errors),
        position_error,
        result.keyframe,
        _median(frame_pair_errors),
        result.landmarks,
        result.phase.value,
        result.keyframe_reason,
    )


def run_frames(
    frames: Iterable[TrueFrame],
    config: PipelineConfig,
    sink: Sink | None = None,
    total: int | None = None,
    progress: bool = True,
    tracker: Tracker | None = None,
    seed: int = 0,
    ground_truth: GroundTruth | None = None,
) -> RunOutput:
    """Process frames in order through the pipeline of ``config`` (with ``tracker`` instead of its
    front-end if given, fed by ``ground_truth`` if it is an oracle of one's own; ``seed``: the oracle's
    noise), handing each (frame, result, diagnostics) to ``sink`` as soon as it is done (Ctrl-C and
    SIGTERM take effect between frames). ``RunOutput.pipeline.trajectory()`` has the final trajectory
    (refined by later frames)."""
    truth, online, diagnostics, errors, pair_errors, frame_ms, inlier_shares = [], [], [], [], [], [], []
    observations = TrackObservations()
    previous: tuple[TrueFrame, Tracks] | None = None
    kept: dict[int, tuple[TrueFrame, Tracks]] = {}  # the frames a later pose may be measured against
    pipeline = None
    with held_signals() as signals:
        frames = progress_bar(frames, total=total, unit="frame", disable=not progress)
        for pipeline, frame, result in run_pipeline(frames, config, tracker, seed, ground_truth):
            frame_errors = track_errors(*previous, frame, result.tracks) if previous else np.zeros(0)
            frame_pair_errors = _pair_errors(frame, result, kept)
            diagnostics.append(_diagnostics(frame, result, frame_errors, frame_pair_errors))
            errors.append(frame_errors)
            pair_errors.append(frame_pair_errors)
            truth.append(frame.T_world_cam)
            online.append(result.T_world_cam)
            frame_ms.append(sum(result.timings_ms.values()))
            if result.relative is not None:
                inlier_shares.append(result.relative.inliers.sum() / result.shared if result.shared else np.nan)
            if frame.T_world_cam is not None:
                observations.add(result.tracks.ids, result.tracks.points, frame.K, frame.T_world_cam)
            if sink is not None:
                sink(frame, result, diagnostics[-1])
            previous = (replace(frame, image=None, landmarks=None), result.tracks)  # what the next frame needs
            kept[result.index] = previous
            odometry = pipeline.odometry
            kept = {i: v for i, v in kept.items() if i in (odometry.keyframe, odometry.previous_keyframe)}
            signals.checkpoint()
    if not online:
        raise InputError("no frames to process")
    unknown = np.full((4, 4), np.nan)
    known = [T if T is not None else unknown for T in truth]
    has_truth = any(T is not None for T in truth)
    return RunOutput(
        np.stack(online),
        np.stack(known) if has_truth else None,
        diagnostics,
        np.concatenate(errors),
        np.concatenate(pair_errors),
        pipeline,
        np.array(frame_ms),
        np.array(inlier_shares, float),
        observations.errors(),
        observations,
    )


def simulate(
    scenario_config: ScenarioConfig,
    tracker_config: TrackerConfig,
    odometry_config: OdometryConfig,
    out: str | Path | None = None,
    metadata: dict | None = None,
    progress: bool = True,
    limit: bool = False,
) -> dict:
    """Run one simulated trajectory end to end (logged to ``out`` if given); ``limit``: its summary has the
    batch bundle adjustment's limit too (``RunOutput.summary``).

    Returns {"estimate", "truth", "summary" (``RunOutput.summary``), "final_ate_se3", "scale", "pipeline",
    "world", "diagnostics"}.
    """
    if out is not None:
        from deepslam.logs.writer import check_output

        check_output(out)
    scenario = Scenario(scenario_config)
    through = scenario.passes_through()
    if through is not None:
        warnings.warn(  # said once a command however many runs meet it (deepslam.cli)
            f"the camera passes through a surface of the {scenario_config.world} world at frame {through} of "
            f"{scenario_config.frames} ({scenario_config.trajectory}, seed {scenario_config.seed}): from there on "
            "it sees the world from behind (fewer --frames, a lower --speed or another path keep it in front)",
            stacklevel=2,
        )
    if odometry_config.scale == "plane" and odometry_config.plane_distance is None:
        odometry_config = replace(odometry_config, plane_distance=scenario.plane_distance())
    config, seed = PipelineConfig(tracker_config, odometry_config), scenario_config.seed
    frames = simulated_frames(scenario)
    if out is None:
        output = run_frames(frames, config, None, len(scenario), progress, seed=seed)
    else:
        meta = {
            "scenario": asdict(scenario_config),
            "odometry": asdict(odometry_config),
            "frontend": tracker_config.frontend,
            "tracker": asdict(tracker_config),
            **(metadata or {}),
        }
        output = run_logged(frames, config, out, meta, len(scenario), progress, seed)
    return {
        "estimate": output.estimate,
        "truth": output.truth,
        "summary": output.summary(limit=limit),
        "final_ate_se3": drift.ate_rmse(output.pipeline.trajectory(), output.truth),
        "scale": odometry_config.scale,
        "pipeline": output.pipeline,
        "world": scenario.world,
        "diagnostics": output.diagnostics,
    }


def replay(
    source: str | Path,
    tracker_config: TrackerConfig,
    odometry_config: OdometryConfig,
    out: str | Path,
    metadata: dict | None = None,
    progress: bool = True,
    source_options: SourceOptions = SourceOptions(),
) -> dict:
    """Run the pipeline on recorded data into a new log (never over its input): a deepslam log, a ROS 2
    bag, a TUM RGB-D or an EuRoC/ASL folder (``deepslam.inputs``), checked before any work starts.
    The log's metadata keeps the input's own calibration; its CameraInfo the K the pipeline used."""
    from deepslam.logs.writer import check_output

    if tracker_config.frontend == "oracle":
        raise InputError("the oracle front-end needs the simulator's landmarks, which recorded data does not hold")
    check_output(out, inputs=(source,))
    frames = open_source(source, source_options)
    if odometry_config.scale == "gt" and frames.frames_with_truth < len(frames):
        raise InputError(
            f"{source}: --scale gt needs ground truth in every frame, {frames.frames_with_truth} of {len(frames)} "
            f"have it; use --scale map (the default: the first baseline from the truth there is), none or plane"
        )
    meta = {
        "replayed_from": str(source),
        "source": frames.kind,
        "source_calibration": frames.calibration.to_metadata() if frames.calibration else None,
        "odometry": asdict(odometry_config),
        "frontend": tracker_config.frontend,
        "tracker": asdict(tracker_config),
        **(metadata or {}),
    }
    inputs = (TrueFrame(f.image, f.K, f.stamp_ns, f.T_world_cam) for f in frames.frames())
    output = run_logged(inputs, PipelineConfig(tracker_config, odometry_config), out, meta, len(frames), progress)
    return {
        "estimate": output.estimate,
        "truth": output.truth,
        "scale": odometry_config.scale,
        "summary": output.summary(odometry_config.scale),
        "diagnostics": output.diagnostics,
    }


def to_log_frame(
    frame: TrueFrame, result: FrameResult, reference_stamp_ns: int | None, diagnostics: FrameDiagnostics
) -> LogFrame:
    """The log record of one processed frame (the format lives in ``logs``; the content here)."""
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
        diagnostics,
        result.map_points,
    )


def run_logged(
    frames: Iterable[TrueFrame],
    config: PipelineConfig,
    out: str | Path,
    metadata: dict,
    total: int | None = None,
    progress: bool = True,
    seed: int = 0,
) -> RunOutput:
    """``run_frames`` writing every frame to an MCAP log at ``out`` as it is processed, and the run's
    summary when it ends. The log is finished cleanly on Ctrl-C (and then the interruption propagates)."""
    from deepslam.logs.writer import LogWriter

    stamps: list[int] = []
    with LogWriter(out, metadata) as log:

        def sink(frame: TrueFrame, result: FrameResult, diagnostics: FrameDiagnostics) -> None:
            stamps.append(frame.stamp_ns)
            log.write(to_log_frame(frame, result, stamps[result.reference], diagnostics))

        output = run_frames(frames, config, sink, total, progress, seed=seed)
        log.add_summary(output.summary(config.odometry.scale, timing=False))  # the same seed, the same bytes
        return output
