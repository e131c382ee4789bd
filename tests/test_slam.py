"""Engine components on small fixtures: ORB bucketing, matching, g2o optimisation, tracking on an analytic room,
determinism, the filter hook and bad input."""

import dataclasses

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from d2slam.config import DEFAULT, EngineConfig
from d2slam.errors import D2SlamError
from d2slam.ranges import overridden
from d2slam.slam.engine import Engine
from d2slam.slam.fixture import FR3, room_sequence
from d2slam.slam.frame import OrbExtractor, bucket_select, level_quotas
from d2slam.slam.matching import hamming, rotation_consistent, unique_by_target
from d2slam.slam.optimizer import local_bundle_adjustment, pose_optimization, reprojection_chi2

K = FR3.K
BF = 40.0


@pytest.fixture(scope="module")
def room():
    return room_sequence(24, seed=3)


def _run(frames, ts, kfilter=None, masks=None):
    eng = Engine(FR3, DEFAULT, kfilter)
    res = [eng.process(g, d, i, ts[i], masks=masks) for i, (g, d) in enumerate(frames)]
    return eng, res


def _rel(poses):
    return np.einsum("ij,njk->nik", np.linalg.inv(poses[0]), poses)


# ------------------------------------------------------------------ features
def test_level_quotas_follow_orbslam():
    q = level_quotas(DEFAULT.orb)
    assert q.sum() == 1000 and len(q) == 8
    assert np.all(np.diff(q) < 0)
    assert abs(q[0] / q[1] - 1.2) < 0.05


def test_bucketing_spreads_features_over_cells():
    rng = np.random.default_rng(0)
    # 5000 corners crowded in the left quarter with high response, 500 spread elsewhere with low response.
    crowd = np.c_[rng.uniform(0, 160, 5000), rng.uniform(0, 480, 5000)]
    spread = np.c_[rng.uniform(160, 640, 500), rng.uniform(0, 480, 500)]
    pts = np.r_[crowd, spread]
    resp = np.r_[rng.uniform(10, 20, 5000), rng.uniform(0, 1, 500)]
    level = np.zeros(len(pts), dtype=np.int64)
    cfg = DEFAULT.orb
    keep = bucket_select(pts, level, resp, cfg, 640, 480)
    assert len(keep) == level_quotas(cfg)[0]
    # Pure top-response selection would take only crowded corners; bucketing takes the spread ones too.
    assert (keep >= 5000).sum() > 100
    assert len(np.unique(keep)) == len(keep)


def test_extractor_settings_depth_and_virtual_right(room):
    frames, _, _ = room
    gray, depth = frames[0]
    ex = OrbExtractor(DEFAULT.orb, DEFAULT.engine, FR3)
    f = ex(gray, depth)
    assert 900 <= f.n <= 1000 and f.desc.shape == (f.n, 32)
    assert f.octave.max() == 7
    # features cover the image: every 160x120 block has some
    bx = (f.kps[:, 0] // 160).astype(int) * 4 + (f.kps[:, 1] // 120).astype(int)
    assert len(np.unique(bx)) == 16
    u, v = np.rint(f.kps_raw).astype(int).T
    np.testing.assert_allclose(f.depth, depth[v, u], atol=0.02)
    valid = f.depth > 0  # ORB-SLAM: u_R for every keypoint with depth
    np.testing.assert_allclose(f.ur[valid], f.kps[valid, 0] - BF / f.depth[valid])
    assert np.all(f.ur[~valid] == -1)
    from dataclasses import replace

    ex_close = OrbExtractor(DEFAULT.orb, replace(DEFAULT.engine, stereo_far_points=False), FR3)
    depth2 = depth.copy()
    depth2[:, :320] = 1.5  # left half close (< 3 m), right half far (4 m)
    depth2[:, 320:] = 4.0
    f2 = ex_close(gray, depth2)
    close = (f2.depth > 0) & (f2.depth < 40 * BF / FR3.fx)
    assert close.any() and (~close).any()
    np.testing.assert_allclose(f2.ur[close], f2.kps[close, 0] - BF / f2.depth[close])
    assert np.all(f2.ur[~close] == -1)


def test_keypoint_depth_ignores_invalid_pixels():
    from d2slam.slam.depth import keypoint_depth

    d = np.zeros((20, 20), np.float32)
    d[10, 10], d[10, 11], d[11, 10] = 2.0, 2.2, 2.1
    z = keypoint_depth(d, np.array([[10.0, 10.0], [3.0, 3.0]]), 1)
    assert z[0] == pytest.approx(2.1) and z[1] == 0




def _bucket_reference(pts, level, response, orb, width, height, n_features=None):
    """``bucket_select`` with numpy: two lexsorts (cell, -response) then (level, rank, -response), quotas per level."""
    quotas = level_quotas(orb, n_features)
    cell = orb.cell_size * orb.scale_factor ** level.astype(np.float64)
    ncols = np.ceil(width / cell).astype(np.int64)
    cx = np.minimum((pts[:, 0] / cell).astype(np.int64), ncols - 1)
    cell_id = (level.astype(np.int64) << 32) | ((pts[:, 1] / cell).astype(np.int64) * ncols + cx)
    order = np.lexsort((-response, cell_id))
    start = np.r_[0, np.flatnonzero(np.diff(cell_id[order])) + 1]
    rank = np.arange(len(order)) - np.repeat(start, np.diff(np.r_[start, len(order)]))
    lv = level[order]
    key = np.lexsort((-response[order], rank, lv))
    pos = np.arange(len(key)) - np.searchsorted(lv[key], np.arange(orb.n_levels))[lv[key]]
    return np.sort(order[key[pos < quotas[lv[key]]]])


@pytest.mark.parametrize("seed", range(4))
def test_bucket_select_kernel_equals_numpy(seed):
    """The compiled round robin keeps the corners the numpy lexsorts keep: equal responses, corners sharing cells,
    quotas above and below the corners available."""
    rng = np.random.default_rng(seed)
    for trial in range(200):
        n, budget = int(rng.integers(1, 500)), int(rng.integers(1, 400))
        pts = rng.uniform(0, [640, 480], (n, 2))
        if trial % 2:
            pts = np.round(pts / 40) * 40
        level = rng.integers(0, DEFAULT.orb.n_levels, n)
        response = rng.integers(0, 5, n).astype(np.float64) if trial % 3 else rng.random(n)
        np.testing.assert_array_equal(bucket_select(pts, level, response, DEFAULT.orb, 640, 480, budget),
                                      _bucket_reference(pts, level, response, DEFAULT.orb, 640, 480, budget))
    with pytest.raises(ValueError, match="levels"):
        bucket_select(np.zeros((2, 2)), np.array([0, DEFAULT.orb.n_levels]), np.ones(2), DEFAULT.orb, 640, 480)

def _patch_reference(depth, kps, radius):
    """(median, range) of each keypoint's patch with numpy: the (N, P) patches gathered at once, invalid pixels sorted
    to the end as +inf."""
    r = int(radius)
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    h, w = depth.shape
    finite = np.all(np.isfinite(kps), axis=1)
    c = np.where(finite[:, None], np.rint(kps), -10 * (r + 1)).astype(np.int64)
    du, dv = np.meshgrid(np.arange(-r, r + 1), np.arange(-r, r + 1))
    u, v = c[:, 0:1] + du.ravel()[None, :], c[:, 1:2] + dv.ravel()[None, :]
    vals = depth[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)].astype(np.float64)
    with np.errstate(invalid="ignore"):
        ok = (u >= 0) & (u < w) & (v >= 0) & (v < h) & np.isfinite(vals) & (vals > 0)
    srt = np.sort(np.where(ok, vals, np.inf), axis=1)
    cnt, rows = ok.sum(axis=1), np.arange(len(kps))
    med = 0.5 * (srt[rows, np.maximum((cnt - 1) // 2, 0)] + srt[rows, np.minimum(cnt // 2, srt.shape[1] - 1)])
    spread = np.where(ok, vals, -np.inf).max(axis=1) - np.where(ok, vals, np.inf).min(axis=1)
    return np.where(cnt > 0, med, 0.0).astype(np.float32), np.where(cnt >= 2, spread, np.nan)


@pytest.mark.parametrize("seed", range(6))
def test_keypoint_depth_kernel_equals_numpy(seed):
    """The compiled patch statistics give the numpy median and range bit for bit: invalid and non-finite depths, ties,
    keypoints off the image or non-finite, rounding halfway, float32 and float64 depth images, radii 0-2."""
    from d2slam.slam.depth import keypoint_depth, keypoint_depth_range

    rng = np.random.default_rng(seed)
    h, w = rng.integers(1, 40, 2)
    depth = rng.uniform(0.3, 5.0, (h, w)).astype(np.float32 if seed % 2 else np.float64)
    depth[rng.random(depth.shape) < rng.uniform(0, 0.9)] = 0.0
    for bad in (np.nan, np.inf, -1.0):
        depth[rng.random(depth.shape) < 0.05] = bad
    if seed % 3 == 0:
        depth = np.round(depth, 1)
    kps = np.column_stack([rng.uniform(-5, w + 5, 200), rng.uniform(-5, h + 5, 200)])
    kps[rng.random(200) < 0.05, 0] = np.nan
    kps[:20] = np.floor(kps[:20]) + 0.5
    for r in (0, 1, 2):
        med, spread = _patch_reference(depth, kps, r)
        assert keypoint_depth(depth, kps, r).tobytes() == med.tobytes()
        np.testing.assert_array_equal(keypoint_depth_range(depth, kps, r), spread)


def test_keypoint_fields_are_the_keypoints_attributes():
    from d2slam.slam.frame import keypoint_fields

    img = (np.random.default_rng(0).random((120, 160)) * 255).astype(np.uint8)
    kps = cv2.ORB_create(300).detect(img, None)
    pts, response, octave, angle = keypoint_fields(kps, "response", "octave", "angle")
    assert pts.dtype == response.dtype == np.float64 and len(kps) > 50
    np.testing.assert_array_equal(pts, [k.pt for k in kps])
    np.testing.assert_array_equal(response, [k.response for k in kps])
    np.testing.assert_array_equal(octave, [k.octave for k in kps])
    np.testing.assert_array_equal(angle, [k.angle for k in kps])
    assert keypoint_fields([], "octave")[0].shape == (0, 2)

def test_undistort_applied_with_distortion():
    from dataclasses import replace

    from d2slam.slam.frame import undistort

    cam = replace(FR3, dist=(0.2, -0.1, 0.0, 0.0, 0.0))
    pts = np.array([[50.0, 40.0], [320.1, 247.6]])
    out = undistort(pts, cam)
    assert np.allclose(out[1], pts[1], atol=1e-6) and np.linalg.norm(out[0] - pts[0]) > 1
    np.testing.assert_array_equal(undistort(pts, FR3), pts)



def test_image_bounds_are_the_undistorted_corners():
    """ORB-SLAM3 Frame::ComputeImageBounds: projections are kept within the box of the undistorted image corners
    (the freiburg1 lens), the image itself without distortion."""
    from d2slam.data.intrinsics import FREIBURG1
    from d2slam.slam.frame import undistort
    from d2slam.slam.projection import Projector, image_bounds

    assert image_bounds(FR3) == (0.0, 640.0, 0.0, 480.0)
    corners = undistort(np.array([[0.0, 0.0], [640.0, 0.0], [0.0, 480.0], [640.0, 480.0]]), FREIBURG1)
    x0, x1, y0, y1 = image_bounds(FREIBURG1)
    assert (x0, x1, y0, y1) == (corners[[0, 2], 0].min(), corners[[1, 3], 0].max(), corners[[0, 1], 1].min(),
                                corners[[2, 3], 1].max())
    assert 5 < x0 < 20 and 620 < x1 < 635 and 5 < y0 < 20 and 465 < y1 < 478  # fr1's barrel: inside the image
    proj = Projector(FREIBURG1, DEFAULT)
    assert proj.in_image(np.array([x0, x0 - 0.1, x1, 320.0]), np.array([240.0, 240.0, y1, y0])).tolist() == \
        [True, False, True, True]

# ------------------------------------------------------------------ matching
def test_hamming_matches_opencv():
    rng = np.random.default_rng(1)
    a = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    ref = [cv2.norm(a[i], b[i], cv2.NORM_HAMMING) for i in range(50)]
    np.testing.assert_array_equal(hamming(a, b), ref)


def test_rotation_consistency_and_uniqueness():
    rng = np.random.default_rng(2)
    a = rng.uniform(0, 360, 100)
    b = np.mod(a - 30 + rng.normal(0, 1, 100), 360)  # consistent rotation of 30 deg
    b[:10] = rng.uniform(0, 360, 10)  # inconsistent
    ok = rotation_consistent(a, b, 30)
    assert ok[10:].mean() > 0.95 and ok[:10].mean() < 0.6
    keep = unique_by_target(np.arange(4), np.array([5, 5, 6, 5]), np.array([3.0, 1.0, 2.0, 4.0]))
    np.testing.assert_array_equal(keep, [False, True, True, False])


# ------------------------------------------------------------------ optimisation
def _points_problem(rng, n=300, noise=0.5):
    X = rng.uniform([-2, -1.5, 1], [2, 1.5, 5], (n, 3))
    T = np.eye(4)
    T[:3, :3] = Rotation.from_rotvec([0.03, -0.02, 0.04]).as_matrix()
    T[:3, 3] = [0.08, -0.03, 0.1]
    Xc = X @ T[:3, :3].T + T[:3, 3]
    uv = np.c_[K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2], K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]]
    uv += rng.normal(0, noise, uv.shape)
    ur = np.where(Xc[:, 2] < 3, uv[:, 0] - BF / Xc[:, 2], -1.0)
    return X, T, uv, ur


def test_pose_optimization_recovers_pose_and_flags_outliers():
    rng = np.random.default_rng(3)
    X, T, uv, ur = _points_problem(rng)
    uv[:30] += rng.choice([-1, 1], (30, 2)) * rng.uniform(20, 60, (30, 2))  # gross outliers
    T_est, inl = pose_optimization(np.eye(4), X, uv, ur, np.ones(len(X)), K, BF, EngineConfig())
    assert np.abs(T_est[:3, 3] - T[:3, 3]).max() < 5e-3
    assert inl[:30].sum() == 0 and inl[30:].mean() > 0.9



def test_motion_only_ba_weighs_depth_as_orbslam3():
    """Motion-only BA uses ORB-SLAM3's information in every round (pose_opt_coarse_rounds = pose_opt_rounds): the same
    pose and inliers as with disparity_sigma_px 0, so disparities 1-2 px off the map (a real Kinect's depth image
    taken while the camera turned) keep their matches; the disparity model in its last rounds (1) loses them."""
    rng = np.random.default_rng(7)
    X, T, uv, ur = _points_problem(rng, noise=0.3)
    stereo = ur >= 0
    ur[stereo] += rng.choice([-1, 1], stereo.sum()) * rng.uniform(1, 2, stereo.sum())
    cfg = EngineConfig()
    assert cfg.tracking.pose_opt_coarse_rounds == cfg.tracking.pose_opt_rounds
    T0 = T.copy()
    T0[:3, 3] += [0.02, -0.01, 0.03]
    T_est, inl = pose_optimization(T0, X, uv, ur, np.ones(len(X)), K, BF, cfg)
    T_orb, inl_orb = pose_optimization(T0, X, uv, ur, np.ones(len(X)), K, BF,
                                       dataclasses.replace(cfg, disparity_sigma_px=0.0))
    np.testing.assert_array_equal(T_est, T_orb)
    np.testing.assert_array_equal(inl, inl_orb)
    assert inl.mean() > 0.9 and np.abs(T_est[:3, 3] - T[:3, 3]).max() < 0.01
    _, inl_fine = pose_optimization(T0, X, uv, ur, np.ones(len(X)), K, BF,
                                    overridden(cfg, {"tracking": {"pose_opt_coarse_rounds": 1}}))
    assert inl_fine[stereo].mean() < 0.1

@pytest.mark.parametrize("sigma_d", [0.0, 0.057])
def test_local_ba_reduces_error_and_keeps_fixed_poses(sigma_d):
    """ORB-SLAM's information (sigma_d 0: u_R a stereo match, its own noise) and the RGB-D disparity model (u_R
    computed from the noisy u and a depth with 0.2 % noise): poses recovered, chi2 down, fixed pose kept."""
    rng = np.random.default_rng(4)
    cfg = dataclasses.replace(EngineConfig(), disparity_sigma_px=sigma_d)
    X = rng.uniform([-2, -1.5, 2], [2, 1.5, 5], (200, 3))
    poses = np.tile(np.eye(4), (4, 1, 1))
    poses[:, 0, 3] = np.arange(4) * -0.1  # Tcw translations
    cams, pts, uv, ur = [], [], [], []
    for c in range(4):
        Xc = X @ poses[c, :3, :3].T + poses[c, :3, 3]
        u = K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2]
        v = K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]
        obs = np.c_[u, v] + rng.normal(0, 0.3, (len(X), 2))
        if sigma_d > 0:
            z = Xc[:, 2] * (1 + rng.normal(0, 0.002, len(X)))
            r = obs[:, 0] - BF / z
        else:
            r = u - BF / Xc[:, 2]
        cams.append(np.full(len(X), c)), pts.append(np.arange(len(X)))
        uv.append(obs), ur.append(np.where(Xc[:, 2] < 3, r, -1))
    cams, pts, uv, ur = map(np.concatenate, (cams, pts, uv, ur))
    start = poses.copy()
    start[1:, :3, 3] += rng.normal(0, 0.02, (3, 3))
    X0 = X + rng.normal(0, 0.02, X.shape)
    fixed = np.array([True, False, False, False])
    P, Xo, outl = local_bundle_adjustment(start, fixed, X0, cams, pts, uv, ur, np.ones(len(cams)), K, BF, cfg)
    np.testing.assert_array_equal(P[0], start[0])
    assert np.abs(P[1:, :3, 3] - poses[1:, :3, 3]).max() < 5e-3

    def chi2(T, Xs):
        return sum(reprojection_chi2(T[c], Xs[pts[cams == c]], uv[cams == c], ur[cams == c],
                                     np.ones((cams == c).sum()), K, BF, sigma_d)[0].sum() for c in range(4))

    assert chi2(P, Xo) < 0.05 * chi2(start, X0)
    assert outl.mean() < 0.05


@pytest.mark.parametrize("sigma_d", [0.0, 0.057])
def test_compiled_lm_matches_g2o(sigma_d):
    """The compiled Levenberg-Marquardt (``optimizer = "lm"``) and g2o solve the same problems to the same poses,
    points and outliers: motion-only BA with gross outliers (its rounds, Huber, coarse information, then the
    disparity model) and a local BA with fixed keyframes."""
    from d2slam.bench.engine import local_ba_problem

    rng = np.random.default_rng(5)
    X, T, uv, ur = _points_problem(rng)
    uv[:30] += rng.choice([-1, 1], (30, 2)) * rng.uniform(20, 60, (30, 2))
    s2 = rng.choice([1.0, 1 / 1.44, 1 / 2.07], len(X))
    T0 = T.copy()
    T0[:3, 3] += [0.03, -0.02, 0.05]
    out = {}
    p = local_ba_problem(seed=1, n_cams=6, n_points=300)
    for name in ("lm", "g2o"):
        cfg = overridden(EngineConfig(), {"optimizer": name, "disparity_sigma_px": sigma_d,
                                          "tracking": {"pose_opt_coarse_rounds": 1}})
        pose = pose_optimization(T0, X, uv, ur, s2, K, BF, cfg)
        ba = local_bundle_adjustment(p["start"], p["fixed"], p["X0"], p["cams"], p["pts"], p["uv"], p["ur"],
                                     np.ones(len(p["cams"])), p["K"], p["bf"], cfg)
        out[name] = pose, ba
    (T_lm, inl_lm), (P_lm, X_lm, o_lm) = out["lm"]
    (T_g, inl_g), (P_g, X_g, o_g) = out["g2o"]
    np.testing.assert_allclose(T_lm, T_g, atol=1e-7)
    np.testing.assert_array_equal(inl_lm, inl_g)
    np.testing.assert_allclose(P_lm, P_g, atol=1e-7)
    np.testing.assert_allclose(X_lm, X_g, atol=1e-6)
    np.testing.assert_array_equal(o_lm, o_g)
    assert inl_lm[:30].sum() == 0 and np.abs(P_lm[2:, :3, 3] - p["Tcw"][2:, :3, 3]).max() < 0.02
    for R in [T_lm[:3, :3]] + [P[:3, :3] for P in P_lm]:  # rotations stay on SO(3), as g2o's unit quaternions
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)


def test_stereo_information_is_position_plus_disparity():
    """r^T I r = (r_u^2 + r_v^2) / s^2 + (r_u - r_uR)^2 / sigma_d^2, positive definite; sigma_d 0 is ORB-SLAM's
    I / s^2; stereo_chi2 computes the same, and ignores r_uR on monocular observations."""
    from d2slam.slam.optimizer import stereo_chi2, stereo_information

    r = np.array([0.3, -0.5, 0.9])
    I = stereo_information(0.7, 0.2)
    assert np.isclose(r @ I @ r, (0.3 ** 2 + 0.5 ** 2) * 0.7 + (0.3 - 0.9) ** 2 / 0.04)
    assert np.all(np.linalg.eigvalsh(I) > 0)
    np.testing.assert_allclose(stereo_information(0.7, 0.0), 0.7 * np.eye(3))
    assert np.isclose(stereo_chi2(0.3, -0.5, 0.9, True, 0.7, 0.2), r @ I @ r)
    assert np.isclose(stereo_chi2(0.3, -0.5, 0.9, True, 0.7, 0.0), 0.7 * (r @ r))
    assert np.isclose(stereo_chi2(0.3, -0.5, 0.9, False, 0.7, 0.2), 0.7 * 0.34)


# ------------------------------------------------------------------ engine
def test_engine_tracks_room_and_is_deterministic(room):
    frames, gt, ts = room
    eng, res = _run(frames, ts)
    assert all(r.tracked for r in res)
    assert res[0].how == "init" and any(r.how == "motion" for r in res)
    idx, t, P = eng.trajectory()
    np.testing.assert_array_equal(idx, np.arange(len(frames)))
    err = np.linalg.norm(_rel(P)[:, :3, 3] - _rel(gt)[:, :3, 3], axis=1)
    assert err.max() < 0.02
    eng2, _ = _run(frames, ts)
    np.testing.assert_array_equal(eng2.trajectory()[2], P)  # same input -> identical trajectory



def test_a_frame_whose_depth_disagrees_stays_tracked(room):
    """A depth image 10 % off the map (disparities 1-3 px off: as a real Kinect's depth image taken ~15 ms away from
    the colour image while the camera turns) keeps the frame tracked by the motion model, as ORB-SLAM3 tracks it; with
    the disparity model in motion-only BA's last rounds (pose_opt_coarse_rounds 1) the frame was lost."""
    frames, _, ts = room
    states = {}
    for rounds in (DEFAULT.engine.tracking.pose_opt_rounds, 1):
        cfg = overridden(DEFAULT, {"engine": {"tracking": {"pose_opt_coarse_rounds": rounds}}})
        eng = Engine(FR3, cfg)
        for i in range(7):
            gray, depth = frames[i]
            res = eng.process(gray, depth * np.float32(1.1) if i == 6 else depth, i, ts[i])
        states[rounds] = (res.state, res.how)
    assert states[DEFAULT.engine.tracking.pose_opt_rounds] == ("ok", "motion")
    assert states[1][0] == "lost"


def test_the_last_frame_follows_its_reference_keyframe(room):
    """ORB-SLAM3 UpdateLastFrame: before the motion model predicts, the last frame is put back where its reference
    keyframe now is (local BA may have moved the keyframe since the frame was tracked)."""
    frames, _, ts = room
    eng = Engine(FR3)
    for i in range(4):
        assert eng.process(*frames[i], i, ts[i]).tracked
    tr = eng.tracker
    last, ref = tr.last_tracked, eng.map.keyframes[tr.last_tracked.ref_kf]
    np.testing.assert_allclose(last.Tcr @ ref.Tcw, last.Tcw, atol=1e-12)
    shift = np.eye(4)
    shift[:3, 3] = [0.01, 0.0, -0.02]
    ref.Tcw = shift @ ref.Tcw
    f = eng.extractor(*frames[4], 4, ts[4])
    tr.track_with_motion_model(f)
    np.testing.assert_allclose(last.Tcw, last.Tcr @ ref.Tcw, atol=1e-12)

def test_the_motion_model_spans_frames_the_tracker_never_saw(room):
    """An online run drops frames: the next frame is predicted by the constant velocity over the frame steps since
    the last tracked frame (the model is per step), so it is tracked by the motion model, not the reference
    keyframe, and the model carries on per step."""
    from d2slam.slam.optimizer import se3_power

    frames, gt, ts = room
    eng = Engine(FR3)
    for i in range(8):
        assert eng.process(*frames[i], i, ts[i]).tracked
    step = eng.tracker.velocity.copy()
    np.testing.assert_allclose(eng.tracker.motion(11), step @ step @ step @ step, atol=1e-9)  # 7 -> 11
    before = eng.last.Tcw.copy()
    r = eng.process(*frames[11], 11, ts[11])  # frames 8-10 dropped
    assert r.tracked and r.how == "motion"
    moved = eng.last.Tcw @ np.linalg.inv(before)
    np.testing.assert_allclose(se3_power(eng.tracker.velocity, 4), moved, atol=1e-9)
    assert eng.process(*frames[12], 12, ts[12]).how == "motion"


def test_textureless_and_invalid_depth_frames_are_lost(room):
    frames, gt, ts = room
    blank = (np.full_like(frames[0][0], 128), frames[0][1])
    no_depth = (frames[0][0], np.zeros_like(frames[0][1]))
    eng = Engine(FR3)
    r = eng.process(*no_depth, 0, ts[0])
    assert r.state == "not_initialized" and not r.tracked  # no depth: cannot initialise
    r = eng.process(*blank, 1, ts[1])
    assert not r.tracked and r.n_keypoints == 0
    for i in range(2, 5):
        assert eng.process(*frames[i], i, ts[i]).tracked
    # all-invalid depth once the map exists: tracked from monocular edges only (every keypoint has u_R = -1)
    r = eng.process(frames[5][0], np.zeros_like(frames[5][1]), 5, ts[5])
    assert r.tracked and r.n_inliers > 50 and np.all(eng.last.ur == -1)
    r = eng.process(*blank, 6, ts[6])
    assert r.state == "lost" and eng.tracker.velocity is None
    r = eng.process(*frames[7], 7, ts[7])  # relocalisation from the map
    assert r.tracked and r.how == "relocalisation"
    idx = eng.trajectory()[0]
    assert 6 not in idx and 0 not in idx and 1 not in idx and 7 in idx
    with pytest.raises(D2SlamError, match="differ in size"):
        eng.process(frames[8][0], frames[8][1][:100], 8, ts[8])


class LeftHalfDynamic:
    """Marks every keypoint in the left quarter of the image dynamic; records what the engine gives it."""

    def __init__(self):
        self.calls = []

    def reset(self):
        self.calls = []

    def __call__(self, inp):
        self.calls.append(inp)
        n = len(inp.kps)
        assert inp.mappoint_belief.shape == (n,) and inp.kp_depth.shape == (n,)
        assert inp.prev_belief.shape == (len(inp.prev_kps),)
        if len(inp.matches):
            assert inp.matches[:, 0].max() < n and inp.matches[:, 1].max() < len(inp.prev_kps)
        return np.where(inp.kps[:, 0] < 160, 0.9, 0.1)


def test_filter_hook_excludes_dynamic_keypoints(room):
    frames, gt, ts = room
    f = LeftHalfDynamic()
    eng, res = _run(frames[:10], ts[:10], kfilter=f, masks=np.zeros((0, 480, 640), bool))
    assert len(f.calls) == 10 and all(r.tracked for r in res)
    assert len(f.calls[0].matches) == 0 and len(f.calls[3].matches) > 100
    assert f.calls[3].masks is not None
    # No map point comes from a left-quarter keypoint: every point's first observation is a keypoint outside the left quarter.
    M = eng.map
    valid = M.obs.view("valid")
    rows = np.flatnonzero(valid)
    for kf in M.good_keyframes():
        sel = rows[M.obs.kf[rows] == kf.id]
        assert np.all(kf.kps[M.obs.kp[sel], 0] >= 160)
    # Map points carry beliefs; those above 0.5 are culled.
    alive = M.points.view("alive")
    assert np.all(M.points.view("belief")[alive] <= 0.5)
    # mappoint beliefs are passed back to the hook (not all NaN once the map exists)
    assert np.isfinite(f.calls[5].mappoint_belief).sum() > 50


def test_filter_bad_output_is_a_clear_error(room):
    frames, _, ts = room

    class Bad:
        def reset(self):
            pass

        def __call__(self, inp):
            return np.zeros(3)

    eng = Engine(FR3, DEFAULT, Bad())
    with pytest.raises(D2SlamError, match="keypoint filter returned"):
        eng.process(*frames[0], 0, ts[0])


class LateFalseAlarms(LeftHalfDynamic):
    """Static scene; from frame 3 on the filter flags the left quarter (false alarms on mapped static points)."""

    def __call__(self, inp):
        self.calls.append(inp)
        late = inp.frame_index >= 3
        return np.where(late & (inp.kps[:, 0] < 160), 0.9, 0.1)


def test_dynamic_keypoints_take_no_match_and_cull_no_static_point(room):
    """As in DynaSLAM (keypoints in masks never extracted): a keypoint flagged dynamic is not a candidate in any
    search, so it neither takes a map point's match nor deletes the static point it would have matched."""
    frames, gt, ts = room
    eng, res = _run(frames[:8], ts[:8], kfilter=LateFalseAlarms(), masks=None)
    assert all(r.tracked for r in res)
    M = eng.map
    first = M.keyframes[0]
    left = (first.mp >= 0) & (first.kps[:, 0] < 160)
    created = (first.kps[:, 0] < 160) & (first.depth > 0)  # frame 0 (all static) made a point for each of these
    assert created.sum() > 100 and left.sum() >= 0.9 * created.sum()  # they survive the later false alarms
    assert M.points.view("alive")[first.mp[left]].all()
    assert np.all(eng.last.mp[eng.last.dynamic] < 0)


# ------------------------------------------------------------------ guided filter matches, point fusion
def test_guided_filter_matches_follow_the_camera(room):
    """The hook's frame-to-frame matches (guided by the constant-velocity model once it exists) pair keypoints that
    are the same 3D point: their reprojection through the true relative pose agrees within a few pixels."""
    frames, gt, ts = room
    f = LeftHalfDynamic()
    eng, res = _run(frames[:8], ts[:8], kfilter=f, masks=np.zeros((0, 480, 640), bool))
    inp = f.calls[6]  # velocity known: guided
    assert len(inp.matches) > 200
    T = np.linalg.inv(gt[6]) @ gt[5]  # camera 5 -> camera 6
    q, z = inp.prev_kps[inp.matches[:, 1]].astype(float), inp.prev_kp_depth[inp.matches[:, 1]].astype(float)
    ok = z > 0
    X = np.c_[(q[:, 0] - K[0, 2]) * z / K[0, 0], (q[:, 1] - K[1, 2]) * z / K[1, 1], z][ok]
    Xc = X @ T[:3, :3].T + T[:3, 3]
    uv = np.c_[K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2], K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]]
    err = np.linalg.norm(uv - inp.kps[inp.matches[ok, 0]], axis=1)
    assert np.median(err) < 1.5 and np.mean(err < 5) > 0.95
    assert len(np.unique(inp.matches[:, 0])) == len(inp.matches) == len(np.unique(inp.matches[:, 1]))


def test_replace_points_moves_observations_and_kills_old():
    from d2slam.slam.map import KeyFrame, Map

    M = Map()
    kfs = []
    for i in range(3):
        n = 4
        kf = KeyFrame(id=i, frame_index=i, timestamp=float(i), Tcw=np.eye(4), kps=np.zeros((n, 2)),
                      octave=np.zeros(n, np.int64), angle=np.zeros(n, np.float32), desc=np.zeros((n, 32), np.uint8),
                      depth=np.ones(n), ur=np.zeros(n), inv_sigma2=np.ones(n), mp=np.full(n, -1, np.int64))
        M.add_keyframe(kf)
        kfs.append(kf)
    ids = M.add_points(np.zeros((3, 3)), np.zeros((3, 32), np.uint8), np.zeros((3, 3)), np.zeros(3), np.ones(3),
                       np.zeros(3), 0, np.zeros(3, np.float32), np.zeros(3, np.int64))
    a, b, c = ids
    M.add_observations(kfs[0], np.array([0, 1]), np.array([a, b]))  # kf0 sees a and b: a's row there is erased
    M.add_observations(kfs[1], np.array([0]), np.array([a]))  # kf1 sees a only: moves to b
    M.add_observations(kfs[2], np.array([2]), np.array([c]))
    M.replace_points(np.array([a]), np.array([b]))
    P = M.points
    assert not P.alive[a] and P.alive[b] and P.alive[c]
    assert kfs[0].mp.tolist() == [-1, b, -1, -1] and kfs[1].mp.tolist() == [b, -1, -1, -1]
    assert P.nobs[b] == 4 and P.nobs[a] == 0 and P.nobs[c] == 2
    rows = M.observation_rows(np.arange(P.n) == b)
    assert sorted(M.obs.kf[rows].tolist()) == [0, 1]


def test_replace_points_keeps_one_observation_per_keyframe():
    """Two old points seen by one keyframe at two keypoints, both replaced by a point that keyframe does not see:
    the keyframe observes the new point once (the first keypoint), the other observation is erased."""
    from d2slam.slam.map import KeyFrame, Map

    M = Map()
    n = 4
    kf = KeyFrame(id=0, frame_index=0, timestamp=0.0, Tcw=np.eye(4), kps=np.zeros((n, 2)),
                  octave=np.zeros(n, np.int64), angle=np.zeros(n, np.float32), desc=np.zeros((n, 32), np.uint8),
                  depth=np.ones(n), ur=np.zeros(n), inv_sigma2=np.ones(n), mp=np.full(n, -1, np.int64))
    M.add_keyframe(kf)
    a1, a2, b = M.add_points(np.zeros((3, 3)), np.zeros((3, 32), np.uint8), np.zeros((3, 3)), np.zeros(3),
                             np.ones(3), np.zeros(3), 0, np.zeros(3, np.float32), np.zeros(3, np.int64))
    M.add_observations(kf, np.array([0, 2]), np.array([a1, a2]))
    M.replace_points(np.array([a1, a2]), np.array([b, b]))
    P = M.points
    assert kf.mp.tolist() == [b, -1, -1, -1]
    assert P.nobs[b] == 2 and not P.alive[a1] and not P.alive[a2]
    rows = M.observation_rows(P.view("alive"))
    assert M.obs.pt[rows].tolist() == [b] and M.obs.kp[rows].tolist() == [0]



def test_keyframe_culling_needs_more_than_three_other_observers():
    """ORB-SLAM3 1.0 KeyFrameCulling: a keyframe is redundant when 90 % of its close points are seen by more than
    three other keyframes at the same or a finer scale (ORB-SLAM2: at least three)."""
    from d2slam.slam.local_mapping import LocalMapper
    from d2slam.slam.map import KeyFrame, Map
    from d2slam.slam.projection import Projector

    n = 20
    M = Map()
    ids = M.add_points(np.zeros((n, 3)), np.zeros((n, 32), np.uint8), np.zeros((n, 3)), np.zeros(n), np.ones(n),
                       np.zeros(n), 0, np.zeros(n, np.float32), np.zeros(n, np.int64))
    mapper = LocalMapper(M, Projector(FR3, DEFAULT), DEFAULT)
    for i in range(6):
        kf = KeyFrame(id=i, frame_index=i, timestamp=float(i), Tcw=np.eye(4), kps=np.zeros((n, 2)),
                      octave=np.zeros(n, np.int64), angle=np.zeros(n, np.float32), desc=np.zeros((n, 32), np.uint8),
                      depth=np.ones(n), ur=np.zeros(n), inv_sigma2=np.ones(n), mp=np.full(n, -1, np.int64))
        M.add_keyframe(kf)
        if i > 0:  # keyframe 0 sees none of them
            M.add_observations(kf, np.arange(n), ids)
        if i == 4:  # keyframe 1's points seen by keyframes 2, 3, 4: three others
            assert mapper.keyframe_culling(kf) == []
    # with 5, four others: keyframe 1 goes, and then 2-4 are back to three other observers each
    assert mapper.keyframe_culling(M.keyframes[5]) == [1]


@pytest.mark.parametrize("keep_image", [True, False])
def test_local_ba_drops_a_disagreeing_depth_but_keeps_the_image_observation(room, keep_image):
    """After local BA, an observation whose depth disagrees with the map (3 px of disparity: a depth image taken while
    the camera turned) but whose image residual fits stays as a monocular observation, the keyframe's u_R dropped and
    counted once (``lba_depth_outliers_mono``); ORB-SLAM3's rule (False) erases it."""
    frames, _, ts = room
    cfg = overridden(DEFAULT, {"engine": {"mapping": {"lba_depth_outliers_mono": keep_image, "ba_when_idle": False}}})
    eng = Engine(FR3, cfg)
    for i in range(8):
        assert eng.process(*frames[i], i, ts[i]).tracked
    M = eng.map
    kf = eng.tracker.create_keyframe(eng.last)  # a second keyframe, mapped (its local BA run)
    eng.mapper.insert(kf)
    assert eng.mapper.covisible(kf.id, 10) == [0]
    seen = np.flatnonzero((kf.mp >= 0) & (kf.ur >= 0))
    seen = seen[M.points.nobs[kf.mp[seen]] >= 4]  # points keyframe 0 sees with depth too
    bad = seen[::5]
    pts = kf.mp[bad]
    nobs = M.points.nobs[pts].copy()
    kf.ur[bad] -= 3.0
    kf.grids.clear()
    eng.mapper.local_bundle_adjustment(kf)
    kept = kf.mp[bad] == pts
    if keep_image:
        assert kept.mean() > 0.9
        assert (kf.ur[bad][kept] == -1).all()
        rows = M.observation_rows(np.isin(np.arange(M.points.n), pts[kept]))
        assert (M.obs.weight[rows[M.obs.kf[rows] == kf.id]] == 1).all()  # counted once now
        assert np.isin(nobs[kept] - M.points.nobs[pts][kept], [1, 2]).all()  # (keyframe 0 may have lost its depth too)
        assert (kf.ur[seen[1::5]] >= 0).mean() > 0.9  # the others keep their depth
    else:
        assert kept.mean() < 0.1

def test_fusion_adds_observations_but_never_to_dynamic_keypoints(room):
    frames, gt, ts = room
    f = LeftHalfDynamic()
    eng, res = _run(frames[:16], ts[:16], kfilter=f, masks=np.zeros((0, 480, 640), bool))
    M = eng.map
    rows = np.flatnonzero(M.obs.view("valid"))
    for kf in M.good_keyframes():
        assert kf.dynamic is not None
        sel = rows[M.obs.kf[rows] == kf.id]
        assert not kf.dynamic[M.obs.kp[sel]].any()
    # every keypoint -> point link of a keyframe is one valid observation row (no stale links after merging)
    for kf in M.good_keyframes():
        linked = np.flatnonzero(kf.mp >= 0)
        sel = rows[M.obs.kf[rows] == kf.id]
        assert sorted(M.obs.kp[sel].tolist()) == linked.tolist()
        assert np.all(M.obs.pt[sel] == kf.mp[M.obs.kp[sel]])
        assert M.points.alive[kf.mp[linked]].all()


@pytest.mark.parametrize("new_points_depth", [0.0, 4.5])
def test_keyframe_points_from_depth_up_to_the_kinect_range(room, new_points_depth):
    """CreateNewKeyFrame: a new keyframe makes points for its untracked keypoints closer than th_depth * b (2.99 m,
    ORB-SLAM3) or kf_new_points_depth (4.5 m, ours) if larger; beyond, only until kf_new_points_min points (tracked
    ones included) are counted."""
    frames, _, ts = room
    cfg = overridden(DEFAULT, {"engine": {"keyframes": {"kf_new_points_depth": new_points_depth}}})
    eng = Engine(FR3, cfg)
    for i in range(2):
        assert eng.process(*frames[i], i, ts[i]).tracked
    f = eng.last
    # the count is past maxPoint already
    assert ((f.mp >= 0) & (f.depth > 0)).sum() > cfg.engine.keyframes.kf_new_points_min
    free = np.flatnonzero(f.mp < 0)
    mid, far = free[::2], free[1::2]
    f.depth[mid], f.depth[far] = 3.5, 5.0  # between 2.99 m and 4.5 m / beyond both
    assert len(mid) > 10
    kf = eng.tracker.create_keyframe(f)
    made = kf.mp >= 0
    assert not made[far].any()
    if new_points_depth == 4.5:
        assert made[mid].all()
    else:
        assert not made[mid].any()


def test_the_warm_up_compiles_every_kernel_a_run_uses():
    """After ``d2slam.run.warmup.warm_up`` a run of the engine with the d2slam filter on other frames compiles nothing
    (no kernel gets a new signature): what make install and the study rely on."""
    import importlib

    from numba.core.registry import CPUDispatcher

    from d2slam.run.methods import get_filter
    from d2slam.run.warmup import warm_up

    def signatures():
        out = {}
        for name in ("d2slam.slam.lm", "d2slam.slam.matching", "d2slam.dynamics.kernels"):
            mod = importlib.import_module(name)
            out.update({f"{name}.{k}": set(f.signatures) for k, f in vars(mod).items() if isinstance(f, CPUDispatcher)})
        return out

    warm_up()
    after_warm_up = signatures()
    assert after_warm_up["d2slam.slam.lm.local_ba_lm"] and after_warm_up["d2slam.dynamics.kernels.nearest_sq"]
    frames, _, ts = room_sequence(24, seed=5)
    mask = np.zeros((2, FR3.height, FR3.width), bool)
    mask[0, 100:300, 50:200] = mask[1, 200:480, 400:520] = True
    _run(frames, ts, get_filter("d2slam", DEFAULT), masks=mask)
    assert signatures() == after_warm_up
