import json
import re

import cv2
import numpy as np
import pytest

from deepslam.backend import drift, relpose
from deepslam.backend.config import GraphConfig, OdometryConfig, PipelineConfig
from deepslam.backend.evaluation.bench import bench_pipeline
from deepslam.backend.evaluation.runs import run_frames, simulate, simulated_frames
from deepslam.backend.evaluation.sweep import SweepConfig, matrix_lines, pipeline_matrix, summary_lines
from deepslam.backend.evaluation.truth import GroundTruth, TrueFrame, run_pipeline
from deepslam.backend.graph import PoseGraph
from deepslam.backend.pipeline import Pipeline
from deepslam.backend.scale import PlaneScale
from deepslam.errors import InputError
from deepslam.frontend.config import TrackerConfig
from deepslam.frontend.tracking import OracleTracker, Truth, make_tracker
from deepslam.geometry import in_image, path_length, rotation_angle, vector_angle
from deepslam.sim.camera import intrinsics, invert, pose, project, transform
from deepslam.sim.scenario import Scenario, ScenarioConfig

K = intrinsics((120, 160))
ORACLE_EXACT = TrackerConfig("oracle", oracle_noise=0.0)
T_TRUE = pose(np.array([0.02, -0.04, 0.03]), np.array([0.3, 0.05, 0.1]))  # camera 2 in camera 1


def _views(rng, planar: bool, T_c1_c2=T_TRUE, n=150, noise=0.2):
    depth = np.full(n, 4.0) if planar else rng.uniform(3, 7, n)
    X = np.c_[rng.uniform(-2, 2, (n, 2)), depth]
    p1, _ = project(X, K)
    p2, _ = project(transform(invert(T_c1_c2), X), K)
    return p1 + rng.normal(0, noise, p1.shape), p2 + rng.normal(0, noise, p2.shape)


def _rotation_error_deg(T, T_true):
    return np.degrees(rotation_angle(T[:3, :3].T @ T_true[:3, :3]))


def _errors(T, T_true):
    angle = _rotation_error_deg(T, T_true)
    return angle, np.degrees(vector_angle(T[:3, 3], T_true[:3, 3]))


@pytest.mark.parametrize(
    "method, planar",
    [
        ("homography", True),
        ("essential", False),
        ("auto", True),
        ("auto", False),
        ("pycolmap", True),
        ("pycolmap", False),
    ],
)
def test_relative_pose_recovers_known_motion(rng, method, planar):
    p1, p2 = _views(rng, planar)
    result = relpose.estimate(p1, p2, K, method)
    assert result.ok
    if method == "auto":  # a plane: the homography; points at many depths: the essential matrix
        assert result.model == ("homography" if planar else "essential")
    rotation_error, direction_error = _errors(result.T_c1_c2, T_TRUE)
    assert rotation_error < 0.5 and direction_error < 5


def test_homography_path_gives_t_over_d_and_the_plane(rng):
    p1, p2 = _views(rng, True, noise=0.0)
    result = relpose.estimate(p1, p2, K, "homography")
    assert result.t_over_d == pytest.approx(np.linalg.norm(T_TRUE[:3, 3]) / 4.0, rel=1e-3)
    np.testing.assert_allclose(result.plane_normal, [0, 0, 1], atol=1e-3)


@pytest.mark.parametrize(
    "rotation, translation",
    [([0.001, 0.001, -0.06], [-0.2, 0.027, -0.11]), ([0.017, 0.073, 0.019], [-0.033, -0.084, 0.145])],
)
def test_homography_pose_takes_the_decomposition_the_points_off_its_plane_agree_with(rng, rotation, translation):
    T_c1_c2 = pose(np.array(rotation), np.array(translation))
    wall = np.c_[rng.uniform(-2, 2, (100, 2)), np.full(100, 4.0)]
    side = np.c_[np.full(50, -0.7), rng.uniform(-0.5, 0.5, 50), rng.uniform(1.2, 1.8, 50)]  # a side wall, x = -0.7
    X = np.r_[wall, side]
    p1, p2 = project(X, K)[0], project(transform(invert(T_c1_c2), X), K)[0]
    _, rotations, translations, normals = cv2.decomposeHomographyMat(cv2.findHomography(p1[:100], p2[:100])[0], K)
    facing = [i for i in range(len(rotations)) if normals[i][2, 0] > 0]
    assert len(facing) == 2  # the wall's own points fit both of these equally
    for i in facing:  # whichever of them the motion before suggests
        previous_t = -rotations[i].T @ translations[i].ravel()
        result = relpose.estimate(p1, p2, K, "homography", previous_t=previous_t)
        assert _errors(result.T_c1_c2, T_c1_c2)[1] < 1


@pytest.mark.parametrize("translation", [[-0.2, 0.027, -0.11], [-0.033, -0.084, 0.145]])
def test_homography_pose_keeps_the_plane_seen_before_when_the_path_turns(rng, translation):
    T_c1_c2 = pose(np.array([0.01, -0.02, 0.03]), np.array(translation))
    wall = np.c_[rng.uniform(-2, 2, (100, 2)), np.full(100, 4.0)]  # a wall facing camera 1: n = (0, 0, 1)
    p1, p2 = project(wall, K)[0], project(transform(invert(T_c1_c2), wall), K)[0]
    _, rotations, translations, normals = cv2.decomposeHomographyMat(cv2.findHomography(p1, p2)[0], K)
    wrong = max(range(len(rotations)), key=lambda i: normals[i][2, 0] > 0 and abs(normals[i][2, 0]) < 0.99)
    turned = -rotations[wrong].T @ translations[wrong].ravel()  # the motion before points to the other solution
    fooled = relpose.estimate(p1, p2, K, "homography", previous_t=turned)
    kept = relpose.estimate(p1, p2, K, "homography", previous_t=turned, previous_normal=np.array([0.0, 0.0, 1.0]))
    another = relpose.estimate(p1, p2, K, "homography", previous_t=turned, previous_normal=np.array([1.0, 0.0, 0.0]))
    assert _errors(fooled.T_c1_c2, T_c1_c2)[1] > 10  # the wall's points alone cannot tell
    assert _errors(kept.T_c1_c2, T_c1_c2)[1] < 1
    np.testing.assert_allclose(kept.plane_normal, [0, 0, 1], atol=1e-3)
    assert _errors(another.T_c1_c2, T_c1_c2)[1] > 10  # a normal far from both: the motion before decides


def test_homography_pose_keeps_the_true_solution_when_a_few_inliers_lie_off_its_plane(rng):
    T_c1_c2 = pose(np.array([0.0, 0.01, 0.0]), np.array([0.05, 0.0, 0.02]))
    down = pose(np.array([0.3, 0.0, 0.0]), np.zeros(3))[:3, :3]  # camera 1 looks 17 deg down
    floor = np.c_[rng.uniform(-1, 1, 95), np.full(95, 1.0), rng.uniform(3, 8, 95)]  # level: 1 m below the camera
    far = np.c_[rng.uniform(-5, 5, 5), rng.uniform(-4, -1.5, 5), np.full(5, 40.0)]  # above the horizon, barely moving
    points = np.vstack([floor, far]) @ down.T
    normal = down @ [0.0, 1.0, 0.0]
    p1, p2 = project(points, K)[0], project(transform(invert(T_c1_c2), points), K)[0]
    assert in_image(p1, (120, 160)).all() and in_image(p2, (120, 160)).all()
    H = cv2.findHomography(p1[:95], p2[:95])[0]  # the floor's; the far points fit it within a pixel
    assert np.abs(cv2.perspectiveTransform(p1[95:, None], H)[:, 0] - p2[95:]).max() < 1.0
    _, rotations, _, normals = cv2.decomposeHomographyMat(H, K)
    true = [i for i in range(len(normals)) if normals[i].ravel() @ normal > 0.99]
    m1, m2 = (cv2.undistortPoints(p[:, None], K, None).astype(np.float32) for p in (p1, p2))
    opencv = np.ravel(cv2.filterHomographyDecompByVisibleRefpoints(rotations, normals, m1, m2))
    assert true and not set(true) & set(opencv)  # OpenCV asks it of every point: the far ones rule it out
    result = relpose.homography_pose(p1, p2, K, H, inliers=np.ones(100, bool), previous_normal=normal)
    assert _errors(result.T_c1_c2, T_c1_c2)[1] < 2
    np.testing.assert_allclose(result.plane_normal, normal, atol=0.02)


def test_auto_takes_the_essential_matrix_where_a_second_wall_shows_the_homography_pose_wrong():
    rng = np.random.default_rng(3)
    T_c1_c2 = pose(np.array([0.0, 0.01, 0.0]), np.array([0.03, 0.0, 0.15]))  # 15 cm ahead, 4 m from the wall
    wall = np.c_[rng.uniform(-2, 2, (100, 2)), np.full(100, 4.0)]
    side = np.c_[np.full(30, -1.2), rng.uniform(-0.6, 0.6, 30), rng.uniform(1.5, 3.5, 30)]  # a side wall, x = -1.2
    X = np.r_[wall, side]
    p1, p2 = project(X, K)[0], project(transform(invert(T_c1_c2), X), K)[0]
    seen = in_image(p1, (120, 160)) & in_image(p2, (120, 160))
    p1, p2 = (p[seen] + rng.normal(0, 0.1, (seen.sum(), 2)) for p in (p1, p2))
    planar = relpose.estimate(p1, p2, K, "homography")
    auto = relpose.estimate(p1, p2, K, "auto")
    assert relpose.select_model(p1, p2)[0] == "homography"  # the scores alone keep the wall's homography
    assert _errors(planar.T_c1_c2, T_c1_c2)[1] > 20  # whose pose the side wall's pairs contradict
    assert auto.model == "essential" and _errors(auto.T_c1_c2, T_c1_c2)[1] < 5


def test_a_homography_opencv_cannot_decompose_gives_a_failed_pose(rng):
    # a 9.5 px sideways step along a wall, as noise-free matches fit it: OpenCV's closed form returns NaN
    H = np.array([[1.0, 0.0, -9.52], [0.0, 1.0, 0.0], [0.0, 1e-15, 1.0]])
    if np.isfinite(cv2.decomposeHomographyMat(H, K)[1][0]).all():
        pytest.skip("this OpenCV decomposes the homography")
    p1 = rng.uniform([10, 10], [150, 110], (60, 2))
    p2 = cv2.perspectiveTransform(p1[None], H)[0]
    planar = relpose.homography_pose(p1, p2, K, H)
    assert planar.model == "failed" and "not finite" in planar.reason and np.isfinite(planar.T_c1_c2).all()


@pytest.mark.slow
def test_a_noise_free_oracle_in_the_room_keeps_a_finite_trajectory():
    # along the line, seed 1, the exact matches of frame 47 fit a homography that OpenCV cannot decompose
    output = run_frames(
        simulated_frames(Scenario(ScenarioConfig(world="room", trajectory="line", seed=1))),
        PipelineConfig(ORACLE_EXACT, OdometryConfig()),
        progress=False,
        seed=1,
    )
    assert np.isfinite(output.estimate).all() and drift.ate_rmse(output.estimate, output.truth) < 0.02


def test_pycolmap_agrees_with_opencv(rng):
    p1, p2 = _views(rng, False)
    ours, theirs = relpose.estimate(p1, p2, K, "essential"), relpose.estimate(p1, p2, K, "pycolmap")
    assert _errors(ours.T_c1_c2, theirs.T_c1_c2)[0] < 0.5


def test_a_fit_opencv_refuses_gives_a_failed_pose_with_its_reason_on_one_line(rng, monkeypatch):
    def refused(p1, p2, *args):  # OpenCV asserts on some samples instead of failing softly
        return cv2.findHomography(p1[:3], p2[:3], cv2.RANSAC)

    monkeypatch.setattr(relpose, "_estimate", refused)
    p1, p2 = _views(rng, True)
    result = relpose.estimate(p1, p2, K)
    assert result.model == "failed" and result.reason.startswith("OpenCV could not fit a model")
    assert "4 corresponding point sets" in result.reason and "\n" not in result.reason and ".cpp" not in result.reason


def test_a_fundamental_matrix_usac_asserts_on_is_fitted_by_ransac(rng, monkeypatch):
    fit = cv2.findFundamentalMat

    def asserting(p1, p2, method, *args):  # as OpenCV's USAC does on some samples ("!model.empty()")
        if method == cv2.USAC_MAGSAC:
            raise cv2.error("!model.empty()")
        return fit(p1, p2, method, *args)

    monkeypatch.setattr(relpose.cv2, "findFundamentalMat", asserting)
    p1, p2 = _views(rng, False)
    result = relpose.estimate(p1, p2, K)
    assert result.model == "essential"  # the scores still chose: points at many depths
    assert max(_errors(result.T_c1_c2, T_TRUE)) < 3.0


def test_vector_angle_broadcasts_and_is_zero_for_a_vector_without_length():
    normals = np.array([[0.0, 0.0, 2.0], [1.0, 0.0, 1.0], [0.0, -3.0, 0.0]])
    np.testing.assert_allclose(np.degrees(vector_angle(normals, [0.0, 0.0, 1.0])), [0.0, 45.0, 90.0], atol=1e-12)
    assert vector_angle([0.0, 0.0, 0.0], [1.0, 0.0, 0.0]) == 0.0
    assert np.isclose(vector_angle([1.0, 0.0, 0.0], [-1e-9, 0.0, 0.0]), np.pi)


def test_degenerate_cases_do_not_crash(rng):
    p1, p2 = _views(rng, False)
    assert relpose.estimate(p1[:5], p2[:5], K).model == "failed"
    assert relpose.estimate(p1, p1 + 0.01, K).model == "static"
    rotation_only = pose(np.array([0.0, 0.05, 0.0]), np.zeros(3))
    q1, q2 = _views(rng, True, rotation_only, noise=0.0)
    for method in ("homography", "essential"):  # a pure rotation: no translation is invented
        result = relpose.estimate(q1, q2, K, method)
        assert result.ok and result.rotation_only, method
        assert _rotation_error_deg(result.T_c1_c2, rotation_only) < 0.1 and not result.T_c1_c2[:3, 3].any(), method
    line = np.c_[np.linspace(10, 150, 40), np.linspace(20, 100, 40)]
    singular = K.copy()
    singular[1] = 0
    random = rng.uniform([0, 0], [160, 120], (100, 2))
    for a, b, camera, reason in [
        (np.repeat(p1[:1], 100, 0), np.repeat(p2[:1], 100, 0), K, "distinct"),  # 100 copies of one match
        (line, line + [3.0, 1.0], K, "collinear"),
        (p1, p2, singular, "singular"),
        (np.where(np.arange(len(p1))[:, None] == 3, np.nan, p1), p2, K, "non-finite"),
        (random, rng.uniform([0, 0], [160, 120], (100, 2)), K, "explains"),  # random matches
    ]:
        for method in ("homography", "essential", "auto"):
            result = relpose.estimate(a, b, camera, method)
            assert not result.ok and reason in result.reason, (reason, method, result.reason)
    with pytest.raises(ValueError, match="method"):
        relpose.estimate(p1, p2, K, "magic")
    with pytest.raises(ValueError, match="same length"):
        relpose.estimate(p1, p2[:-1], K)


def test_isam2_agrees_with_batch_levenberg_marquardt(rng):
    poses = [np.eye(4)]
    for _ in range(10):
        poses.append(poses[-1] @ pose(rng.normal(0, 0.05, 3), rng.normal(0, 0.2, 3)))
    graph = PoseGraph(poses[0], GraphConfig(window=None))
    sigmas = np.array([0.01] * 3 + [0.05] * 3)
    for k in range(1, len(poses)):
        measured = invert(poses[k - 1]) @ poses[k] @ pose(rng.normal(0, 0.01, 3), rng.normal(0, 0.02, 3))
        graph.add_pose(k, graph.pose(k - 1) @ measured)
        graph.add_between(k - 1, k, measured, sigmas)
        if k >= 3:
            graph.add_between(k - 3, k, invert(poses[k - 3]) @ poses[k], sigmas)
        graph.update()
    graph.refine(5)
    batch = graph.batch_solve()
    np.testing.assert_allclose(graph.poses(), batch, atol=3e-3)  # metres / rotation entries, on a ~2 m path
    assert np.abs(graph.poses()[:, :3, 3] - batch[:, :3, 3]).mean() < 1e-3
    covariance = graph.covariance(len(poses) - 1)
    assert covariance.shape == (6, 6) and np.all(np.linalg.eigvalsh(covariance) > 0)


def test_a_pose_seen_from_one_other_has_the_covariance_that_pose_carries_through_the_measurement(rng):
    graph = PoseGraph(np.eye(4))
    sigmas = np.array([0.02] * 3 + [0.1] * 3)
    for k in (1, 2):
        step = pose(rng.normal(0, 0.1, 3), rng.normal(0, 0.5, 3))
        graph.add_pose(k, graph.pose(k - 1) @ step)
        graph.add_between(k - 1, k, step, sigmas)
        graph.update()
    T = pose([0.3, -0.2, 0.5], [0.4, 0.1, 1.0])  # far enough that rotation and translation mix
    expected = graph.covariance_through(2, T, sigmas / 2)
    assert 3 not in graph
    graph.add_pose(3, graph.pose(2) @ T)
    graph.add_between(2, 3, T, sigmas / 2)
    graph.update()
    assert 3 in graph
    np.testing.assert_allclose(expected, graph.covariance(3), rtol=1e-6, atol=1e-12)
    assert not np.allclose(expected, graph.covariance(2) + np.diag((sigmas / 2) ** 2))  # the turn matters


def test_a_windowed_graph_marginalises_old_poses_and_keeps_their_estimates(rng):
    poses = [np.eye(4)]
    for _ in range(60):
        poses.append(poses[-1] @ pose(rng.normal(0, 0.02, 3), rng.normal(0, 0.1, 3)))
    sigmas = np.array([0.01] * 3 + [0.05] * 3)
    graphs = {window: PoseGraph(poses[0], GraphConfig(window=window)) for window in (None, 10)}
    for k in range(1, len(poses)):
        measured = invert(poses[k - 1]) @ poses[k] @ pose(rng.normal(0, 0.005, 3), rng.normal(0, 0.01, 3))
        for graph in graphs.values():
            graph.add_pose(k, graph.pose(k - 1) @ measured)
            graph.add_between(k - 1, k, measured, sigmas)
            if k % 5 == 0:  # a loop to the first pose, kept in the window on purpose
                graph.add_between(0, k, invert(poses[0]) @ poses[k], sigmas)
            graph.update(keep=[0])
    full, windowed = graphs[None], graphs[10]
    assert not windowed.in_window(20) and windowed.in_window(0) and windowed.in_window(60)
    with pytest.raises(ValueError, match="left the graph's window"):
        windowed.add_between(20, 60, np.eye(4), sigmas)
    with pytest.raises(ValueError, match="window=None"):
        windowed.batch_solve()
    assert windowed.poses().shape == (61, 4, 4)  # every pose keeps an estimate
    gap = np.linalg.norm(windowed.poses()[:, :3, 3] - full.poses()[:, :3, 3], axis=1)
    assert gap.max() < 0.01  # marginalising keeps what the old poses said about the recent ones


def test_drift_metrics(rng):
    truth = np.stack([pose(rng.normal(0, 0.1, 3), [i * 0.1, np.sin(i), 0.2 * i]) for i in range(20)])
    assert drift.ate_rmse(truth, truth) == pytest.approx(0, abs=1e-12)
    moved = pose([0.1, 0.2, 0.3], [1, 2, 3]) @ truth
    scaled = moved.copy()
    scaled[:, :3, 3] *= 2.5
    assert drift.ate_rmse(moved, truth) == pytest.approx(0, abs=1e-9)
    assert drift.ate_rmse(scaled, truth, with_scale=True) == pytest.approx(0, abs=1e-9)
    assert drift.ate_rmse(scaled, truth) > 0.1
    rpe_t, rpe_r = drift.rpe(moved, truth)
    np.testing.assert_allclose(rpe_t, 0, atol=1e-9)
    shifted = truth.copy()
    shifted[-1, :3, 3] += [0, 0, 1.0]
    summary = drift.summary(shifted, truth)
    assert summary["final_drift_pct"] == pytest.approx(100 / path_length(truth))
    with pytest.raises(ValueError):
        drift.summary(truth[:1], truth[:1])
    unknown = truth.copy()
    unknown[3] = np.nan  # a frame without truth, left in
    for metric in (drift.ate_rmse, drift.rpe, drift.summary):
        with pytest.raises(InputError, match="1 of 20 poses are not finite: leave out the frames without"):
            metric(truth, unknown)
        with pytest.raises(InputError, match=r"must both be \(N, 4, 4\), got \(20, 4, 4\) and \(19, 4, 4\)"):
            metric(truth, truth[1:])
        with pytest.raises(InputError, match=r"trajectories must be \(N, 4, 4\) arrays of numbers"):
            metric(truth, [["a"]])
    assert drift.summary(shifted.tolist(), truth.tolist()) == summary  # lists of poses read as arrays
    for delta in (0, -1):  # -1 once compared the first frame's step with the last's
        with pytest.raises(InputError, match=f"the RPE's delta must be at least 1 frame, got {delta}"):
            drift.rpe(moved, truth, delta)


def test_planar_world_with_oracle_recovers_the_trajectory():
    scenario = Scenario(ScenarioConfig(world="plane", frames=30))
    models = []

    def keep_model(frame, result, diagnostics):
        models.append(result.relative.model if result.relative else None)

    output = run_frames(  # two-view poses only: true step lengths
        simulated_frames(scenario), PipelineConfig(ORACLE_EXACT, OdometryConfig(scale="gt")), keep_model, progress=False
    )
    assert drift.ate_rmse(output.estimate, output.truth) < 1e-3
    assert models[0] is None and set(models[1:]) == {"homography"}  # "auto" sees the plane in every pair
    # exact projections: every track error against the depth buffer is zero, nothing is lost
    assert len(output.track_errors) > 100 and np.abs(output.track_errors).max() < 1e-3
    assert len(output.pair_errors) > 100 and np.abs(output.pair_errors).max() < 1e-3  # keyframe to frame, too
    assert not any(d.lost for d in output.diagnostics) and output.summary()["lost_frames"] == 0


def test_track_errors_measure_pixel_noise_against_the_truth():
    scenario = Scenario(ScenarioConfig(world="room", frames=12))
    config = PipelineConfig(TrackerConfig("oracle", oracle_noise=1.0), OdometryConfig())
    output = run_frames(simulated_frames(scenario), config, progress=False)
    # two independent 1 px Gaussian offsets: the difference has sigma sqrt(2); median radius 1.18 sqrt(2)
    assert 1.3 < output.summary()["track_error_px"] < 2.1
    assert 1.3 < output.summary()["pair_error_px"] < 2.1


def test_plane_scale_needs_no_ground_truth_steps():
    scenario = Scenario(ScenarioConfig(world="plane", frames=20))
    config = OdometryConfig(scale="plane", plane_distance=scenario.plane_distance())
    output = run_frames(simulated_frames(scenario), PipelineConfig(ORACLE_EXACT, config), progress=False)
    assert drift.ate_rmse(output.estimate, output.truth) < 1e-3
    with pytest.raises(InputError, match="distance"):
        Pipeline(PipelineConfig(odometry=OdometryConfig(scale="plane")))


def test_plane_scale_moves_the_distance_on_by_the_step_towards_the_plane():
    plane = PlaneScale(2.0)
    step = relpose.RelativePose(
        np.eye(4), "homography", np.ones(20, bool), t_over_d=0.25, plane_normal=np.array([0, 0, 1.0])
    )
    assert plane.length(step) == pytest.approx(0.5)
    towards = np.eye(4)
    towards[:3, 3] = [0.1, 0.0, 0.5]  # half a metre towards the wall ahead
    plane.moved_on(step, towards)
    assert plane.distance == pytest.approx(1.5)
    through = towards.copy()
    through[2, 3] = 2.0  # would pass the wall: the distance is kept
    plane.moved_on(step, through)
    assert plane.distance == pytest.approx(1.5)


def test_lost_frames_are_flagged_and_tracking_reinitialises():
    class Blind(OracleTracker):
        """Sees the landmarks except in frames 10-15, where it reports nothing."""

        def track(self, image):
            self.frame = getattr(self, "frame", -1) + 1
            tracks = super().track(image)
            return type(tracks).empty() if 10 <= self.frame <= 15 else tracks

    scenario = Scenario(ScenarioConfig(world="plane", frames=30))
    truth, config = GroundTruth(), PipelineConfig(odometry=OdometryConfig(reinitialise_after=3))
    blind = Blind(truth.landmarks, noise_px=0.0)
    output = run_frames(simulated_frames(scenario), config, progress=False, tracker=blind, ground_truth=truth)
    lost = [i for i, d in enumerate(output.diagnostics) if d.lost]
    assert lost[:6] == list(range(10, 16)) and "matched points" in output.diagnostics[10].reason
    assert output.summary()["lost_frames"] == len(lost)
    assert not output.diagnostics[-1].lost  # tracking picked up again after re-initialising


@pytest.mark.parametrize(
    "config, kept", [(OdometryConfig(scale="gt"), True), (OdometryConfig(scale="gt", max_rotation_jump=0), False)]
)
def test_a_pose_that_turns_away_from_the_frame_before_gives_way_to_a_model_that_does_not(monkeypatch, config, kept):
    real, wrong_frames = relpose.estimate, {12}
    turned = pose(np.array([0.0, np.radians(20), 0.0]), np.zeros(3))
    frame_index = [0]

    def turned_when_chosen(p1, p2, K, method="auto", **options):  # the chosen model is 20 deg off in frame 12
        estimate = real(p1, p2, K, method, **options)
        if method == "auto" and frame_index[0] in wrong_frames and estimate.ok:
            estimate.T_c1_c2 = estimate.T_c1_c2 @ turned
        return estimate

    monkeypatch.setattr(relpose, "estimate", turned_when_chosen)

    def counted(frames):  # the frame being processed, for the patched estimate
        for frame_index[0], frame in enumerate(frames):
            yield frame

    frames = counted(simulated_frames(Scenario(ScenarioConfig(world="plane", frames=14))))
    for _, frame, result in run_pipeline(frames, PipelineConfig(ORACLE_EXACT, config)):
        if result.index == 12:
            error = _rotation_error_deg(result.T_world_cam, frame.T_world_cam)
    assert (error < 0.5) if kept else (error > 10)


def test_a_sweep_summarises_the_runs_whose_limit_adjusted_nothing_without_them():
    def run(ate, limit):
        return {"ate_se3": ate, "limit_ate_se3": limit, "path_length": 3.0, "scale_drift": 1.0, "corner_poor": False,
                "lost_frames": 0}  # fmt: skip

    row = {"frontend": "magic", "noise": 0.0, "lighting": 0.0, "runs": [run(0.02, 0.01), run(0.03, 0.0)]}
    summary = summary_lines([row])[-1].split()
    assert summary[:4] == ["magic", "0.00", "0.00", "2"] and float(summary[6]) == pytest.approx(2.0)


def test_sweep_keeps_every_run_and_summarises_textured_and_corner_poor_seeds_apart(tmp_path):
    config = SweepConfig(
        worlds=("plane",), trajectories=("circle",), frontends=("oracle",), noise=(0.0, 0.5), lighting=(0.0,),
        frames=8, seeds=5,
    )  # fmt: skip
    sweep = pipeline_matrix(config, progress=False)
    rows = sweep.rows
    assert len(rows) == 2 and [r["noise"] for r in rows] == [0.0, 0.5]
    runs = rows[0]["runs"]
    assert [r["texture"] for r in runs] == ["page", "coffee", "brick", "grass", "mosaic"]  # named per seed
    textured = [r["ate_se3"] for r in runs if not r["corner_poor"]]
    assert rows[0]["median_ate_se3"] == pytest.approx(np.median(textured)) and len(textured) == 4
    assert rows[0]["median_ate_se3_corner_poor"] == runs[3]["ate_se3"]  # grass, apart
    assert rows[0]["failed"] == 0  # the oracle never drifts 5% of its path
    over_limit = [r["ate_se3"] / r["limit_ate_se3"] for r in runs if not r["corner_poor"]]
    assert rows[0]["median_ate_over_limit"] == pytest.approx(np.median(over_limit)) and min(over_limit) > 0
    lines = sweep.table().splitlines()
    assert lines == matrix_lines(rows)
    assert "3 grass" in lines[4] and any(line.split()[-5:] == [f"{r['ate_se3']:.4f}" for r in runs] for line in lines)
    summary = lines[-2:]  # a line per front-end, noise and lighting, over all cells and seeds
    assert lines[-4:-2] == summary_lines(rows)[:2] and summary == summary_lines(rows)[2:]
    clean = summary[0].split()
    share = [100 * r["ate_se3"] / r["path_length"] for r in runs if not r["corner_poor"]]
    assert clean[:4] == ["oracle", "0.00", "0.00", "4"]
    assert float(clean[4]) == pytest.approx(np.median(share), abs=0.005)
    assert float(clean[5]) == pytest.approx(np.mean(share), abs=0.005)
    assert float(clean[6]) == pytest.approx(rows[0]["median_ate_over_limit"], abs=0.005)
    final = [100 * r["final_ate_se3"] / r["path_length"] for r in runs if not r["corner_poor"]]  # the graph at the end
    assert float(clean[7]) == pytest.approx(np.median(final), abs=0.005) and np.isfinite(float(clean[8]))
    assert int(clean[-1]) == sum(r["lost_frames"] for r in runs)
    written = sweep.save(tmp_path)
    assert [p.name for p in written] == ["pipeline_ate_vs_noise.png", "pipeline.txt", "pipeline.json"]
    assert json.loads((tmp_path / "pipeline.json").read_text()) == {"rows": rows}
    assert (tmp_path / "pipeline.txt").read_text() == sweep.table() + "\n"


def test_sweep_measures_with_the_relative_pose_method_it_is_given():
    def ates(method):
        config = SweepConfig(
            worlds=("plane",), trajectories=("circle",), frontends=("oracle",), noise=(0.0,), lighting=(0.0,),
            frames=8, seeds=2, method=method,
        )  # fmt: skip
        return [run["ate_se3"] for run in pipeline_matrix(config, progress=False).rows[0]["runs"]]

    assert SweepConfig().method == OdometryConfig().method  # the odometry's default unless told
    planar, general = ates("homography"), ates("essential")
    assert max(planar) < 0.02 and min(general) > 3 * max(planar)  # E is degenerate on one plane


def test_the_oracle_takes_its_pixel_noise_from_the_config_and_its_landmarks_from_the_truth():
    image = np.zeros((120, 160), np.uint8)
    landmarks = Truth(np.arange(50), np.random.default_rng(0).uniform(0, 100, (50, 2)))
    truth = GroundTruth()
    truth.see(TrueFrame(image, np.eye(3), 0, landmarks=landmarks))
    exact = truth.oracle(TrackerConfig("oracle", oracle_noise=0.0)).track(image)
    np.testing.assert_array_equal(exact.points, landmarks.pixels[exact.ids])
    noisy = truth.oracle(TrackerConfig("oracle", oracle_noise=2.0)).track(image)
    error = np.linalg.norm(noisy.points - landmarks.pixels[noisy.ids], axis=1)
    with pytest.raises(InputError, match="oracle"):
        make_tracker(TrackerConfig("oracle"))  # the library has no truth to give it
    assert 1.5 < np.median(error) < 3.5  # a 2-D Gaussian of sigma 2 has a median radius of 2.35


def test_the_pipeline_refuses_a_bad_frame_with_what_is_wrong_and_keeps_its_run():
    K, image = np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]]), np.zeros((120, 160), np.uint8)
    pipeline = Pipeline(PipelineConfig(TrackerConfig("classical")))
    pipeline.process(image, K, 10)
    for frame, message in [
        ((image.astype(np.float32), K, 20), "must be uint8 (H, W) grayscale, got float32 (120, 160)"),
        ((np.zeros((120, 160, 3), np.uint8), K, 20), "got uint8 (120, 160, 3)"),
        ((image, np.eye(2), 20), "K must be a finite (3, 3) camera matrix"),
        ((image, K.T, 20), "K must be [[fx, s, cx], [0, fy, cy], [0, 0, 1]] (not transposed)"),
        ((image, [["fx", 0, 79.5], [0, 100, 59.5], [0, 0, 1]], 20), "K must be a (3, 3) array of numbers, got [['fx'"),
        ((image, np.array([[200.0, 0, 159.5], [0, 200, 119.5], [0, 0, 1]]), 20), "principal point (159.5, 119.5)"),
        ((image, K, 20.5), "stamp_ns must be integer nanoseconds, got 20.5"),
        ((image, K, 10), "stamps must increase: 10 ns after 10 ns"),
        ((np.zeros((240, 320), np.uint8), K, 20), "frame 1 is 240x320, the first was 120x160"),
    ]:
        with pytest.raises(InputError, match=re.escape(message)):
            pipeline.process(*frame)
    assert pipeline.process(image, K, 20).index == 1 and len(pipeline.trajectory()) == 2


def test_the_pipeline_takes_k_as_nested_lists_as_it_takes_the_array():
    frames = list(Scenario(ScenarioConfig(world="room", trajectory="circle", frames=6, seed=0)))
    trajectories = []
    for as_given in (np.asarray, lambda K: K.tolist()):
        pipeline = Pipeline(PipelineConfig(TrackerConfig("classical")))
        results = [pipeline.process(f.image, as_given(f.K), i) for i, f in enumerate(frames)]
        assert not any(result.lost for result in results)
        trajectories.append(pipeline.trajectory())
    np.testing.assert_array_equal(*trajectories)


def test_the_pipeline_refuses_an_origin_that_is_no_pose_and_a_config_of_another_kind():
    turned = pose(np.array([0.1, 0.2, 0.3]), np.array([1.0, 2.0, 3.0]))
    turned[:3, :3] = turned[:3, :3].astype(np.float32)  # a rotation stored in float32 is still one
    for origin in (np.eye(3), np.full((4, 4), np.nan), 2 * np.eye(4), np.r_[np.eye(4)[:3], [[0, 0, 1, 1]]]):
        with pytest.raises(InputError, match="origin must be a .4, 4. T_world_cam"):
            Pipeline(PipelineConfig(TrackerConfig("classical")), origin=origin)
    pipeline = Pipeline(PipelineConfig(TrackerConfig("classical")), origin=turned)
    image, K = np.zeros((120, 160), np.uint8), np.array([[100.0, 0, 79.5], [0, 100.0, 59.5], [0, 0, 1]])
    np.testing.assert_allclose(pipeline.process(image, K, 0).T_world_cam, turned, atol=1e-6)
    with pytest.raises(InputError, match="config must be a PipelineConfig .its tracker and odometry., got Odometry"):
        Pipeline(OdometryConfig())
    with pytest.raises(InputError, match="step_lengths must be a function .i, j. -> the true distance .m.+got a list"):
        Pipeline(PipelineConfig(TrackerConfig("classical"), OdometryConfig(scale="gt")), step_lengths=[0.1] * 10)


def test_magic_tracks_are_carried_only_where_relative_poses_may_come_from_a_homography():
    for method, options, carried in [
        ("homography", {}, True),
        ("auto", {}, True),
        ("essential", {}, False),
        ("homography", {"carry": False}, False),
    ]:
        tracker = TrackerConfig("magic", **options)
        run = simulate(ScenarioConfig(frames=3), tracker, OdometryConfig(method=method), progress=False)
        assert run["pipeline"].tracker.carry is carried
        assert Pipeline(PipelineConfig(tracker, OdometryConfig(method=method, scale="none"))).tracker.carry is carried


def test_poses_are_measured_from_the_pairs_the_front_end_confirms():
    class Choosy(OracleTracker):
        """Confirms every other pair and moves it by a quarter pixel."""

        def confirm(self, reference, current, pairs):
            kept = pairs[::2]
            return kept, current.points[kept[:, 1]] + 0.25

    scenario = Scenario(ScenarioConfig(world="plane", frames=24))
    truth = GroundTruth()
    keyframes, choosy = 0, Choosy(truth.landmarks, noise_px=0.0)
    frames = simulated_frames(scenario)
    two_view = PipelineConfig(odometry=OdometryConfig(scale="gt"))  # measured from pairs with the keyframe
    for pipeline, _, result in run_pipeline(frames, two_view, choosy, truth=truth):
        odometry = pipeline.odometry
        if result.index:
            shared = np.intersect1d(odometry.history[result.reference][1].ids, result.tracks.ids)
            assert len(result.correspondences) == (len(shared) + 1) // 2
            assert result.relative.ok
            # a frame reports its points where its pose was measured from them; a keyframe keeps its
            # detections (the oracle's exact projections), as later frames are measured against them
            reported = result.tracks.points[result.correspondences[:, 1]]
            np.testing.assert_allclose(reported, result.measured_points - (0.25 if result.keyframe else 0.0))
            keyframes += result.keyframe
    assert keyframes >= 1


def test_a_frames_inliers_are_a_share_of_the_tracks_it_shares_with_its_own_reference():
    # the extra factor to the keyframe before once left its count of shared tracks in the frame's result
    scenario = Scenario(ScenarioConfig(world="room", trajectory="circle", frames=40, seed=1))
    config = PipelineConfig(TrackerConfig("oracle"), OdometryConfig(scale="gt"))
    linked = 0
    for pipeline, _, result in run_pipeline(simulated_frames(scenario), config):
        if result.index:
            assert result.relative.inliers.sum() <= result.shared
            linked += pipeline.odometry.previous_keyframe not in (None, result.reference)
    assert linked > 0  # frames with the extra factor were among them


def test_pipeline_bench_reports_the_median_round_and_the_spread_of_rounds():
    bench = bench_pipeline(6, tracker_config=TrackerConfig(frontend="oracle"), rounds=3)
    timings = bench.timings
    assert bench.to_dict() == timings and "odometry.graph" in bench.table()
    assert timings["fps_slowest_round"] <= timings["fps"] <= timings["fps_fastest_round"]
    assert timings["fps"] == pytest.approx(1e3 / timings["per_frame_total"])
    assert timings["odometry.graph"] > 0 and "memory_mb@end" not in timings  # short runs report no growth
    with pytest.raises(ValueError, match="at least 1 round"):
        bench_pipeline(6, rounds=0)


def test_auto_flags_pairs_a_homography_and_an_essential_matrix_explain_with_different_motions():
    flagged = wrong_ok = 0
    for seed in range(10):
        rng = np.random.default_rng(seed)
        X = np.c_[rng.uniform(-1.5, 1.5, (100, 2)), rng.uniform(3, 6, 100)]  # no dominant plane
        direction = rng.normal(size=3)
        T = pose(np.radians(rng.uniform(-3, 3, 3)), 0.2 * direction / np.linalg.norm(direction))
        p1 = _project(np.eye(4), X) + rng.normal(0, 0.3, (100, 2))
        p2 = _project(T, X) + rng.normal(0, 0.3, (100, 2))
        result = relpose.estimate(p1, p2, K, "auto")
        flagged += "ambiguous" in result.reason
        wrong_ok += result.ok and np.degrees(vector_angle(result.T_c1_c2[:3, 3], T[:3, 3])) > 30
    assert flagged >= 2 and wrong_ok <= 3, (flagged, wrong_ok)


def test_ambiguous_pairs_take_the_essential_matrix_where_no_motion_so_far_tells():
    taken = []
    for seed in range(10):  # the pairs of the test above
        rng = np.random.default_rng(seed)
        X = np.c_[rng.uniform(-1.5, 1.5, (100, 2)), rng.uniform(3, 6, 100)]
        direction = rng.normal(size=3)
        T = pose(np.radians(rng.uniform(-3, 3, 3)), 0.2 * direction / np.linalg.norm(direction))
        p1 = _project(np.eye(4), X) + rng.normal(0, 0.3, (100, 2))
        p2 = _project(T, X) + rng.normal(0, 0.3, (100, 2))
        if "ambiguous" not in relpose.estimate(p1, p2, K, "auto").reason:
            continue
        result = relpose.estimate(p1, p2, K, "auto", ambiguous_takes_essential=True)
        planar = relpose.estimate(p1, p2, K, "homography")
        off = [np.degrees(vector_angle(pose.T_c1_c2[:3, 3], T[:3, 3])) for pose in (result, planar)]
        taken.append((result.model, *off))
    assert len(taken) >= 2 and all(model == "essential" for model, _, _ in taken), taken
    near = np.array([(essential < 15, homography < 15) for _, essential, homography in taken])
    assert near[:, 0].mean() >= 2 / 3 and near[:, 0].sum() > near[:, 1].sum(), taken  # a better guess than H's


def test_a_pose_measured_over_little_flow_neither_leads_the_next_nor_names_the_plane(rng):
    from deepslam.backend.twoview import TwoView

    two_view = TwoView("auto", 0.0, plane_lengths=False, min_flow_px=3.0)
    p1, p2 = _views(rng, True, pose(np.zeros(3), np.array([0.05, 0.0, 0.0])))  # a wall, 5 cm sideways
    flow = float(np.median(np.linalg.norm(p2 - p1, axis=1)))
    rel = two_view.measure(p1, p2, K, (120, 160), np.eye(3), np.eye(4))
    assert flow < 3.0 and rel.model == "homography" and rel.plane_normal is not None
    two_view.moved(rel.T_c1_c2, flow_px=flow)
    assert two_view.last_translation is None and two_view.plane_normal_world is None
    p1, p2 = _views(rng, True)  # the same wall, 0.3 m sideways: pixels of flow
    rel = two_view.measure(p1, p2, K, (120, 160), np.eye(3), np.eye(4))
    two_view.moved(rel.T_c1_c2, flow_px=8.0)
    assert two_view.last_translation is not None and two_view.plane_normal_world is not None
    assert np.degrees(vector_angle(two_view.plane_normal_world, [0, 0, 1])) < 5  # facing the camera
    with pytest.raises(InputError, match="lead the next"):
        OdometryConfig(vote_flow_px=-1.0)


def test_a_pose_from_fewer_pairs_than_the_minimum_is_not_trusted(rng):
    X = np.c_[rng.uniform(-1, 1, (relpose.MIN_INLIERS - 1, 2)), rng.uniform(3, 6, relpose.MIN_INLIERS - 1)]
    T = pose(np.zeros(3), np.array([0.3, 0.0, 0.0]))
    p1, p2 = _project(np.eye(4), X), _project(T, X)
    for method in ("essential", "homography", "auto"):
        result = relpose.estimate(p1, p2, K, method)
        assert not result.ok and "fewer than" in result.reason, (method, result.reason)


def _project(T_world_cam, X):
    """Pixels (N, 2) of world points X (N, 3) seen from ``T_world_cam`` (4, 4) with the tests' K."""
    return project(transform(invert(T_world_cam), X), K)[0]


@pytest.mark.parametrize(
    "failure",
    [
        RuntimeError("Indeterminate linear system detected while working near variable 8"),
        ValueError("Asking to remove variables from the variable index that are not unused"),
    ],
)
def test_a_window_whose_marginalisation_fails_starts_again_from_its_estimates(failure):
    graph = PoseGraph(np.eye(4), GraphConfig(window=5))
    step = pose(np.zeros(3), np.array([1.0, 0.0, 0.0]))
    sigmas = np.array([0.01] * 3 + [0.05] * 3)
    for key in range(1, 8):
        graph.add_pose(key, graph.pose(key - 1) @ step)
        graph.add_between(key - 1, key, step, sigmas)
        graph.update()

    class Failing:  # gtsam's fixed-lag smoother, failing once as it does on some marginalisations
        def __init__(self, solver):
            self.solver = solver

        def update(self, *args):
            raise failure

        def __getattr__(self, name):
            return getattr(self.solver, name)

    graph.solver = Failing(graph.solver)
    graph.add_pose(8, graph.pose(7) @ step)
    graph.add_between(7, 8, step, sigmas)
    graph.update()
    assert not isinstance(graph.solver, Failing)  # a new smoother took over
    assert np.allclose(graph.pose(8)[:3, 3], [8.0, 0.0, 0.0], atol=1e-6)
    graph.add_pose(9, graph.pose(8) @ step)
    graph.add_between(8, 9, step, sigmas)
    graph.update()
    assert np.allclose(graph.poses()[:, 0, 3], np.arange(10.0), atol=1e-6)
