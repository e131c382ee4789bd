"""The synthetic sensor model and renderer against their definitions: depth noise sigma(z), quantisation, holes,
the rasteriser's depth and coverage, the simulated segmenter's depth-dependent errors."""

from __future__ import annotations

import numpy as np
import pytest

from d2slam.config import SynthConfig
from d2slam.synth.config import SYNTH_CAMERA as CAM
from d2slam.synth.render import Quad, QuadSet, Renderer, boxes
from d2slam.synth.segsim import simulate_segmenter
from d2slam.synth.sensor import depth_holes, depth_to_png, motion_blur_kernel, rgb_sensor
from d2slam.synth.textures import make_texture

CFG = SynthConfig()
K = CAM.K


def _renderer(textures=None):
    if textures is None:
        textures = [make_texture(np.random.default_rng(0), "poster", 200, 150),
                    make_texture(np.random.default_rng(1), "cloth", 100, 100)]
    return Renderer(K, CAM.width, CAM.height, textures, CFG.near_plane)


def _wall(z: float, half: float = 50.0, tex: int = 0, oid: int = 0) -> Quad:
    """A fronto-parallel quad at depth z (camera at the world origin, identity pose), visible from the camera."""
    return Quad(np.array([-half, -half, z]), np.array([2 * half, 0.0, 0.0]), np.array([0.0, 2 * half, 0.0]), tex, oid)


def test_wall_renders_at_exact_depth_and_fills_the_image():
    r = _renderer()
    rgb, invz, ids = r.render([_wall(2.5, oid=7)], np.eye(4))
    z = 1.0 / invz
    np.testing.assert_allclose(z, 2.5, rtol=1e-5)
    assert (ids == 7).all() and rgb.std() > 10  # textured, written through the views


def test_near_quad_occludes_far_one_and_backfaces_are_culled():
    r = _renderer()
    near = Quad(np.array([-0.2, -0.2, 1.0]), np.array([0.4, 0, 0]), np.array([0, 0.4, 0]), 1, 3)
    back = Quad(near.O + np.array([0, 0, 0.5]), near.V * 1, near.U * 1, 1, 4)  # swapped U/V: faces away
    rgb, invz, ids = r.render([_wall(3.0), near, back], np.eye(4))
    H, W = ids.shape
    assert ids[H // 2 + 8, W // 2] == 3 and ids[5, 5] == 0
    assert not (ids == 4).any()
    # the near square spans 0.4 m at 1 m: about 0.4 * fx pixels wide
    width = (ids[H // 2 + 8] == 3).sum()
    assert abs(width - 0.4 * CAM.fx) <= 2
    np.testing.assert_allclose(1.0 / invz[ids == 3], 1.0, rtol=1e-5)


def test_box_faces_point_outwards():
    qs = boxes(np.eye(4)[None], np.array([[0.5, 0.5, 0.5]]), np.array([0]), np.array([1]))
    centres = qs.O + qs.U / 2 + qs.V / 2
    normals = np.cross(qs.V, qs.U)
    assert (np.einsum("ij,ij->i", centres, normals) > 0).all()


def test_quad_crossing_the_near_plane_is_clipped_not_dropped():
    r = _renderer()
    floor = Quad(np.array([-2.0, 1.0, -1.0]), np.array([4.0, 0, 0]), np.array([0, 0, 6.0]), 0, 5)  # y = 1 (below)
    floor = Quad(floor.O + floor.V, floor.U, -floor.V, 0, 5)  # visible from above (camera y points down)
    rgb, invz, ids = r.render([floor], np.eye(4))
    assert (ids[-1] == 5).all() and not (ids[0] == 5).any()
    # depth on the floor row v: y = 1 => z = fy / (v - cy)
    v = CAM.height - 1
    np.testing.assert_allclose(1.0 / invz[v, CAM.width // 2], CAM.fy / (v - CAM.cy), rtol=1e-4)


@pytest.mark.parametrize("z", [0.8, 1.5, 2.5, 3.5, 4.4])
def test_depth_noise_matches_sigma_model(z):
    clean = np.full((480, 640), z, np.float32)
    png = depth_to_png(clean, np.random.default_rng(5), CFG, holes=False)
    assert png.dtype == np.uint16
    metres = png.astype(np.float64) / CAM.depth_factor
    sigma = float(CAM.depth_noise.sigma(z))
    # quantisation adds step^2 / 12 of variance (step = 0.2 mm)
    expected = np.sqrt(sigma ** 2 + (1 / CAM.depth_factor) ** 2 / 12)
    assert abs(metres.std() / expected - 1) < 0.02
    n_eff = metres.size / max(1.0, 4 * np.pi * CFG.depth_noise_corr_px ** 2)  # correlated pixels: fewer samples
    assert abs(metres.mean() - z) < 5 * expected / np.sqrt(n_eff) + 0.5 / CAM.depth_factor


def test_depth_noise_is_correlated_between_neighbours_and_keeps_its_variance():
    """A 3x3 median does not average the noise away, as it would with independent pixels: neighbours share it."""
    import cv2

    from d2slam.synth.sensor import correlated_noise

    white = np.random.default_rng(3).standard_normal((480, 640), dtype=np.float32)
    assert correlated_noise(white, 0.0) is white
    n = correlated_noise(white, CFG.depth_noise_corr_px)
    assert abs(n.std() - 1) < 0.03
    assert np.corrcoef(n[:, :-1].ravel(), n[:, 1:].ravel())[0, 1] > 0.8
    assert cv2.medianBlur(n, 3).std() > 0.85 and cv2.medianBlur(white, 3).std() < 0.5


def test_sigma_formula_and_quantisation_step():
    assert CAM.depth_noise.sigma(0.4) == pytest.approx(0.0012)
    assert CAM.depth_noise.sigma(1.4) == pytest.approx(0.0012 + 0.0019)
    clean = np.full((200, 200), 0.5, np.float32)  # sigma 1.2 mm = 6 steps of 0.2 mm
    png = depth_to_png(clean, np.random.default_rng(0), CFG, holes=False)
    values = np.unique(png)
    assert np.diff(values).min() == 1  # consecutive 0.2 mm steps are used
    assert len(values) > 20


def test_depth_beyond_range_is_a_hole_and_blob_fraction_matches():
    far = np.full((480, 640), 4.8, np.float32)
    assert (depth_to_png(far, np.random.default_rng(0), CFG) == 0).all()
    flat = np.full((480, 640), 2.0, np.float32)
    png = depth_to_png(flat, np.random.default_rng(1), CFG)
    frac = (png == 0).mean()
    assert abs(frac - CFG.hole_blob_fraction) < 0.002  # no edges: only the random blobs
    # blobs are small connected regions, not salt-and-pepper
    import cv2

    n, _, stats, _ = cv2.connectedComponentsWithStats((png == 0).astype(np.uint8))
    sizes = stats[1:, cv2.CC_STAT_AREA]
    assert n > 5 and np.median(sizes) > 10 and sizes.max() < 0.01 * png.size


def test_kth_smallest_is_exactly_the_partition_value():
    """The blob threshold: the same value as a full partition, with ties, skewed data and small arrays (the full
    partition's path)."""
    from d2slam.synth.sensor import kth_smallest

    rng = np.random.default_rng(4)
    cases = [rng.random((480, 640), dtype=np.float32), np.round(rng.random((200, 300)) * 50).astype(np.float32),
             np.sort(rng.random(100_000)), rng.random((20, 10)), np.full((300, 300), 0.5, np.float32)]
    adverse = np.ones(100_000)
    adverse[::16] = rng.random(6250) * 0.5  # the sample holds all the small values: its bound is too low
    cases.append(adverse)
    for a in cases:
        for k in (0, 1, 7, a.size // 100, a.size // 3):
            assert kth_smallest(a, k) == np.partition(a.ravel(), k)[k]


def test_holes_concentrate_at_depth_edges():
    z = np.full((480, 640), 3.0, np.float32)
    z[:, :320] = 1.0  # a vertical depth step at column 320
    far, edge, blob = depth_holes(z, np.random.default_rng(2), CFG)
    band = np.zeros_like(edge)
    band[:, 318:322] = True
    assert abs(edge[:, 318:322].mean() - CFG.hole_edge_prob) < 0.05
    assert not edge[~band].any() and not far.any()


def test_motion_blur_and_rgb_noise():
    assert motion_blur_kernel(0.3, 0.2, 9.0) is None
    k = motion_blur_kernel(6.0, 0.0, 9.0)
    assert k.sum() == pytest.approx(1.0) and k.shape[1] >= 7 and (k.sum(axis=1) > 0).sum() <= 2
    flat = np.full((480, 640, 3), 128, np.uint8)
    noisy = rgb_sensor(flat, (0.0, 0.0), np.random.default_rng(0), CFG)
    assert noisy.dtype == np.uint8 and abs(noisy.astype(float).std() - CFG.rgb_noise_sigma) < 0.3


def _person_mask(z: float, x_centre: int = 320):
    """A person-like blob (torso + head + legs) of a 1.75 m x 0.45 m body at depth z, as an id image."""
    import cv2

    ids = np.zeros((480, 640), np.uint8)
    h, w = 1.75 * CAM.fy / z, 0.45 * CAM.fx / z
    top = int(CAM.cy - 0.45 * h)
    cv2.rectangle(ids, (int(x_centre - w / 2), top + int(0.15 * h)), (int(x_centre + w / 2), top + int(0.6 * h)), 1, -1)
    cv2.circle(ids, (x_centre, top + int(0.08 * h)), int(0.07 * h), 1, -1)
    for s in (-1, 1):
        cv2.rectangle(ids, (int(x_centre + s * w / 4 - w / 8), top + int(0.6 * h)),
                      (int(x_centre + s * w / 4 + w / 8), top + int(h)), 1, -1)
    depth = np.where(ids > 0, z, 4.0).astype(np.float32)
    return ids, depth


def _iou(a, b):
    return (a & b).sum() / max((a | b).sum(), 1)


def test_segmenter_errors_grow_with_depth():
    ious, misses = {}, {}
    for z in (1.2, 4.2):
        ids, depth = _person_mask(z)
        vals, miss = [], 0
        for seed in range(40):
            lab = simulate_segmenter(ids, depth, [1], K, np.random.default_rng(seed), CFG)
            if not lab.any():
                miss += 1
                continue
            assert set(np.unique(lab)) == {0, 1}
            vals.append(_iou(lab > 0, ids == 1))
        ious[z], misses[z] = np.mean(vals), miss / 40
    assert ious[1.2] > 0.85
    assert ious[4.2] < ious[1.2] - 0.1
    assert misses[1.2] <= 0.15 and misses[4.2] > misses[1.2]


def test_segmenter_never_labels_objects_and_labels_instances_by_area():
    ids = np.zeros((480, 640), np.uint8)
    ids[100:300, 100:200] = 11  # a moved box only
    depth = np.full((480, 640), 2.0, np.float32)
    assert not simulate_segmenter(ids, depth, [1, 2], K, np.random.default_rng(0), CFG).any()
    a, _ = _person_mask(1.5, 200)
    b, _ = _person_mask(3.0, 480)
    ids = np.where(a > 0, 1, np.where(b > 0, 2, 0)).astype(np.uint8)
    depth = np.where(a > 0, 1.5, np.where(b > 0, 3.0, 4.0)).astype(np.float32)
    for seed in range(10):
        lab, info = simulate_segmenter(ids, depth, [1, 2], K, np.random.default_rng(seed), CFG, return_info=True)
        n = int(lab.max())
        assert set(np.unique(lab)) == set(range(n + 1))  # instances 1..n
        if n == 2:
            assert (lab == 1).sum() > (lab == 2).sum()  # by decreasing area: the near person first


def test_rendered_depth_stays_within_each_box_even_for_edge_on_faces():
    """Rasterised edge pixels of (nearly) edge-on faces must not extrapolate the plane's depth (a regression:
    thin lines of pixels a few cm from the camera)."""
    from d2slam.synth.scene import rot_x, rot_y, rot_z, tf

    r = _renderer()
    rng = np.random.default_rng(3)
    Ts, halves = [], []
    for k in range(12):
        R = rot_z(rng.uniform(-3, 3)) @ rot_x(rng.uniform(-3, 3)) @ rot_y(rng.uniform(-3, 3))
        if k < 4:  # faces exactly or nearly edge-on to the camera
            R = rot_y(np.pi / 2 + rng.uniform(-1e-3, 1e-3))
        Ts.append(tf(R, [rng.uniform(-1.5, 1.5), rng.uniform(-1, 1), rng.uniform(1.0, 4.0)]))
        halves.append(rng.uniform(0.05, 0.4, 3))
    qs = boxes(np.stack(Ts), np.stack(halves), np.zeros(12, int), np.arange(1, 13))
    _, invz, ids = r.render(qs, np.eye(4))
    z = np.divide(1.0, invz, out=np.zeros_like(invz), where=invz > 0)
    corners = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], float)
    seen = 0
    for k in range(12):
        m = ids == k + 1
        if not m.any():
            continue
        seen += 1
        cz = (corners * halves[k]) @ Ts[k][:3, :3].T + Ts[k][:3, 3]
        assert z[m].min() >= cz[:, 2].min() - 1e-4 and z[m].max() <= cz[:, 2].max() + 1e-4
    assert seen >= 6
