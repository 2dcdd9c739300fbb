from dataclasses import replace

import cv2
import numpy as np
import pytest
import torch

from deepslam.frontend import MagicPoint, MagicWarp, match
from deepslam.frontend.cells import points_to_cells
from deepslam.frontend.classical import ClassicalDetector
from deepslam.frontend.config import MagicWarpConfig, PolishConfig
from deepslam.frontend.magicpoint import VARIANTS, MagicPointConfig, MagicPointNet
from deepslam.frontend.magicwarp import MagicWarpNet, normalizer
from deepslam.frontend.nets import BlurMaxPool, OneDnnConv2d, fold_batchnorm
from deepslam.frontend.polish import normalise_contrast, polish
from deepslam.frontend.training.magicwarp import warp_loss
from deepslam.sim import shapes


def _randomise_batchnorm(model):
    for m in model.modules():
        if isinstance(m, torch.nn.BatchNorm2d):
            m.running_mean.uniform_(-1, 1)
            m.running_var.uniform_(0.5, 2)
            m.weight.data.uniform_(0.5, 2)
            m.bias.data.uniform_(-1, 1)
    return model.eval()


@pytest.mark.parametrize(
    "net, shape",
    [
        (MagicPointNet(VARIANTS["S"]), (2, 1, 120, 160)),
        (MagicPointNet(VARIANTS["S"]), (1, 1, 120, 160)),  # batch 1: PyTorch would pick its reference kernel
        (MagicPointNet(VARIANTS["S"]).double(), (1, 1, 120, 160)),  # float64 stays float64, on PyTorch's kernels
        (MagicPointNet(MagicPointConfig(pool="blur")), (2, 1, 120, 160)),
        (MagicWarpNet(), (2, 130, 15, 20)),
    ],
)
def test_batchnorm_folding_keeps_outputs(net, shape, monkeypatch):
    torch.manual_seed(0)
    net = _randomise_batchnorm(net)
    x = torch.rand(shape, dtype=next(net.parameters()).dtype)
    folded = fold_batchnorm(net)
    assert not any(isinstance(m, torch.nn.BatchNorm2d) for m in folded.modules())
    convs = [m for m in folded.modules() if isinstance(m, torch.nn.Conv2d)]
    assert all(isinstance(m, OneDnnConv2d) == (m.in_channels == 1) for m in convs)
    with torch.no_grad():
        torch.testing.assert_close(folded(x), net(x), atol=1e-5, rtol=1e-5)
        monkeypatch.setattr(torch.backends.mkldnn, "enabled", False)  # oneDNN switched off: PyTorch's own kernels
        torch.testing.assert_close(folded(x), net(x), atol=1e-5, rtol=1e-5)


def test_blur_max_pool_is_a_max_then_a_binomial_blur_and_moves_less_with_a_one_pixel_shift():
    rng = np.random.default_rng(0)
    image = cv2.GaussianBlur(rng.random((64, 80)).astype(np.float32), (0, 0), 0.7)  # texture near the grid scale
    pooled = BlurMaxPool()(torch.from_numpy(image)[None, None])[0, 0].numpy()
    window_max = np.maximum.reduce([np.pad(image, ((0, 1), (0, 1)), mode="edge")[dy : dy + 64, dx : dx + 80]
                                    for dy in (0, 1) for dx in (0, 1)])  # fmt: skip
    blurred = cv2.sepFilter2D(window_max, -1, np.array([0.25, 0.5, 0.25]), np.array([0.25, 0.5, 0.25]),
                              borderType=cv2.BORDER_REFLECT_101)  # fmt: skip
    np.testing.assert_allclose(pooled, blurred[::2, ::2], atol=1e-6)

    def change_under_shift(pool):  # a one-pixel shift moves the pooled grid by half a cell
        x = torch.from_numpy(image)[None, None]
        return (pool(x[..., 1:63, 1:79]) - pool(x[..., :62, :78])).abs().mean().item()

    assert change_under_shift(BlurMaxPool()) < 0.7 * change_under_shift(torch.nn.MaxPool2d(2))


def test_cells_encoding():
    cells = points_to_cells(np.array([[3.0, 2.0], [8.0, 0.0], [9.0, 1.0]]), (16, 16))
    assert cells.shape == (65, 2, 2)
    np.testing.assert_allclose(cells.sum(0), 1.0)
    assert cells[2 * 8 + 3, 0, 0] == 1.0
    assert cells[0, 0, 1] == 0.5 and cells[9, 0, 1] == 0.5
    assert cells[64, 1, 0] == 1.0 and cells[64, 1, 1] == 1.0


def test_shipped_magicpoint_detects_corners_of_a_shape(rng):
    model = MagicPoint.pretrained("S")
    image, corners = shapes.render("quadrilaterals", rng)
    points = model.detect(image)
    assert points.dtype == np.float32 and points.shape[1] == 3
    assert np.all(np.diff(points[:, 2]) <= 0)
    assert model.heatmap(image).shape == (120, 160)
    cells = model.cells(image)
    assert cells.shape == (65, 15, 20)
    np.testing.assert_allclose(cells.sum(0), 1.0, atol=1e-5)


def test_grid_shifts_make_the_heatmap_move_with_the_image(rng):
    image, _ = shapes.render("checkerboards", rng)
    moved = np.roll(image, 4, axis=1)  # 4 px to the right; compare away from the wrapped border
    single, shifted = MagicPoint.pretrained("S"), MagicPoint.pretrained("S", grid_shifts=4)

    def gap(detector):
        return np.abs(detector.heatmap(moved)[:, 44:-40] - detector.heatmap(image)[:, 40:-44]).max()

    assert gap(shifted) < 1e-4 < 0.05 < gap(single)  # exact in the interior with shifts; not without
    with pytest.raises(ValueError, match="grid_shifts"):
        MagicPoint.pretrained("S", grid_shifts=3)


def test_upsampled_detections_land_on_the_true_corners_in_input_pixels():
    rng = np.random.default_rng(0)
    detector = MagicPoint.pretrained("S", upsample=2, subpixel="parabola")
    offsets = []
    for category in ("checkerboards", "quadrilaterals", "triangles") * 5:
        image, corners = shapes.render(category, rng)
        points = detector.detect(image)[:, :2]
        distance = np.linalg.norm(points[:, None] - corners[None], axis=2)
        near = distance.min(1) < 3
        offsets.append(points[near] - corners[distance.argmin(1)[near]])
    offsets = np.vstack(offsets)
    assert len(offsets) > 100
    assert np.all(np.abs(offsets.mean(0)) < 0.15)  # a half-pixel slip in the mapping back would show here
    assert np.median(np.linalg.norm(offsets, axis=1)) < 0.4
    with pytest.raises(ValueError, match="upsample"):
        MagicPoint.pretrained("S", upsample=0)
    with pytest.raises(ValueError, match="upsample"):
        MagicPoint.pretrained("S", upsample=2.0)


def test_magicpoint_rejects_bad_images():
    model = MagicPoint(MagicPointNet())
    with pytest.raises(ValueError, match="divisible by 8, got .100, 160.: crop or resize it .to 96x160, for one.$"):
        model.detect(np.zeros((100, 160), np.uint8))
    with pytest.raises(ValueError, match="got .7, 9.: crop or resize it .to 8x8, for one.$"):
        model.detect(np.zeros((7, 9), np.uint8))
    with pytest.raises(ValueError, match="grayscale"):
        model.detect(np.zeros((120, 160, 3), np.uint8))
    with pytest.raises(ValueError, match="non-empty"):
        model.detect(np.zeros((0, 160), np.uint8))
    with pytest.raises(ValueError, match="uint8"):
        model.detect(np.zeros((120, 160), np.float32))
    with pytest.raises(ValueError, match="variant"):
        MagicPoint.pretrained("XL")


def test_classical_detectors_find_checkerboard_corners(rng):
    image, corners = shapes.render("checkerboards", rng)
    for kind in ("fast", "harris", "shi"):
        points = ClassicalDetector(kind).detect(image)
        assert points.dtype == np.float32 and points.shape[1] == 3
        assert np.all(np.diff(points[:, 2]) <= 0)
        top = points[: len(corners)]
        hits = np.linalg.norm(top[:, None, :2] - corners[None], axis=2).min(1) <= 4
        assert hits.mean() > 0.3, kind
    with pytest.raises(ValueError, match="unknown classical"):
        ClassicalDetector("sift")


def test_warp_loss_is_zero_for_the_true_homography(rng):
    H = torch.tensor([[1.1, 0.05, 0.1], [-0.02, 0.95, -0.05], [0.01, 0.02, 1.0]])[None]
    a = torch.rand(1, 10, 2) * 2 - 1
    moved = a @ H[0, :2, :2].T + H[0, :2, 2]
    moved = moved / (a @ H[0, 2, :2] + 1)[..., None]
    mask = torch.ones(1, 10, dtype=torch.bool)
    assert warp_loss(H, a, moved, mask) < 1e-10
    assert warp_loss(torch.eye(3)[None], a, moved, mask) > 1e-4


def test_warp_loss_weighs_matches_or_pairs():
    """Pair 0 has 1 match with squared error 4, pair 1 has 3 matches with squared error 1 each."""
    identity = torch.eye(3).repeat(2, 1, 1)
    true_a = torch.zeros(2, 4, 2)
    true_b = torch.tensor([[[2.0, 0], [9, 9], [9, 9], [9, 9]], [[1, 0], [0, 1], [-1, 0], [9, 9]]])
    mask = torch.tensor([[True, False, False, False], [True, True, True, False]])
    assert warp_loss(identity, true_a, true_b, mask) == pytest.approx((4 + 3) / 4)
    assert warp_loss(identity, true_a, true_b, mask, "pairs") == pytest.approx((4 + 1) / 2)
    empty = mask.clone()
    empty[0] = False  # a pair without true matches does not count
    assert warp_loss(identity, true_a, true_b, empty, "pairs") == pytest.approx(1.0)
    with pytest.raises(ValueError, match="unknown loss weighting"):
        warp_loss(identity, true_a, true_b, mask, "points")


def test_cauchy_warp_loss_matches_the_squared_one_for_small_errors_only():
    identity = torch.eye(3)[None]
    true_a = torch.zeros(1, 2, 2)
    true_b = torch.tensor([[[0.001, 0.0], [2.0, 0.0]]])  # squared errors 1e-6 and 4
    small, large = torch.tensor([[True, False]]), torch.tensor([[False, True]])
    assert warp_loss(identity, true_a, true_b, small, cauchy=1.0) == pytest.approx(1e-6, rel=1e-5)
    assert warp_loss(identity, true_a, true_b, large, cauchy=1.0) == pytest.approx(np.log(5.0))  # c^2 log(1 + 4 / c^2)
    assert warp_loss(identity, true_a, true_b, large, cauchy=0.5) == pytest.approx(0.25 * np.log(17.0))


def test_magicwarp_api_and_iterations(rng):
    warp = MagicWarp.pretrained()
    assert warp.net.config == MagicWarpConfig()  # training with no shape options trains what ships
    a = rng.uniform([0, 0], [155, 119], (40, 2))
    b = a + [4.0, 0.0]
    H1 = warp.estimate(a, b, (120, 160))
    H2 = warp.estimate(a, b, (120, 160), iterations=2)
    for H in (H1, H2):
        assert H.dtype == np.float64 and H.shape == (3, 3) and H[2, 2] == 1.0
    with pytest.raises(ValueError, match="iterations"):
        warp.estimate(a, b, iterations=0)
    with pytest.raises(ValueError, match="points_a"):
        warp.estimate(np.zeros(5), b)
    for bad_a, bad_b, message in [  # degenerate input is declined, not answered with a confident homography
        (a[:0], b, "at least 4 points"),
        (a, b[:3], "at least 4 points"),
        (np.where(np.arange(40)[:, None] == 0, np.nan, a), b, "non-finite"),
        (a, b + [100.0, 0.0], "outside the 120x160 image"),
    ]:
        with pytest.raises(ValueError, match=message):
            warp.estimate(bad_a, bad_b, (120, 160))


def test_normalizer_maps_pixel_centres_to_unit_square():
    N = normalizer((120, 160))
    corners = np.array([[0, 0, 1], [159, 119, 1.0]]) @ N.T
    np.testing.assert_allclose(corners[:, :2], [[-1, -1], [1, 1]])


def test_match_is_mutually_exclusive_nearest_neighbour():
    a = np.array([[10.0, 10.0], [12.0, 10.0], [50.0, 50.0]])
    b = np.array([[11.0, 10.0], [50.5, 50.0], [100.0, 100.0]])
    pairs = match(a, b, np.eye(3), max_dist=2.0)
    assert sorted(map(tuple, pairs.tolist())) == [(0, 0), (2, 1)]  # a[1] lost b[0] to a[0] (tie, first wins)
    shift = np.array([[1.0, 0, 40], [0, 1, 40], [0, 0, 1]])
    assert match(a[:1], b[1:2], shift, 1.0).tolist() == [[0, 0]]
    assert match(a, np.zeros((0, 2)), np.eye(3)).shape == (0, 2)
    for H, max_dist, message in [
        (np.eye(2), 2.0, "H must be a finite .3, 3. homography, got shape .2, 2."),
        (np.full((3, 3), np.nan), 2.0, "H must be a finite"),
        (np.eye(3), -1.0, "max_dist must be a finite distance of at least 0 px, got -1.0"),
        (np.eye(3), float("nan"), "max_dist must be"),
    ]:
        with pytest.raises(ValueError, match=message):  # InputError: not an empty or a wrong answer
            match(a, b, H, max_dist)


def test_refine_recovers_a_homography_from_a_rough_guess_or_the_best_of_several(rng):
    from deepslam.frontend.magicwarp import refine
    from deepslam.geometry import warp_points

    true_H = np.array([[1.02, 0.03, 9.0], [-0.02, 0.99, -4.0], [1e-4, 0, 1]])
    a = rng.uniform([0, 0], [159, 119], (60, 2))
    b = np.vstack([warp_points(a, true_H), rng.uniform([0, 0], [159, 119], (12, 2))])  # 20% spurious points
    rough = np.array([[1.0, 0, 6.0], [0, 1, -2.0], [0, 0, 1]])  # 3-4 px off everywhere
    refined = refine(a, b, rough)
    assert refined[2, 2] == 1.0
    assert np.abs(warp_points(a, refined) - warp_points(a, true_H)).max() < 1e-3
    assert refine(a[:5], b[:5], rough) is rough  # too few pairs: the guess stands
    far_off = np.array([[1.0, 0, 40.0], [0, 1, 30.0], [0, 0, 1]])
    joint = refine(a, b, [far_off, rough, np.eye(3)])  # one fit over all their pairs: the far-off ones are outliers
    assert np.abs(warp_points(a, joint) - warp_points(a, true_H)).max() < 1e-3
    assert refine(a[:5], b[:5], [far_off, true_H]) is true_H  # too few pairs: the guess most points agree with
    with pytest.raises(ValueError, match="at least one guess"):
        refine(a, b, [])


def test_motion_errors_measure_what_the_warp_recovers():
    from deepslam.frontend.evaluation.warp import ERROR_MAGNITUDES, motion_errors
    from deepslam.sim.homography import normalize

    class Identity:  # recovers nothing: its corner error is the whole corner shift
        def estimate_batch(self, pairs, size):
            return np.stack([np.eye(3)] * len(pairs))

    class Fitted:  # RANSAC on nearest-neighbour guesses: exact for a small translation
        def estimate_batch(self, pairs, size):
            fits = []
            for a, b in pairs:
                nearest = b[np.argmin(np.linalg.norm(a[:, None] - b[None], axis=2), axis=1)]
                fits.append(normalize(cv2.findHomography(a, nearest, cv2.RANSAC, 0.5)[0]))
            return np.stack(fits)

    nothing = motion_errors(Identity(), runs=3)
    assert list(nothing) == list(ERROR_MAGNITUDES)
    for motion, rows in nothing.items():
        for row in rows:  # the same shift in every run, except random_h's random corner directions
            assert row["corner_shift_px"] > 0
            assert np.isclose(
                row["corner_error_px"], row["corner_shift_px"], rtol=0.5 if motion == "random_h" else 1e-9
            )
    assert nothing["translation"][1]["corner_shift_px"] == pytest.approx(10.0)
    small = motion_errors(Fitted(), runs=3)["translation"][0]  # 5 px: nearest neighbours are mostly the truth
    assert small["corner_error_px"] < 0.5 < small["corner_shift_px"]


class _ScriptedDetector:
    """Stands in for MagicPoint: returns the given (x, y) points of each frame in turn, score 1."""

    def __init__(self, frames):
        self.frames = iter(frames)

    def detect(self, image):
        points = next(self.frames)
        return np.c_[points, np.ones(len(points))]


@pytest.mark.parametrize("carry", [True, False])
def test_magic_tracker_carries_a_missed_point_within_its_budget_and_picks_it_up_again(carry):
    from deepslam.frontend.tracking import MagicTracker
    from deepslam.sim.pointsets import detector_points

    points = detector_points(np.random.default_rng(0), 60, (120, 160))
    points = points[(points > 8).all(1) & (points < [150, 110]).all(1)]
    shift = np.array([2.0, 1.0])
    frames = [points, np.delete(points + shift, 0, axis=0), points + 2 * shift]  # frame 2 misses point 0
    texture = cv2.GaussianBlur(np.random.default_rng(1).uniform(0, 255, (120, 160)).astype(np.float32), (0, 0), 2)
    moving = [cv2.warpAffine(texture, np.float32([[1, 0, dx], [0, 1, dy]]), (160, 120), borderMode=cv2.BORDER_REFLECT)
              for dx, dy in (0 * shift, shift, 2 * shift)]  # fmt: skip
    images = [cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX).astype(np.uint8) for image in moving]
    tracker = MagicTracker(_ScriptedDetector(frames), MagicWarp.pretrained(), carry=carry)
    first, second, third = (tracker.track(image) for image in images)
    missed = first.ids[0]
    assert np.array_equal(np.sort(third.ids), np.sort(first.ids))  # every track, the missed one too, goes on
    np.testing.assert_allclose(third.points[third.ids == missed][0], points[0] + 2 * shift)
    if carry:  # reported where its patch of the frame it was detected in aligns, marked as not detected
        assert len(second.ids) == len(points) and second.scores[second.ids == missed] == 0
        np.testing.assert_allclose(second.points[second.ids == missed][0], points[0] + shift, atol=0.05)
    else:
        assert missed not in second.ids and len(second.ids) == len(points) - 1
    blank = MagicTracker(_ScriptedDetector(frames), MagicWarp.pretrained(), carry=carry)
    image = np.zeros((120, 160), np.uint8)
    _, second, _ = (blank.track(image) for _ in frames)
    assert missed not in second.ids  # nothing to align it by: followed, not reported
    frames = [points, points[1:] + shift]
    tight = MagicTracker(_ScriptedDetector(frames), MagicWarp.pretrained(), carry=carry, budget=len(points) - 1)
    tight.track(images[0])
    assert len(tight.track(images[1]).ids) == len(points) - 1  # no room left in the budget for the missed point
    # new detections come after the tracks a keyframe shares, yet are followed when they are not reported
    frames = [points[:-5], np.vstack([points[1:-5], points[-5:]]) + shift, points + 2 * shift]
    crowded = MagicTracker(_ScriptedDetector(frames), MagicWarp.pretrained(), carry=carry, budget=len(points) - 5)
    first, second, third = (crowded.track(image) for image in images)
    assert len(second.ids) == len(points) - 5 and (first.ids[0] in second.ids) == carry
    assert len(third.ids) == len(points)  # all continue a track: the five new ones were followed unreported


def test_magic_tracker_keeps_its_tracks_when_magicwarp_is_far_off():
    from deepslam.frontend.tracking import MagicTracker
    from deepslam.sim.pointsets import detector_points

    class FarOff:  # every estimate 20 px away from the truth: too far for snapping to mend
        def estimate(self, points_a, points_b, image_size, iterations=1, min_support=0.0):
            return np.array([[1.0, 0, 20], [0, 1, -20], [0, 0, 1]])

    points = detector_points(np.random.default_rng(1), 60, (120, 160))
    points = points[(points > 8).all(1) & (points < [150, 110]).all(1)]
    shift = np.array([1.0, 0.5])  # the small motion of a slow camera
    frames = [points + i * shift for i in range(4)]
    image = np.zeros((120, 160), np.uint8)
    tracker = MagicTracker(_ScriptedDetector(frames), FarOff())
    tracks = [tracker.track(image) for _ in frames]
    assert all(np.array_equal(t.ids, tracks[0].ids) for t in tracks)  # the no-motion guess, refined, wins
    unrefined = MagicTracker(_ScriptedDetector(frames), FarOff(), refine=False, carry=False)
    first, second = unrefined.track(image), unrefined.track(image)
    assert len(np.intersect1d(first.ids, second.ids)) < len(points) / 10  # MagicWarp alone loses its tracks


def _blurred_noise(rng: np.random.Generator, sigma: float) -> np.ndarray:
    """A float32 (120, 160) texture: uniform noise blurred by ``sigma`` px, stretched to 0-255."""
    noise = rng.uniform(0, 255, (120, 160)).astype(np.float32)
    return cv2.normalize(cv2.GaussianBlur(noise, (0, 0), sigma), None, 0, 255, cv2.NORM_MINMAX)


def test_polish_aligns_pairs_through_a_contrast_change_and_drops_the_ones_it_cannot_confirm():
    rng = np.random.default_rng(3)
    texture = _blurred_noise(rng, 2.0)
    shift = np.array([1.3, -0.7])
    moved = cv2.warpAffine(texture, np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]), (160, 120), flags=cv2.INTER_CUBIC)
    reference = texture.astype(np.uint8)
    current = np.clip(0.6 * moved + 50, 0, 255).astype(np.uint8)  # darker, flatter: raw Lucas-Kanade is biased
    points = np.stack(np.meshgrid(np.arange(24, 140, 12.0), np.arange(24, 100, 12.0)), -1).reshape(-1, 2)
    start = points + shift + rng.uniform(-0.8, 0.8, points.shape)  # detections a pixel or so off
    start[:6] += [4.0, 0.0]  # snapped to a neighbour
    polished, confirmed = polish(normalise_contrast(reference), normalise_contrast(current), points, start)
    assert not confirmed[:6].any() and confirmed[6:].mean() > 0.9
    errors = np.linalg.norm(polished[confirmed] - (points[confirmed] + shift), axis=1)
    before = np.linalg.norm(start[confirmed] - (points[confirmed] + shift), axis=1)
    assert np.median(errors) < 0.1 < 0.3 < np.median(before) and errors.max() < 0.25
    empty, none = polish(reference, current, np.zeros((0, 2)), np.zeros((0, 2)))
    assert empty.shape == (0, 2) and none.shape == (0,)


def test_polish_aligns_pairs_that_drifted_off_their_point_again_from_where_the_others_homography_puts_them():
    rng = np.random.default_rng(6)
    reference = _blurred_noise(rng, 2.0)
    shift = np.array([0.9, -1.1])
    current = cv2.warpAffine(reference, np.float32([[1, 0, shift[0]], [0, 1, shift[1]]]), (160, 120))
    images = normalise_contrast(reference.astype(np.uint8)), normalise_contrast(current.astype(np.uint8))
    points = np.stack(np.meshgrid(np.arange(24, 140, 10.0), np.arange(24, 100, 10.0)), -1).reshape(-1, 2)
    start = points + shift + rng.uniform(-0.3, 0.3, points.shape)
    drifted = np.arange(len(points)) % 4 == 0  # tracks that snapped to jittering detections for a while
    start[drifted] += rng.choice([-1, 1], (drifted.sum(), 2)) * rng.uniform(1.6, 2.0, (drifted.sum(), 2))
    _, once = polish(*images, points, start, PolishConfig(retry_gate=None))
    polished, twice = polish(*images, points, start)
    assert not once[drifted].any() and once[~drifted].all()  # Lucas-Kanade from there moves them too far
    assert twice.all()  # from where the other pairs' homography puts them, they align
    assert np.abs(polished[drifted] - (points[drifted] + shift)).max() < 0.1


def test_polish_drops_pairs_that_do_not_align_back_to_their_partner():
    reference, shift = _blurred_noise(np.random.default_rng(0), 2.0), np.array([0.6, -0.4])
    move = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    current = cv2.warpAffine(reference, move, (160, 120), flags=cv2.INTER_CUBIC)
    other = _blurred_noise(np.random.default_rng(1), 2.0)
    current[:, 80:] = other[:, 80:]  # the right half now shows something else: an occluder, a wrong match
    points = np.stack(np.meshgrid(np.arange(20, 144, 8.0), np.arange(20, 104, 8.0)), -1).reshape(-1, 2)
    start = points + shift + np.random.default_rng(4).uniform(-0.3, 0.3, points.shape)
    occluded = points[:, 0] + shift[0] > 80 - 8  # their windows see the other texture
    images = normalise_contrast(reference.astype(np.uint8)), normalise_contrast(current.astype(np.uint8))
    config = PolishConfig(warp_threshold=None)
    _, checked = polish(*images, points, start, config)
    _, unchecked = polish(*images, points, start, replace(config, max_return=None))
    assert unchecked[occluded].sum() >= 10  # Lucas-Kanade settles within max_move on the wrong texture ...
    assert checked[occluded].sum() <= unchecked[occluded].sum() / 4  # ... but does not align back from there
    assert checked[~occluded].all()


def test_polish_warps_the_keyframe_so_that_a_rotated_and_zoomed_view_aligns():
    rng = np.random.default_rng(5)
    reference = _blurred_noise(rng, 1.5).astype(np.uint8)
    H = cv2.getRotationMatrix2D((80.0, 60.0), 8.0, 1.12)  # 8 degrees, 12% closer: as after a few frames
    H = np.vstack([H, [0, 0, 1]])
    current = cv2.warpPerspective(reference, H, (160, 120), flags=cv2.INTER_CUBIC)
    points = np.stack(np.meshgrid(np.arange(40, 124, 8.0), np.arange(36, 88, 8.0)), -1).reshape(-1, 2)
    truth = cv2.perspectiveTransform(points[None], H)[0]
    start = truth + rng.uniform(-0.8, 0.8, truth.shape)
    errors = {}
    for threshold in (3.0, None):
        config = PolishConfig(warp_threshold=threshold)
        polished, confirmed = polish(normalise_contrast(reference), normalise_contrast(current), points, start, config)
        errors[threshold] = np.linalg.norm(polished - truth, axis=1)[confirmed]
    assert len(errors[3.0]) > 0.9 * len(points) and np.median(errors[3.0]) < 0.05
    assert np.median(errors[None]) > 2 * np.median(errors[3.0])  # unwarped patches disagree: biased or dropped


def test_the_magic_tracker_keeps_what_polishing_needs_only_when_it_polishes():
    from deepslam.frontend.tracking import MagicTracker

    image = np.zeros((120, 160), np.uint8)
    points = np.array([[20.0, 30.0], [60.0, 70.0]])
    for config, has_appearance in ((PolishConfig(), True), (None, False)):
        tracker = MagicTracker(_ScriptedDetector([points]), MagicWarp.pretrained(), polish=config)
        tracks = tracker.track(image)
        assert (tracks.appearance is not None) == has_appearance
    pairs = np.array([[0, 1], [1, 0]])
    kept, moved = tracker.confirm(tracks, tracks, pairs)  # without polishing every pair stands, as tracked
    np.testing.assert_array_equal(kept, pairs)
    np.testing.assert_array_equal(moved, tracks.points[[1, 0]])


def _parallax_pair(rng, shift, parallax, moved):
    """Two uint8 (120, 160) frames of one texture, the second shifted by ``shift`` (2,), except that the patches
    around the ``moved`` points (M, 2) of the first lie ``parallax`` (2,) px farther (nearer surfaces)."""
    texture = _blurred_noise(rng, 2.0)
    affine = np.float32([[1, 0, shift[0]], [0, 1, shift[1]]])
    current = cv2.warpAffine(texture, affine, (160, 120), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    for x, y in moved.astype(int):
        x1, y1 = np.array([x, y]) + (shift + parallax).astype(int)
        current[y1 - 10 : y1 + 11, x1 - 10 : x1 + 11] = texture[y - 10 : y + 11, x - 10 : x + 11]
    return texture.astype(np.uint8), current.astype(np.uint8)


def test_follow_finds_points_where_the_image_moved_them_and_not_where_it_lost_them():
    from deepslam.frontend.polish import follow

    rng = np.random.default_rng(5)
    points = np.stack(np.meshgrid(np.arange(30, 131, 25.0), np.arange(30, 91, 30.0)), -1).reshape(-1, 2)
    shift, parallax = np.array([3.0, -2.0]), np.array([3.0, 0.0])
    previous, current = _parallax_pair(rng, shift, parallax, points[:4])
    found, ok = follow(normalise_contrast(previous), normalise_contrast(current), points, points + shift)
    assert ok.all()
    np.testing.assert_allclose(found[:4], points[:4] + shift + parallax, atol=0.1)  # 3 px off the prediction
    np.testing.assert_allclose(found[4:], points[4:] + shift, atol=0.1)
    flat = current.copy()
    flat[:, 80:] = 128  # the right half covered by a plain surface: nothing there to align
    _, ok = follow(normalise_contrast(previous), normalise_contrast(flat), points, points + shift)
    assert not ok[points[:, 0] + shift[0] > 90].any() and ok[points[:, 0] + shift[0] < 70].all()


def test_a_following_magic_tracker_keeps_a_point_through_parallax_where_snapping_takes_a_neighbour():
    from deepslam.frontend.tracking import MagicTracker

    rng = np.random.default_rng(6)
    points = np.stack(np.meshgrid(np.arange(25, 136, 22.0), np.arange(25, 96, 23.0)), -1).reshape(-1, 2)
    shift, parallax = np.array([2.0, 1.0]), np.array([2.5, 0.0])
    near = np.arange(4)  # the points of a nearer surface: 2.5 px of parallax against the rest
    images = _parallax_pair(rng, shift, parallax, points[near])
    second = points + shift
    second[near] += parallax
    decoys = points[near] + shift + [-0.5, 0.0]  # other points, where the homography puts the near ones
    frames = [points, np.vstack([second, decoys])]
    for radius, kept in ((None, False), (1.5, True)):
        tracker = MagicTracker(_ScriptedDetector(list(frames)), MagicWarp.pretrained(), follow=radius)
        first, tracked = (tracker.track(image) for image in images)
        at = {int(i): p for i, p in zip(tracked.ids, tracked.points, strict=True)}
        on_their_point = [np.allclose(at.get(int(first.ids[i]), np.inf), second[i]) for i in near]
        assert all(on_their_point) == kept and any(on_their_point) == kept


def test_a_magic_tracker_looks_for_a_track_where_it_is_predicted_not_where_the_homography_puts_it():
    from deepslam.frontend.tracking import MagicTracker, Predicted

    rng = np.random.default_rng(6)
    points = np.stack(np.meshgrid(np.arange(25, 136, 22.0), np.arange(25, 96, 23.0)), -1).reshape(-1, 2)
    shift, parallax = np.array([2.0, 1.0]), np.array([2.5, 0.0])
    near = np.arange(4)  # the points of a nearer surface, as in the following test above
    images = _parallax_pair(rng, shift, parallax, points[near])
    second = points + shift
    second[near] += parallax
    decoys = points[near] + shift + [-0.5, 0.0]
    # a map's guess near the point, none, and one too far from the homography's to be believed (> 4 px)
    for offset, told in (([0.4, -0.3], True), (None, False), ([6.0, 0.0], False)):
        tracker = MagicTracker(_ScriptedDetector([points, np.vstack([second, decoys])]), MagicWarp.pretrained())
        first = tracker.track(images[0])
        if offset is not None:
            tracker.expect(Predicted(first.ids[near], second[near] + offset))
        tracked = tracker.track(images[1])
        at = {int(i): p for i, p in zip(tracked.ids, tracked.points, strict=True)}
        assert [np.allclose(at.get(int(first.ids[i]), np.inf), second[i]) for i in near] == [told] * len(near)
        far = np.setdiff1d(np.arange(len(points)), near)
        np.testing.assert_allclose([at[int(first.ids[i])] for i in far], second[far])  # the rest as before


def test_a_sparse_frame_is_topped_up_with_the_second_detectors_points_that_are_new():
    from deepslam.frontend.tracking import ToppedUpDetector

    image = np.zeros((120, 160), np.uint8)
    sparse = np.array([[10.0, 10.0], [50.0, 50.0]])
    dense = np.stack([np.arange(8, 152, 6.0), np.full(24, 80.0)], 1)
    other = np.array([[11.0, 11.0], [30.0, 30.0], [90.0, 20.0]])  # the first within 4 px of a primary point
    middle = dense[:12]  # at least min_points, fewer than enough_points
    frames = [sparse, middle, dense, middle]
    detector = ToppedUpDetector(
        _ScriptedDetector(frames), _ScriptedDetector([other] * 4), min_points=10, enough_points=20, top_k=14
    )
    topped = detector.detect(image)
    np.testing.assert_array_equal(topped[:, :2], [[10, 10], [50, 50], [30, 30], [90, 20]])  # primary first, new ones
    assert len(detector.detect(image)) == 14  # still topped up until the primary finds enough_points again ...
    np.testing.assert_array_equal(detector.detect(image)[:, :2], dense)  # ... as here: nothing added
    np.testing.assert_array_equal(detector.detect(image)[:, :2], middle)  # and not before it falls under min_points


def test_extraction_settings_have_one_source_with_named_presets():
    from deepslam.frontend.config import DETECTOR_PRESETS, EXTRACTION_PRESETS, ExtractionConfig

    assert MagicPoint.pretrained("S").extraction == EXTRACTION_PRESETS["default"] == ExtractionConfig()
    assert MagicPoint.pretrained("S-HA").extraction.subpixel == "smoothed"  # S-HA's own
    changed = MagicPoint.pretrained("S-HA", extraction=DETECTOR_PRESETS["S-HA"], top_k=7).extraction
    assert changed.subpixel == "parabola" and changed.top_k == 7 and changed.threshold == 0.001
    with pytest.raises(ValueError, match="grid_shifts"):
        ExtractionConfig(grid_shifts=3)


def test_ctrl_c_takes_effect_between_magicwarp_iterations_inside_a_held_block():
    import os
    import signal
    import threading
    import time

    from deepslam.interrupts import held_signals

    warp = MagicWarp.pretrained()
    points = np.random.default_rng(0).uniform([10, 10], [150, 110], (60, 2))
    # Python's Ctrl-C handler, as from a terminal, even where the test runner was started with Ctrl-C ignored
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        threading.Timer(0.3, lambda: os.kill(os.getpid(), signal.SIGINT)).start()
        started = time.time()
        with pytest.raises(KeyboardInterrupt), held_signals():
            warp.estimate(points, points, iterations=1_000_000)  # about 20 minutes of work unless interrupted
        assert time.time() - started < 5
    finally:
        signal.signal(signal.SIGINT, previous)


def test_magicwarp_refuses_degenerate_or_unrelated_point_sets_instead_of_inventing_a_homography():
    from deepslam.frontend.magicwarp import DegeneratePoints

    warp, rng = MagicWarp.pretrained(), np.random.default_rng(1)
    points = rng.uniform([10, 10], [150, 110], (60, 2))
    with pytest.raises(DegeneratePoints, match="at least 4 points in each image, all distinct"):
        warp.estimate(np.repeat(points[:1], 50, axis=0), points)  # 50 copies of one point
    with pytest.raises(DegeneratePoints, match="do not overlap"):
        warp.estimate(points, rng.uniform([10, 10], [150, 110], (60, 2)))  # unrelated sets
    with pytest.raises(ValueError, match=r"must be an \(N, 2\) or \(N, 3\) array"):
        warp.estimate(np.c_[points, np.zeros((60, 3))], points)  # (N, 5)
    H = warp.estimate(points, points + [3.0, 0.0])  # related sets still give their homography
    assert abs(H[0, 2] - 3) < 2
