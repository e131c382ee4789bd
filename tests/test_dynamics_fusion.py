"""Fusion (eq 7, four cases) and the Bayesian filter (eq 8) against hand computations."""

import numpy as np
import pytest

from d2slam.config import DynamicsConfig
from d2slam.dynamics.fusion import bayes_update, check_edge_band, edge_band, fuse, predict, prior_belief
from d2slam.errors import D2SlamError

CFG = DynamicsConfig()


def test_eq7_four_cases():
    n = 5
    p_s = np.full(n, 0.8)
    p_g = np.array([0.2, 0.2, np.nan, 0.2, np.nan])
    observed = np.array([True, True, False, True, False])
    in_area = np.array([True, True, True, False, False])
    uncertain = np.array([True, False, False, False, False])
    got = fuse(p_s, p_g, observed, in_area, uncertain, CFG)
    np.testing.assert_allclose(got, [
        0.5 * 0.2 + 0.5 * 0.8,  # matched, uncertainty zone: omega 0.5
        0.1 * 0.2 + 0.9 * 0.8,  # matched, reliable mask area: omega 0.1
        0.8,  # not matched, in the mask area: P_S
        0.2,  # matched, outside: P_g
        0.5,  # no observation
    ])


def test_eq7_neighbours_p_g_only_raises_unmatched_keypoints():
    """Ours: a keypoint that is not matched gets max(P, p_nb); matched keypoints and NaN p_nb keep eq 7's P."""
    p_s = np.array([0.8, 0.3, 0.8, 0.3, 0.3, 0.3])
    p_g = np.array([np.nan, np.nan, np.nan, 0.2, np.nan, np.nan])
    observed = np.array([False, False, False, True, False, False])
    in_area = np.array([False, False, True, False, True, False])
    uncertain = np.array([False, False, False, False, True, False])
    p_nb = np.array([0.8, 0.3, 0.6, 0.9, 0.6, np.nan])
    got = fuse(p_s, p_g, observed, in_area, uncertain, CFG, p_nb)
    np.testing.assert_allclose(got, [
        0.8,  # no observation: 0.5 -> the neighbours' 0.8
        0.5,  # the neighbours' 0.3 is lower than 0.5: kept
        0.8,  # not matched in the mask area: P_S 0.8 is higher
        0.2,  # matched: its own P_g, whatever the neighbours
        0.6,  # not matched in the uncertainty zone: P_S 0.3 -> 0.6
        0.5,  # too few neighbours (NaN)
    ])
    np.testing.assert_array_equal(fuse(p_s, p_g, observed, in_area, uncertain, CFG),
                                  fuse(p_s, p_g, observed, in_area, uncertain, CFG, np.full(6, np.nan)))


def test_edge_band_by_hand():
    """Ours (flow_edge_band): unobserved keypoints with eq 1's d_max in (-band, 0) get max(P, p_edge)."""
    p = np.array([0.3, 0.3, 0.3, 0.3, 0.95, 0.8, 0.5, 0.5, 0.2])
    d_max = np.array([-3.0, -6.0, -8.0, -3.0, -1.0, 2.0, -np.inf, np.nan, -0.5])
    observed = np.array([False, False, False, True, False, False, False, False, False])
    got, edge = edge_band(p, d_max, observed, 6.0, 0.9)
    np.testing.assert_array_equal(edge, [True, False, False, False, True, False, False, False, True])
    np.testing.assert_allclose(got, [
        0.9,  # unobserved, 3 px outside: raised
        0.3,  # exactly at the band's width: kept (open interval)
        0.3,  # farther out
        0.3,  # observed: eq 7's P stands
        0.95,  # already above p_edge: max keeps it
        0.8,  # inside the mask (d > 0): eq 7's P_S
        0.5,  # no masks (-inf)
        0.5,  # non-finite keypoint (NaN)
        0.9,  # half a pixel outside
    ])
    same, none = edge_band(p, d_max, observed, 0.0, 0.9)
    np.testing.assert_array_equal(same, p)
    assert not none.any()
    check_edge_band(6.0, 0.9)
    with pytest.raises(D2SlamError, match="flow_edge_p"):
        check_edge_band(6.0, -0.1)
    with pytest.raises(D2SlamError, match="flow_edge_band"):
        check_edge_band(np.inf, 0.9)


def test_eq8_two_steps_by_hand():
    b1 = bayes_update(np.array([0.5]), np.array([0.8]), CFG)[0]
    assert b1 == pytest.approx(0.8)  # b- = 0.5 -> 0.8 * 0.5 / (0.8 * 0.5 + 0.2 * 0.5)
    b2 = bayes_update(np.array([b1]), np.array([0.7]), CFG)[0]
    bm = 0.9 * 0.8 + 0.1 * 0.2  # 0.74
    assert b2 == pytest.approx(0.7 * bm / (0.7 * bm + 0.3 * (1 - bm)))  # 0.86913...
    assert b2 == pytest.approx(0.869128, abs=1e-6)
    # no observation (P = 0.5) only applies the transition
    assert bayes_update(np.array([0.9]), np.array([0.5]), CFG)[0] == pytest.approx(0.9 * 0.9 + 0.1 * 0.1)


def test_prediction_and_clip_avoid_lock_in():
    np.testing.assert_allclose(predict(np.array([0.0, 1.0, 0.5]), CFG), [0.1, 0.9, 0.5])
    b = bayes_update(np.array([0.0, 1.0]), np.array([1.0, 0.0]), CFG)
    assert ((b > 0) & (b < 1)).all()
    # a strong static prior survives one certain-looking observation less than completely
    b = bayes_update(np.array([0.0]), np.array([1.0]), CFG)[0]
    assert 0.9 < b < 1.0


def test_prior_precedence_previous_keypoint_then_map_point_then_0_5():
    matches = np.array([[0, 2], [1, 0]])
    prev_belief = np.array([0.9, 0.3, 0.7])
    mp = np.array([0.1, np.nan, 0.6, np.nan])
    got = prior_belief(4, matches, prev_belief, mp, CFG)
    np.testing.assert_allclose(got, [0.7, 0.9, 0.6, 0.5])
    # NaN previous belief falls back to the map point
    got = prior_belief(2, np.array([[0, 0]]), np.array([np.nan]), np.array([0.2, np.nan]), CFG)
    np.testing.assert_allclose(got, [0.2, 0.5])
