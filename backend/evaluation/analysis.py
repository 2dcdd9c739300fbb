"""Drift analysis from logs alone: figures side by side, plots, TUM export."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from deepslam.backend import drift
from deepslam.backend.evaluation.config import DriftConfig
from deepslam.backend.evaluation.consistency import TrackObservations
from deepslam.backend.evaluation.limit import batch_adjust, over_limit
from deepslam.files import distinct_names
from deepslam.geometry import quaternion_from_matrix
from deepslam.logs.reader import LogError, read_frames, read_metadata
from deepslam.results import Result


def load_trajectories(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(stamps_ns (N,), ground truth (N, 4, 4), estimate (N, 4, 4)) of the frames that have both."""
    stamps, truth, estimate, truth_seen = [], [], [], False
    for frame in read_frames(path):
        truth_seen |= frame.T_groundtruth is not None
        if frame.T_groundtruth is not None and frame.T_estimate is not None:
            stamps.append(frame.stamp_ns)
            truth.append(frame.T_groundtruth)
            estimate.append(frame.T_estimate)
    if len(stamps) < 2:
        if not truth_seen:
            raise LogError(
                f"{path}: no frame has ground truth (/groundtruth/pose), so there is no drift to measure; "
                "`deepslam report` draws a run without it"
            )
        raise LogError(f"{path}: fewer than 2 frames with both /groundtruth/pose and /estimate/pose")
    return np.array(stamps, np.int64), np.stack(truth), np.stack(estimate)


def lost_frames(path: str | Path) -> int | None:
    """How many frames of a log were lost (no relative pose); None for a log without diagnostics."""
    flags = [frame.diagnostics.lost for frame in read_frames(path) if frame.diagnostics is not None]
    return sum(flags) if flags else None


def track_observations(path: str | Path) -> TrackObservations:
    """Every track observation of a log, with each frame's true pose; every frame must have both."""
    observations = TrackObservations()
    for frame in read_frames(path):
        if frame.T_groundtruth is None or frame.tracks is None:
            raise LogError(f"{path}: the limit needs ground truth and tracks in every frame; frame {frame.stamp_ns} ns")
        observations.add(frame.tracks[:, 3].astype(np.int64), frame.tracks[:, :2], frame.K, frame.T_groundtruth)
    return observations


def analyse(
    paths: list[str | Path], delta: int = DriftConfig.delta, limit: bool = DriftConfig.limit
) -> DriftComparison:
    """Drift figures per log, with its front-end and scale method from the log's metadata and its lost
    frames (-1 where the log does not say); with ``limit``, the ATE SE3 of the batch bundle adjustment of its
    own tracks started at the truth (``deepslam.backend.evaluation.limit``) and the log's ATE over it."""
    results = {}
    for path in paths:
        _, truth, estimate = load_trajectories(path)
        meta = read_metadata(path)
        lost = lost_frames(path)
        results[str(path)] = {
            **drift.summary(estimate, truth, delta),
            "frontend": meta.get("frontend", "?"),
            "scale": meta.get("odometry", {}).get("scale", "?"),
            "lost_frames": -1 if lost is None else lost,
        }
        if limit:
            best, figures = batch_adjust(track_observations(path)).ate_se3, results[str(path)]
            figures |= {"limit_ate_se3": best, "ate_over_limit": over_limit(figures["ate_se3"], best)}
    return DriftComparison(results, delta)


LIMIT_NOTE = [
    "limit: ATE SE3 (m) of one batch bundle adjustment of the log's own tracks, started at the truth (the best any "
    "back-end could do with them); /limit: the log's ATE SE3 over it"
]


@dataclass
class DriftComparison(Result):
    """``deepslam drift``: per log (by path) its drift figures (``backend.drift.summary``, RPE over ``delta``
    frames), front-end, scale and lost frames; its plots read the logs again."""

    logs: dict[str, dict]
    delta: int = DriftConfig.delta
    name: ClassVar[str] = "drift"

    def to_dict(self) -> dict:
        return self.logs

    def lines(self) -> list[str]:
        meanings = (
            f"ATE: RMSE of positions after SE(3) / Sim(3) alignment (m); RPE: mean over frame pairs {self.delta} "
            "apart (m, deg); final: position error at the end, % of the true path; scale dr(ift): estimated over "
            "true path length, last quarter against first"
        )
        limit = any("limit_ate_se3" in r for r in self.logs.values())
        return [*table_lines(self.logs), meanings, *(LIMIT_NOTE if limit else [])]

    def plots(self, out: Path) -> list[Path]:
        return save_plots(list(self.logs), out, self.delta)


def table_lines(results: dict[str, dict]) -> list[str]:
    """A row per log, named whole by its file name (with its folders where names repeat: ``distinct_names``); the
    limit's columns where the figures have them."""
    names = distinct_names(list(results))
    width = max([len("log")] + [len(name) for name in names.values()])
    limit = any("limit_ate_se3" in r for r in results.values())
    header = (
        f"{'log':<{width}} {'frontend':<9} {'scale':<6} {'ATE SE3':>8} {'ATE Sim3':>8} {'RPE m':>8} {'RPE deg':>8} "
        f"{'final %':>8} {'scale dr':>8} {'path m':>7} {'lost':>5}" + (f" {'limit':>8} {'/limit':>6}" if limit else "")
    )
    rows = [header]
    for path, r in results.items():
        rows.append(
            f"{names[path]:<{width}} {r['frontend']:<9} {r['scale']:<6} "
            f"{r['ate_se3']:>8.4f} {r['ate_sim3']:>8.4f} "
            f"{r['rpe_trans']:>8.4f} {r['rpe_rot_deg']:>8.3f} {r['final_drift_pct']:>8.2f} "
            f"{r.get('scale_drift', float('nan')):>8.3f} {r['path_length']:>7.2f} "
            f"{r['lost_frames'] if r['lost_frames'] >= 0 else '?':>5}"
            + (f" {r['limit_ate_se3']:>8.4f} {r['ate_over_limit']:>6.2f}" if limit else "")
        )
    return rows


def save_plots(paths: list[str | Path], out_dir: Path, delta: int = DriftConfig.delta) -> list[Path]:
    """PNG plots: the ground truth and estimates seen along the axis with the least motion (a top view for
    a camera moving on the ground; a front view for one circling in a vertical plane), translation error
    over time, RPE distribution."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    fig, axes = plt.subplots(1, 3, figsize=(16, 4.5))
    names = distinct_names(paths)
    for index, path in enumerate(paths):
        stamps, truth, estimate = load_trajectories(path)
        label = str(Path(names[str(path)]).with_suffix(""))
        if index == 0:
            shown = np.sort(np.argsort(truth[:, :3, 3].std(0))[1:])  # the two axes with the most motion
            axes[0].plot(truth[:, shown[0], 3], truth[:, shown[1], 3], "k-", lw=2, label="ground truth")
        axes[0].plot(estimate[:, shown[0], 3], estimate[:, shown[1], 3], "-", label=label)
        seconds = (stamps - stamps[0]) / 1e9
        axes[1].plot(seconds, np.linalg.norm(estimate[:, :3, 3] - truth[:, :3, 3], axis=1), label=label)
        axes[2].hist(drift.rpe(estimate, truth, delta)[0], bins=30, alpha=0.5, label=label)
    names = "xyz"
    axes[0].set(
        title=f"trajectory ({names[shown[0]]}, {names[shown[1]]})",
        xlabel=f"{names[shown[0]]} (m)",
        ylabel=f"{names[shown[1]]} (m)",
    )
    axes[0].axis("equal")
    axes[1].set(title="translation error over time (no alignment)", xlabel="time (s)", ylabel="error (m)")
    axes[2].set(title=f"RPE translation, delta = {delta} frame(s)", xlabel="error (m)", ylabel="frames")
    for ax in axes:
        ax.legend(fontsize=8)
    fig.tight_layout()
    path = out_dir / "drift.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]


def export_tum(path: str | Path, out_dir: Path, name: str | None = None) -> list[Path]:
    """Write NAME.groundtruth.tum and NAME.estimate.tum: "t x y z qx qy qz qw" per line, t in seconds; NAME: the
    log's file name without its suffix, or ``name`` (its folders, as ``distinct_names`` gives them, joined by _)."""
    stamps, truth, estimate = load_trajectories(path)
    out_dir.mkdir(parents=True, exist_ok=True)
    stem = str(Path(name or Path(path).name).with_suffix("")).replace("/", "_")
    written = []
    for kind, poses in (("groundtruth", truth), ("estimate", estimate)):
        target = out_dir / f"{stem}.{kind}.tum"
        lines = [
            f"{t / 1e9:.9f} " + " ".join(f"{v:.9f}" for v in (*T[:3, 3], *quaternion_from_matrix(T[:3, :3])))
            for t, T in zip(stamps, poses, strict=False)
        ]
        target.write_text("\n".join(lines) + "\n")
        written.append(target)
    return written
