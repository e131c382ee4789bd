"""The compiled kernels give exactly what the numpy / OpenCV / scipy code they replace gives: a mask's edge pixels by
row, nearest edge distances (bounded and not, boundary cases included), the one-to-one match filter and the
rotation histogram of the frame-to-frame matches."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial import cKDTree

from d2slam.dynamics.kernels import edge_rows, nearest_sq
from d2slam.slam.matching import rotation_consistent, unique_by_target

CROSS = cv2.getStructuringElement(cv2.MORPH_CROSS, (3, 3))


def _blobs(rng, h=40, w=50):
    m = np.zeros((h, w), np.uint8)
    for _ in range(3):
        cv2.ellipse(m, (int(rng.integers(0, w)), int(rng.integers(0, h))),
                    (int(rng.integers(2, 15)), int(rng.integers(2, 15))), float(rng.uniform(0, 180)), 0, 360, 1, -1)
    m[rng.random((h, w)) < 0.02] ^= 1  # holes and specks
    return m


@pytest.mark.parametrize("seed", range(5))
def test_edge_rows_lists_the_nonzero_pixels_row_by_row(seed):
    img = cv2.dilate(_blobs(np.random.default_rng(seed)), CROSS) - _blobs(np.random.default_rng(seed))
    start, xs = edge_rows(img)
    idx = np.flatnonzero(img)
    assert np.array_equal(start, np.searchsorted(idx // img.shape[1], np.arange(img.shape[0] + 1)))
    assert np.array_equal(xs, idx % img.shape[1])
    assert edge_rows(np.zeros((3, 4), np.uint8))[1].size == 0


@pytest.mark.parametrize("seed", range(5))
def test_nearest_sq_equals_the_kd_tree(seed):
    """Squared distances whose roots are cKDTree's, and a bounded search that finds a neighbour exactly when the
    tree does (d^2 < bound^2, also at bounds equal to a distance or just above it)."""
    rng = np.random.default_rng(seed)
    mask = _blobs(rng)
    edge = cv2.dilate(mask, CROSS) - mask
    y0, x0 = 7, 11  # the crop's origin in the frame
    start, xs = edge_rows(edge)
    pts = np.stack([xs, np.repeat(np.arange(edge.shape[0]), np.diff(start))], axis=1) + [x0, y0]
    tree = cKDTree(pts.astype(np.float64))
    q = rng.integers(-10, 70, (300, 2))
    got = nearest_sq(start, xs, x0, y0, q[:, 0].astype(np.int64), q[:, 1].astype(np.int64), np.inf)
    assert np.array_equal(np.sqrt(got), tree.query(q.astype(np.float64))[0])
    for bound in (0.0, 1.0, np.sqrt(2.0), 3.0, np.nextafter(3.0, 4.0), 4.7, 12.5):
        got = nearest_sq(start, xs, x0, y0, q[:, 0].astype(np.int64), q[:, 1].astype(np.int64), bound)
        ref = tree.query(q.astype(np.float64), distance_upper_bound=bound)[0]
        assert np.array_equal(np.sqrt(got), ref), bound
    empty = edge_rows(np.zeros((4, 4), np.uint8))
    assert np.isinf(nearest_sq(*empty, 0, 0, np.zeros(2, np.int64), np.zeros(2, np.int64), np.inf)).all()


def _unique_ref(target, dist):
    order = np.lexsort((dist, target))
    first = np.r_[True, target[order][1:] != target[order][:-1]]
    keep = np.zeros(len(target), dtype=bool)
    keep[order[first]] = True
    return keep


def _rotation_ref(a, b, bins):
    rot = np.mod(np.asarray(a, np.float64) - np.asarray(b, np.float64), 360.0)
    idx = np.minimum((rot * (bins / 360.0)).astype(np.int64), bins - 1)
    counts = np.bincount(idx, minlength=bins)
    order = np.argsort(-counts, kind="stable")[:3]
    top = counts[order]
    keep = [order[0]]
    if top[1] >= 0.1 * top[0]:
        keep.append(order[1])
        if top[2] >= 0.1 * top[0]:
            keep.append(order[2])
    return np.isin(idx, keep)


def test_match_filters_equal_their_numpy_versions():
    """Ties (equal distances, equally populated bins) and NaN distances included."""
    rng = np.random.default_rng(0)
    for _ in range(500):
        n = int(rng.integers(1, 60))
        target = rng.integers(3, 18, n)
        dist = rng.integers(0, 6, n).astype(np.float64)
        dist[rng.random(n) < 0.1] = np.nan
        assert np.array_equal(unique_by_target(np.arange(n), target, dist), _unique_ref(target, dist))
        a = rng.integers(0, 8, n) * 45.0 + rng.normal(0, 3, n)
        b = rng.uniform(0, 360, n) * (rng.random() < 0.5)
        assert np.array_equal(rotation_consistent(a, b, 30), _rotation_ref(a, b, 30))
    assert unique_by_target(np.zeros(0), np.zeros(0, np.int64), np.zeros(0)).shape == (0,)


def test_keypoint_grid_buckets_as_a_stable_argsort():
    from d2slam.slam.matching import KeypointGrid

    rng = np.random.default_rng(1)
    for n in (0, 1, 7, 300):
        kps = rng.uniform(-5, 640, (n, 2))
        kps[: n // 3] = np.round(kps[: n // 3])  # keypoints on cell borders
        g = KeypointGrid(kps, rng.integers(0, 8, n), rng.uniform(-1, 600, n),
                         rng.integers(0, 256, (n, 32), dtype=np.uint8), 10.0)
        cid = ((np.floor(g.kps[:, 1] / g.cell).astype(np.int64) - g.row0) * g.cols
               + np.floor(g.kps[:, 0] / g.cell).astype(np.int64) - g.col0)
        order = np.argsort(cid, kind="stable")
        assert np.array_equal(g.order, order)
        assert np.array_equal(g.start, np.searchsorted(cid[order], np.arange(g.rows * g.cols + 1)))
