"""Local mapping as ORB-SLAM3 does it: triangulation between keyframes (``CreateNewMapPoints``, its search and its
checks), the fusion of duplicate points (``SearchInNeighbors`` / ``Fuse``), and the points' descriptors, normals and
distance ranges (``ComputeDistinctiveDescriptors``, ``UpdateNormalAndDepth``), on small synthetic cases and on the
analytic room."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from d2slam.config import DEFAULT
from d2slam.slam import geometric_tools as gt
from d2slam.slam.engine import Engine
from d2slam.slam.fixture import FR3, room_sequence
from d2slam.slam.local_mapping import LocalMapper
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.matching import hamming, medoid_descriptors, search_for_triangulation
from d2slam.slam.projection import Projector, inv

K = FR3.K
SCALES = DEFAULT.orb.scale_factor ** np.arange(DEFAULT.orb.n_levels)


def _pose(rotvec, t) -> np.ndarray:
    """Tcw of a camera at centre ``t`` turned by ``rotvec`` (camera-to-world rotation)."""
    Twc = np.eye(4)
    Twc[:3, :3] = Rotation.from_rotvec(rotvec).as_matrix()
    Twc[:3, 3] = t
    return inv(Twc)


def _pixels(Tcw, X):
    Xc = X @ Tcw[:3, :3].T + Tcw[:3, 3]
    return np.c_[K[0, 0] * Xc[:, 0] / Xc[:, 2] + K[0, 2], K[1, 1] * Xc[:, 1] / Xc[:, 2] + K[1, 2]], Xc[:, 2]


def _scene(n=200, seed=0):
    """``n`` points 2-4 m ahead, inside both images (40 px margin), and two keyframes 0.37 m apart."""
    rng = np.random.default_rng(seed)
    T1 = _pose([0.0, 0.0, 0.0], [0.0, 0.0, 0.0])
    T2 = _pose([0.0, 0.08, 0.02], [0.35, 0.05, 0.1])
    X = np.c_[rng.uniform(-1.5, 1.5, 4 * n), rng.uniform(-1.0, 1.0, 4 * n), rng.uniform(2.0, 4.0, 4 * n)]
    inside = np.ones(len(X), bool)
    for T in (T1, T2):
        uv, _ = _pixels(T, X)
        inside &= (uv[:, 0] > 40) & (uv[:, 0] < FR3.width - 40) & (uv[:, 1] > 40) & (uv[:, 1] < FR3.height - 40)
    return rng, X[inside][:n], T1, T2


# ------------------------------------------------------------------ triangulation and its checks
def test_triangulated_points_are_within_noise_of_the_truth():
    rng, X, T1, T2 = _scene()
    uv1, _ = _pixels(T1, X)
    uv2, _ = _pixels(T2, X)
    uv1 += rng.normal(0, 0.5, uv1.shape)
    uv2 += rng.normal(0, 0.5, uv2.shape)
    xn1 = np.c_[(uv1 - K[:2, 2]) / np.diag(K)[:2]]
    xn2 = np.c_[(uv2 - K[:2, 2]) / np.diag(K)[:2]]
    Xt, ok = gt.triangulate(xn1, xn2, T1, T2)
    assert ok.all()
    err = np.linalg.norm(Xt - X, axis=1)
    # within the two-view depth noise z^2 sigma / (f B) (0.5 px in each view, baseline B 0.37 m: 1-5 cm at 2-4 m)
    B = np.linalg.norm(inv(T2)[:3, 3])
    sigma_z = X[:, 2] ** 2 * 0.5 * np.sqrt(2) / (K[0, 0] * B)
    assert np.median(err / sigma_z) < 1.5 and np.max(err / sigma_z) < 5
    exact, _ = gt.triangulate(*(np.c_[(p - K[:2, 2]) / np.diag(K)[:2]] for p in (_pixels(T1, X)[0],
                                                                                  _pixels(T2, X)[0])), T1, T2)
    np.testing.assert_allclose(exact, X, atol=1e-6)


def _views(X, T1, T2, uv1=None, uv2=None, depth=False, oct1=0, oct2=0):
    p1, z1 = _pixels(T1, X)
    p2, z2 = _pixels(T2, X)
    uv1 = p1 if uv1 is None else uv1
    uv2 = p2 if uv2 is None else uv2
    n = len(X)
    ur1 = uv1[:, 0] - 40.0 / z1 if depth else np.full(n, -1.0)
    ur2 = uv2[:, 0] - 40.0 / z2 if depth else np.full(n, -1.0)
    return (gt.View(T1, uv1, ur1, z1 if depth else np.zeros(n), np.full(n, oct1)),
            gt.View(T2, uv2, ur2, z2 if depth else np.zeros(n), np.full(n, oct2)))


def _new_points(v1, v2):
    return gt.new_points(v1, v2, Projector(FR3, DEFAULT), 0.9998, 5.991, 7.815, 1.5 * 1.2)


def test_new_points_keep_good_pairs_and_reject_bad_ones():
    rng, X, T1, T2 = _scene(50)
    Xt, ok = _new_points(*_views(X, T1, T2))
    assert ok.all()
    np.testing.assert_allclose(Xt, X, atol=1e-6)
    # a keypoint 6 px off the epipolar line (which runs along x here) in the second view: the residuals split between
    # the views fail the chi-square test (5.991 px^2 at level 0)
    off = _pixels(T2, X)[0] + [0.0, 6.0]
    assert not _new_points(*_views(X, T1, T2, uv2=off))[1].any()
    # ... but a level-5 keypoint (sigma 2.5 px) is allowed that much where the octaves agree with the distances
    assert _new_points(*_views(X, T1, T2, uv2=off, oct1=5, oct2=5))[1].mean() > 0.9
    # octaves far apart for points at about the same distance from both keyframes: not the same scale
    assert not _new_points(*_views(X, T1, T2, oct1=0, oct2=5))[1].any()
    # points behind the second camera
    T2_back = _pose([0.0, np.pi, 0.0], [0.3, 0.0, 6.0])
    v1, v2 = _views(X, T1, T2)
    v2.Tcw = T2_back
    assert not _new_points(v1, v2)[1].any()


def test_low_parallax_without_depth_is_dropped_and_with_depth_is_back_projected():
    rng, X, T1, _ = _scene(50)
    T2 = _pose([0.0, 0.0, 0.0], [0.002, 0.0, 0.0])  # 2 mm: rays nearly parallel
    assert not _new_points(*_views(X, T1, T2))[1].any()
    Xt, ok = _new_points(*_views(X, T1, T2, depth=True))
    assert ok.all()  # from keyframe 1's depth
    np.testing.assert_allclose(Xt, X, atol=1e-9)


# ------------------------------------------------------------------ the search
def _descriptors(rng, n):
    return rng.integers(0, 256, (n, 32), dtype=np.uint8)


def test_search_for_triangulation_follows_the_epipolar_line():
    rng, X, T1, T2 = _scene(120, seed=1)
    uv1, _ = _pixels(T1, X)
    uv2, _ = _pixels(T2, X)
    d = _descriptors(rng, len(X))
    d2 = d.copy()
    d2[:, 0] ^= 0b111  # 3 bits apart
    F = gt.fundamental_matrix(T1, T2, K)
    line = np.c_[uv1, np.ones(len(X))] @ F  # the epipolar lines in view 2
    normal = line[:, :2] / np.linalg.norm(line[:, :2], axis=1, keepdims=True)
    shifted = uv2.copy()
    shifted[::2] += 4.0 * normal[::2]  # every other keypoint 4 px off its line (allowed: sqrt(3.84) px at level 0)
    nodes = np.zeros(len(X), np.int64)
    st = np.zeros(len(X), bool)
    octv = np.zeros(len(X), np.int64)
    rows = search_for_triangulation(nodes, uv1, st, d, nodes, shifted, st, octv, d2, F,
                                    gt.epipole(T1, T2, K), SCALES ** 2, 50, 3.84, 100.0, SCALES)
    matched = dict(zip(rows[:, 0].tolist(), rows[:, 1].tolist()))
    on_line = np.arange(1, len(X), 2)
    assert all(matched.get(i) == i for i in on_line)
    assert not any(i in matched for i in range(0, len(X), 2))
    # different vocabulary nodes are never compared
    rows = search_for_triangulation(np.arange(len(X)), uv1, st, d, np.arange(len(X)) + 1000, uv2, st, octv, d2, F,
                                    gt.epipole(T1, T2, K), SCALES ** 2, 50, 3.84, 100.0, SCALES)
    assert len(rows) == 0
    # far descriptors are never matched
    rows = search_for_triangulation(nodes, uv1, st, d, nodes, uv2, st, octv, _descriptors(rng, len(X)), F,
                                    gt.epipole(T1, T2, K), SCALES ** 2, 50, 3.84, 100.0, SCALES)
    assert len(rows) == 0


def test_medoid_descriptor_is_the_least_median_distance():
    rng = np.random.default_rng(0)
    base = _descriptors(rng, 1)[0]
    group = np.repeat(base[None], 4, axis=0)
    for i, bits in enumerate((0, 1, 2, 60)):
        group[i, :bits // 8] ^= 0xFF
        group[i, bits // 8] ^= (1 << (bits % 8)) - 1
    other = _descriptors(rng, 2)
    desc = np.r_[group, other]
    pick = medoid_descriptors(desc, np.array([0, 4, 6]))
    med = [np.sort(hamming(desc[i], group))[1] for i in range(4)]  # ORB-SLAM's median: sorted[(n - 1) // 2]
    assert med == [1, 1, 1, 58] and pick[0] == 0  # ties: the first
    assert pick[1] == 4  # two descriptors: the first one (ORB-SLAM's median of [0, d] is 0 for both)


# ------------------------------------------------------------------ a small map: fusion and point updates
def _keyframe(M, id_, Tcw, uv, z, desc, octave=None):
    n = len(uv)
    kf = KeyFrame(id=id_, frame_index=id_, timestamp=float(id_), Tcw=Tcw, kps=uv,
                  octave=np.zeros(n, np.int64) if octave is None else octave, angle=np.zeros(n, np.float32),
                  desc=desc, depth=z, ur=uv[:, 0] - 40.0 / z, inv_sigma2=np.ones(n), mp=np.full(n, -1, np.int64))
    M.add_keyframe(kf)
    return kf


def _points_from(M, kf, X):
    Twc = inv(kf.Tcw)
    PO = X - Twc[:3, 3]
    dist = np.linalg.norm(PO, axis=1)
    n = len(X)
    ids = M.add_points(X, kf.desc, PO / dist[:, None], dist / SCALES[-1], dist, np.zeros(n), kf.id,
                       np.zeros(n, np.float32), np.zeros(n, np.int64))
    M.add_observations(kf, np.arange(n), ids)
    return ids


def test_fusion_merges_duplicate_points_into_one():
    rng, X, T1, T2 = _scene(80, seed=2)
    M = Map()
    d = _descriptors(rng, len(X))
    (uv1, z1), (uv2, z2) = _pixels(T1, X), _pixels(T2, X)
    kf1 = _keyframe(M, 0, T1, uv1, z1, d)
    kf2 = _keyframe(M, 1, T2, uv2, z2, d.copy())
    a = _points_from(M, kf1, X)
    b = _points_from(M, kf2, X + rng.normal(0, 0.002, X.shape))  # the same points made again by keyframe 2
    b_more = b[::2]
    kf3 = _keyframe(M, 2, T2, uv2, z2, d.copy())
    M.add_observations(kf3, np.arange(0, len(X), 2), b_more)  # half of keyframe 2's points seen twice
    mapper = LocalMapper(M, Projector(FR3, DEFAULT), DEFAULT)
    survivors = mapper.fuse_into(kf2, a, 3.0, 0.0, merge_all=True)
    P = M.points
    assert len(survivors) == len(X)
    # the points with more observations survive (ties: the projected one, keyframe 1's)
    np.testing.assert_array_equal(np.sort(survivors), np.sort(np.r_[b_more, a[1::2]]))
    assert P.alive[survivors].all() and not P.alive[a[::2]].any() and not P.alive[b[1::2]].any()
    np.testing.assert_array_equal(kf1.mp, kf2.mp)  # one point per keypoint, seen by both keyframes
    assert (P.nobs[kf1.mp] == np.where(np.arange(len(X)) % 2 == 0, 6, 4)).all()
    rows = M.observation_rows(P.view("alive"))
    assert len(rows) == 2 * len(X) + len(b_more)


def test_fusion_adds_an_observation_where_the_keypoint_is_free():
    rng, X, T1, T2 = _scene(60, seed=3)
    M = Map()
    d = _descriptors(rng, len(X))
    kf1 = _keyframe(M, 0, T1, *_pixels(T1, X), d)
    kf2 = _keyframe(M, 1, T2, *_pixels(T2, X), d.copy())
    a = _points_from(M, kf1, X)
    mapper = LocalMapper(M, Projector(FR3, DEFAULT), DEFAULT)
    assert len(mapper.fuse_into(kf2, a, 3.0, 0.0)) == 0
    np.testing.assert_array_equal(kf2.mp, a)
    assert (M.points.nobs[a] == 4).all()


def test_update_points_gives_medoid_descriptor_mean_ray_and_range_from_the_maker():
    rng, X, T1, T2 = _scene(5, seed=4)
    M = Map()
    d1 = _descriptors(rng, len(X))
    d2 = d1.copy()
    d2[:, :4] ^= 0xFF  # 32 bits apart
    kf1 = _keyframe(M, 0, T1, *_pixels(T1, X), d1, octave=np.full(len(X), 2))
    kf2 = _keyframe(M, 1, T2, *_pixels(T2, X), d2)
    kf3 = _keyframe(M, 2, T2, *_pixels(T2, X), d2.copy())
    ids = _points_from(M, kf2, X)  # made by keyframe 2 (level 0), then seen by 1 (level 2) and 3
    M.add_observations(kf1, np.arange(len(X)), ids)
    M.add_observations(kf3, np.arange(len(X)), ids)
    M.points.desc[ids] = 0
    M.update_points(ids, SCALES)
    P = M.points
    np.testing.assert_array_equal(P.desc[ids], d2)  # 2 of 3 agree: their median distance is 0
    c1, c2 = inv(T1)[:3, 3], inv(T2)[:3, 3]
    r1 = (X - c1) / np.linalg.norm(X - c1, axis=1, keepdims=True)
    r2 = (X - c2) / np.linalg.norm(X - c2, axis=1, keepdims=True)
    np.testing.assert_allclose(P.normal[ids], (r1 + 2 * r2) / 3)
    np.testing.assert_allclose(P.dmax[ids], np.linalg.norm(X - c2, axis=1))  # keyframe 2, level 0
    np.testing.assert_allclose(P.dmin[ids], P.dmax[ids] / SCALES[-1])


# ------------------------------------------------------------------ on the analytic room
def _mapping_config(**mapping):
    engine = dataclasses.replace(DEFAULT.engine, mapping=dataclasses.replace(DEFAULT.engine.mapping, **mapping))
    return dataclasses.replace(DEFAULT, engine=engine)


@pytest.fixture(scope="module")
def room():
    return room_sequence(24, seed=3)


def test_keyframes_triangulate_points_where_the_depth_is_missing(room):
    """Keypoints without depth (the left 200 px here) make no point from depth; CreateNewMapPoints triangulates them
    between keyframes (one every 4 frames), near the room's walls (the truth: keyframes 4-12 cm apart, 2-4 m from the
    walls, so a few cm of noise), and every keypoint -> point link stays one valid observation."""
    frames, poses, ts = room
    cfg = _mapping_config(triangulate_neighbours=10, fuse_neighbours=10, update_points=True, ba_when_idle=False)
    eng = Engine(FR3, cfg)
    for i, (gray, depth) in enumerate(frames):
        depth = depth.copy()
        depth[:, :200] = 0.0
        assert eng.process(gray, depth, i, ts[i]).tracked
        if i % 4 == 3:
            kf = eng.tracker.create_keyframe(eng.last)
            eng.mapper.insert(kf)
            eng.loop.insert(kf)
    M, P = eng.map, eng.map.points
    alive = np.flatnonzero(P.view("alive"))
    rows = M.observation_rows(P.view("alive"))
    with_depth = np.zeros(P.n, bool)
    for kf in M.keyframes:
        sel = rows[M.obs.kf[rows] == kf.id]
        with_depth[M.obs.pt[sel][kf.depth[M.obs.kp[sel]] > 0]] = True
    tri = alive[~with_depth[alive]]  # no observation with depth: triangulated
    assert len(tri) > 50
    Xw = P.pos[tri] @ poses[0][:3, :3].T + poses[0][:3, 3]  # the engine's world is the first camera
    off_wall = np.min(np.abs(np.abs(Xw) - np.array([2.0, 1.2, 2.0])), axis=1)
    assert np.median(off_wall) < 0.05 and np.percentile(off_wall, 90) < 0.15
    for kf in M.good_keyframes():
        linked = np.flatnonzero(kf.mp >= 0)
        sel = rows[M.obs.kf[rows] == kf.id]
        assert sorted(M.obs.kp[sel].tolist()) == linked.tolist()
        assert P.alive[kf.mp[linked]].all()
