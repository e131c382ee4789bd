"""Semantic module (eq 1-2): signed distances equal the distance transforms, P_S, uncertainty zone, odd masks."""

import numpy as np
import pytest
from scipy import ndimage

from d2slam.dynamics.semantic import semantic_module, semantic_probability, signed_distances
from d2slam.errors import D2SlamError


def _random_mask(rng, h, w):
    m = np.zeros((h, w), bool)
    for _ in range(rng.integers(1, 4)):
        cx, cy = rng.integers(0, w), rng.integers(0, h)
        m[max(cy - rng.integers(1, 15), 0):cy + rng.integers(1, 15), max(cx - rng.integers(1, 15), 0):cx + rng.integers(1, 15)] = True
    if rng.random() < 0.5:
        m &= rng.random((h, w)) > 0.05  # holes and ragged borders
    return m


def test_signed_distance_equals_distance_transforms_everywhere():
    rng = np.random.default_rng(0)
    h, w = 40, 56
    grid = np.stack(np.meshgrid(np.arange(w), np.arange(h)), -1).reshape(-1, 2).astype(float)
    for _ in range(25):
        m = _random_mask(rng, h, w)
        if m.all():
            continue
        ref = np.where(m, ndimage.distance_transform_edt(m), -ndimage.distance_transform_edt(~m))
        got = signed_distances(m[None], grid)[:, 0].reshape(h, w)
        np.testing.assert_allclose(got, ref)


def test_margin_gives_lower_bound_beyond_and_exact_within():
    m = np.zeros((50, 80), bool)
    m[20:30, 10:20] = True
    kps = np.array([[25.0, 25.0], [40.0, 25.0], [70.0, 25.0]])  # 6 and 21 and 51 px right of the mask
    d = signed_distances(m[None], kps, margin=30.0)[:, 0]
    np.testing.assert_allclose(d[:2], [-6.0, -21.0])
    assert d[2] <= -30.0 and d[2] >= -51.0  # beyond the margin: a lower bound of the distance (|d| <= true)


def test_semantic_probability_and_uncertainty_zone():
    assert semantic_probability(0.0, 0.05) == pytest.approx(0.5)
    b = np.array([0.05, 0.25])
    np.testing.assert_allclose(semantic_probability(np.log(3) / b, b), 0.75)
    np.testing.assert_allclose(semantic_probability(-np.log(3) / b, b), 0.25)
    assert semantic_probability(-np.inf, 0.1) == 0.0
    # A keypoint 10 px outside a mask: uncertain near (beta 0.05, width 22 px), reliable far (beta 0.25, 4.4 px).
    m = np.zeros((60, 60), bool)
    m[10:50, 10:30] = True
    kps = np.array([[39.0, 30.0], [39.0, 30.0], [20.0, 30.0]])
    res = semantic_module(m[None], kps, np.array([0.05, 0.25, 0.25]))
    np.testing.assert_allclose(res.d_max[:2], -10.0)
    np.testing.assert_array_equal(res.uncertain, [True, False, False])
    np.testing.assert_array_equal(res.inside, [False, False, True])
    np.testing.assert_array_equal(res.in_area, [True, False, True])
    assert res.p_s[0] == pytest.approx(1 / (1 + np.exp(0.5)))
    assert res.p_s[2] == pytest.approx(1 / (1 + np.exp(-0.25 * 10)))  # centre column 20: 10 px to the edge


def test_max_over_masks():
    m = np.zeros((2, 40, 60), bool)
    m[0, 5:35, 5:20] = True
    m[1, 5:35, 30:55] = True
    kps = np.array([[25.0, 20.0], [42.0, 20.0]])
    res = semantic_module(m, kps, np.full(2, 0.1))
    d = signed_distances(m, kps)
    np.testing.assert_allclose(res.d_max, d.max(axis=1))
    assert res.inside.tolist() == [False, True]


def test_no_masks_empty_mask_full_mask():
    kps = np.array([[3.0, 4.0], [10.0, 10.0]])
    b = np.full(2, 0.15)
    for masks in (None, np.zeros((0, 20, 30), bool), np.zeros((1, 20, 30), bool)):
        res = semantic_module(masks, kps, b)
        np.testing.assert_array_equal(res.p_s, 0.0)
        assert not res.in_area.any() and not res.uncertain.any()
    full = np.ones((1, 20, 30), bool)
    res = semantic_module(full, kps, b)
    np.testing.assert_allclose(res.d_max, np.hypot(20, 30))
    assert res.inside.all() and not res.uncertain.any()
    assert (res.p_s > 0.98).all()


def test_bad_keypoints_and_bad_masks():
    m = np.zeros((1, 20, 30), bool)
    m[0, 5:10, 5:10] = True
    d = signed_distances(m, np.array([[np.nan, 1.0], [-5.0, 100.0]]))
    assert np.isnan(d[0, 0]) and np.isfinite(d[1, 0])  # out-of-image keypoints are clipped to the border
    res = semantic_module(m, np.array([[np.nan, 1.0]]), np.array([0.1]))
    assert res.p_s[0] == 0.0 and not res.in_area[0]
    with pytest.raises(D2SlamError):
        signed_distances(np.zeros((20, 30), bool), np.zeros((1, 2)))
