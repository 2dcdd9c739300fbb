import numpy as np
import pytest

from deepslam.frontend.cells import points_to_cells
from deepslam.geometry import warp_points
from deepslam.sim import noise, shapes
from deepslam.sim.homography import HomographyConfig, sample_homography, warp_image_and_points
from deepslam.sim.pointclouds import GEOMETRIES, PairConfig, sample_pair
from deepslam.sim.pointsets import detector_points, make_pair, motion_homography, random_direction


def test_ten_categories_render_with_corners_inside_the_image(rng):
    assert len(shapes.CATEGORIES) == 10
    for category in shapes.CATEGORIES:
        image, corners = shapes.render(category, rng)
        assert image.dtype == np.uint8 and image.shape == (120, 160)
        assert corners.dtype == np.float32 and corners.shape[1] == 2
        assert np.all((corners >= -0.5) & (corners <= [159.5, 119.5]))
        if category in ("ellipses", "noise"):
            assert len(corners) == 0


def test_positive_categories_have_corners_on_edges(rng):
    """A labelled corner sits where the image changes: its neighbourhood is not flat."""
    for category in ("triangles", "quadrilaterals", "checkerboards", "cubes"):
        image, corners = shapes.render(category, rng)
        assert len(corners) >= 1  # corners that fall outside the image are not labels
        for x, y in corners:
            x0, y0 = int(round(x)), int(round(y))
            patch = image[max(0, y0 - 2) : y0 + 3, max(0, x0 - 2) : x0 + 3].astype(int)
            assert patch.max() - patch.min() > 15


def test_same_seed_same_bytes():
    a = shapes.evaluation_set(3, seed=7)
    b = shapes.evaluation_set(3, seed=7)
    assert all(x[1].tobytes() == y[1].tobytes() and np.array_equal(x[2], y[2]) for x, y in zip(a, b, strict=False))
    c = shapes.evaluation_set(3, seed=8)
    assert any(x[1].tobytes() != y[1].tobytes() for x, y in zip(a, c, strict=False))


def test_render_rejects_bad_input(rng):
    with pytest.raises(ValueError, match="unknown category"):
        shapes.render("hexagons", rng)
    with pytest.raises(ValueError, match="divisible by 8"):
        shapes.render("triangles", rng, size=(100, 160))


def test_training_stream_yields_noisy_warped_examples(rng):
    stream = shapes.training_stream(rng)
    images = [next(stream)[0] for _ in range(5)]
    assert len({im.tobytes() for im in images}) == 5


def test_training_stream_clean_share_leaves_images_clean():
    def first(clean_share):
        stream = shapes.training_stream(np.random.default_rng(3), homography=None, clean_share=clean_share)
        return next(stream)[0]

    rng = np.random.default_rng(3)
    rendered, _ = shapes.render(shapes.CATEGORIES[int(rng.integers(len(shapes.CATEGORIES)))], rng)
    assert np.array_equal(first(1.0), rendered)
    assert not np.array_equal(first(0.0), rendered)
    with pytest.raises(ValueError, match=r"\[0, 1\]"):
        next(shapes.training_stream(np.random.default_rng(0), clean_share=1.5))


def test_noise_magnitude_ends(rng):
    image, _ = shapes.render("checkerboards", rng)
    assert np.array_equal(noise.apply(image, rng, 0.0), image)
    noisy = noise.apply(image, np.random.default_rng(0), 1.0)
    assert noisy.dtype == np.uint8 and noisy.shape == image.shape and not np.array_equal(noisy, image)
    random = noise.apply(image, np.random.default_rng(0), 2.0)
    assert abs(np.corrcoef(random.ravel(), image.ravel())[0, 1]) < 0.3
    for kind in noise.KINDS:
        assert noise.apply(image, np.random.default_rng(0), 1.0, kind).shape == image.shape
    with pytest.raises(ValueError, match="unknown noise kind"):
        noise.apply(image, rng, 1.0, "fog")
    with pytest.raises(ValueError, match=r"\[0, 2\]"):
        noise.apply(image, rng, 2.5)
    with pytest.raises(ValueError, match="grayscale"):
        noise.apply(np.zeros((8, 8, 3), np.uint8), rng)


def test_homography_warp_moves_corners_with_the_image(rng):
    image, corners = shapes.render("quadrilaterals", rng)
    H = sample_homography(rng, image.shape, HomographyConfig(rotation=0.1, perspective=0.05))
    assert H[2, 2] == pytest.approx(1.0)
    warped, moved = warp_image_and_points(image, corners, H)
    expected = warp_points(corners, H)
    kept = (expected[:, 0] >= -0.5) & (expected[:, 0] <= 159.5) & (expected[:, 1] >= -0.5) & (expected[:, 1] <= 119.5)
    np.testing.assert_allclose(moved, expected[kept], atol=1e-4)
    shifted = np.array([[1.0, 0, 200.0], [0, 1, 0], [0, 0, 1]])
    assert len(warp_image_and_points(image, corners, shifted)[1]) == 0


def test_point_cloud_pairs_are_consistent(rng):
    for geometry in GEOMETRIES:
        pair = sample_pair(rng, PairConfig(), geometry)
        assert len(pair.true_a) == len(pair.true_b) >= 4
        assert np.all((pair.points_b >= -0.5) & (pair.points_b <= [159.5, 119.5]))
    with pytest.raises(ValueError, match="geometry_weights"):
        PairConfig(geometry_weights=(1.0, 0.0, 0.0, 0.0))
    with pytest.raises(ValueError, match="max_extra"):
        PairConfig(max_extra=1.5)
    with pytest.raises(ValueError, match="clean_a_share"):
        PairConfig(clean_a_share=-0.5)


def test_spurious_points_grow_with_max_extra():
    """The same seeds draw the same pairs: spurious points are drawn last, so the true matches stay and
    image B only gains points."""

    def counts(max_extra):
        pairs = [
            sample_pair(np.random.default_rng([3, i]), PairConfig(max_extra=max_extra), "homography") for i in range(20)
        ]
        return np.array([len(p.points_b) for p in pairs]), np.array([len(p.true_b) for p in pairs])

    (none, true_none), (many, true_many) = counts(0.0), counts(1.0)
    assert np.array_equal(true_none, true_many)
    assert np.all(many >= none) and many.sum() > 1.3 * none.sum()


def test_clean_a_pairs_are_drawn_as_the_breakdown_evaluation_draws_them():
    """With clean_a_share=1, image A keeps every point and only B gets spurious points; they are drawn
    last, so the same seeds give the same A points and true matches at any max_extra."""

    def pairs(**options):
        return [sample_pair(np.random.default_rng([5, i]), PairConfig(**options), "homography") for i in range(20)]

    clean, noisy, default = pairs(clean_a_share=1.0, max_extra=0.0), pairs(clean_a_share=1.0, max_extra=1.0), pairs()
    for c, n in zip(clean, noisy, strict=False):
        np.testing.assert_array_equal(c.points_a, n.points_a)
        np.testing.assert_array_equal(c.true_b, n.true_b)
        assert sorted(map(tuple, c.points_b)) == sorted(map(tuple, c.true_b))  # no dropout in B
        assert set(map(tuple, c.true_a)) <= set(map(tuple, c.points_a))
        assert len(n.points_b) - len(n.true_b) <= len(n.points_a)  # up to max_extra times A's count
    assert sum(len(n.points_b) for n in noisy) > 1.3 * sum(len(c.points_b) for c in clean)
    assert sum(len(d.points_a) for d in default) < sum(len(c.points_a) for c in clean)  # dropout removes A points


@pytest.mark.parametrize("geometry", ["plane", "homography"])
def test_planar_pairs_follow_a_homography(rng, geometry):
    import cv2

    pair = sample_pair(rng, PairConfig(), geometry)
    H, _ = cv2.findHomography(pair.true_a, pair.true_b, 0)
    np.testing.assert_allclose(warp_points(pair.true_a, H), pair.true_b, atol=1e-3)


def test_breakdown_motions_and_pairs(rng):
    size = (120, 160)
    H = motion_homography("translation", 10, size)
    assert H[0, 2] == 10
    direction = random_direction(rng)
    corners = np.array([[-0.5, -0.5], [159.5, -0.5], [159.5, 119.5], [-0.5, 119.5]])
    moved = warp_points(corners, motion_homography("random_h", 30, size, direction))
    assert np.linalg.norm(moved - corners, axis=1).mean() == pytest.approx(30, rel=1e-6)
    pair = make_pair(rng, H, 40, 0.2, size)
    partners = pair.true_index >= 0
    np.testing.assert_allclose(pair.points_b[pair.true_index[partners]], warp_points(pair.points_a[partners], H))
    assert len(pair.points_b) == partners.sum() + 8


def test_a_pair_without_its_spurious_points_keeps_every_true_partner(rng):
    size = (120, 160)
    H = motion_homography("random_h", 40, size, random_direction(rng))  # far enough that some points leave B
    pair = make_pair(rng, H, 50, 0.4, size)
    clean = pair.without_spurious()
    partners = pair.true_index >= 0
    assert 0 < partners.sum() < 50 and len(pair.points_b) == partners.sum() + 20
    assert len(clean.points_b) == partners.sum() and clean.points_a is pair.points_a
    np.testing.assert_array_equal(clean.true_index < 0, ~partners)
    np.testing.assert_allclose(clean.points_b[clean.true_index[partners]], warp_points(pair.points_a[partners], H))
    assert sorted(clean.true_index[partners]) == list(range(partners.sum()))  # B's order kept, nothing lost
    no_extra = make_pair(rng, H, 30, 0.0, size)
    np.testing.assert_array_equal(no_extra.without_spurious().points_b, no_extra.points_b)
    gone = make_pair(rng, motion_homography("translation", 200, size), 10, 0.0, size).without_spurious()
    assert len(gone.points_b) == 0 and np.all(gone.true_index == -1)  # every point left: B is empty


def test_detector_points_fill_distinct_cells_as_the_cell_encoding_sees_them(rng):
    size = (120, 160)
    points = detector_points(rng, 300, size)  # every cell of a 120x160 image
    cells = points_to_cells(points, size)
    assert points.shape == (300, 2) and not cells[64].any() and cells[:64].max() == 1.0
    np.testing.assert_array_equal(
        detector_points(np.random.default_rng(5), 40, size), detector_points(np.random.default_rng(5), 40, size)
    )
    with pytest.raises(ValueError, match="301 points do not fit"):
        detector_points(rng, 301, size)


def test_look_at_keeps_world_up_at_the_top_of_the_image():
    from deepslam.sim.camera import intrinsics, invert, look_at, project, transform

    T_world_cam = look_at(np.array([0.0, -2.0, 0.5]), np.zeros(3))
    K = intrinsics((120, 160))
    (above, right), _ = project(transform(invert(T_world_cam), np.array([[0.0, 0, 1], [1.0, 0, 0]])), K)
    assert above[1] < K[1, 2] and right[0] > K[0, 2]  # world up is image up, world +x (to the right) is image right


def test_world_render_samples_textures_by_ray_casting_with_occlusion():
    from deepslam.sim.world import Surface, World

    K = np.array([[80.0, 0, 79.5], [0, 80.0, 59.5], [0, 0, 1]])
    cols, rows = np.meshgrid(np.arange(100), np.arange(51))
    ramp = (cols + rows).astype(np.uint8)  # linear in the texel position: bilinear sampling is exact
    far = Surface(np.array([-1.0, -0.5, 2.0]), np.array([2.0, 0, 0]), np.array([0, 1.0, 0]), ramp)  # z = 2
    near = Surface(
        np.array([0.0, -0.1, 1.0]), np.array([0.2, 0, 0]), np.array([0, 0.2, 0]), np.full((8, 8), 250, np.uint8)
    )
    landmarks = np.array(
        [[-0.5, 0.0, 2.0], [0.1, 0.0, 2.0], [3.0, 0.0, 2.0]]
    )  # seen, behind the near square, out of view
    world = World("test", [far, near], landmarks)
    frame = world.render(np.eye(4), K, (120, 160))  # the camera at the origin looking along +z
    x, y = np.meshgrid(np.arange(160.0), np.arange(120.0))
    X, Y = (x - 79.5) / 80 * 2, (y - 59.5) / 80 * 2  # where each pixel's ray meets z = 2
    on_far = (np.abs(X) <= 1) & (np.abs(Y) <= 0.5)
    on_near = (X / 2 >= 0) & (X / 2 <= 0.2) & (Y / 2 >= -0.1) & (Y / 2 <= 0.1)
    expected = np.floor((X + 1) / 2 * 99 + (Y + 0.5) * 50 + 1e-3)
    only_far = on_far & ~on_near
    assert 0 < only_far.mean() < 0.5  # the wall is partly in view, so the test covers its edges
    assert np.abs(frame.image[only_far] - expected[only_far]).max() <= 1
    np.testing.assert_allclose(frame.depth[only_far], 2.0, rtol=1e-5)
    assert np.all(frame.image[on_near] == 250) and np.allclose(frame.depth[on_near], 1.0, rtol=1e-5)
    assert np.all(frame.image[~on_far & ~on_near] == 0) and np.all(np.isinf(frame.depth[~on_far & ~on_near]))
    assert frame.landmark_ids.tolist() == [0]
    np.testing.assert_allclose(frame.landmark_pixels, [[79.5 - 20, 59.5]])


def test_the_cluttered_world_has_depth_and_no_dominant_plane_and_the_forward_path_moves_into_it():
    from deepslam.errors import InputError
    from deepslam.sim.scenario import Scenario, ScenarioConfig

    scenario = Scenario(ScenarioConfig(world="clutter", trajectory="forward", frames=20))
    frames = list(scenario)
    depth = frames[0].depth[np.isfinite(frames[0].depth)]
    assert np.percentile(depth, 5) < 2.5 and np.percentile(depth, 95) > 5  # near boxes and the far wall at once
    assert all(len(f.landmark_ids) > 100 for f in frames)
    ahead = scenario.trajectory.poses[-1][:3, 3] - scenario.trajectory.poses[0][:3, 3]
    looking = scenario.trajectory.poses[0][:3, 2]  # the camera's z axis: where it looks
    assert ahead @ looking > 0.9 * np.linalg.norm(ahead)  # it moves the way it looks
    with pytest.raises(InputError, match="no dominant plane"):
        scenario.plane_distance()


def test_a_path_through_a_wall_is_found_where_it_passes_through_and_a_run_warns_of_it():
    from deepslam.backend.config import OdometryConfig
    from deepslam.backend.evaluation.runs import simulate
    from deepslam.frontend.config import TrackerConfig
    from deepslam.sim.scenario import Scenario, ScenarioConfig

    wall = Scenario(ScenarioConfig(world="plane")).world.surfaces[0]
    before, behind = wall.origin + 0.5 * (wall.axis_u + wall.axis_v) + np.outer([1.0, -1.0], wall.normal)
    beside = before + 10 * wall.axis_u  # the same step beyond the wall's edge
    crossed = wall.crossed(np.stack([before, beside]), np.stack([behind, beside - 2 * wall.normal]))
    assert crossed.tolist() == [True, False]
    # forward at 0.05 m a frame from 2 m before the wall: through it at frame 40 (on it) or 41
    assert Scenario(ScenarioConfig(world="plane", trajectory="forward")).passes_through() in (40, 41)
    assert Scenario(ScenarioConfig(world="plane", trajectory="forward", frames=40)).passes_through() is None
    assert Scenario(ScenarioConfig(world="room", trajectory="circle")).passes_through() is None
    short = ScenarioConfig(world="plane", trajectory="forward", frames=45, size=(48, 64))
    with pytest.warns(UserWarning, match="passes through a surface of the plane world at frame 4"):
        simulate(short, TrackerConfig("oracle"), OdometryConfig(scale="map"), progress=False)
