"""Keypoint truth lookup and precision / recall / F1 accumulation."""

import math

import numpy as np
import pytest

from d2slam.errors import D2SlamError
from d2slam.eval.keypoints import KeypointMetrics, ModuleMetrics, keypoint_truth


def test_keypoint_truth_rounding_bounds_nan():
    m = np.zeros((4, 5), np.uint8)
    m[1, 2] = 7  # any non-zero id is dynamic
    kps = np.array([[2.4, 0.6], [1.6, 1.4], [2.6, 1.0], [-0.4, 0.0], [-0.6, 0.0], [4.6, 1.0], [np.nan, 1.0],
                    [2.0, 1.49]])
    assert keypoint_truth(kps, m).tolist() == [True, True, False, False, False, False, False, True]
    assert keypoint_truth(np.zeros((0, 2)), m).shape == (0,)
    with pytest.raises(D2SlamError):
        keypoint_truth(kps, np.zeros((2, 4, 5)))


def test_metrics_by_hand_and_accumulation():
    pred = np.array([1, 1, 0, 0, 1, 0], bool)
    truth = np.array([1, 0, 1, 0, 1, 0], bool)
    m = KeypointMetrics().update(pred, truth)
    assert (m.tp, m.fp, m.fn, m.tn) == (2, 1, 1, 2)
    assert m.precision == pytest.approx(2 / 3) and m.recall == pytest.approx(2 / 3)
    assert m.f1 == pytest.approx(2 / 3) and m.static_precision == pytest.approx(2 / 3)
    # accumulating two frames equals one frame of the concatenation
    m2 = KeypointMetrics().update(pred[:3], truth[:3]).update(pred[3:], truth[3:])
    assert m2 == m
    assert (KeypointMetrics().update(pred[:3], truth[:3]) + KeypointMetrics().update(pred[3:], truth[3:])) == m
    d = m.as_dict()
    assert d["tp"] == 2 and d["f1"] == pytest.approx(2 / 3)


def test_undefined_ratios_are_nan_and_zero_f1():
    m = KeypointMetrics().update(np.zeros(3, bool), np.zeros(3, bool))
    assert math.isnan(m.precision) and math.isnan(m.recall) and math.isnan(m.f1)
    assert m.static_precision == 1.0
    m = KeypointMetrics().update(np.array([True, False]), np.array([False, True]))
    assert m.precision == 0.0 and m.recall == 0.0 and m.f1 == 0.0
    with pytest.raises(D2SlamError):
        KeypointMetrics().update(np.zeros(2, bool), np.zeros(3, bool))


def test_module_metrics():
    mm = ModuleMetrics().update({"semantic": np.array([True, False]), "final": np.array([True, True])},
                                np.array([True, False]))
    d = mm.as_dict()
    assert d["semantic"]["f1"] == 1.0 and d["final"]["precision"] == 0.5
