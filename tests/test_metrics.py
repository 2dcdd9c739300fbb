import numpy as np
import pytest
import torch

from deepslam.frontend import MagicWarp
from deepslam.frontend.classical import ClassicalDetector
from deepslam.frontend.config import MagicWarpConfig
from deepslam.frontend.evaluation.detector import _jittered
from deepslam.frontend.evaluation.metrics import (
    average_precision,
    localization_error,
    match_detections,
    merge,
    repeatability,
    repeatability_at_n,
)
from deepslam.frontend.evaluation.warp import (
    GRIDS,
    PAPER,
    short_of_paper,
    table_lines,
    validation_figures,
    validation_set,
)
from deepslam.frontend.magicwarp import MagicWarpNet
from deepslam.sim.world import photo


def test_average_precision_by_hand():
    corners = np.array([[10.0, 10.0], [50.0, 50.0]])
    detections = np.array(
        [
            [11.0, 10.0, 0.9],  # true, 1 px
            [30.0, 30.0, 0.8],  # false
            [50.0, 53.0, 0.7],  # true, 3 px
            [10.0, 12.0, 0.6],
        ]
    )  # near a corner already matched: false
    result = match_detections(detections, corners, eps=4)
    assert result.correct.tolist() == [True, False, True, False]
    # precision 1 at recall 0.5, 2/3 at recall 1
    assert average_precision(result) == pytest.approx(0.5 * 1 + 0.5 * 2 / 3)
    assert localization_error(result) == pytest.approx(2.0)


def test_average_precision_pools_images_and_monotone_precision():
    a = match_detections(np.array([[0.0, 0, 0.5]]), np.array([[0.0, 0]]))
    b = match_detections(np.array([[9.0, 9, 0.9]]), np.zeros((0, 2)))  # a negative image's false positive
    pooled = merge([a, b])
    assert pooled.positives == 1
    assert average_precision(pooled) == pytest.approx(0.5)
    assert average_precision(merge([b])) == 0.0


def test_repeatability_by_hand():
    H = np.eye(3)
    p1 = np.array([[10.0, 10.0], [40.0, 40.0]])
    p2 = np.array([[11.0, 10.0], [43.0, 40.0], [80.0, 80.0]])
    # p1[0] and p2[0] repeat (1 px); p1[1]-p2[1] 3 px > eps 2; p2[2] alone
    assert repeatability(p1, p2, H, (120, 160), eps=2) == pytest.approx(2 / 5)
    shift = np.array([[1.0, 0, 5], [0, 1, 0], [0, 0, 1]])
    assert repeatability(p1, p1 + [5, 0], shift, (120, 160)) == 1.0


def test_repeatability_at_n_takes_the_best_count():
    p1 = np.array([[10.0, 10.0, 0.9], [50.0, 50.0, 0.5]])
    p2 = np.array([[10.5, 10.0, 0.9], [90.0, 90.0, 0.5]])
    rep, n, error = repeatability_at_n([(p1, p2, np.eye(3))], (120, 160), counts=(1, 2))
    assert rep == 1.0 and n == 1.0 and error == pytest.approx(0.5)  # the repeated points are 0.5 px apart


def test_nms_is_greedy_in_order_of_score():
    from deepslam.frontend.points import nms_points

    chain = np.array([[10, 10, 0.5], [13, 10, 0.9], [16, 10, 0.7], [40, 40, 0.7]], np.float32)  # 3 px apart
    kept = nms_points(chain, 4.0)
    assert kept[:, :2].tolist() == [[13, 10], [40, 40]]  # the best takes both neighbours
    kept = nms_points(chain[[0, 2, 3]], 4.0)  # without the middle point, 6 px apart: all stay
    assert kept[:, 2].tolist() == pytest.approx([0.7, 0.7, 0.5])
    weaker_middle = chain.copy()
    weaker_middle[1, 2] = 0.1
    assert nms_points(weaker_middle, 4.0)[:, :2].tolist() == [[16, 10], [40, 40], [10, 10]]  # both ends stay
    assert len(nms_points(chain, 0)) == 4 and len(nms_points(chain[:0], 4.0)) == 0


def test_point_extraction_nms_border_top_k_and_subpixel():
    from deepslam.frontend.points import extract_points

    yy, xx = np.mgrid[0:40, 0:48].astype(np.float32)
    peaks = [
        (20.3, 12.6, 0.9),
        (23.0, 13.0, 0.5),
        (40.0, 30.0, 0.7),
        (1.0, 1.0, 1.0),
    ]  # 2nd: within NMS of 1st; 4th: border
    scores = sum(s * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / 2) for x, y, s in peaks).astype(np.float32)
    points = extract_points(scores, 0.1, nms_radius=4, border=4)
    assert points[:, :2].tolist() == [[20, 13], [40, 30]]  # sorted by score, neighbour and border peaks gone
    assert len(extract_points(scores, 0.1, top_k=1)) == 1
    diagonal = np.zeros((40, 48), np.float32)
    diagonal[10, 10], diagonal[14, 13], diagonal[13, 14] = 1.0, 0.8, 0.6  # 5.0 px and 5.0 px away, 1.4 px apart
    assert extract_points(diagonal, 0.1, nms_radius=4, border=0)[:, :2].tolist() == [[10, 10], [13, 14]]
    refined = extract_points(scores, 0.1, refine="parabola")
    assert np.abs(refined[0, :2] - [20.3, 12.6]).max() < np.abs(points[0, :2] - [20.3, 12.6]).max() / 2
    np.testing.assert_allclose(refined[1, :2], [40, 30], atol=1e-6)  # a symmetric peak stays put
    bilinear = np.zeros((40, 48), np.float32)
    bilinear[20, 10:12] = [0.6, 0.2]  # a peak at x = 10.25 spread over two pixels, as a soft label is
    bilinear[21, 10] = 0.2  # and at y = 20.25
    np.testing.assert_allclose(extract_points(bilinear, 0.1, refine="centroid")[0, :2], [10.2, 20.2], atol=1e-6)
    sharp = np.exp(-((xx - 20.4) ** 2 + (yy - 12.0) ** 2) / (2 * 0.6**2)).astype(np.float32)  # a one-pass peak
    parabola, smoothed = (extract_points(sharp, 0.1, refine=r)[0, 0] for r in ("parabola", "smoothed"))
    assert abs(smoothed - 20.4) < 0.05 < 0.1 < abs(parabola - 20.4)  # three sharp samples pull it to the pixel
    with pytest.raises(ValueError, match="sub-pixel"):
        extract_points(scores, 0.1, refine="quadratic")


def test_jittered_real_image_frames_come_with_their_true_motion():
    image = photo("camera", (120, 160))
    frames, homographies = _jittered([image] * 4, np.random.default_rng(0), jitter_px=3.0)
    assert len(homographies) == 3 and not np.allclose(homographies[0], np.eye(3))
    points = [ClassicalDetector("shi").detect(f) for f in frames]
    true_motion, *_ = repeatability_at_n(list(zip(points, points[1:], homographies, strict=False)), image.shape)
    no_motion, *_ = repeatability_at_n(
        [(a, b, np.eye(3)) for a, b in zip(points, points[1:], strict=False)], image.shape
    )
    assert true_motion > 0.8 > no_motion + 0.2


def test_breakdown_cells_are_checked_against_the_papers_magicwarp_column():
    def table(shift):
        return {
            density: {
                str(extra): {"magicwarp": {m: v + shift for m, v in zip(GRIDS, mw, strict=False)}}
                for (d, extra), (_, mw) in PAPER.items()
                if d == density
            }
            for density in ("low", "medium", "high")
        }

    assert short_of_paper({"breakdown": table(0.0)}, "magicwarp") == []
    result = {"breakdown": table(0.0)}
    result["breakdown"]["medium"]["0.2"]["magicwarp"]["random_h"] = 17.71
    assert short_of_paper(result, "magicwarp") == ["medium 20% random_h 17.71<24.84"]
    assert "35 of 36 cells at or above the paper; short: medium 20% random_h 17.71<24.84" in "\n".join(
        table_lines(result)
    )


def test_warp_validation_moves_pairs_by_the_papers_breakdown_magnitudes():
    validation = validation_set(seed=3, runs=2)
    assert len(validation) == 36 * 2 and [motion for motion, _ in validation[:8:2]] == list(GRIDS)
    _, first = validation[0]  # low density, no extra points, translation: the paper's 24.00 px
    partner = first.true_index >= 0
    np.testing.assert_allclose(
        first.points_b[first.true_index[partner]] - first.points_a[partner], [[24.0, 0.0]] * partner.sum()
    )
    identity = MagicWarpNet(MagicWarpConfig(widths=(4, 4), hidden=8))
    torch.nn.init.zeros_(identity.head[-1].weight)  # outputs its bias: H = I, the nearest-neighbour baseline
    identity.eval()
    nearest, shipped = (
        validation_figures(identity, validation),
        validation_figures(MagicWarp.pretrained().net, validation),
    )
    assert 0 <= nearest["pass@paper"] <= 100 and set(shipped) == set(nearest)
    assert shipped["score"] > nearest["score"] + 20  # the paper's MagicWarp magnitudes are about 3x NN's breakdown
