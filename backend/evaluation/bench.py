"""Per-frame timings of the whole pipeline on a simulated run, and how they and memory grow on long runs."""

from __future__ import annotations

import resource
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from deepslam.backend.config import OdometryConfig
from deepslam.backend.evaluation.config import PipelineBenchConfig
from deepslam.backend.evaluation.runs import simulated_frames
from deepslam.backend.evaluation.truth import run_pipeline
from deepslam.backend.pipeline import PipelineConfig
from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig
from deepslam.progress import progress_bar
from deepslam.results import Result
from deepslam.sim.scenario import Scenario, ScenarioConfig

EARLY_FRAME = 500  # long runs: growth is measured from this frame to the last
WINDOW = 100  # frames averaged for the graph time around a point of the run


def resident_mb() -> float:
    """This process's resident memory in MB (the peak where /proc is missing)."""
    statm = Path("/proc/self/statm")
    if statm.exists():
        return int(statm.read_text().split()[1]) * resource.getpagesize() / 1e6
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1e3


def bench_pipeline(
    frames: int = PipelineBenchConfig.frames,
    seed: int = 0,
    tracker_config: TrackerConfig = TrackerConfig(),
    rounds: int = PipelineBenchConfig.rounds,
) -> PipelineTimings:
    """Per-frame milliseconds of each stage (rendering not counted) of the front-end ``tracker_config``
    describes: the odometry's stages, and inside a magic front-end MagicPoint, MagicWarp, matching and
    ``polish_carried`` (contrast normalisation, alignment of carried tracks); the marginal covariance is off
    (it is only for the log). The run is timed ``rounds`` times, each with a fresh front-end and odometry,
    and every stage reports the median of its per-round means, so that a round slowed by other work on the
    machine does not decide the figure; with several rounds ``fps_slowest_round`` and ``fps_fastest_round``
    show the spread. Frames are rendered as they go, so a long run holds one at a time. Runs longer than
    ``EARLY_FRAME`` frames also report resident memory (MB) and the graph's milliseconds per frame (mean over
    ``WINDOW`` frames) at frame ``EARLY_FRAME`` and at the end, of the last round. Time it on one torch
    thread (the CLI sets it)."""
    if rounds < 1:
        raise InputError(f"the bench needs at least 1 round, got {rounds}")
    per_round, growth = [], {}
    for _ in range(rounds):
        means, growth = _timed_run(frames, seed, tracker_config)
        per_round.append(means)
    medians = {name: float(np.median([means[name] for means in per_round])) for name in per_round[0]}
    medians["fps"] = 1e3 / medians["per_frame_total"]
    if rounds > 1:
        fps = [1e3 / means["per_frame_total"] for means in per_round]
        medians |= {"fps_slowest_round": min(fps), "fps_fastest_round": max(fps)}
    return PipelineTimings(medians | growth)


@dataclass
class PipelineTimings(Result):
    """``deepslam bench pipeline``: milliseconds per frame of each stage, frames per second, and on long
    runs memory (MB) and the graph's time at frame ``EARLY_FRAME`` and at the end (``timings``)."""

    timings: dict[str, float]
    name: ClassVar[str] = "bench_pipeline"

    def to_dict(self) -> dict:
        return self.timings

    def lines(self) -> list[str]:
        def unit(name: str) -> str:
            return "" if name.startswith("fps") else "MB" if name.startswith("memory") else "ms"

        return [f"  {name:<24} {value:8.2f} {unit(name)}" for name, value in self.timings.items()]

    def plots(self, out: Path) -> list[Path]:
        return save_plots(self.timings, out)


def _timed_run(frames: int, seed: int, tracker_config: TrackerConfig) -> tuple[dict[str, float], dict[str, float]]:
    """One timed run of ``bench_pipeline``: (mean milliseconds per frame of each stage and their total,
    memory and graph time at frame ``EARLY_FRAME`` and at the end of a long run)."""
    config = PipelineConfig(tracker_config, OdometryConfig(covariance=False))
    stages: dict[str, list[float]] = {}
    growth: dict[str, float] = {}
    scenario = Scenario(ScenarioConfig(frames=frames, seed=seed))
    timed = run_pipeline(progress_bar(simulated_frames(scenario), total=frames, unit="frame"), config, seed=seed)
    for index, (pipeline, _, result) in enumerate(timed):
        tracker, timings = pipeline.tracker, result.timings_ms
        for name, ms in [*tracker.timings_ms.items(), *((f"odometry.{k}", v) for k, v in timings.items())]:
            stages.setdefault(name, []).append(ms)
        if frames > EARLY_FRAME and index + 1 in (EARLY_FRAME, frames):
            at = "end" if index + 1 == frames else str(EARLY_FRAME)
            growth[f"memory_mb@{at}"] = resident_mb()
            growth[f"graph_ms@{at}"] = float(np.mean(stages["odometry.graph"][-WINDOW:]))
    means = {name: float(np.mean(values)) for name, values in stages.items()}
    means["per_frame_total"] = sum(v for k, v in means.items() if k.startswith("odometry."))
    return means, growth


def save_plots(timings: dict[str, float], out_dir) -> list:
    """PNG: milliseconds per frame of each stage (the odometry's, and inside the front-end)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    stages = {k: v for k, v in timings.items() if not k.startswith(("memory", "graph_ms", "fps", "per_frame"))}
    fig, ax = plt.subplots(figsize=(8, 3.6))
    ax.barh(list(stages), list(stages.values()))
    ax.set(xlabel="ms per frame", title=f"pipeline stages ({timings['fps']:.0f} frames per second)")
    fig.tight_layout()
    path = out_dir / "bench_pipeline.png"
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return [path]
