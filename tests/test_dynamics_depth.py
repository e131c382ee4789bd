"""Depth-adaptive maps (eq 2, 5, 9, 10) and the robust keypoint depth, against hand-computed values."""

import numpy as np
import pytest

from d2slam.config import DynamicsConfig
from d2slam.dynamics import depth as dz

CFG = DynamicsConfig()


def test_beta_endpoints_midpoint_and_clipping():
    z = np.array([0.5, 4.5, 2.5, 0.1, 10.0])
    np.testing.assert_allclose(dz.beta(z), [0.05, 0.25, 0.15, 0.05, 0.25])


def test_alpha_gamma_inversely_proportional():
    np.testing.assert_allclose(dz.alpha([0.5, 4.5, 2.5, 0.2, 7.0]), [0.9, 0.5, 0.7, 0.9, 0.5])
    np.testing.assert_allclose(dz.gamma([0.5, 4.5, 2.5, 0.2, 7.0]), [28.0, 10.0, 19.0, 28.0, 10.0])
    # gamma(2) = 28 - 18 * (1.5 / 4)
    assert dz.gamma(2.0) == pytest.approx(21.25)


def test_delta_printed_formula_and_clip():
    np.testing.assert_allclose(dz.delta([0.25, 0.5, 1.0, 2.0, 9.25, 20.0]), [47.0, 46.0, 44.0, 40.0, 11.0, 11.0])


def test_invalid_depth_uses_midpoints():
    bad = np.array([0.0, -1.0, np.nan, np.inf, -np.inf])
    np.testing.assert_allclose(dz.beta(bad), 0.15)
    np.testing.assert_allclose(dz.alpha(bad), 0.7)
    np.testing.assert_allclose(dz.delta(bad), 29.5)
    np.testing.assert_allclose(dz.gamma(bad), 19.0)
    assert not dz.valid_depth(bad).any()
    assert np.isnan(dz.normalised_depth(bad)).all()


def test_no_depth_ablation_midpoints_everywhere():
    z = np.array([0.5, 1.0, 4.5])
    np.testing.assert_allclose(dz.beta(z, CFG, use_depth=False), 0.15)
    np.testing.assert_allclose(dz.alpha(z, CFG, use_depth=False), 0.7)
    np.testing.assert_allclose(dz.delta(z, CFG, use_depth=False), 29.5)
    np.testing.assert_allclose(dz.gamma(z, CFG, use_depth=False), 19.0)


def test_uncertainty_width_is_ln3_over_beta():
    np.testing.assert_allclose(dz.uncertainty_width([0.05, 0.25]), [np.log(3) / 0.05, np.log(3) / 0.25])
    assert dz.uncertainty_width(0.05) == pytest.approx(21.97, abs=0.01)  # "about 22 px near"
    assert dz.uncertainty_width(0.25) == pytest.approx(4.39, abs=0.01)  # "about 4 px far"


def test_keypoint_depth_matches_brute_force():
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.5, 4.0, (30, 40)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.3] = 0.0
    depth[3, 3] = np.nan
    depth[5, 5] = np.inf
    kps = np.column_stack([rng.uniform(-1, 40, 200), rng.uniform(-1, 30, 200)])
    got = dz.keypoint_depth(depth, kps, 1)
    for (u, v), g in zip(kps, got):
        cu, cv = int(np.rint(u)), int(np.rint(v))
        patch = depth[max(cv - 1, 0):cv + 2, max(cu - 1, 0):cu + 2].ravel() if 0 <= cu + 1 and 0 <= cv + 1 else []
        vals = [x for x in patch if np.isfinite(x) and x > 0]
        assert g == pytest.approx(np.median(vals) if vals else 0.0, rel=1e-6)


def test_keypoint_depth_edge_cases():
    depth = np.zeros((10, 10), np.float32)
    assert dz.keypoint_depth(depth, np.zeros((0, 2)), 1).shape == (0,)
    np.testing.assert_array_equal(dz.keypoint_depth(depth, [[5, 5], [np.nan, 1], [100, 100]], 1), 0.0)
    depth[4:7, 4:7] = [[1, 2, 3], [4, 5, 6], [7, 8, 0]]
    assert dz.keypoint_depth(depth, [[5, 5]], 1)[0] == pytest.approx(4.5)  # 8 valid values: mean of the middle two
