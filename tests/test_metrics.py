import numpy as np
import pytest

from frontend.metrics import (average_precision, localization_error, match_detections, merge, repeatability,
                              repeatability_at_n)


def test_average_precision_by_hand():
    corners = np.array([[10.0, 10.0], [50.0, 50.0]])
    detections = np.array([[11.0, 10.0, 0.9],    # true, 1 px
                           [30.0, 30.0, 0.8],    # false
                           [50.0, 53.0, 0.7],    # true, 3 px
                           [10.0, 12.0, 0.6]])   # near a corner already matched: false
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
    p2 = np.array([[10.0, 10.0, 0.9], [90.0, 90.0, 0.5]])
    rep, n = repeatability_at_n([(p1, p2, np.eye(3))], (120, 160), counts=(1, 2))
    assert rep == 1.0 and n == 1.0
