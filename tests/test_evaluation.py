"""Evaluation against the simulator's truth: track consistency and the batch bundle adjustment's limit."""

import tracemalloc

import numpy as np
import pytest

from deepslam.backend.config import PipelineConfig
from deepslam.backend.drift import ate_rmse
from deepslam.backend.evaluation.consistency import CONSISTENT_PX, TrackObservations, consistent_share
from deepslam.backend.evaluation.limit import batch_adjust, causal_adjust, over_limit
from deepslam.backend.evaluation.runs import run_frames, simulated_frames
from deepslam.backend.mapping import project
from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig
from deepslam.geometry import path_length
from deepslam.sim.scenario import Scenario, ScenarioConfig


def _circle(frames: int, radius: float = 0.5) -> list[np.ndarray]:
    """Camera poses (4, 4) on a circle in the x-z plane, all looking along +z."""
    poses = []
    for angle in np.linspace(0, np.pi / 2, frames):
        T = np.eye(4)
        T[:3, 3] = radius * np.array([np.cos(angle) - 1, 0.1 * np.sin(3 * angle), np.sin(angle)])
        poses.append(T)
    return poses


def _observed(poses: list[np.ndarray], world: np.ndarray, K: np.ndarray, noise: float, seed: int = 0):
    rng = np.random.default_rng(seed)
    observations = TrackObservations()
    for T in poses:
        pixels = project(T, K, world)[0] + rng.normal(0, noise, (len(world), 2))
        observations.add(np.arange(len(world)), pixels, K, T)
    return observations


K = np.array([[100.0, 0, 80], [0, 100.0, 60], [0, 0, 1]])


def test_consistency_finds_the_observations_of_a_track_that_jumped():
    world = np.c_[np.random.default_rng(1).uniform(-1, 1, (40, 2)), np.random.default_rng(2).uniform(3, 5, 40)]
    observations = _observed(_circle(10), world, K, noise=0.3)
    observations.points[-1][0] += 15.0  # track 0 jumps to another point in the last frame
    errors = observations.errors()
    assert len(errors) == 400
    assert 0.97 < consistent_share(errors) < 1.0
    assert np.sum(errors > CONSISTENT_PX) >= 1


def test_consistency_of_a_track_seen_for_thousands_of_frames_takes_little_memory():
    world = np.array([[0.0, 0.0, 4.0]])
    observations = _observed(_circle(3000), world, K, noise=0.3)
    tracemalloc.start()
    errors = observations.errors()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert len(errors) == 3000 and consistent_share(errors) == 1.0
    assert peak < 5e6, f"{peak / 1e6:.0f} MB for one track seen 3000 times"


def _scene(points: int = 150, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.c_[rng.uniform(-2, 2, (points, 2)), rng.uniform(3, 6, points)]


def test_the_limit_keeps_a_run_with_exact_tracks_at_the_truth():
    poses = _circle(20)
    limit = batch_adjust(_observed(poses, _scene(), K, noise=0.0))
    assert limit.tracks >= 140 and limit.observations == 20 * limit.tracks  # a few too far to triangulate
    assert limit.ate_se3 < 1e-6


def test_the_limit_of_noisy_tracks_is_small_and_grows_with_the_noise():
    poses = _circle(30)
    length = path_length(np.stack(poses))
    figures = [batch_adjust(_observed(poses, _scene(), K, noise=noise)).ate_se3 for noise in (0.5, 2.0)]
    assert 0 < figures[0] < 0.02 * length and figures[1] > 2 * figures[0]


def test_the_limit_holds_the_scale_by_the_baseline_it_is_given():
    poses = _circle(30)
    observations = _observed(poses, _scene(), K, noise=0.5)
    scales = {b: batch_adjust(observations, baseline=b).ate_se3 for b in (None, 5, 20)}
    assert len(set(scales.values())) == 3  # each baseline's true length sets another scale
    for outside in (0, 30, -1):
        with pytest.raises(InputError, match="the baseline must be one of frames 1 to 29"):
            batch_adjust(observations, baseline=outside)


def test_the_causal_limit_places_each_frame_without_the_frames_after_it():
    poses = _circle(12)
    exact = causal_adjust(_observed(poses, _scene(), K, noise=0.0))
    assert np.allclose(exact[5:], np.stack(poses[5:]), atol=1e-6)  # frames 2-4 alone see no point 6 px apart
    observations = _observed(poses, _scene(), K, noise=0.5)
    causal, batch = causal_adjust(observations), batch_adjust(observations)
    assert np.allclose(causal[-1], batch.poses[-1])  # the last frame: one and the same adjustment
    assert np.allclose(causal[6], batch_adjust(observations.head(7)).poses[-1])
    assert not np.allclose(causal[6], batch.poses[6], atol=1e-5)  # the frames after frame 6 move it
    assert ate_rmse(causal, np.stack(poses)) > batch.ate_se3  # less to go on: further from the truth


def test_the_limit_drops_the_observations_of_a_track_that_jumped():
    poses = _circle(20)
    observations = _observed(poses, _scene(), K, noise=0.3)
    near = int(np.argmin(_scene()[:, 2]))
    for frame in range(15, 20):  # the nearest point's track follows another point for the last five frames
        observations.points[frame][near] += 25.0
    limit = batch_adjust(observations)
    assert limit.tracks >= 140
    assert 20 * limit.tracks - 10 <= limit.observations <= 20 * limit.tracks - 5  # the five, and a few it pulled


def test_a_frame_whose_few_observations_leave_its_pose_loose_moves_on_as_a_lost_frame():
    poses = _circle(20)
    observations = _observed(poses, _scene(), K, noise=0.5)
    near = np.array([[0.1, 0.05, 0.5], [-0.12, 0.03, 0.55], [0.03, -0.1, 0.45], [-0.07, -0.06, 0.6], [0, 0.1, 0.5]])
    pixels = [project(poses[frame], K, near + poses[-1][:3, 3])[0] for frame in (17, 18, 19)]
    pixels = [p + np.random.default_rng(1).normal(0, 0.5, p.shape) for p in pixels]
    observations.ids[17] = np.r_[observations.ids[17], np.arange(1000, 1005)]
    observations.points[17] = np.r_[observations.points[17], pixels[0]]
    for frame, seen in zip((18, 19), pixels[1:], strict=True):  # only five near points, seen from frame 17 on
        observations.ids[frame], observations.points[frame] = np.arange(1000, 1005), seen
    limit = batch_adjust(observations)  # five points each would let the adjustment move them 5-13 cm
    for frame in (18, 19):  # the step before, again
        previous, before = limit.poses[frame - 1], limit.poses[frame - 2]
        assert np.allclose(limit.poses[frame], previous @ np.linalg.inv(before) @ previous)
    assert limit.ate_se3 < 0.015
    assert not np.allclose(limit.poses[17], poses[17], atol=1e-4)  # the frames before are adjusted


def test_a_rotation_gives_the_limit_no_track_to_adjust():
    poses = []
    for angle in np.radians(np.arange(10)):
        T = np.eye(4)
        T[:3, :3] = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
        poses.append(T)
    limit = batch_adjust(_observed(poses, _scene(), K, noise=0.3))
    assert limit.tracks == 0 and np.allclose(limit.poses, np.stack(poses))
    assert limit.ate_se3 == 0 and np.isnan(over_limit(0.01, limit.ate_se3))  # no limit, not a division by zero


def test_a_run_drifts_more_than_the_limit_of_its_own_tracks():
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="circle", frames=30, seed=0))
    output = run_frames(simulated_frames(scenario), PipelineConfig(TrackerConfig("oracle")), progress=False)
    summary = output.summary(limit=True)
    limit = output.limit()
    assert limit.tracks > 50 and limit.observations > 10 * limit.tracks
    assert summary["limit_ate_se3"] == limit.ate_se3 < summary["ate_se3"]
    assert summary["ate_over_limit"] == pytest.approx(summary["ate_se3"] / limit.ate_se3)
    assert "limit_ate_se3" not in output.summary()  # only when asked: it adjusts the whole run
