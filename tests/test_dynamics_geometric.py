"""Geometric module (eq 4-6): epipolar error of a known F, P_g, RANSAC on a synthetic two-view scene."""

import numpy as np
import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

from d2slam.config import DynamicsConfig
from d2slam.dynamics.depth import depth_sigma
from d2slam.dynamics.geometric import (PoseInputs, epipolar_error, fundamental_matrix, geometric_module,
                                       geometric_probability)
from d2slam.errors import D2SlamError
from d2slam.ranges import overridden

CFG = DynamicsConfig()
# Pure translation along x with K = I: F = [t]_x, epipolar lines are horizontal (y = v of the previous point).
F_X = np.array([[0.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])
K_TEST = np.array([[500.0, 0, 320], [0, 500.0, 240], [0, 0, 1]])


def _project(P, K=K_TEST):
    """Pixels of camera-frame points P (N, 3)."""
    y = P @ K.T
    return y[:, :2] / y[:, 2:]


def test_epipolar_error_of_a_known_F():
    q = np.array([[10.0, 20.0], [5.0, -3.0]])
    p = np.array([[50.0, 23.0], [0.0, -3.0]])  # 3 px off the line y = 20; on the line y = -3
    np.testing.assert_allclose(epipolar_error(F_X, p, q), [3.0, 0.0], atol=1e-12)
    # A general F: compare with the point-line distance computed by hand.
    F = np.array([[1e-6, -2e-5, 3e-3], [1e-5, 2e-6, -4e-3], [-2e-3, 5e-3, 1.0]])
    qh, ph = np.array([100.0, 200.0, 1.0]), np.array([110.0, 190.0, 1.0])
    line = F @ qh
    expected = abs(ph @ line) / np.hypot(line[0], line[1])
    assert epipolar_error(F, ph[None, :2], qh[None, :2])[0] == pytest.approx(expected)


def test_epipolar_error_degenerate_line_is_nan():
    F = np.diag([1.0, 1.0, 0.0])  # l = F q~ = (u, v, 0): zero at q = (0, 0)
    err = epipolar_error(F, np.array([[1.0, 1.0]]), np.array([[0.0, 0.0]]))
    assert np.isnan(err[0])


def test_geometric_probability_eq6_and_threshold():
    err = np.array([0.0, 0.5, 0.69, 0.71, 3.0, np.nan])
    p, dyn = geometric_probability(err, 0.7, sigma=1.0)
    np.testing.assert_allclose(p[:3], 1 - np.exp(-err[:3] ** 2 / 2))
    np.testing.assert_array_equal(p[3:5], 1.0)
    np.testing.assert_array_equal(dyn, [False, False, False, True, True, False])
    assert np.isnan(p[5])
    # depth-adaptive threshold per keypoint
    _, dyn = geometric_probability(np.array([0.6, 0.6]), np.array([0.5, 0.9]))
    np.testing.assert_array_equal(dyn, [True, False])
    # the measured reliability of an exceedance (config p_g_exceed, 0.7) replaces the paper's 1 above the threshold
    p7, dyn7 = geometric_probability(err, 0.7, 1.0, 0.7)
    np.testing.assert_array_equal(p7[3:5], 0.7)
    np.testing.assert_array_equal(p7[:3], p[:3])
    np.testing.assert_array_equal(dyn7, [False, False, False, True, True, False])


def test_one_exceedance_does_not_erase_a_static_history():
    """eq 8 with P_g = 0.7: a keypoint believed static (0.05) that exceeds alpha once stays static; with the
    paper's P_g = 1 the same observation makes it dynamic whatever its history. A new keypoint (prior 0.5) that
    exceeds is dynamic either way."""
    from d2slam.config import DynamicsConfig
    from d2slam.dynamics.fusion import bayes_update

    prior = np.array([0.05, 0.5])
    assert (bayes_update(prior, np.array([0.7, 0.7]), CFG) > 0.5).tolist() == [False, True]
    paper = overridden(DynamicsConfig(), {"ours": {"p_g_exceed": 1.0}})
    assert (bayes_update(prior, np.array([1.0, 1.0]), paper) > 0.5).tolist() == [True, True]
    assert CFG.ours.p_g_exceed == 0.7


def test_fewer_than_8_matches_gives_no_F():
    rng = np.random.default_rng(0)
    q = rng.uniform(0, 100, (7, 2))
    F, inl = fundamental_matrix(q, q + 1.0, CFG)
    assert F is None and inl.shape == (7,) and not inl.any()
    kps = rng.uniform(0, 100, (10, 2))
    res = geometric_module(kps, kps, np.column_stack([np.arange(7), np.arange(7)]), np.full(10, 0.5),
                           np.full(10, 0.7), CFG)
    assert res.F is None and not res.observed.any() and np.isnan(res.p_g).all() and not res.dynamic.any()


def test_no_F_gives_nan_pose_fields_when_the_pose_test_is_asked_for():
    rng = np.random.default_rng(0)
    kps = rng.uniform(0, 100, (10, 2))
    z = np.full(10, 2.0)
    few = np.column_stack([np.arange(7), np.arange(7)])
    for matches in (few, np.zeros((0, 2), int)):  # fewer than 8 matches, no match at all
        res = geometric_module(kps, kps, matches, np.full(10, 0.5), np.full(10, 0.7), CFG,
                               pose=PoseInputs(z, z, K_TEST))
        assert res.F is None and res.reproj_err.shape == res.depth_err.shape == res.pose_dynamic.shape == (10,)
        assert np.isnan(res.reproj_err).all() and np.isnan(res.depth_err).all() and not res.pose_dynamic.any()
    # not asked for (no K or no depths): the fields stay None
    # depths without intrinsics: no pose test
    res = geometric_module(kps, kps, few, np.full(10, 0.5), np.full(10, 0.7), CFG)
    assert res.reproj_err is None and res.pose_dynamic is None


def _two_view(rng, n_static=300, n_dyn=60, noise_px=0.2):
    """Camera moves sideways (horizontal epipolar lines); an object at 2 m moves up by 5 cm (about 13 px); keypoints
    carry Gaussian noise of ``noise_px`` in both views."""
    Xs = np.column_stack([rng.uniform(-2, 2, n_static), rng.uniform(-1.5, 1.5, n_static), rng.uniform(1.5, 5, n_static)])
    Xd = np.column_stack([rng.uniform(-0.3, 0.3, n_dyn), rng.uniform(-0.5, 0.5, n_dyn), rng.uniform(1.9, 2.1, n_dyn)])
    X = np.vstack([Xs, Xd])
    t = np.array([0.04, 0.0, 0.01])
    q = _project(X) + rng.normal(0, noise_px, (len(X), 2))
    X_now = X - t
    X_now[n_static:, 1] -= 0.05
    p = _project(X_now) + rng.normal(0, noise_px, (len(X), 2))
    truth = np.r_[np.zeros(n_static, bool), np.ones(n_dyn, bool)]
    perm = rng.permutation(len(X))  # previous keypoints in another order
    prev = np.empty_like(q)
    prev[perm] = q
    matches = np.column_stack([np.arange(len(X)), perm])
    return p, prev, matches, truth, X_now[:, 2]


def test_two_view_moving_object_high_P_g_static_low():
    rng = np.random.default_rng(1)
    p, prev, matches, truth, z = _two_view(rng)
    res = geometric_module(p, prev, matches, np.full(len(prev), 0.5), np.full(len(p), 0.7), CFG)
    assert res.F is not None and res.observed.all()
    assert res.dynamic[truth].mean() >= 0.95
    assert (res.p_g[truth] >= CFG.ours.p_g_exceed).mean() >= 0.95
    assert res.dynamic[~truth].mean() <= 0.10  # 0.2 px noise in both views, F from RANSAC
    assert np.median(res.p_g[~truth]) < 0.1


def test_noise_widening_keeps_the_static_false_alarms_low_whatever_the_noise():
    """The thresholds widen to the frame's static noise (ours, geometric.widening): a static match exceeds alpha with
    a small probability at any keypoint noise, where the paper's fixed alpha (0.7 px) flags most of them once the
    noise reaches it. An object moving 13 px across the lines stays dynamic while RANSAC still finds this short
    baseline's F (0.6 px); at 1.5 px eq 5 loses the object rather than flagging the static scene."""
    import dataclasses

    kappa = []
    for noise_px in (0.1, 0.6, 1.5):
        rng = np.random.default_rng(7)
        p, prev, matches, truth, z = _two_view(rng, noise_px=noise_px)
        b = np.full(len(prev), 0.5)
        res = geometric_module(p, prev, matches, b, np.full(len(p), 0.7), CFG)
        paper = geometric_module(p, prev, matches, b, np.full(len(p), 0.7),
                                 overridden(CFG, {"ours": {"noise_widening": False}}))
        assert paper.widening == (1.0, 1.0, 1.0)
        assert res.dynamic[~truth].mean() <= 0.12, noise_px
        if noise_px <= 0.6:
            assert res.dynamic[truth].mean() >= 0.95, noise_px
        np.testing.assert_array_equal(res.dynamic, res.err > 0.7 * res.widening[0])
        if noise_px >= 0.6:
            assert paper.dynamic[~truth].mean() >= 0.3
        kappa.append(res.widening[0])
    assert kappa[0] == 1.0 and kappa[0] < kappa[1] < kappa[2]


def test_noise_widening_needs_enough_static_residuals():
    from d2slam.dynamics.geometric import widening

    assert widening(np.full(CFG.f_min_static_matches - 1, 10.0), 0.7, 1, CFG) == 1.0
    assert widening(np.full(CFG.f_min_static_matches, 10.0), 0.7, 1, CFG) > 1.0
    assert widening(np.full(100, 10.0), 0.0, 2, CFG) == 1.0  # a test turned off stays off
    # the threshold is the chi quantile: residuals r ~ sigma |N(0, 1)| -> kappa 0.7 = 1.96 sigma
    r = np.abs(np.random.default_rng(0).normal(0, 2.0, 20000))
    assert widening(r, 0.7, 1, CFG) * 0.7 == pytest.approx(1.96 * 2.0, rel=0.03)


def test_eq6_sigma_at_the_detection_scale():
    """P_g below the threshold reads the error at the keypoint's scale, like alpha: P_g(err, s) = P_g(err / s, 1), so a
    match under its scaled threshold a s has P_g <= 1 - exp(-a^2 / 2 sigma^2) at every level (sigma_at_scale)."""
    import dataclasses

    rng = np.random.default_rng(1)
    p, prev, matches, truth, z = _two_view(rng)
    n = len(p)
    scale = 1.2 ** rng.integers(0, 8, n).astype(float)
    a = np.full(n, 0.9)
    b = np.full(len(prev), 0.5)
    res = geometric_module(p, prev, matches, b, a * scale, CFG, scale=scale)
    below = res.observed & ~res.dynamic
    assert below.sum() > 200
    np.testing.assert_allclose(res.p_g[below], -np.expm1(-(res.err[below] / scale[below]) ** 2 / (2 * CFG.sigma ** 2)))
    assert res.p_g[below].max() <= -np.expm1(-0.9 ** 2 / (2 * CFG.sigma ** 2)) + 1e-12  # 0.333 < 0.5
    assert (res.p_g[res.dynamic] == CFG.ours.p_g_exceed).all()
    # the paper's unscaled sigma: the same errors, larger P_g at coarse levels (where a 1.5 px error passes)
    paper = geometric_module(p, prev, matches, b, a * scale, overridden(CFG, {"ours": {"sigma_at_scale": False}}),
                             scale=scale)
    np.testing.assert_array_equal(paper.dynamic, res.dynamic)
    np.testing.assert_allclose(paper.p_g[below], -np.expm1(-res.err[below] ** 2 / (2 * CFG.sigma ** 2)))
    coarse = below & (scale > 1)
    assert (paper.p_g[coarse] >= res.p_g[coarse]).all() and (paper.p_g[coarse] > res.p_g[coarse]).any()


def test_static_believed_matches_first_and_determinism():
    rng = np.random.default_rng(2)
    p, prev, matches, truth, z = _two_view(rng)
    belief = np.full(len(prev), 0.2)
    belief[matches[truth, 1]] = 0.9  # the object is believed dynamic
    a = np.full(len(p), 0.7)
    r1 = geometric_module(p, prev, matches, belief, a, CFG)
    r2 = geometric_module(p, prev, matches, belief, a, CFG)
    assert r1.used_static and r1.n_used == (~truth).sum()
    np.testing.assert_array_equal(r1.F, r2.F)
    np.testing.assert_array_equal(r1.p_g, r2.p_g)
    # Too few static-believed matches: all matches are used.
    belief[:] = 0.9
    r3 = geometric_module(p, prev, matches, belief, a, CFG)
    assert not r3.used_static and r3.n_used == len(matches)


def test_bad_match_indices_raise_clear_error():
    kps = np.zeros((5, 2))
    with pytest.raises(D2SlamError, match="out of range"):
        geometric_module(kps, kps, np.array([[0, 7]]), np.full(5, 0.5), 0.7, CFG)
    with pytest.raises(D2SlamError):
        geometric_module(kps, kps, np.array([0, 1, 2]), np.full(5, 0.5), 0.7, CFG)


@pytest.mark.parametrize("method", ["magsac", "usac_accurate"])
def test_usac_flavours_separate_moving_from_static(method):
    import dataclasses

    cfg = dataclasses.replace(CFG, f_ransac_method=method)
    rng = np.random.default_rng(1)
    p, prev, matches, truth, z = _two_view(rng)
    res = geometric_module(p, prev, matches, np.full(len(prev), 0.5), np.full(len(p), 0.7), cfg)
    assert res.F is not None
    assert res.dynamic[truth].mean() >= 0.95 and res.dynamic[~truth].mean() <= 0.10
    again = geometric_module(p, prev, matches, np.full(len(prev), 0.5), np.full(len(p), 0.7), cfg)
    np.testing.assert_array_equal(res.err, again.err)  # seeded: deterministic


def test_unknown_ransac_flavour_is_a_clear_error():
    import dataclasses

    rng = np.random.default_rng(1)
    p, prev, matches, truth, z = _two_view(rng)
    with pytest.raises(D2SlamError, match="f_ransac_method"):
        fundamental_matrix(prev, p, dataclasses.replace(CFG, f_ransac_method="lmeds?"))


# ----------------------------------------------------------------------------------------- pose test (ours, RGB-D)


def _two_view_rgbd(rng, n_static=300, n_obj=40):
    """Camera moves sideways by 4 cm (horizontal epipolar lines). Object A (2 m) slides 10 cm sideways, along its
    epipolar lines (about 25 px); object B (2 m) moves 15 cm away along its viewing rays (same pixels). Eq 5 sees
    little of either; the reprojection error sees A, the depth residual sees B. Depth noise: 0.5 sigma(z) of the
    config."""
    Xs = np.column_stack([rng.uniform(-2, 2, n_static), rng.uniform(-1.5, 1.5, n_static),
                          rng.uniform(1.5, 5, n_static)])
    Xa = np.column_stack([rng.uniform(-0.4, 0.0, n_obj), rng.uniform(-0.5, 0.5, n_obj), rng.uniform(1.9, 2.1, n_obj)])
    Xb = np.column_stack([rng.uniform(0.1, 0.5, n_obj), rng.uniform(-0.5, 0.5, n_obj), rng.uniform(1.9, 2.1, n_obj)])
    X = np.vstack([Xs, Xa, Xb])
    label = np.r_[np.zeros(n_static, int), np.ones(n_obj, int), np.full(n_obj, 2)]
    X_now = X - np.array([0.04, 0.0, 0.0])
    X_now[label == 1, 0] += 0.10
    X_now[label == 2] *= (1.0 + 0.15 / X_now[label == 2, 2])[:, None]

    def noisy_depth(z):
        return z + 0.5 * depth_sigma(z) * rng.normal(size=len(z))

    q, p = _project(X) + rng.normal(0, 0.2, (len(X), 2)), _project(X_now) + rng.normal(0, 0.2, (len(X), 2))
    perm = rng.permutation(len(X))
    prev, z_prev = np.empty_like(q), np.empty(len(X))
    prev[perm], z_prev[perm] = q, noisy_depth(X[:, 2])
    matches = np.column_stack([np.arange(len(X)), perm])
    return p, prev, matches, noisy_depth(X_now[:, 2]), z_prev, label


def test_pose_test_sees_motion_along_the_epipolar_line_and_along_the_ray():
    import dataclasses

    rng = np.random.default_rng(5)
    p, prev, matches, z, z_prev, label = _two_view_rgbd(rng)
    a = np.full(len(p), 0.7)
    b = np.full(len(prev), 0.5)
    eq5 = geometric_module(p, prev, matches, b, a, CFG)  # no depths given: eq 5 alone
    res = geometric_module(p, prev, matches, b, a, CFG, pose=PoseInputs(z, z_prev, K_TEST))
    # eq 5 barely sees either object: A slides 25 px along its lines, B stays on its pixels
    assert eq5.pose_dynamic is None
    assert np.median(eq5.err[label == 1]) < 2.0 and np.median(eq5.err[label == 2]) < 0.7
    np.testing.assert_array_equal(res.err, eq5.err)  # the pose test adds to eq 5, it does not change it
    assert res.pose_dynamic[label == 1].mean() >= 0.95 and res.pose_dynamic[label == 2].mean() >= 0.95
    assert np.median(res.reproj_err[label == 1]) > 20 and np.median(res.reproj_err[label == 2]) < 1.0
    assert np.median(np.abs(res.depth_err[label == 2])) > 10
    assert res.pose_dynamic[label == 0].mean() <= 0.03 and np.median(res.reproj_err[label == 0]) < 0.5
    assert (res.p_g[res.pose_dynamic] >= CFG.pose_test.p_pose_exceed).all() and np.array_equal(
        res.dynamic, eq5.dynamic | res.pose_dynamic)
    # each half of the test alone
    only_reproj = geometric_module(p, prev, matches, b, a, overridden(CFG, {"pose_test": {"pose_depth_sigmas": 0.0}}),
                                   pose=PoseInputs(z, z_prev, K_TEST))
    only_depth = geometric_module(p, prev, matches, b, a, overridden(CFG, {"pose_test": {"pose_reproj_px": 0.0}}),
                                  pose=PoseInputs(z, z_prev, K_TEST))
    assert only_reproj.pose_dynamic[label == 1].mean() >= 0.95 and only_reproj.pose_dynamic[label == 2].mean() <= 0.1
    assert only_depth.pose_dynamic[label == 2].mean() >= 0.95
    # the reprojection threshold is at each keypoint's detection scale: x 8 (32 px) lets object A's 25 px pass
    coarse = geometric_module(p, prev, matches, b, a, overridden(CFG, {"pose_test": {"pose_depth_sigmas": 0.0}}),
                              pose=PoseInputs(z, z_prev, K_TEST), scale=np.full(len(p), 8.0))
    assert coarse.pose_dynamic[label == 1].mean() <= 0.05
    # off in the config: eq 5 alone again
    off = geometric_module(p, prev, matches, b, a, overridden(CFG, {"pose_test": {"enabled": False}}),
                           pose=PoseInputs(z, z_prev, K_TEST))
    assert off.pose_dynamic is None and np.array_equal(off.dynamic, eq5.dynamic)


def test_relative_pose_recovers_the_motion_despite_outliers_and_is_deterministic():
    import cv2

    from d2slam.dynamics.geometric import back_project, relative_pose

    rng = np.random.default_rng(3)
    X = np.column_stack([rng.uniform(-2, 2, 200), rng.uniform(-1.5, 1.5, 200), rng.uniform(1.5, 5, 200)])
    R, _ = cv2.Rodrigues(np.array([0.02, -0.01, 0.03]))
    t = np.array([0.03, -0.01, 0.02])
    Xc = X @ R.T + t
    p = _project(Xc) + rng.normal(0, 0.2, (200, 2))
    p[:40] += rng.uniform(10, 40, (40, 2))  # 20 % outliers
    pose = relative_pose(X, p, K_TEST, CFG)
    assert pose is not None
    np.testing.assert_allclose(pose[0], R, atol=2e-3)
    np.testing.assert_allclose(pose[1], t, atol=5e-3)
    again = relative_pose(X, p, K_TEST, CFG)
    np.testing.assert_array_equal(pose[0], again[0])
    np.testing.assert_array_equal(pose[1], again[1])
    # non-finite rows are dropped; fewer than pnp_min_matches usable points: no pose
    Xn = X.copy()
    Xn[: 200 - CFG.pose_test.pnp_min_matches + 1] = np.nan
    assert relative_pose(Xn, p, K_TEST, CFG) is None
    assert relative_pose(X[:5], p[:5], K_TEST, CFG) is None
    np.testing.assert_allclose(back_project(p[:1], np.array([2.0]), K_TEST)[0, 2], 2.0)


def test_pose_test_without_usable_depth_leaves_eq5_alone_and_checks_sizes():
    rng = np.random.default_rng(5)
    p, prev, matches, z, z_prev, label = _two_view_rgbd(rng)
    a, b = np.full(len(p), 0.7), np.full(len(prev), 0.5)
    eq5 = geometric_module(p, prev, matches, b, a, CFG)
    bad = np.where(np.arange(len(z_prev)) % 2 == 0, 0.0, np.nan)  # every previous depth invalid (0 or NaN)
    res = geometric_module(p, prev, matches, b, a, CFG, pose=PoseInputs(z, bad, K_TEST))
    assert np.isnan(res.reproj_err).all() and np.isnan(res.depth_err).all() and not res.pose_dynamic.any()
    np.testing.assert_array_equal(res.dynamic, eq5.dynamic)
    np.testing.assert_array_equal(res.p_g, eq5.p_g)
    # invalid current depths: the reprojection half still runs, the depth half is NaN there
    z_bad = z.copy()
    z_bad[label == 2] = np.inf
    res = geometric_module(p, prev, matches, b, a, CFG, pose=PoseInputs(z_bad, z_prev, K_TEST))
    assert np.isnan(res.depth_err[label == 2]).all() and res.pose_dynamic[label == 1].mean() >= 0.95
    with pytest.raises(D2SlamError, match="keypoint depths"):
        geometric_module(p, prev, matches, b, a, CFG, pose=PoseInputs(z[:-1], z_prev, K_TEST))


@settings(max_examples=80, deadline=None, derandomize=True)
@given(seed=st.integers(0, 2**31 - 1), n=st.sampled_from([200, 40, 13, 12, 11, 5, 0]),
       outliers=st.sampled_from([0.2, 0.0, 0.6, 1.0]), bad_depth=st.sampled_from([0.1, 0.0, 0.5, 0.95, 1.0]),
       identity_k=st.booleans())
def test_property_pose_test_never_raises_and_stays_in_range(seed, n, outliers, bad_depth, identity_k):
    """Random rigid motions, outlier matches and corrupted depths (0, NaN, +-inf, negative) in both frames: the
    geometric module never raises, P_g stays in [0, 1] (NaN where unobserved), the pose test flags only observed
    keypoints (the clean cases are the tests above)."""
    import cv2

    rng = np.random.default_rng(seed)
    K = np.eye(3) if identity_k else K_TEST
    X = np.column_stack([rng.uniform(-2, 2, n), rng.uniform(-1.5, 1.5, n), rng.uniform(0.5, 5, n)])
    R, _ = cv2.Rodrigues(rng.normal(0, 0.02, 3))
    Xc = X @ R.T + rng.normal(0, 0.03, 3)
    q, p = _project(X, K), _project(Xc, K) + rng.normal(0, 0.2 if not identity_k else 1e-4, (n, 2))
    out = rng.random(n) < outliers
    p[out] = rng.uniform(0, 640, (int(out.sum()), 2))
    bad = np.array([0.0, np.nan, np.inf, -np.inf, -1.0])

    def corrupt(z):
        z = z.copy()
        hit = rng.random(n) < bad_depth
        z[hit] = rng.choice(bad, int(hit.sum()))
        return z

    z_prev, z = corrupt(X[:, 2]), corrupt(Xc[:, 2])
    matches = np.column_stack([np.arange(n), np.arange(n)]).astype(np.int64).reshape(-1, 2)
    res = geometric_module(p, q, matches, np.full(n, 0.2), np.full(n, 0.7), CFG, pose=PoseInputs(z, z_prev, K))
    finite = np.isfinite(res.p_g)
    assert ((res.p_g[finite] >= 0) & (res.p_g[finite] <= 1)).all()
    assert not (res.dynamic & ~res.observed).any()
    event(f"pose found: {res.reproj_err is not None and bool(np.isfinite(res.reproj_err).any())}")
    if res.pose_dynamic is not None:
        assert res.pose_dynamic.shape == (n,) and not (res.pose_dynamic & ~res.observed).any()
        assert (res.p_g[res.pose_dynamic] >= CFG.pose_test.p_pose_exceed).all()
        r = res.reproj_err[np.isfinite(res.reproj_err)]
        assert (r >= 0).all()


@pytest.mark.parametrize("seed", range(3))
def test_pose_test_on_an_executor_gives_the_same_result(seed):
    """The PnP-RANSAC run on an executor while F is fitted gives what it gives after F on the calling thread, with an
    F and without one (too few matches)."""
    from concurrent.futures import ThreadPoolExecutor

    rng = np.random.default_rng(seed)
    p, prev, matches, z, z_prev, label = _two_view_rgbd(rng)
    a, b = np.full(len(p), 0.7), np.full(len(prev), 0.5)
    with ThreadPoolExecutor(max_workers=1) as pool:
        for m in (matches, matches[:6]):
            ref = geometric_module(p, prev, m, b, a, CFG, seed=seed, pose=PoseInputs(z, z_prev, K_TEST))
            got = geometric_module(p, prev, m, b, a, CFG, seed=seed, pose=PoseInputs(z, z_prev, K_TEST),
                                   executor=pool)
            assert (ref.F is None) == (got.F is None) == (len(m) == 6)
            for name in ("err", "p_g", "observed", "dynamic", "reproj_err", "depth_err", "pose_dynamic"):
                np.testing.assert_array_equal(getattr(got, name), getattr(ref, name), err_msg=name)
            assert got.widening == ref.widening
