"""Sub-pixel LK correspondences for eq 4-6 (d2slam.dynamics.flow) and the ``d2slam-flow`` mode."""

import cv2
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy import ndimage

from d2slam.config import DynamicsConfig, FlowConfig
from d2slam.dynamics.depth import keypoint_depth
from d2slam.dynamics.flow import flow_correspondences, flow_keypoints, flow_matches
from d2slam.dynamics.geometric import geometric_module
from d2slam.dynamics.semantic import signed_distances
from d2slam.dynamics.toy import K_FR3
from d2slam.errors import D2SlamError
from d2slam.ranges import overridden
from d2slam.run.methods import get_filter
from d2slam.slam.hook import FilterInput

H, W = 240, 320
BOX = (slice(80, 160), slice(200, 280))  # rows, cols of the moving object in the current image


def texture(seed: int, shape=(H, W)) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = cv2.GaussianBlur(rng.uniform(0, 255, shape).astype(np.float32), (0, 0), 1.6)
    return cv2.normalize(t, None, 0, 255, cv2.NORM_MINMAX)


def image_pair(seed: int = 0, box_motion: float = 3.0):
    """Previous and current grey images of a camera moving along x: the correspondence in the previous image of
    current pixel (u, v) is (u - d(u, v), v), d a smooth, non-planar disparity of 1-3 px (horizontal epipolar lines),
    except inside BOX, an object that moved down by ``box_motion`` px: there it is (u, v - box_motion)."""
    prev = texture(seed)
    vv, uu = np.mgrid[0:H, 0:W].astype(np.float32)
    d = (2.0 + np.sin(uu / 23.0) * np.cos(vv / 17.0)).astype(np.float32)
    mx, my = uu - d, vv.copy()
    mx[BOX], my[BOX] = uu[BOX], vv[BOX] - box_motion
    cur = cv2.remap(prev, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    return prev.astype(np.uint8), cur.astype(np.uint8), mx, my


def grid_keypoints(step: int = 12, border: int = 16) -> np.ndarray:
    v, u = np.mgrid[border:H - border:step, border:W - border:step]
    return np.stack([u.ravel(), v.ravel()], 1).astype(np.float32) + 0.37


def in_box(kps: np.ndarray, margin: float = 0.0) -> np.ndarray:
    return (kps[:, 1] >= BOX[0].start - margin) & (kps[:, 1] < BOX[0].stop + margin) & \
        (kps[:, 0] >= BOX[1].start - margin) & (kps[:, 0] < BOX[1].stop + margin)


def test_flow_finds_the_sub_pixel_correspondence():
    prev, cur, mx, my = image_pair(0)
    kps = grid_keypoints()
    q = flow_correspondences(cur, prev, kps, np.zeros((0, 2)), np.zeros((0, 2), np.int64))
    assert q.shape == kps.shape
    pix = np.rint(kps).astype(int)
    true = np.stack([mx[pix[:, 1], pix[:, 0]] + (kps[:, 0] - pix[:, 0]),
                     my[pix[:, 1], pix[:, 0]] + (kps[:, 1] - pix[:, 1])], 1)
    clean = ~in_box(kps, margin=12)  # away from the object's border (the window straddles two motions there)
    ok = np.isfinite(q).all(axis=1)
    assert ok[clean].mean() > 0.95
    err = np.hypot(*(q - true)[clean & ok].T)
    assert np.median(err) < 0.05 and np.quantile(err, 0.95) < 0.2
    inside = in_box(kps, margin=-12) & ok
    assert inside.sum() > 10 and np.abs(q[inside, 1] - (kps[inside, 1] - 3.0)).max() < 0.2


def test_flow_starts_matched_keypoints_at_their_match_and_rejects_failures():
    prev, cur, mx, my = image_pair(1, box_motion=0.0)
    kps = grid_keypoints()
    # a large camera-like jump is beyond a 3x3-window, no-pyramid search from the keypoint itself, but not from a
    # match that lies near the right place
    cfg = overridden(DynamicsConfig(), {"flow": {"flow_window": 5, "flow_levels": 0}})
    big = np.roll(prev, 9, axis=1)  # the previous image moved right by 9 px: p corresponds to (u - d + 9, v)
    pix = np.rint(kps).astype(int)
    true = np.stack([mx[pix[:, 1], pix[:, 0]] + (kps[:, 0] - pix[:, 0]) + 9.0, kps[:, 1]], 1)
    free = flow_correspondences(cur, big, kps, np.zeros((0, 2)), np.zeros((0, 2), np.int64), cfg)
    prev_kps = true + np.random.default_rng(0).uniform(-1, 1, true.shape)  # ORB-like matches, about a pixel off
    m = np.stack([np.arange(len(kps)), np.arange(len(kps))], 1)
    guided = flow_correspondences(cur, big, kps, prev_kps, m, cfg)
    valid = (true[:, 0] > 14) & (true[:, 0] < W - 8)
    good = lambda q: (np.hypot(*(q - true).T) < 0.2)[valid].mean()  # noqa: E731 (NaN compares False)
    assert good(guided) > 0.9 > 0.3 > good(free)
    # an unrelated previous image: the forward-backward check rejects most tracks
    other = flow_correspondences(cur, texture(99).astype(np.uint8), kps, np.zeros((0, 2)), np.zeros((0, 2), np.int64))
    assert np.isnan(other[:, 0]).mean() > 0.7


def test_flow_bad_input():
    prev, cur, _, _ = image_pair(2)
    kps = np.array([[np.nan, 3.0], [np.inf, 5.0], [50.0, 60.0]], np.float32)
    q = flow_correspondences(cur, prev, kps, np.zeros((0, 2)), np.zeros((0, 2), np.int64))
    assert np.isnan(q[:2]).all() and np.isfinite(q[2]).all()
    assert flow_correspondences(cur, prev, np.zeros((0, 2)), np.zeros((0, 2)), np.zeros((0, 2), np.int64)).shape == \
        (0, 2)
    with pytest.raises(D2SlamError, match="one size"):
        flow_correspondences(cur, prev[:, :-1], kps, np.zeros((0, 2)), np.zeros((0, 2), np.int64))
    with pytest.raises(D2SlamError, match="2 entries for 3 keypoints"):
        flow_correspondences(cur, prev, kps, np.zeros((0, 2)), np.zeros((0, 2), np.int64), track=[True, False])


def test_flow_matches():
    q = np.array([[1.0, 1.0], [np.nan, np.nan], [3.0, 3.0], [4.0, 4.0]])
    prev_kps = np.array([[10.0, 10.0], [11.0, 11.0], [12.0, 12.0]])
    matches = np.array([[0, 2], [1, 0]])
    pk, pz, pb, m, fit, tracked = flow_matches(q, prev_kps, np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.2, 0.9]),
                                               matches)
    np.testing.assert_array_equal(tracked, [True, False, True, True])
    np.testing.assert_array_equal(pk[:3], [[10, 10], [11, 11], [1, 1]])  # matched 0 refined, matched 1 kept
    np.testing.assert_array_equal(pk[3:], [[3, 3], [4, 4]])  # unmatched, tracked: new previous points
    np.testing.assert_array_equal(pz, [1, 2, 3, 0, 0])
    np.testing.assert_array_equal(pb[:3], [0.1, 0.2, 0.9])
    np.testing.assert_array_equal(m, [[0, 2], [1, 0], [2, 3], [3, 4]])
    np.testing.assert_array_equal(fit, [True, True, False, False])
    assert np.isnan(pb[3:]).all()


def test_flow_matches_new_depth():
    """The new matches take the previous depth image's robust depth at their tracked position (pose test), unless
    flow_new_depth is off or no image is given; the matched ones keep their previous keypoint's depth."""
    q = np.array([[1.0, 1.0], [np.nan, np.nan], [30.2, 20.3], [40.6, 10.1]])
    prev_kps = np.array([[10.0, 10.0], [11.0, 11.0], [12.0, 12.0]])
    matches = np.array([[0, 2], [1, 0]])
    depth = np.random.default_rng(0).uniform(0.5, 4.0, (H, W)).astype(np.float32)
    depth[20, 30] = 0.0  # an invalid pixel (the centre of the 3 x 3 patch) is ignored
    args = (q, prev_kps, np.array([1.0, 2.0, 3.0]), np.array([0.1, 0.2, 0.9]), matches)
    pz = flow_matches(*args, prev_depth=depth)[1]
    np.testing.assert_array_equal(pz[:3], [1, 2, 3])
    np.testing.assert_array_equal(pz[3:], keypoint_depth(depth, q[2:], 1))
    assert np.all(pz[3:] > 0) and pz[3] == np.median(np.delete(depth[19:22, 29:32].ravel(), 4))
    no_new_depth = overridden(DynamicsConfig(), {"flow": {"flow_new_depth": False}})
    np.testing.assert_array_equal(flow_matches(*args, prev_depth=depth, cfg=no_new_depth)[1], [1, 2, 3, 0, 0])
    np.testing.assert_array_equal(flow_matches(*args)[1], [1, 2, 3, 0, 0])
    np.testing.assert_array_equal(flow_matches(*args, prev_depth=depth, shape=(H, W))[1], pz)
    # a previous depth image of another size than the grey images, or not 2-D: a clear error, not 0 depths
    for bad in (depth[:, :-1], depth[None]):
        with pytest.raises(D2SlamError, match="must be one size"):
            flow_matches(*args, prev_depth=bad, shape=(H, W))
    with pytest.raises(D2SlamError, match="must be one size"):
        flow_matches(*args, prev_depth=depth[None])


def test_flow_keypoints_choose_what_is_tracked():
    """flow_keypoints per flow_area; leaving keypoints out of the flow does not change the others' tracks (the
    classifier tracks only the keypoints it uses)."""
    in_area = np.array([True, True, False, False])
    m = np.array([[0, 5], [2, 6]])
    np.testing.assert_array_equal(flow_keypoints(in_area, m, "all"), [True] * 4)
    np.testing.assert_array_equal(flow_keypoints(in_area, m, "matched"), [True, False, True, True])
    np.testing.assert_array_equal(flow_keypoints(in_area, m, "outside"), [False, False, True, True])
    with pytest.raises(D2SlamError, match="flow_area"):
        flow_keypoints(in_area, m, "inside")
    prev, cur, _, _ = image_pair(4)
    kps = grid_keypoints()
    prev_kps = kps - [2.0, 0.0]
    mm = np.stack([np.arange(0, len(kps), 3)] * 2, 1)
    track = np.random.default_rng(1).random(len(kps)) < 0.5
    full = flow_correspondences(cur, prev, kps, prev_kps, mm)
    part = flow_correspondences(cur, prev, kps, prev_kps, mm, track=track)
    np.testing.assert_array_equal(part[track], full[track])
    assert np.isnan(part[~track]).all() and np.isfinite(full[~track]).mean() > 0.9


def test_geometric_fits_f_only_on_fit_matches():
    rng = np.random.default_rng(3)
    kps = rng.uniform([0, 0], [W, H], (60, 2))
    prev = kps - [2.0, 0.0] + rng.normal(0, 0.05, (60, 2))
    prev[40:] += rng.uniform(-30, 30, (20, 2))  # gross outliers
    m = np.stack([np.arange(60), np.arange(60)], 1)
    fit = np.arange(60) < 40
    a = np.full(60, 0.7)
    geo = geometric_module(kps, prev, m, np.zeros(60), a, DynamicsConfig(f_min_static_matches=10), fit=fit)
    assert geo.n_used == 40 and geo.observed.all() and geo.dynamic[40:].mean() > 0.8
    with pytest.raises(D2SlamError, match="fit"):
        geometric_module(kps, prev, m, np.zeros(60), a, fit=fit[:5])


def flow_scene(seed: int = 0, with_images: bool = True):
    """Hook input: keypoints on a grid, ORB-like matches (each coordinate off by up to 0.7 px) for 60 % of them."""
    prev, cur, mx, my = image_pair(seed)
    kps = grid_keypoints()
    n = len(kps)
    pix = np.rint(kps).astype(int)
    true = np.stack([mx[pix[:, 1], pix[:, 0]] + (kps[:, 0] - pix[:, 0]),
                     my[pix[:, 1], pix[:, 0]] + (kps[:, 1] - pix[:, 1])], 1)
    rng = np.random.default_rng(seed)
    cur_idx = np.sort(rng.choice(n, int(0.6 * n), replace=False))
    prev_kps = (true + rng.uniform(-0.7, 0.7, true.shape)).astype(np.float32)  # ORB-like: off by up to a pixel
    depth = np.full((H, W), 2.0, np.float32)
    inp = FilterInput(frame_index=1, timestamp=1 / 30, gray=cur if with_images else None, depth=depth,
                      K=K_FR3.copy(), kps=kps, kp_depth=np.full(n, 2.0, np.float32), prev_kps=prev_kps,
                      prev_kp_depth=np.full(n, 2.0, np.float32), prev_belief=np.full(n, 0.2),
                      matches=np.stack([cur_idx, cur_idx], 1).astype(np.int64), mappoint_belief=np.full(n, np.nan),
                      masks=np.zeros((0, H, W), bool), prev_gray=prev if with_images else None)
    return inp, in_box(kps), cur_idx


def test_d2slam_flow_observes_unmatched_keypoints_and_sharpens_eq5():
    inp, moving, matched_idx = flow_scene(0)
    matched = np.zeros(len(inp.kps), bool)
    matched[matched_idx] = True
    plain = get_filter("d2slam")
    plain(inp)
    flow = get_filter("d2slam-flow")
    flow(inp)
    dp, dfl = plain.last, flow.last
    assert "flow" in dfl.timings_ms and "flow" not in dp.timings_ms
    assert not dp.observed[~matched].any()  # without flow, unmatched keypoints have no eq 5 observation
    assert dfl.observed[~matched].mean() > 0.9  # with flow nearly all are observed
    clean = ~in_box(inp.kps, margin=12)
    static = clean & ~moving
    # eq 5's error of static keypoints: ORB-like integer matches about a pixel, tracked ones a small fraction
    assert np.nanmedian(dfl.err[static]) < 0.1 < np.nanmedian(dp.err[static & matched])
    assert dfl.geo_dynamic[static & dfl.observed].mean() < 0.05
    inner = in_box(inp.kps, margin=-12)
    assert dfl.geo_dynamic[inner & ~matched].mean() > 0.9  # unmatched moving keypoints caught by the flow
    # the same with FlowConfig.enabled in the d2slam mode
    with_flow = overridden(DynamicsConfig(), {"flow": {"enabled": True}})
    np.testing.assert_array_equal(get_filter("d2slam", with_flow)(inp), flow(inp))


def test_d2slam_flow_pose_test_on_new_matches():
    """With the previous depth image the flow's new matches (unmatched keypoints that tracked) get the pose test
    (finite reprojection error); without it, or with flow_new_depth off, eq 5 alone."""
    inp, _, matched_idx = flow_scene(3)
    new = np.ones(len(inp.kps), bool)
    new[matched_idx] = False
    with_depth = FilterInput(**{**inp.__dict__, "prev_depth": np.full((H, W), 2.0, np.float32)})
    f = get_filter("d2slam-flow")
    f(with_depth)
    assert f.last.observed[new].mean() > 0.9 and np.isfinite(f.last.reproj_err[new & f.last.observed]).all()
    no_new_depth = overridden(DynamicsConfig(), {"flow": {"flow_new_depth": False}})
    for cfg, x in ((DynamicsConfig(), inp), (no_new_depth, with_depth)):
        g = get_filter("d2slam-flow", cfg)
        g(x)
        assert g.last.observed[new].mean() > 0.9 and np.isnan(g.last.reproj_err[new]).all()
    small = FilterInput(**{**inp.__dict__, "prev_depth": np.full((H // 2, W // 2), 2.0, np.float32)})
    with pytest.raises(D2SlamError, match="must be one size"):
        get_filter("d2slam-flow")(small)


def test_d2slam_flow_without_images_runs_as_d2slam():
    """Without images nothing is tracked: d2slam plus the edge band (no mask here, so exactly d2slam), and exactly
    d2slam with a mask once the band is off."""
    inp, _, _ = flow_scene(1, with_images=False)
    np.testing.assert_array_equal(get_filter("d2slam-flow")(inp), get_filter("d2slam")(inp))
    inp2 = FilterInput(**{**flow_scene(1)[0].__dict__, "prev_gray": None})  # first frame: no previous image
    np.testing.assert_array_equal(get_filter("d2slam-flow")(inp2), get_filter("d2slam")(inp2))
    inp3 = FilterInput(**{**box_scene(1)[0].__dict__, "prev_gray": None})  # the same frame with the BOX mask
    no_band = overridden(DynamicsConfig(), {"flow": {"flow_edge_band": 0.0}})
    np.testing.assert_array_equal(get_filter("d2slam-flow", no_band)(inp3), get_filter("d2slam")(inp3))
    f = get_filter("d2slam-flow")
    f(inp3)
    assert f.last.edge.any() and not f.last.observed[f.last.edge].any()


def box_scene(seed: int = 2):
    """``flow_scene`` with one person mask on BOX: (hook input, matched (N,) bool, each keypoint's distance outside
    the mask in px, 0 inside)."""
    inp, _, matched_idx = flow_scene(seed)
    masks = np.zeros((1, H, W), bool)
    masks[0][BOX] = True
    matched = np.zeros(len(inp.kps), bool)
    matched[matched_idx] = True
    # the mask's outside distance at each keypoint's pixel (scipy's exact Euclidean distance transform)
    pix = np.rint(inp.kps).astype(int)
    outside = ndimage.distance_transform_edt(~masks[0])[pix[:, 1], pix[:, 0]]
    return FilterInput(**{**inp.__dict__, "masks": masks}), matched, outside


def test_edge_band_flags_unobserved_keypoints_just_outside_the_mask():
    """Ours (FlowConfig.flow_edge_band): an unobserved keypoint within the band outside the mask gets
    P = max(P, flow_edge_p) before eq 8; matched ones, farther ones and those inside keep eq 7's P; d2slam has no
    band."""
    inp, matched, outside = box_scene()
    band = DynamicsConfig().flow.flow_edge_band
    near = (outside > 0) & (outside < band)
    f = get_filter("d2slam-flow")
    f(inp)
    d = f.last
    assert near.sum() >= 20 and (near & matched).any() and (near & ~matched).any()
    # just outside the box is the mask's uncertainty zone: the flow ("outside") leaves it to the ORB matches
    np.testing.assert_array_equal(d.observed[near], matched[near])
    np.testing.assert_array_equal(d.edge, near & ~matched)
    assert (d.fused[d.edge] >= 0.9).all() and (d.belief[d.edge] > 0.5).all()
    assert d.predictions()["edge"].sum() == d.edge.sum()
    # the same frame without the band: every other keypoint's P is unchanged, the band's ones were below 0.5
    g = get_filter("d2slam-flow", overridden(DynamicsConfig(), {"flow": {"flow_edge_band": 0.0}}))
    g(inp)
    assert not g.last.edge.any()
    np.testing.assert_array_equal(g.last.fused[~d.edge], d.fused[~d.edge])
    assert (g.last.fused[d.edge] < 0.5).all()
    # a wider band reaches the next ring of keypoints, 12 px further out, beyond the uncertainty zone: there the flow
    # observes nearly all of them, so they are not flagged
    w = get_filter("d2slam-flow", overridden(DynamicsConfig(), {"flow": {"flow_edge_band": 20.0}}))
    w(inp)
    ring = (outside >= band) & (outside < 20)
    np.testing.assert_array_equal(w.last.edge, (outside > 0) & (outside < 20) & ~w.last.observed)
    assert ring.sum() >= 20 and w.last.observed[ring].mean() > 0.9 and (w.last.edge & ~near).sum() < 0.1 * ring.sum()
    p = get_filter("d2slam")
    p(inp)
    assert p.last.edge is None and "edge" not in p.last.predictions()


def test_silhouette_band_flags_keypoints_whose_corner_reaches_a_mask():
    """Ours (OursConfig.silhouette_px): a keypoint outside the mask within silhouette_px x 1.2^octave of it gets
    P = max(P, silhouette_p) before eq 8, matched or not; every other keypoint keeps eq 7's P; off by default."""
    inp, matched, outside = box_scene()
    octave = np.where((outside >= 3) & (outside < 6), 4, 0)  # 3 x 1.2^4 = 6.2 px at level 4
    inp = FilterInput(**{**inp.__dict__, "octave": octave})
    off = get_filter("d2slam")
    off(inp)
    assert off.last.silhouette is None and "silhouette" not in off.last.predictions()
    f = get_filter("d2slam", overridden(DynamicsConfig(), {"ours": {"silhouette_px": 3.0}}))
    f(inp)
    want = (outside > 0) & (outside < 3.0 * 1.2 ** octave)
    assert want.sum() >= 10 and (want & matched).any() and (want & (octave == 4)).any()
    np.testing.assert_array_equal(f.last.silhouette, want)
    np.testing.assert_array_equal(f.last.predictions()["silhouette"], want)
    assert (f.last.fused[want] >= 0.9).all() and (off.last.fused[want] < 0.5).any()
    np.testing.assert_array_equal(f.last.fused[~want], off.last.fused[~want])
    with pytest.raises(D2SlamError, match=r"dynamics.ours.silhouette_p = 2"):
        overridden(DynamicsConfig(), {"ours": {"silhouette_p": 2.0}})


def test_edge_band_bad_settings_are_clear_errors():
    """Refused when the config is built (its range), used by a filter or not."""
    for kwargs, what in (({"flow_edge_p": 1.5}, r"dynamics.flow.flow_edge_p = 1.5 .*\[0, 1\]"),
                         ({"flow_edge_band": float("nan")}, r"dynamics.flow.flow_edge_band = nan .*finite")):
        with pytest.raises(D2SlamError, match=what):
            FlowConfig(**kwargs)


def test_flow_area_option():
    """flow_area: "all" tracks unmatched keypoints in a mask area too, "matched" only refines matched ones there,
    "outside" leaves the mask area to the ORB matches."""
    inp, matched, _ = box_scene(2)
    obs = {}
    for area in ("all", "matched", "outside"):
        f = get_filter("d2slam-flow", overridden(DynamicsConfig(), {"flow": {"flow_area": area}}))
        f(inp)
        obs[area] = f.last.observed
        area_kp = f.last.in_area
    assert obs["all"][area_kp & ~matched].mean() > 0.8
    assert not obs["matched"][area_kp & ~matched].any() and not obs["outside"][area_kp & ~matched].any()
    assert obs["matched"][~area_kp & ~matched].mean() > 0.8


@settings(max_examples=25, deadline=None, derandomize=True, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2**31 - 1), n=st.sampled_from([0, 1, 9, 60]), k=st.sampled_from([0, 5, 40]),
       same=st.booleans(), flat=st.booleans())
def test_property_flow_mode_on_random_images(seed, n, k, same, flat):
    rng = np.random.default_rng(seed)
    h, w = 48, 64
    prev = np.zeros((h, w), np.uint8) if flat else rng.integers(0, 256, (h, w), dtype=np.uint8)
    cur = prev.copy() if same else rng.integers(0, 256, (h, w), dtype=np.uint8)
    kps = rng.uniform([-5, -5], [w + 5, h + 5], (n, 2)).astype(np.float32)  # some outside the image
    if n:
        kps[0] = np.nan
    prev_kps = rng.uniform([0, 0], [w, h], (n, 2)).astype(np.float32)
    kk = min(k, n)
    m = np.stack([rng.permutation(n)[:kk], rng.permutation(n)[:kk]], 1).astype(np.int64).reshape(-1, 2)
    inp = FilterInput(frame_index=1, timestamp=0.0, gray=cur, depth=rng.uniform(0.5, 4, (h, w)).astype(np.float32),
                      K=K_FR3.copy(), kps=kps, kp_depth=rng.uniform(0.5, 4, n).astype(np.float32), prev_kps=prev_kps,
                      prev_kp_depth=rng.uniform(0.5, 4, n).astype(np.float32),
                      prev_belief=rng.choice([0.1, 0.5, 0.9, np.nan], n), matches=m,
                      mappoint_belief=np.full(n, np.nan), masks=(rng.random((1, h, w)) < 0.3), prev_gray=prev,
                      prev_depth=rng.choice(np.array([0.0, np.nan, np.inf, -1.0, 0.8, 2.5, 6.0], np.float32), (h, w)))
    f = get_filter("d2slam-flow")
    bel = f(inp)
    assert bel.shape == (n,) and np.isfinite(bel).all() and ((bel >= 0) & (bel <= 1)).all()
    v = f.last.p_g[np.isfinite(f.last.p_g)]
    assert ((v >= 0) & (v <= 1)).all()
    # the edge band: exactly the unobserved keypoints within flow_edge_band outside the mask (eq 1 searched without
    # a margin), their P raised to at least flow_edge_p
    d_max = signed_distances(inp.masks, kps).max(axis=1) if n else np.zeros(0)
    with np.errstate(invalid="ignore"):
        want = ~f.last.observed & (d_max < 0) & (d_max > -f.cfg.flow.flow_edge_band)
    np.testing.assert_array_equal(f.last.edge, want)
    assert (f.last.fused[want] >= f.cfg.flow.flow_edge_p).all() and ((f.last.fused >= 0) & (f.last.fused <= 1)).all()


def test_unknown_flow_area_is_a_clear_error():
    with pytest.raises(D2SlamError, match="dynamics.flow.flow_area = 'inside' .*'all', 'matched', 'outside'"):
        FlowConfig(flow_area="inside")  # refused when the config is built, used by a filter or not
