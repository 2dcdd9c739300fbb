"""Running the odometry end to end on a simulated scenario (evaluation code: it uses ``sim``)."""

from __future__ import annotations

from dataclasses import asdict, replace
from pathlib import Path
from typing import Callable, Iterable

import numpy as np
from tqdm import tqdm

from deepslam.backend import drift
from deepslam.backend.odometry import FrameResult, InputFrame, Odometry, OdometryConfig
from deepslam.frontend.tracking import FRONTENDS, ClassicalTracker, MagicTracker, OracleTracker, Tracker, Truth
from deepslam.sim.scenario import Scenario, ScenarioConfig


def make_tracker(
    name: str,
    seed: int = 0,
    iterations: int = 1,
    ransac: bool = False,
    refine: bool = True,
    carry: bool = True,
    oracle_noise_px: float = 0.5,
    detector_scale: int = 2,
) -> Tracker:
    """A front-end by name (``frontend.tracking.FRONTENDS``), with the shipped networks for "magic"
    (MagicPoint S at the evaluation threshold 0.001, at most 150 points: the oracle's budget, on the
    image enlarged ``detector_scale`` times, with grid shifts so that detections move with the image:
    four at scale 1, two above, to stay within the 30 fps budget); the oracle's projections get
    Gaussian noise of ``oracle_noise_px`` pixels."""
    if name == "magic":
        from deepslam.frontend.magicpoint import MagicPoint
        from deepslam.frontend.magicwarp import MagicWarp

        detector = MagicPoint.pretrained(
            "S",
            threshold=0.001,
            top_k=150,
            grid_shifts=4 if detector_scale == 1 else 2,
            subpixel=True,
            upsample=detector_scale,
        )
        return MagicTracker(
            detector, MagicWarp.pretrained(), iterations=iterations, ransac=ransac, refine=refine, carry=carry
        )
    if name == "classical":
        return ClassicalTracker()
    if name == "oracle":
        return OracleTracker(noise_px=oracle_noise_px, seed=seed)
    raise ValueError(f"unknown front-end {name!r}; expected one of {', '.join(FRONTENDS)}")


def _front_end_options(frontend: str, config: OdometryConfig, tracker_options: dict) -> dict:
    """``tracker_options`` with the defaults that depend on the odometry: carried magic tracks sit where
    the dominant plane's homography puts them, so they are on by default only when relative poses come
    from that homography too."""
    return {"carry": config.method == "homography", **tracker_options} if frontend == "magic" else tracker_options


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
    for frame in tqdm(frames, total=total, unit="frame", disable=not progress, dynamic_ncols=True):
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
    frontend: str,
    odometry_config: OdometryConfig,
    out: str | Path | None = None,
    metadata: dict | None = None,
    progress: bool = True,
    **tracker_options,
) -> dict:
    """Run one simulated trajectory end to end (logged to ``out`` if given).

    Returns {"estimate", "truth", "drift", "scale", "odometry"}; the drift figures say which scale was used.
    """
    scenario = Scenario(scenario_config)
    if odometry_config.scale == "plane" and odometry_config.plane_distance is None:
        odometry_config = replace(odometry_config, plane_distance=scenario.plane_distance())
    tracker_options = _front_end_options(frontend, odometry_config, tracker_options)
    odometry = Odometry(make_tracker(frontend, scenario_config.seed, **tracker_options), odometry_config)
    frames = simulated_frames(scenario)
    if out is None:
        estimate, truth = run_frames(frames, odometry, None, len(scenario), progress)
    else:
        meta = {
            "scenario": asdict(scenario_config),
            "odometry": asdict(odometry_config),
            "frontend": frontend,
            "frontend_options": tracker_options,
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
    frontend: str,
    odometry_config: OdometryConfig,
    out: str | Path,
    metadata: dict | None = None,
    progress: bool = True,
    **tracker_options,
) -> dict:
    """Feed a log's images (camera info, ground truth) through the pipeline again into a new log
    (never over the log it reads)."""
    from deepslam.logs.reader import check_log

    if frontend == "oracle":
        raise ValueError("the oracle front-end needs the simulator's landmarks, which logs do not hold")
    check_log(log)
    if Path(out).resolve() == Path(log).resolve():
        raise ValueError(f"replaying {log} into itself would overwrite it; choose another --out")
    tracker_options = _front_end_options(frontend, odometry_config, tracker_options)
    odometry = Odometry(make_tracker(frontend, **tracker_options), odometry_config)
    meta = {
        "replayed_from": str(log),
        "odometry": asdict(odometry_config),
        "frontend": frontend,
        "frontend_options": tracker_options,
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


def bench_pipeline(frames: int = 60, seed: int = 0, detector_scale: int = 2) -> dict[str, float]:
    """Mean per-frame milliseconds of each stage on one thread (rendering not counted), magic front-end
    (``make_tracker`` defaults but for ``detector_scale``): the odometry's stages, and inside its
    front-end MagicPoint, MagicWarp and matching."""
    import torch

    torch.set_num_threads(1)
    rendered = list(simulated_frames(Scenario(ScenarioConfig(frames=frames, seed=seed))))
    tracker = make_tracker("magic", seed, detector_scale=detector_scale)
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


def pipeline_matrix(
    worlds: tuple[str, ...] = ("plane", "room"),
    frontends: tuple[str, ...] = ("oracle", "magic", "classical"),
    noises: tuple[float, ...] = (0.0, 1.0),
    frames: int = 60,
    seeds: tuple[int, ...] = tuple(range(6)),
    scale: str = "gt",
    trajectory: str = "circle",
    detector_scale: int = 2,
    progress: bool = True,
) -> list[dict]:
    """Drift of every world x front-end x noise combination, averaged over ``seeds`` (the magic front-end's
    MagicPoint on the image enlarged ``detector_scale`` times); each row also keeps its per-seed ATE SE3."""
    if not (worlds and frontends and noises and seeds):
        raise ValueError("the drift matrix needs at least one world, front-end, noise magnitude and seed")
    cells = [(world, noise, frontend) for world in worlds for noise in noises for frontend in frontends]
    rows = []
    with tqdm(total=len(cells) * len(seeds), unit="run", disable=not progress, dynamic_ncols=True) as bar:
        for world, noise, frontend in cells:
            runs = []
            for seed in seeds:
                bar.set_description(f"{world} noise {noise:g} {frontend} seed {seed}")
                scenario = ScenarioConfig(world=world, trajectory=trajectory, frames=frames, noise=noise, seed=seed)
                runs.append(
                    simulate(
                        scenario, frontend, OdometryConfig(scale=scale), progress=False, detector_scale=detector_scale
                    )["drift"]
                )
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
