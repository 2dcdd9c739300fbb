"""The local map (triangulation, PnP, bundle adjustment, culling) and scale "map"."""

from copy import deepcopy
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from deepslam.backend import drift
from deepslam.backend.config import MapConfig, OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.runs import run_frames, simulated_frames
from deepslam.backend.evaluation.truth import GroundTruth, run_pipeline
from deepslam.backend.mapping import InitialViews, Keyframe, LocalMap, _fit_error, adjust_views, project
from deepslam.backend.pipeline import Pipeline
from deepslam.backend.scale import MapScale, with_length
from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig
from deepslam.frontend.tracking import OracleTracker, Tracks
from deepslam.geometry import vector_angle
from deepslam.sim.camera import intrinsics
from deepslam.sim.scenario import Scenario, ScenarioConfig

K = intrinsics((120, 160))


def _world(rng, count=200, nearest=2.0, farthest=8.0):
    """Points (N, 3) at ``nearest``-``farthest`` m in front of the origin, spread across the view."""
    depth = rng.uniform(nearest, farthest, count)
    return np.c_[rng.uniform(-0.6, 0.6, (count, 2)) * depth[:, None], depth]


def _keyframe(index, T_world_cam, world, rng, noise=0.3):
    pixels, depth = project(T_world_cam, K, world)
    seen = (depth > 0) & np.all((pixels >= 0) & (pixels <= [159, 119]), axis=1)
    ids = np.nonzero(seen)[0]
    return Keyframe(index, T_world_cam, K, ids, pixels[seen] + rng.normal(0, noise, (len(ids), 2)))


def _sideways(x):
    T = np.eye(4)
    T[0, 3] = x
    return T


def test_a_map_tells_its_keyframes_poses_and_a_located_frames_baseline(rng):
    world = _world(rng, nearest=3.0, farthest=3.0)  # every point 3 m ahead
    local_map = LocalMap(MapConfig())
    assert not local_map.holds(0)  # not started
    local_map.start(_keyframe(0, np.eye(4), world, rng, noise=0.0), _keyframe(4, _sideways(0.6), world, rng, noise=0.0))
    assert local_map.holds(0) and local_map.holds(4) and not local_map.holds(2)
    assert local_map.pose(4)[0, 3] == pytest.approx(0.6, abs=1e-3)
    seen = _keyframe(5, _sideways(0.9), world, rng, noise=0.0)
    location = local_map.locate(seen.ids, seen.points, K, _sideways(0.8))
    # 0.3 m sideways of keyframe 4 at 3 m: 0.1 rad, times the focal length
    assert local_map.baseline_px(location, K, 4) == pytest.approx(0.1 * K[0, 0], rel=0.01)


def test_a_map_triangulates_locates_and_keeps_its_scale_through_bundle_adjustment(rng):
    world = _world(rng)
    local_map = LocalMap(MapConfig(window=4))
    assert local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.6), world, rng)) > 50
    ids, points = local_map.points()
    assert np.median(np.linalg.norm(points - world[ids], axis=1) / world[ids, 2]) < 0.03
    for index, x in enumerate((1.0, 1.4, 1.8, 2.2), start=2):  # each keyframe located, then added
        truth = _sideways(x)
        seen = _keyframe(index, truth, world, rng)
        location = local_map.locate(seen.ids, seen.points, K, _sideways(x - 0.4))
        assert location.T_world_cam is not None
        assert np.linalg.norm(location.T_world_cam[:3, 3] - truth[:3, 3]) < 0.05
        assert location.inliers.mean() > 0.9
        local_map.add(Keyframe(index, location.T_world_cam, K, seen.ids, seen.points))
    assert [k.index for k in local_map.keyframes] == [2, 3, 4, 5]  # the window
    observed = set(np.concatenate([k.ids for k in local_map.keyframes]).tolist())
    assert set(local_map.landmarks) <= observed  # culled with the keyframes that left
    ids, points = local_map.points()
    assert np.median(np.linalg.norm(points - world[ids], axis=1) / world[ids, 2]) < 0.03  # the first baseline's scale


def test_keyframes_that_left_the_window_hold_its_landmarks_where_they_saw_them(rng):
    world = _world(rng)
    config = MapConfig(window=3, fixed_keyframes=2)
    local_map = LocalMap(config)
    local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.4), world, rng))
    for index in range(2, 7):
        local_map.add(_keyframe(index, _sideways(0.4 * index), world, rng))
    assert [k.index for k in local_map.keyframes] == [4, 5, 6] and [k.index for k in local_map.retired] == [2, 3]
    held = [k.T_world_cam.copy() for k in local_map.retired]
    ids = np.array(sorted(local_map.landmarks))
    errors = {}
    for retired in (True, False):
        copy = deepcopy(local_map)
        copy.retired = copy.retired if retired else []
        for track in ids:  # every landmark 3% off its true depth, to be mended by the views of it
            copy.landmarks[int(track)] = world[track] * 1.03
        copy.adjust()
        errors[retired] = np.median(np.linalg.norm(copy.points_of(ids) - world[ids], axis=1) / world[ids, 2])
        if retired:
            assert all(np.allclose(k.T_world_cam, T) for k, T in zip(copy.retired, held, strict=True))  # held
    assert errors[True] < 0.7 * errors[False], errors  # more views, wider apart: nearer the truth


def test_pycolmap_adjusts_a_window_held_by_its_retired_keyframes_as_gtsam_does(rng):
    world = _world(rng)
    maps = {}
    for adjuster in ("gtsam", "pycolmap"):
        local_map = LocalMap(MapConfig(window=3, fixed_keyframes=2, adjuster=adjuster))
        rng_views = np.random.default_rng(1)  # the same noisy views for both
        local_map.start(_keyframe(0, np.eye(4), world, rng_views), _keyframe(1, _sideways(0.4), world, rng_views))
        for index in range(2, 7):
            moved = _sideways(0.4 * index)
            moved[:3, 3] += rng_views.normal(0, 0.02, 3)  # each keyframe placed 2 cm off, as PnP might
            local_map.add(_keyframe(index, moved, world, rng_views))
        maps[adjuster] = local_map
    assert maps["pycolmap"].retired  # the windows it solved were held by keyframes that left them
    errors = {}  # metres of the window's keyframes from the truth, and the landmarks' median share of their depth
    for adjuster, local_map in maps.items():
        placed = [np.linalg.norm(k.T_world_cam[:3, 3] - [0.4 * k.index, 0.0, 0.0]) for k in local_map.keyframes]
        ids, points = local_map.points()
        errors[adjuster] = max(placed), np.median(np.linalg.norm(points - world[ids], axis=1) / world[ids, 2])
    (gtsam_placed, gtsam_points), (colmap_placed, colmap_points) = errors["gtsam"], errors["pycolmap"]
    assert colmap_placed != gtsam_placed  # solved by the other solver ...
    assert colmap_placed < 1.1 * gtsam_placed + 0.002 and colmap_points < 1.1 * gtsam_points + 1e-3  # ... as well
    assert colmap_points < 0.03
    with pytest.raises(InputError, match="adjuster"):
        MapConfig(adjuster="ceres")


def test_pycolmap_keeps_the_first_baseline_of_a_window_no_retired_keyframe_holds(rng):
    world = _world(rng)
    maps = {}
    for adjuster in ("gtsam", "pycolmap"):
        local_map = LocalMap(MapConfig(window=6, adjuster=adjuster))
        rng_views = np.random.default_rng(2)  # the same noisy views for both
        local_map.start(_keyframe(0, np.eye(4), world, rng_views), _keyframe(1, _sideways(0.4), world, rng_views))
        for index in range(2, 5):
            moved = _sideways(0.4 * index)
            moved[:3, 3] += rng_views.normal(0, 0.02, 3)
            local_map.add(_keyframe(index, moved, world, rng_views))
        maps[adjuster] = local_map
    assert not maps["pycolmap"].retired  # only the oldest keyframe and the first baseline hold the window
    first, second = maps["pycolmap"].keyframes[:2]
    kept = np.linalg.norm(second.T_world_cam[:3, 3] - first.T_world_cam[:3, 3])
    assert kept == pytest.approx(np.linalg.norm(maps["gtsam"].pose(1)[:3, 3] - maps["gtsam"].pose(0)[:3, 3]), rel=1e-3)
    apart = [np.linalg.norm(maps["pycolmap"].pose(i)[:3, 3] - maps["gtsam"].pose(i)[:3, 3]) for i in range(5)]
    assert 0 < max(apart) < 0.002  # solved by the other solver, to the same poses


def test_pycolmaps_warnings_while_it_solves_stay_off_the_terminal(rng, capfd, monkeypatch):
    import pycolmap

    world, real = _world(rng), pycolmap.create_default_bundle_adjuster

    class Warning:  # as Ceres warns when a step's factorisation fails (then damps the step more)
        def __init__(self, *args):
            self.adjuster = real(*args)

        def solve(self):
            pycolmap.logging.warning("Linear solver failure")
            pycolmap.logging.error("an error still shows")
            return self.adjuster.solve()

    monkeypatch.setattr(pycolmap, "create_default_bundle_adjuster", Warning)
    level = pycolmap.logging.minloglevel
    local_map = LocalMap(MapConfig(window=6))
    local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.4), world, rng))
    local_map.add(_keyframe(2, _sideways(0.8), world, rng))
    err = capfd.readouterr().err
    assert "Linear solver failure" not in err and "an error still shows" in err
    assert pycolmap.logging.minloglevel == level  # restored


def _forward(z):
    """A camera ``z`` m ahead of the origin."""
    T = np.eye(4)
    T[2, 3] = z
    return T


def test_views_adjusted_together_point_the_way_one_two_view_pose_cannot(rng):
    # a camera moving ahead 5 cm a frame: the last view's direction 6 deg off (its length right), as one two-view
    # pose measures it; the views before it, 1 deg off either way, correct it together
    world = _world(rng, nearest=3.0, farthest=9.0)
    truth = [_forward(0.05 * i) for i in range(8)]
    views = [_keyframe(i, T, world, rng) for i, T in enumerate(truth)]
    for i, view in enumerate(views[1:], start=1):
        off = Rotation.from_euler("x", (-1.0) ** i if i < 7 else 6.0, degrees=True).as_matrix()
        view.T_world_cam = truth[i].copy()
        view.T_world_cam[:3, 3] = off @ truth[i][:3, 3]
    before = [view.T_world_cam.copy() for view in views]
    adjusted = adjust_views(views, MapConfig(), min_px=1.0)
    direction = np.degrees(vector_angle(adjusted[:3, 3], truth[-1][:3, 3]))
    assert direction < 3.0, direction
    assert np.linalg.norm(adjusted[:3, 3]) == pytest.approx(0.35, rel=1e-3)  # its distance from the first kept
    assert all(np.array_equal(view.T_world_cam, T) for view, T in zip(views, before, strict=True))  # copies
    standing = [views[0], _keyframe(1, truth[0], world, rng)]
    assert adjust_views(standing, MapConfig(), min_px=1.0) is None  # no baseline: no landmarks


def _ahead_with_the_last_turned(rng, count, step, degrees):
    """True poses of ``count`` views ``step`` m apart straight ahead, and the views, the last one's position turned
    ``degrees`` about x around the first (its direction that far off, its distance right)."""
    world = _world(rng, nearest=3.0, farthest=9.0)
    truth = [_forward(step * i) for i in range(count)]
    views = [_keyframe(i, T, world, rng) for i, T in enumerate(truth)]
    views[-1].T_world_cam = truth[-1].copy()
    views[-1].T_world_cam[:3, 3] = Rotation.from_euler("x", degrees, degrees=True).as_matrix() @ truth[-1][:3, 3]
    return truth, views


def test_views_adjusted_together_converge_from_a_pose_measured_far_off(rng):
    # the last view's direction 30 deg off, as a two-view pose over a few pixels can be: with gtsam's default
    # damping Levenberg-Marquardt takes no step from there; damped by the Hessian's diagonal it converges
    truth, views = _ahead_with_the_last_turned(rng, 8, 0.05, 30.0)
    adjusted = adjust_views(views, MapConfig(), min_px=1.0)
    assert np.degrees(vector_angle(adjusted[:3, 3], truth[-1][:3, 3])) < 5.0
    assert np.linalg.norm(adjusted[:3, 3]) == pytest.approx(0.35, rel=1e-3)  # its distance from the first kept


def test_views_adjusted_together_also_start_from_the_frame_before_where_that_ends_with_far_less_error(rng):
    # four views 10 cm apart, the last one's direction 120 deg off: from there the adjustment settles tens of
    # degrees off; started from the frame before (at the last view's distance) it ends with several times less error
    truth, views = _ahead_with_the_last_turned(rng, 4, 0.1, 120.0)
    alone = adjust_views(views, MapConfig(), min_px=1.0)
    waiting = InitialViews(MapConfig())
    for view in views[1:-1]:
        waiting.add(view)
    both = waiting.adjust(views[0], views[-1], lambda index: views[index].T_world_cam)
    assert np.degrees(vector_angle(alone[:3, 3], truth[-1][:3, 3])) > 40
    assert np.degrees(vector_angle(both[:3, 3], truth[-1][:3, 3])) < 8
    assert np.linalg.norm(both[:3, 3]) == pytest.approx(0.3, rel=1e-3)  # its distance from the first kept


def test_the_fit_that_chooses_a_start_counts_a_landmark_behind_the_cameras_as_outliers(rng):
    # gtsam's error takes a factor whose landmark lies behind its camera at a residual of twice the focal length in
    # each coordinate: two such landmarks outweighed a thousand inliers when adjust_views compared its starts by it
    world = _world(rng, count=60)
    views = [_keyframe(i, _sideways(0.1 * i), world, rng, noise=0.0) for i in range(3)]
    fitted = LocalMap(MapConfig())
    fitted.keyframes, fitted.landmarks = views, {int(track): world[track].copy() for track in views[0].ids}
    adjusted = fitted.adjusted_landmarks()
    observations = sum(int(np.isin(view.ids, adjusted).sum()) for view in views)
    assert _fit_error(fitted, adjusted, observations) == pytest.approx(0.0, abs=1e-12)
    behind = int(adjusted[0])
    fitted.landmarks[behind] = fitted.landmarks[behind] * [1.0, 1.0, -1.0]
    fitted._drop_outliers()  # as the adjustment does
    dropped = observations - sum(int(np.isin(view.ids, adjusted).sum()) for view in views)
    outlier = gtsam.noiseModel.mEstimator.Huber.Create(MapConfig().huber_px).loss(MapConfig().max_reprojection_px)
    assert dropped == 3
    assert _fit_error(fitted, adjusted, observations) == pytest.approx(dropped * outlier / observations)


def test_the_map_keeps_every_keyframe_that_left_its_window_up_to_its_fixed_keyframes(rng):
    world = _world(rng)
    local_map = LocalMap(MapConfig(window=2, fixed_keyframes=6))
    local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.4), world, rng))
    for index in range(2, 7):
        local_map.add(_keyframe(index, _sideways(0.4 * index), world, rng))
        assert [k.index for k in local_map.retired] == list(range(index - 1))  # all that left, fewer than six
    for index in range(7, 10):
        local_map.add(_keyframe(index, _sideways(0.4 * index), world, rng))
    assert [k.index for k in local_map.retired] == list(range(2, 8))  # the last six


def test_a_map_does_not_start_from_too_little_parallax_and_pnp_needs_enough_landmarks(rng):
    world = _world(rng)
    local_map = LocalMap()
    assert local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.01), world, rng)) == 0
    assert not local_map.started
    local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.4), world, rng))
    few = np.array(list(local_map.landmarks)[: MapConfig().min_located - 1])
    location = local_map.locate(few, project(np.eye(4), K, world[few])[0], K, np.eye(4))
    assert location.T_world_cam is None and "landmarks in view" in location.reason


def test_a_map_waits_for_a_baseline_whose_direction_its_landmarks_determine(rng):
    # points 1-3 m away seen 0.15 m apart with 2 px of noise: landmarks enough, from parallax enough, but the
    # baseline's direction is uncertain by a few degrees (noisy pairs like these started maps 20-85 deg off)
    world = _world(rng, nearest=1.0, farthest=3.0)
    close = [_keyframe(i, _sideways(x), world, rng, noise=2.0) for i, x in enumerate((0.0, 0.15))]
    lenient = LocalMap(MapConfig(max_start_deg=90.0))
    assert lenient.start(*(replace(view, T_world_cam=view.T_world_cam.copy()) for view in close)) > 30
    assert LocalMap().start(*close) == 0
    apart = [_keyframe(i, _sideways(x), world, rng, noise=2.0) for i, x in enumerate((0.0, 0.5))]
    assert LocalMap().start(*apart) > 30


def test_bundle_adjustment_drops_observations_that_do_not_fit(rng):
    world = _world(rng)
    local_map = LocalMap(MapConfig(window=3))
    local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.6), world, rng))
    third = _keyframe(2, _sideways(1.0), world, rng)
    moved = third.ids[:20]
    third.points[:20] += 15.0  # twenty tracks jumped to other points
    were_landmarks = moved[np.isin(moved, list(local_map.landmarks))]
    local_map.add(third)
    assert len(were_landmarks) >= 3
    assert not np.isin(were_landmarks, local_map.keyframes[-1].ids).any()  # their observations dropped
    kept = local_map.keyframes[-1].ids
    assert not any(int(track) in local_map.landmarks for track in kept[np.isin(kept, moved)])  # none made


def _run(world, trajectory, frontend="oracle", scale="map", frames=45, seed=0, map_config=None):
    scenario = Scenario(ScenarioConfig(world=world, trajectory=trajectory, frames=frames, seed=seed))
    config = PipelineConfig(TrackerConfig(frontend), OdometryConfig(scale=scale, map=map_config or MapConfig()))
    results, truth = [], []
    for pipeline, frame, result in run_pipeline(simulated_frames(scenario), config):  # noqa: B007 (the last is kept)
        results.append(result)
        truth.append(frame.T_world_cam)
    return pipeline, results, np.stack(truth)


@pytest.mark.slow
def test_scale_map_follows_a_cluttered_world_with_the_first_baselines_scale():
    pipeline, results, truth = _run("clutter", "circle")
    estimate = np.stack([r.T_world_cam for r in results])
    figures = drift.summary(estimate, truth)
    assert figures["ate_se3"] < 0.03 * figures["path_length"], figures  # metric, not only up to scale
    assert abs(np.log(figures["scale_drift"])) < 0.2, figures
    started = next(r.index for r in results[1:] if r.relative.model == "pnp")
    assert started < 15 and not any(r.lost for r in results[started:])  # (two-view poses may be ambiguous before)
    assert sum(r.relative.model == "pnp" for r in results[started:]) > 0.9 * (len(results) - started)
    assert pipeline.odometry.map.started and len(pipeline.odometry.map.keyframes) <= MapConfig().window


def test_frames_located_between_keyframes_join_the_adjustment_until_the_keyframe_before_leaves(rng):
    world = _world(rng)
    local_map = LocalMap(MapConfig())
    local_map.start(_keyframe(0, np.eye(4), world, rng), _keyframe(1, _sideways(0.6), world, rng))
    for index, x in ((2, 0.7), (3, 0.8)):
        seen = _keyframe(index, _sideways(x), world, rng)
        location = local_map.locate(seen.ids, seen.points, K, _sideways(x - 0.1))
        known = local_map.known(seen.ids)
        inliers = location.inliers
        frame = Keyframe(index, location.T_world_cam, K, location.ids[inliers], seen.points[known][inliers])
        adjusted = local_map.observe(frame)
        assert np.linalg.norm(adjusted[:3, 3] - [x, 0, 0]) < 0.05
    assert [frame.index for frame in local_map.frames] == [2, 3]
    seen_in = {track for frame in local_map.frames for track in frame.ids.tolist()}
    assert seen_in & set(local_map.landmarks)  # their observations are the landmarks'
    local_map.add(_keyframe(4, _sideways(1.0), world, rng))
    assert [frame.index for frame in local_map.frames] == [2, 3]  # since keyframe 1, the one before the current
    local_map.add(_keyframe(5, _sideways(1.2), world, rng))
    assert local_map.frames == []


@pytest.mark.slow
def test_located_frames_in_the_adjustment_bring_the_online_poses_nearer_the_truth():
    errors = {}
    for adjust_frames in (True, False):
        _, results, truth = _run("room", "circle", frames=60, map_config=MapConfig(adjust_frames=adjust_frames))
        errors[adjust_frames] = drift.ate_rmse(np.stack([r.T_world_cam for r in results]), truth)
    assert errors[True] < 0.8 * errors[False], errors


@pytest.mark.slow
@pytest.mark.parametrize("world", ["room", "clutter"])
def test_a_noisy_run_that_makes_a_keyframe_every_frame_keeps_a_solvable_graph(world):
    # classical tracks at noise 0.5 thin the map every frame: each keyframe's adjusted pose joins the graph
    # (these two runs once ended in gtsam's IndeterminateSystemException)
    scenario = Scenario(ScenarioConfig(world=world, trajectory="circle", frames=60, seed=2, noise=0.5))
    output = run_frames(simulated_frames(scenario), PipelineConfig(TrackerConfig("classical")), progress=False)
    assert np.all(np.isfinite(output.estimate)) and np.all(np.isfinite(output.pipeline.trajectory()))


class _PredictionsMeasured(OracleTracker):
    """The oracle, measuring how far each prediction it is given lies from its track's true projection (px)."""

    def expect(self, predicted):
        truth = self.landmarks()  # of the frame tracked next
        _, a, b = np.intersect1d(predicted.ids, truth.ids, return_indices=True)
        self.errors.append(np.linalg.norm(predicted.pixels[a] - truth.pixels[b], axis=1))


def _prediction_errors(scenario: Scenario, config: PipelineConfig) -> list[np.ndarray]:
    """Per frame the front-end was given predictions: their distances (px) from the true projections."""
    truth = GroundTruth()
    tracker = _PredictionsMeasured(truth.landmarks, noise_px=config.tracker.oracle_noise)
    tracker.errors = []
    for _ in run_pipeline(simulated_frames(scenario), config, tracker, truth=truth):
        pass
    return tracker.errors


@pytest.mark.parametrize("trajectory", ["circle", "forward"])
def test_the_map_predicts_where_the_next_frame_sees_its_landmarks(trajectory):
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory=trajectory, frames=40, seed=1))
    predicted = _prediction_errors(scenario, PipelineConfig(TrackerConfig("oracle")))
    assert len(predicted) > 10 and min(map(len, predicted)) >= MapConfig().min_located
    errors = np.concatenate(predicted)
    assert np.median(errors) < 1.0 and np.mean(errors < 3.0) > 0.95, np.percentile(errors, [50, 90, 99])
    off = PipelineConfig(TrackerConfig("oracle"), OdometryConfig(map=MapConfig(predict=False)))
    assert not _prediction_errors(scenario, off)


@dataclass
class _WithFleetingTracks(OracleTracker):
    """The oracle plus ``extra`` tracks a frame that live one frame only (new ids, random pixels): tracks the map
    can never locate, so that it covers a small share of every frame's tracks."""

    extra: int = 400
    frames: int = field(default=0, init=False)

    def track(self, image):
        true = super().track(image)
        self.frames += 1
        fleeting = 10**9 + self.frames * self.extra + np.arange(self.extra)
        pixels = self.rng.uniform([0, 0], [159, 119], (self.extra, 2))
        return Tracks(np.r_[true.points, pixels], np.r_[true.ids, fleeting], np.ones(len(true.ids) + self.extra))


def test_a_map_that_locates_few_of_the_tracks_does_not_make_every_frame_a_keyframe():
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="circle", frames=40, seed=1))
    truth = GroundTruth()
    tracker = _WithFleetingTracks(truth.landmarks, noise_px=0.5)
    run = list(run_pipeline(simulated_frames(scenario), PipelineConfig(TrackerConfig("oracle")), tracker, truth=truth))
    results = [result for _, _, result in run]
    started = next(r.index for r in results[1:] if r.relative.model == "pnp")
    after = results[started + 1 :]
    assert np.mean([r.shared < 0.3 * len(r.tracks.ids) for r in after]) > 0.9  # the share rule alone would fire
    assert sum(r.keyframe for r in after) < 0.5 * len(after), [r.index for r in after if r.keyframe]
    assert min(r.landmarks for r in after) >= MapConfig().min_initial_landmarks  # the map is not starved
    assert not any(r.lost for r in after)


def test_the_graph_holds_keyframes_and_frames_measured_two_view_not_frames_located_in_the_map():
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="circle", frames=30))
    located = 0
    for pipeline, _, result in run_pipeline(simulated_frames(scenario), PipelineConfig(TrackerConfig("oracle"))):
        graph = pipeline.odometry.graph
        in_map = result.relative is not None and result.relative.model == "pnp"
        assert (result.index in graph) == (result.keyframe or not in_map), result.index
        if in_map and not result.keyframe:
            located += 1
            np.testing.assert_allclose(result.T_world_cam, graph.pose(result.reference) @ result.T_ref_cur)
            assert np.all(np.linalg.eigvalsh(result.covariance) > 0)
            assert np.all(np.diag(result.covariance) > np.diag(graph.covariance(result.reference)))
    assert located >= 15
    trajectory = pipeline.trajectory()
    assert trajectory.shape == (30, 4, 4)
    np.testing.assert_allclose(trajectory[-1], pipeline.odometry.estimate(29))
    held = pipeline.odometry.graph.poses()  # the graph's own poses, in key order, with keys left out
    assert len(held) == 30 - located and np.allclose(held[0], trajectory[0])


def test_the_frame_that_starts_the_map_enters_the_graph_as_the_map_has_it():
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="circle", frames=20))
    run = run_pipeline(simulated_frames(scenario), PipelineConfig(TrackerConfig("oracle")))
    truth = {}
    for pipeline, frame, result in run:
        truth[result.index] = frame.T_world_cam
        if result.keyframe_reason == "a map starts":
            odometry = pipeline.odometry
            break
    else:
        pytest.fail("no map started")
    first, second = odometry.map.keyframes
    assert (first.index, second.index) == (result.reference, result.index)
    in_map = np.linalg.inv(first.T_world_cam) @ second.T_world_cam
    np.testing.assert_allclose(result.T_ref_cur, in_map)
    graph = odometry.graph
    np.testing.assert_allclose(np.linalg.inv(graph.pose(first.index)) @ graph.pose(second.index), in_map, atol=1e-6)
    true_length = np.linalg.norm(truth[second.index][:3, 3] - truth[first.index][:3, 3])
    assert np.linalg.norm(result.T_ref_cur[:3, 3]) == pytest.approx(true_length, rel=1e-3)


def test_frames_before_the_map_are_adjusted_together_not_measured_one_by_one():
    # forward motion: a frame's two-view pose from the keyframe points its translation degrees off, a different
    # way each frame; adjusted with the frames before it, its measurement (T_ref_cur) points nearer the truth
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="forward", frames=30))
    truth, two_view, adjusted = {}, [], []
    for _, frame, result in run_pipeline(simulated_frames(scenario), PipelineConfig(TrackerConfig("oracle"))):
        truth[result.index] = frame.T_world_cam
        two_view_model = result.relative is not None and result.relative.model in ("homography", "essential")
        if result.phase != "initialising" or result.keyframe or not two_view_model:
            continue
        true = (np.linalg.inv(truth[result.reference]) @ truth[result.index])[:3, 3]
        two_view.append(np.degrees(vector_angle(result.relative.T_c1_c2[:3, 3], true)))
        adjusted.append(np.degrees(vector_angle(result.T_ref_cur[:3, 3], true)))
    assert len(adjusted) >= 10
    assert np.median(adjusted) < 0.5 * np.median(two_view), (np.median(adjusted), np.median(two_view))


def test_the_final_trajectory_places_the_frames_before_a_map_where_the_map_locates_them():
    # forward motion: the map starts at frame 24; measured two-view over a few pixels, the frames before it are
    # placed up to 15 cm off online, and the map's landmarks locate them once it stands
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="forward", frames=30))
    truth, online, starts = [], [], []
    for pipeline, frame, result in run_pipeline(simulated_frames(scenario), PipelineConfig(TrackerConfig("oracle"))):
        truth.append(frame.T_world_cam)
        online.append(result.T_world_cam)
        starts += [result.index] if result.keyframe_reason == "a map starts" else []
        odometry = pipeline.odometry
    final = odometry.poses()  # what Pipeline.trajectory returns
    located = sorted(odometry.waiting.located)
    assert len(starts) == 1 and len(located) >= 15 and 0 < min(located) and max(located) < starts[0]
    assert not odometry.waiting.kept  # kept only while a map waits
    for index in set(range(30)) - set(located):
        np.testing.assert_array_equal(final[index], odometry.estimate(index))
    assert drift.ate_rmse(final, np.array(truth)) < 0.6 * drift.ate_rmse(np.array(online), np.array(truth))


@dataclass
class _Thinned(OracleTracker):
    """The oracle, keeping only the first ``thin[i]`` tracks of frame i (0: none, as in a blank image)."""

    thin: dict[int, int] = field(default_factory=dict)
    frames: int = field(default=0, init=False)

    def track(self, image):
        tracks = super().track(image)
        keep, self.frames = self.thin.get(self.frames), self.frames + 1
        if keep is None:
            return tracks
        return Tracks(tracks.points[:keep], tracks.ids[:keep], tracks.scores[:keep])


def _thinned_run(trajectory: str, thin: dict[int, int]) -> list:
    """(true pose (4, 4), result) of each frame of a 36-frame oracle run in the clutter world, thinned as ``thin``."""
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory=trajectory, frames=36))
    truth = GroundTruth()
    tracker = _Thinned(truth.landmarks, noise_px=0.5, thin=thin)
    run = run_pipeline(simulated_frames(scenario), PipelineConfig(TrackerConfig("oracle")), tracker, truth=truth)
    return [(frame.T_world_cam, result) for _, frame, result in run]


def test_frames_lost_after_a_map_go_on_at_the_cameras_velocity():
    run = _thinned_run("circle", {30: 0, 31: 0, 32: 0})  # three blank frames
    assert run[29][1].phase == "tracking"
    for (before, _), (true, result) in zip(run[29:32], run[30:33], strict=True):
        assert result.lost
        step = np.linalg.norm(true[:3, 3] - before[:3, 3])
        assert np.linalg.norm(result.T_world_cam[:3, 3] - true[:3, 3]) < 0.5 * step  # standing still: over 1 step


def test_a_two_view_step_after_a_map_takes_its_length_from_the_cameras_speed():
    # forward, a frame of ten tracks (too few for PnP) is measured two-view; the pixels a step moves its tracks
    # have grown since the first baseline as the camera neared the scene
    run = _thinned_run("forward", {30: 10})
    assert run[29][1].relative.model == "pnp"
    two_view = [result for _, result in run[30:34] if result.relative.model in ("homography", "essential")]
    assert len(two_view) >= 2
    for result in two_view:
        true_length = np.linalg.norm(run[result.index][0][:3, 3] - run[result.reference][0][:3, 3])
        assert np.linalg.norm(result.T_ref_cur[:3, 3]) == pytest.approx(true_length, rel=0.15), result.index


def test_scale_map_without_truth_measures_in_units_of_its_first_baseline():
    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="circle", frames=30))
    frames = list(simulated_frames(scenario))
    pipeline = Pipeline(PipelineConfig(TrackerConfig("classical"), OdometryConfig(scale="map")))
    for frame in frames:
        pipeline.process(frame.image, frame.K, frame.stamp_ns)
    estimate, truth = pipeline.trajectory(), np.stack([f.T_world_cam for f in frames])
    assert pipeline.odometry.map.started
    figures = drift.summary(estimate, truth)
    assert figures["ate_sim3"] < 0.05 * figures["path_length"], figures


def test_the_map_is_logged_as_a_point_cloud_with_its_keyframes(tmp_path):
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from deepslam.backend.evaluation.runs import simulate
    from deepslam.logs.reader import read_frames

    log = tmp_path / "map.mcap"
    result = simulate(
        ScenarioConfig(world="clutter", frames=30), TrackerConfig("classical"), OdometryConfig(), log, progress=False
    )
    clouds, keyframes = [], []
    with open(log, "rb") as stream:
        reader = make_reader(stream, decoder_factories=[DecoderFactory()])
        for _, channel, _, message in reader.iter_decoded_messages(topics=["/map/landmarks", "/map/keyframes"]):
            if channel.topic == "/map/landmarks":
                clouds.append(np.frombuffer(bytes(message.data), "<f4").reshape(message.width, 3))
            else:
                keyframes.append(len(message.poses))
    pipeline = result["pipeline"]
    assert clouds and len(clouds[-1]) > 30 and message.header.frame_id == "world"
    ids, points = pipeline.odometry.map.points()
    assert np.array_equal(_rows(clouds[-1]), _rows(points.astype("<f4")))  # the map as the last frame left it
    assert keyframes[-1] == sum(d.keyframe for d in result["diagnostics"])  # every keyframe, marked
    frames = list(read_frames(log))
    assert frames[-1].diagnostics.landmarks == len(ids) > 0


def _rows(points: np.ndarray) -> np.ndarray:
    return points[np.lexsort(points.T[::-1])]


def test_map_scale_takes_true_lengths_until_a_map_then_the_speed_it_measures():
    scale = MapScale(lambda i, j: 0.1 * (j - i), start_within=20, keyframe_parallax=10.0)
    assert scale.two_view(0, 2, parallax=4.0) == pytest.approx(0.2)  # the truth, 0.05 m a pixel
    step = np.eye(4)
    step[:3, 3] = [0.0, 0.0, 1.0]
    assert np.linalg.norm(scale.first_baseline(step, 0, 3)[:3, 3]) == pytest.approx(0.3)
    scale.map_started()
    scale.frame_done(3, map_holds_keyframe=True)
    assert scale.first_baseline(step, 0, 3) is step  # later maps carry the first one's scale
    assert scale.two_view(3, 5, parallax=8.0) == pytest.approx(0.4)  # metres a pixel of the last true length
    scale.record(with_length(step, 0.03))  # the frame before was not located: no step yet
    assert scale.velocity() is None
    scale.record(with_length(step, 0.03))
    scale.record(None)  # a frame the map did not locate keeps the last speed
    assert scale.two_view(5, 7, parallax=8.0) == pytest.approx(0.06)
