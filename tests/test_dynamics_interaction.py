"""Object Interaction Module (eq 9-10): neighbours, weighted centroid, zone, mask depth."""


import numpy as np
import pytest

from d2slam.config import DynamicsConfig
from d2slam.dynamics.depth import DepthMaps
from d2slam.dynamics.interaction import (MatchedPoints, interaction_zone, mask_depths, moving_masks, neighbour_p_g,
                                         object_interaction, oim_candidates)
from d2slam.dynamics.semantic import FrameMasks
from d2slam.ranges import overridden

CFG = DynamicsConfig()


def test_static_keypoint_surrounded_by_dynamic_flips_far_in_depth_does_not():
    kps = np.array([
        [100.0, 100.0],  # 0: static candidate at 2.0 m
        [110.0, 100.0],  # 1: dynamic, dz 0.1 -> w = 6/7
        [130.0, 100.0],  # 2: dynamic, dz 0.35 -> w = 0.5
        [300.0, 300.0],  # 3: static candidate at 2.0 m
        [305.0, 300.0],  # 4: dynamic but 1.5 m behind (dz > rho)
        [295.0, 302.0],  # 5: dynamic, 1.5 m behind
    ])
    z = np.array([2.0, 2.1, 2.35, 2.0, 3.5, 3.5])
    cand = np.array([True, False, False, True, False, False])
    dyn = ~cand
    flip, G = object_interaction(kps, z, cand, dyn, CFG)
    w1, w2 = (0.7 - 0.1) / 0.7, (0.7 - 0.35) / 0.7
    gx = (110 * w1 + 130 * w2) / (w1 + w2)  # 117.37; |p - G| = 17.37 < gamma(2) = 21.25
    np.testing.assert_allclose(G[0], [gx, 100.0])
    assert flip.tolist() == [True, False, False, False, False, False]
    assert np.isnan(G[3]).all()
    # Without the depth tests (no-depth ablation) the far one has neighbours and flips too.
    flip_nd, _ = object_interaction(kps, z, cand, dyn, CFG, use_depth=False)
    assert flip_nd[3]


def test_centroid_far_from_keypoint_does_not_flip():
    # Two dynamic neighbours on the same side, 35-40 px away (< delta(2) = 40): centroid 37.5 px > gamma 21.25.
    kps = np.array([[100.0, 100.0], [135.0, 100.0], [139.0, 100.0]])
    z = np.array([2.0, 2.0, 2.0])
    flip, G = object_interaction(kps, z, np.array([True, False, False]), np.array([False, True, True]), CFG)
    assert not flip[0] and G[0, 0] == pytest.approx(137.0)


def test_neighbour_radius_is_strict_and_self_excluded():
    # delta(2) = 40: a neighbour at exactly 40 px is not a neighbour.
    kps = np.array([[100.0, 100.0], [140.0, 100.0]])
    z = np.array([2.0, 2.0])
    flip, G = object_interaction(kps, z, np.array([True, False]), np.array([False, True]), CFG)
    assert not flip[0] and np.isnan(G[0]).all()
    # A keypoint both candidate and geometric-dynamic is not its own neighbour.
    flip, G = object_interaction(kps[:1], z[:1], np.array([True]), np.array([True]), CFG)
    assert not flip[0]


def test_invalid_depth_fails_depth_tests():
    kps = np.array([[100.0, 100.0], [105.0, 100.0]])
    for z in (np.array([0.0, 2.0]), np.array([2.0, np.nan])):
        flip, _ = object_interaction(kps, z, np.array([True, False]), np.array([False, True]), CFG)
        assert not flip.any()


def test_interaction_zone_reach_and_depth():
    # delta(z_n = 2) = 40 -> reach 80 px; depth within 1 m of z_n.
    d = np.array([[5.0], [-79.0], [-81.0], [-10.0], [-10.0], [np.nan]])
    z = np.array([2.0, 2.5, 2.0, 3.2, 0.0, 2.0])
    got = interaction_zone(d, z, np.array([2.0]), CFG)
    assert got.tolist() == [True, True, False, False, False, False]
    # no-depth: reach 2 * 29.5 = 59 px, depth test dropped
    got = interaction_zone(d, z, np.array([2.0]), CFG, use_depth=False)
    assert got.tolist() == [True, False, False, True, True, False]
    assert interaction_zone(np.zeros((3, 0)), np.ones(3), np.zeros(0), CFG).tolist() == [False] * 3
    # A mask without valid depth has no zone.
    assert not interaction_zone(np.array([[5.0]]), np.array([2.0]), np.array([np.nan]), CFG).any()


def test_mask_depths_strided_median_close_to_full():
    rng = np.random.default_rng(0)
    depth = rng.normal(2.0, 0.3, (120, 160)).astype(np.float32)
    depth[rng.random(depth.shape) < 0.1] = 0.0
    masks = np.zeros((3, 120, 160), bool)
    masks[0, 10:100, 20:60] = True
    masks[1, 50, 70] = True  # single pixel: the stride-4 grid misses it -> every pixel
    full = overridden(DynamicsConfig(), {"ours": {"zone_median_stride": 1}})
    z4, z1 = mask_depths(depth, masks), mask_depths(depth, masks, full)
    valid = depth[masks[0]][depth[masks[0]] > 0]
    assert z1[0] == pytest.approx(np.median(valid))
    assert abs(z4[0] - z1[0]) < 0.05
    assert z4[1] == pytest.approx(depth[50, 70]) or (depth[50, 70] == 0 and np.isnan(z4[1]))
    assert np.isnan(z4[2])  # empty mask
    depth[:] = 0
    assert np.isnan(mask_depths(depth, masks[:1])).all()  # no valid depth
    assert mask_depths(depth, None).shape == (0,)


def test_neighbour_p_g_by_hand():
    """Unmatched keypoint 0 at 2 m (delta = 40 px): matched neighbours 1 and 2 count (P_g 0.7, 0.9); 3 is 0.5 m
    deeper, 4 is 45 px away, 5 is unmatched: mean 0.8. Matched keypoints and invalid depths get NaN."""
    kps = np.array([[100, 100], [105, 100], [100, 130], [103, 100], [145, 100], [101, 101], [300, 300], [301, 300]],
                   float)
    z = np.array([2.0, 2.05, 2.1, 2.5, 2.0, 2.0, 0.0, 2.0])
    observed = np.array([False, True, True, True, True, False, False, True])
    p_g = np.array([np.nan, 0.7, 0.9, 0.0, 0.0, np.nan, np.nan, 0.9])
    got = neighbour_p_g(kps, DepthMaps(z, CFG), observed, p_g, CFG)
    assert got[0] == pytest.approx(0.8)
    assert np.isnan(got[[1, 2, 3, 4, 7]]).all()  # matched
    assert np.isnan(got[6])  # invalid depth
    assert got[5] == pytest.approx(0.8)  # the same two neighbours (4 is 44 px away)
    few = neighbour_p_g(kps, DepthMaps(z, CFG), observed, p_g, overridden(CFG, {"ours": {"neighbour_min": 3}}))
    assert np.isnan(few).all()


def test_neighbour_p_g_equals_a_plain_loop():
    rng = np.random.default_rng(4)
    n = 400
    kps = rng.uniform(0, 200, (n, 2))
    z = rng.choice([1.0, 2.0, 3.5], n) + rng.normal(0, 0.06, n)  # three surfaces, some neighbours too far in depth
    z[rng.random(n) < 0.1] = 0.0
    observed = rng.random(n) < 0.5
    p_g = np.where(observed, rng.random(n), np.nan)
    maps = DepthMaps(z, CFG)
    got = neighbour_p_g(kps, maps, observed, p_g, CFG)
    want = np.full(n, np.nan)
    for i in range(n):
        if observed[i] or z[i] <= 0:
            continue
        d = np.hypot(*(kps - kps[i]).T)
        cand = np.flatnonzero(observed & (z > 0))
        near = cand[np.argsort(d[cand], kind="stable")[:CFG.ours.neighbour_k]]  # the k nearest matched keypoints
        nb = near[(d[near] < maps.delta[i]) & (np.abs(z[near] - z[i]) < CFG.ours.neighbour_depth)]
        if len(nb) >= CFG.ours.neighbour_min:
            want[i] = p_g[nb].mean()
    np.testing.assert_allclose(got, want)
    assert 20 < np.isfinite(got).sum() < (~observed).sum()  # both outcomes are exercised


@pytest.mark.parametrize("use_depth", [True, False])
def test_object_interaction_equals_a_plain_loop_with_and_without_the_shared_tree(use_depth):
    """eq 9-10 by a loop over the candidates, against the vectorised function with its own tree and with the frame's
    ``MatchedPoints`` tree (the one ``neighbour_p_g`` uses): the same flips and centroids."""
    rng = np.random.default_rng(9)
    n = 500
    kps = rng.uniform(0, 250, (n, 2))
    z = rng.choice([1.0, 2.0, 3.5], n) + rng.normal(0, 0.2, n)
    z[rng.random(n) < 0.08] = np.nan
    kps[rng.random(n) < 0.02] = np.inf
    observed = rng.random(n) < 0.7
    dyn = observed & (rng.random(n) < 0.4)  # the geometric flag only marks matched keypoints
    cand = ~dyn & (rng.random(n) < 0.6)
    maps = DepthMaps(z, CFG, use_depth)
    finite = np.isfinite(kps).all(axis=1)
    shared = MatchedPoints(kps, observed, finite, maps.valid if use_depth else None)
    flip_own, g_own = object_interaction(kps, z, cand, dyn, CFG, use_depth, maps=maps)
    flip_sh, g_sh = object_interaction(kps, z, cand, dyn, CFG, use_depth, maps=maps, matched=shared)
    np.testing.assert_array_equal(flip_own, flip_sh)
    np.testing.assert_allclose(g_own, g_sh, rtol=1e-12)
    ok = finite & (maps.valid if use_depth else True)
    want = np.zeros(n, bool)
    for i in np.flatnonzero(cand & ok):
        j = np.flatnonzero(dyn & ok)
        j = j[(np.hypot(*(kps[j] - kps[i]).T) < maps.delta[i]) & (j != i)]
        if use_depth:
            j = j[np.abs(z[j] - z[i]) < CFG.rho]
            w = (CFG.rho - np.abs(z[j] - z[i])) / CFG.rho
        else:
            w = np.ones(len(j))
        if w.sum() > 0:
            g = (w[:, None] * kps[j]).sum(axis=0) / w.sum()
            np.testing.assert_allclose(g_sh[i], g, rtol=1e-9)
            want[i] = np.hypot(*(kps[i] - g)) < maps.gamma[i]
    np.testing.assert_array_equal(flip_sh, want)
    assert 10 < want.sum() < (cand & ok).sum()  # both outcomes are exercised


def test_neighbour_p_g_with_the_shared_tree_equals_its_own():
    rng = np.random.default_rng(5)
    n = 300
    kps = rng.uniform(0, 150, (n, 2))
    z = 2.0 + rng.normal(0, 0.08, n)
    observed = rng.random(n) < 0.6
    p_g = np.where(observed, rng.random(n), np.nan)
    maps = DepthMaps(z, CFG)
    shared = MatchedPoints(kps, observed, np.ones(n, bool), maps.valid)
    own = neighbour_p_g(kps, maps, observed, p_g, CFG)
    np.testing.assert_array_equal(own, neighbour_p_g(kps, maps, observed, p_g, CFG, matched=shared))
    assert np.isfinite(own).sum() > 50


def test_oim_candidates_skip_neighbour_static_only_when_asked():
    belief = np.array([0.2, 0.2, 0.2, 0.2, 0.8])
    observed = np.array([False, False, False, True, False])
    geo_dynamic = np.zeros(5, bool)
    p_nb = np.array([0.3, 0.7, np.nan, np.nan, 0.1])  # static neighbours, dynamic ones, too few
    base = oim_candidates(belief, observed, geo_dynamic, CFG, p_nb)
    np.testing.assert_array_equal(base, [True, True, True, False, False])  # the default ignores p_nb
    skip = overridden(CFG, {"ours": {"oim_skip_neighbour_static": True}})
    strict = oim_candidates(belief, observed, geo_dynamic, skip, p_nb)
    np.testing.assert_array_equal(strict, [False, True, True, False, False])


def test_mask_median_equals_numpy_median():
    from d2slam.dynamics.interaction import _median

    rng = np.random.default_rng(1)
    for n in [1, 2, 3, 4, 7, 10, 501, 1000]:
        for vals in (rng.uniform(0.5, 4.5, n).astype(np.float32), rng.uniform(0.5, 4.5, n),
                     rng.integers(30000, 65535, n).astype(np.uint16)):  # a uint16 sum of two would overflow
            assert _median(vals) == float(np.median(vals))


def test_only_a_person_whose_keypoints_move_beyond_the_false_alarms_has_an_interaction_zone():
    """moving_masks (OursConfig.oim_moving_test): a one-sided binomial test of the failed geometric tests on a
    mask's matched keypoints against the thresholds' false-alarm rate (1 - noise_confidence)."""
    h, w = 60, 80
    masks = np.zeros((3, h, w), bool)
    masks[0, 5:25, 5:25] = True  # walking: 8 of 20 matched keypoints fail
    masks[1, 5:25, 40:60] = True  # seated: 1 of 20 fails, a false alarm
    masks[2, 40:50, 40:50] = True  # 3 matched keypoints: too few to tell still
    kps = np.concatenate([np.stack([np.arange(20) % 20 + 5, np.full(20, 10)], 1),
                          np.stack([np.arange(20) % 20 + 40, np.full(20, 10)], 1),
                          np.array([[42, 45], [44, 45], [46, 45]])]).astype(np.float64)
    observed = np.ones(len(kps), bool)
    dynamic = np.zeros(len(kps), bool)
    dynamic[:8] = True
    dynamic[20] = True
    fm = FrameMasks(masks, kps, (h, w))
    cfg = DynamicsConfig()
    assert moving_masks(fm, observed, dynamic, cfg).tolist() == [True, False, True]
    paper = overridden(cfg, {"ours": {"oim_moving_test": False}})
    assert moving_masks(fm, observed, dynamic, paper).tolist() == [True, True, True]
    unmatched = observed.copy()
    unmatched[:20] = False  # nothing observed on the walking person this frame: it cannot be told still
    assert moving_masks(fm, unmatched, dynamic, cfg).tolist() == [True, False, True]
