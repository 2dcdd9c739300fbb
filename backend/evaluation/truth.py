"""Ground truth for evaluation runs, kept apart from the pipeline.

The pipeline sees images, K and stamps only. What a simulator or a dataset knows of a frame travels as a
``TrueFrame``; ``GroundTruth`` hands the parts an evaluation may use to the pipeline it builds: the first
frame's pose, true step lengths for ``scale="gt"`` (and the first baseline of ``"map"``) and the oracle
front-end's landmark projections.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterable, Iterator

import numpy as np

from deepslam.backend.config import PipelineConfig
from deepslam.backend.odometry import FrameResult
from deepslam.backend.pipeline import Pipeline
from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig
from deepslam.frontend.tracking import OracleTracker, Tracker, Truth


@dataclass
class TrueFrame:
    """A frame with what its source knows of it: image uint8 (H, W); K (3, 3); stamp_ns int; T_world_cam
    (4, 4) ground truth or None; landmarks: the visible landmarks' projections (simulator) or None; depth
    (H, W) true z per pixel (simulator) or None."""

    image: np.ndarray
    K: np.ndarray
    stamp_ns: int
    T_world_cam: np.ndarray | None = None
    landmarks: Truth | None = None
    depth: np.ndarray | None = None


class GroundTruth:
    """The truth of the frames a run has seen so far, in processing order (``see`` each frame before the
    pipeline processes it)."""

    def __init__(self):
        self.poses: list[np.ndarray | None] = []
        self._landmarks: Truth | None = None

    def see(self, frame: TrueFrame) -> None:
        self.poses.append(frame.T_world_cam)
        self._landmarks = frame.landmarks

    def step_length(self, i: int, j: int) -> float:
        """The true distance (m) between the cameras of frames i and j."""
        length = self.known_step_length(i, j)
        if length is None:
            raise InputError("scale 'gt' needs ground-truth poses in every frame")
        return length

    def known_step_length(self, i: int, j: int) -> float | None:
        """The true distance (m) between the cameras of frames i and j, None where either has no truth."""
        a, b = self.poses[i], self.poses[j]
        return None if a is None or b is None else float(np.linalg.norm(b[:3, 3] - a[:3, 3]))

    def landmarks(self) -> Truth:
        """The visible landmarks of the frame last seen (the oracle's input)."""
        if self._landmarks is None:
            raise InputError("the oracle front-end needs the simulator's landmarks (simulated runs only)")
        return self._landmarks

    def oracle(self, config: TrackerConfig, seed: int = 0) -> OracleTracker:
        """The oracle front-end of ``config`` (budget, pixel noise), fed from this truth."""
        return OracleTracker(self.landmarks, budget=config.budget, noise_px=config.oracle_noise, seed=seed)

    def pipeline(
        self, config: PipelineConfig, first: TrueFrame, tracker: Tracker | None = None, seed: int = 0
    ) -> Pipeline:
        """A pipeline for ``config`` that starts where ``first`` truly is (if known), takes true step lengths
        with ``scale="gt"`` and, for the oracle front-end, this truth's landmarks (``seed``: its noise)."""
        if tracker is None and config.tracker.frontend == "oracle":
            tracker = self.oracle(config.tracker, seed)
        scale = config.odometry.scale  # "map" takes its first baseline's length from the truth where there is any
        step_lengths = {"gt": self.step_length, "map": self.known_step_length}.get(scale)
        return Pipeline(config, tracker, first.T_world_cam, step_lengths)


def run_pipeline(
    frames: Iterable[TrueFrame],
    config: PipelineConfig,
    tracker: Tracker | None = None,
    seed: int = 0,
    truth: GroundTruth | None = None,
) -> Iterator[tuple[Pipeline, TrueFrame, FrameResult]]:
    """Each frame through a pipeline built at the first one (``GroundTruth.pipeline``; ``truth``: the one
    ``tracker`` reads, if it is an oracle of one's own), its truth seen first; yields (the pipeline, the
    frame, its result)."""
    truth, pipeline = truth or GroundTruth(), None
    for frame in frames:
        truth.see(frame)
        pipeline = pipeline or truth.pipeline(config, frame, tracker, seed)
        yield pipeline, frame, pipeline.process(frame.image, frame.K, frame.stamp_ns)
