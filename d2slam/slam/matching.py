"""Descriptor matching: Hamming distance by XOR + popcount, search by projection over a grid of keypoints (a
compiled kernel: one pass over the candidates of every projected point), ORB-SLAM's ratio test and
rotation-consistency histogram, and OpenCV brute-force matching for reference-keyframe tracking, relocalisation and
the filter's frame-to-frame matches."""

from __future__ import annotations

import cv2
import numpy as np
from numba import njit


def hamming(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise Hamming distance between (..., 32) uint8 descriptors (broadcasting)."""
    x = np.bitwise_xor(np.ascontiguousarray(a).view(np.uint64), np.ascontiguousarray(b).view(np.uint64))
    return np.bitwise_count(x).sum(axis=-1, dtype=np.int64)


def rotation_consistent(angle_a: np.ndarray, angle_b: np.ndarray, bins: int) -> np.ndarray:
    """ORB-SLAM's orientation check: keep matches whose angle difference falls in the three most populated of
    ``bins`` histogram bins (ORB-SLAM: 30; the 2nd and 3rd only if they hold at least 10 % of the 1st)."""
    n = len(angle_a)
    if n == 0:
        return np.zeros(0, dtype=bool)
    rot = np.mod(np.asarray(angle_a, np.float64) - np.asarray(angle_b, np.float64), 360.0)
    idx = np.minimum((rot * (bins / 360.0)).astype(np.int64), bins - 1)
    return _in_top_bins(idx, int(bins))


@njit(cache=True, nogil=True)
def _in_top_bins(idx, bins):
    """``rotation_consistent``'s histogram: (n,) bool, ``idx`` in the most populated bin, or the 2nd (3rd) when it
    holds at least 10 % of the 1st's count (the 3rd only with the 2nd); ties between bins: the lower bin first."""
    counts = np.zeros(bins, np.int64)
    for v in idx:
        counts[v] += 1
    top = np.full(3, -1, np.int64)  # bins by decreasing count, the lower bin first among equal counts
    for b in range(bins):
        for r in range(3):
            if top[r] < 0 or counts[b] > counts[top[r]]:
                for q in range(2, r, -1):
                    top[q] = top[q - 1]
                top[r] = b
                break
    keep = np.zeros(bins, np.bool_)
    keep[top[0]] = True
    if bins > 1 and counts[top[1]] >= 0.1 * counts[top[0]]:
        keep[top[1]] = True
        if bins > 2 and counts[top[2]] >= 0.1 * counts[top[0]]:
            keep[top[2]] = True
    out = np.empty(len(idx), np.bool_)
    for i in range(len(idx)):
        out[i] = keep[idx[i]]
    return out


class Gridded:
    """What :class:`~d2slam.slam.frame.Frame` and :class:`~d2slam.slam.map.KeyFrame` share for searches by
    projection: their keypoints (``kps``, ``octave``, ``ur``, ``desc``) bucketed in ``cell``-pixel cells, built once
    per cell size into their ``grids`` dict."""

    def grid(self, cell: float) -> KeypointGrid:
        if cell not in self.grids:
            self.grids[cell] = KeypointGrid(self.kps, self.octave, self.ur, self.desc, cell)
        return self.grids[cell]


class KeypointGrid:
    """A frame's keypoints bucketed in square cells of ``cell`` pixels (ORB-SLAM's ``mGrid``), for
    ``GetFeaturesInArea``-style searches: cell ``(row, col)`` holds ``order[start[row * cols + col]:start[... + 1]]``.
    Descriptors are kept as (N, 4) uint64 words for the compiled Hamming distance."""

    def __init__(self, kps: np.ndarray, octave: np.ndarray, ur: np.ndarray, desc: np.ndarray, cell: float):
        self.cell = float(cell)
        n = len(kps)
        self.kps = np.ascontiguousarray(kps, dtype=np.float64).reshape(n, 2)
        self.octave = np.ascontiguousarray(octave, dtype=np.int64)
        self.ur = np.ascontiguousarray(ur, dtype=np.float64)
        self.desc = np.ascontiguousarray(desc, dtype=np.uint8).reshape(n, 32).view(np.uint64)
        cx = np.floor(self.kps[:, 0] / self.cell).astype(np.int64) if n else np.zeros(0, np.int64)
        cy = np.floor(self.kps[:, 1] / self.cell).astype(np.int64) if n else np.zeros(0, np.int64)
        self.col0, self.row0 = (int(cx.min()), int(cy.min())) if n else (0, 0)
        self.cols = int(cx.max()) - self.col0 + 1 if n else 1
        self.rows = int(cy.max()) - self.row0 + 1 if n else 1
        cid = (cy - self.row0) * self.cols + (cx - self.col0)
        self.order, self.start = bucket_order(cid, self.rows * self.cols)  # = np.argsort(cid, kind="stable") and its cells


@njit(cache=True, nogil=True)
def bucket_order(cid, cells):
    """Counting sort of the cell ids ``cid``: (order, start), ``order`` the stable ascending order of ``cid`` and
    cell c's entries ``order[start[c]:start[c + 1]]``."""
    start = np.zeros(cells + 1, np.int64)
    for c in cid:
        start[c + 1] += 1
    for c in range(cells):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(len(cid), np.int64)
    for i in range(len(cid)):
        order[fill[cid[i]]] = i
        fill[cid[i]] += 1
    return order, start


CHECK_DISPARITY, CHECK_CHI2 = 0, 1


@njit(cache=True, nogil=True)
def _popcount64(x):
    x = x - ((x >> np.uint64(1)) & np.uint64(0x5555555555555555))
    x = (x & np.uint64(0x3333333333333333)) + ((x >> np.uint64(2)) & np.uint64(0x3333333333333333))
    x = (x + (x >> np.uint64(4))) & np.uint64(0x0F0F0F0F0F0F0F0F)
    return (x * np.uint64(0x0101010101010101)) >> np.uint64(56)


@njit(cache=True, nogil=True)
def hamming_at(a, i, b, j):
    """Hamming distance between the 256-bit descriptors a[i] and b[j] (four uint64 words each)."""
    d = 0
    for w in range(4):
        d += _popcount64(a[i, w] ^ b[j, w])
    return d


@njit(cache=True, nogil=True)
def _search_grid(cell, col0, row0, cols, rows, order, start, kps, octave, ur, desc, inv_sigma2, available,
                 uv, radius, lo, hi, ur_proj, qdesc, check, disparity_sigma, chi2_mono, chi2_stereo):
    q = uv.shape[0]
    best_idx = np.full(q, -1, np.int64)
    best_dist = np.full(q, 1 << 20, np.int64)
    second_dist = np.full(q, 1 << 20, np.int64)
    best_level = np.full(q, -1, np.int64)
    second_level = np.full(q, -1, np.int64)
    for i in range(q):
        u, v, r = uv[i, 0], uv[i, 1], radius[i]
        c_lo = max(int(np.floor((u - r) / cell)) - col0, 0)
        c_hi = min(int(np.floor((u + r) / cell)) - col0, cols - 1)
        r_lo = max(int(np.floor((v - r) / cell)) - row0, 0)
        r_hi = min(int(np.floor((v + r) / cell)) - row0, rows - 1)
        b1, d1, d2, l1, l2 = -1, 1 << 20, 1 << 20, -1, -1
        for row in range(r_lo, r_hi + 1):
            for col in range(c_lo, c_hi + 1):
                c = row * cols + col
                for j in range(start[c], start[c + 1]):
                    k = order[j]
                    lv = octave[k]
                    if lv < lo[i] or lv > hi[i] or not available[k]:
                        continue
                    dx = u - kps[k, 0]
                    dy = v - kps[k, 1]
                    if dx * dx + dy * dy > r * r:
                        continue
                    if check == 0:  # the projected u_R agrees with the keypoint's (where both exist)
                        if not np.isnan(ur_proj[i]) and ur[k] >= 0 and abs(ur_proj[i] - ur[k]) >= r:
                            continue
                    else:  # reprojection chi-square test (stereo where the keypoint has u_R)
                        e2 = (dx * dx + dy * dy) * inv_sigma2[k]
                        if ur[k] >= 0:
                            dur = ur_proj[i] - ur[k]
                            if disparity_sigma > 0:
                                e2 += (dx - dur) ** 2 / disparity_sigma ** 2
                            else:
                                e2 += dur * dur * inv_sigma2[k]
                            if e2 > chi2_stereo:
                                continue
                        elif e2 > chi2_mono:
                            continue
                    d = hamming_at(desc, k, qdesc, i)
                    if d < d1:
                        d2, l2 = d1, l1
                        b1, d1, l1 = k, d, lv
                    elif d < d2:
                        d2, l2 = d, lv
        best_idx[i], best_dist[i], second_dist[i], best_level[i], second_level[i] = b1, d1, d2, l1, l2
    return best_idx, best_dist, second_dist, best_level, second_level


def search_by_projection(grid: KeypointGrid, uv: np.ndarray, ur_proj: np.ndarray, radius: np.ndarray,
                         lo: np.ndarray, hi: np.ndarray, desc: np.ndarray, available: np.ndarray,
                         check: int = CHECK_DISPARITY, inv_sigma2: np.ndarray | None = None,
                         disparity_sigma: float = 0.0, chi2_mono: float = 0.0, chi2_stereo: float = 0.0):
    """ORB-SLAM ``SearchByProjection``'s search, shared by every projection search: for each projected point ``uv``
    (descriptor ``desc``) the best and second-best ``available`` keypoint of ``grid`` within ``radius`` pixels on
    the levels [lo, hi] by Hamming distance (ties: the keypoint met first, cells row by row). Each candidate must
    also pass ``check``: ``CHECK_DISPARITY`` the projected ``u_R`` within ``radius`` of the keypoint's (skipped
    where ``ur_proj`` is NaN or the keypoint has no ``u_R``), or ``CHECK_CHI2`` the reprojection chi-square test
    of ``optimizer.stereo_chi2`` with the keypoints' ``inv_sigma2``. Returns (best index (-1 none), best distance,
    second distance, best level, second level); distances without a candidate are 2^20."""
    q = len(uv)
    f64 = np.float64
    if inv_sigma2 is None:
        inv_sigma2 = np.ones(len(grid.kps))
    qdesc = np.ascontiguousarray(desc, dtype=np.uint8).reshape(q, 32).view(np.uint64)
    return _search_grid(grid.cell, grid.col0, grid.row0, grid.cols, grid.rows, grid.order, grid.start, grid.kps,
                        grid.octave, grid.ur, grid.desc, np.ascontiguousarray(inv_sigma2, dtype=f64),
                        np.ascontiguousarray(available, dtype=np.bool_), np.ascontiguousarray(uv, dtype=f64).reshape(q, 2),
                        np.ascontiguousarray(radius, dtype=f64), np.ascontiguousarray(lo, dtype=np.int64),
                        np.ascontiguousarray(hi, dtype=np.int64), np.ascontiguousarray(ur_proj, dtype=f64), qdesc,
                        int(check), float(disparity_sigma), float(chi2_mono), float(chi2_stereo))


def search_for_triangulation(nodes1: np.ndarray, kps1: np.ndarray, stereo1: np.ndarray, desc1: np.ndarray,
                             nodes2: np.ndarray, kps2: np.ndarray, stereo2: np.ndarray, oct2: np.ndarray,
                             desc2: np.ndarray, F12: np.ndarray, ep: np.ndarray, sigma2: np.ndarray, th_low: int,
                             epipolar_chi2: float, epipole_px2: float, scales: np.ndarray) -> np.ndarray:
    """ORB-SLAM3 ``ORBmatcher::SearchForTriangulation``'s search between the free keypoints of two keyframes (arrays
    of those keypoints only): keypoints are compared only under the same vocabulary node (``nodes*``: feature-vector
    nodes; all equal: every pair); for each keypoint of 1 the nearest of 2 within Hamming ``th_low`` whose pixel
    lies within ``epipolar_chi2 x sigma2[octave]`` (squared px) of the epipolar line ``x1^T F12`` and, when neither
    has depth (``stereo*``), at least ``epipole_px2 x scale`` (squared px) from the epipole ``ep`` (equal distances:
    the later keypoint, as ORB-SLAM3). Returns (K, 3) int rows (index in 1, index in 2, distance), not yet one-to-one
    nor checked for orientation."""
    o1, o2 = np.argsort(nodes1, kind="stable"), np.argsort(nodes2, kind="stable")
    d1 = np.ascontiguousarray(desc1[o1], dtype=np.uint8).reshape(-1, 32).view(np.uint64)
    d2 = np.ascontiguousarray(desc2[o2], dtype=np.uint8).reshape(-1, 32).view(np.uint64)
    f64 = np.float64
    best, dist = _triangulation_pairs(np.ascontiguousarray(nodes1[o1], dtype=np.int64),
                                      np.ascontiguousarray(kps1[o1], dtype=f64), np.ascontiguousarray(stereo1[o1]),
                                      d1, np.ascontiguousarray(nodes2[o2], dtype=np.int64),
                                      np.ascontiguousarray(kps2[o2], dtype=f64), np.ascontiguousarray(stereo2[o2]),
                                      np.ascontiguousarray(oct2[o2], dtype=np.int64), d2,
                                      np.ascontiguousarray(F12, dtype=f64), np.ascontiguousarray(ep, dtype=f64),
                                      np.ascontiguousarray(sigma2, dtype=f64), int(th_low), float(epipolar_chi2),
                                      float(epipole_px2), np.ascontiguousarray(scales, dtype=f64))
    ok = best >= 0
    return np.stack([o1[ok], o2[best[ok]], dist[ok]], axis=1).astype(np.int64).reshape(-1, 3)


@njit(cache=True, nogil=True)
def _triangulation_pairs(n1, kp1, st1, d1, n2, kp2, st2, oct2, d2, F, ep, sigma2, th_low, epi_chi2, epipole_px2,
                         scales):
    best = np.full(len(n1), -1, np.int64)
    dist = np.zeros(len(n1), np.int64)
    j0 = 0
    for i in range(len(n1)):
        while j0 < len(n2) and n2[j0] < n1[i]:
            j0 += 1
        a = kp1[i, 0] * F[0, 0] + kp1[i, 1] * F[1, 0] + F[2, 0]
        b = kp1[i, 0] * F[0, 1] + kp1[i, 1] * F[1, 1] + F[2, 1]
        c = kp1[i, 0] * F[0, 2] + kp1[i, 1] * F[1, 2] + F[2, 2]
        den = a * a + b * b
        b_idx, b_dist = -1, th_low
        j = j0
        while j < len(n2) and n2[j] == n1[i]:
            d = hamming_at(d1, i, d2, j)
            ok = d <= b_dist and den > 0
            if ok and not st1[i] and not st2[j]:
                ex, ey = ep[0] - kp2[j, 0], ep[1] - kp2[j, 1]
                ok = ex * ex + ey * ey >= epipole_px2 * scales[oct2[j]]
            if ok:
                num = a * kp2[j, 0] + b * kp2[j, 1] + c
                if num * num / den < epi_chi2 * sigma2[oct2[j]]:
                    b_idx, b_dist = j, d
            j += 1
        best[i], dist[i] = b_idx, b_dist
    return best, dist


def medoid_descriptors(desc: np.ndarray, start: np.ndarray) -> np.ndarray:
    """ORB-SLAM ``MapPoint::ComputeDistinctiveDescriptors`` for groups of descriptors: group g is ``desc[start[g]:
    start[g + 1]]`` ((N, 32) uint8); its medoid is the descriptor whose median Hamming distance to the group (itself
    included, ``sorted(d)[(n - 1) // 2]``) is the least (ties: the first). Returns each group's medoid's row in
    ``desc``."""
    d = np.ascontiguousarray(desc, dtype=np.uint8).reshape(-1, 32).view(np.uint64)
    return _medoids(d, np.ascontiguousarray(start, dtype=np.int64))


@njit(cache=True, nogil=True)
def _medoids(d, start):
    out = np.empty(len(start) - 1, np.int64)
    for g in range(len(start) - 1):
        a, n = start[g], start[g + 1] - start[g]
        best, best_med = a, 1 << 20
        row = np.empty(n, np.int64)
        for i in range(n):
            for j in range(n):
                row[j] = hamming_at(d, a + i, d, a + j)
            med = np.sort(row)[(n - 1) // 2]
            if med < best_med:
                best, best_med = a + i, med
        out[g] = best
    return out


def unique_by_target(query: np.ndarray, target: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Boolean mask keeping, for every target index, only the query with the smallest distance (one-to-one; equal
    distances: the first query; a NaN distance loses to any number), in one compiled pass."""
    if len(query) == 0:
        return np.zeros(0, dtype=bool)
    return _first_per_target(np.ascontiguousarray(target, dtype=np.int64),
                             np.ascontiguousarray(dist, dtype=np.float64))


@njit(cache=True, nogil=True)
def _first_per_target(target, dist):
    lo, hi = target.min(), target.max()
    best = np.full(hi - lo + 1, -1, np.int64)
    for i in range(len(target)):
        t = target[i] - lo
        b = best[t]
        if b < 0 or dist[i] < dist[b] or (np.isnan(dist[b]) and not np.isnan(dist[i])):
            best[t] = i
    keep = np.zeros(len(target), np.bool_)
    for b in best:
        if b >= 0:
            keep[b] = True
    return keep


def knn_ratio_match(desc_a: np.ndarray, desc_b: np.ndarray, ratio: float, max_dist: int) -> np.ndarray:
    """(K, 3) int rows (index in a, index in b, distance): cv2 brute-force Hamming 2-NN with a ratio test and a
    distance threshold, made one-to-one on b."""
    if len(desc_a) == 0 or len(desc_b) < 2:
        return np.zeros((0, 3), dtype=np.int64)
    bf = cv2.BFMatcher(cv2.NORM_HAMMING)
    knn = bf.knnMatch(desc_a, desc_b, k=2)
    rows = np.array([(m[0].queryIdx, m[0].trainIdx, m[0].distance, m[1].distance) for m in knn if len(m) == 2],
                    dtype=np.float64).reshape(-1, 4)
    ok = (rows[:, 2] <= max_dist) & (rows[:, 2] < ratio * rows[:, 3])
    rows = rows[ok]
    keep = unique_by_target(rows[:, 0], rows[:, 1].astype(np.int64), rows[:, 2])
    return rows[keep][:, :3].astype(np.int64)


def nearest_matches(desc_a: np.ndarray, desc_b: np.ndarray, cross_check: bool = False) -> np.ndarray:
    """(K, 3) float rows (index in a, index in b, Hamming distance): cv2 brute-force nearest neighbour of each
    descriptor of a in b (mutual nearest only with ``cross_check``)."""
    if len(desc_a) == 0 or len(desc_b) == 0:
        return np.zeros((0, 3))
    ms = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=cross_check).match(desc_a, desc_b)
    return np.array([(m.queryIdx, m.trainIdx, m.distance) for m in ms], dtype=np.float64).reshape(-1, 3)


def window_cross_match(kps_a: np.ndarray, desc_a: np.ndarray, kps_b: np.ndarray, desc_b: np.ndarray,
                       window: float, max_dist: int) -> np.ndarray:
    """(K, 2) int one-to-one frame-to-frame matches (index in a, index in b): mutual nearest neighbours in Hamming
    distance (cv2 cross-check), kept when the pixel displacement is below ``window`` and the distance below
    ``max_dist``."""
    rows = nearest_matches(desc_a, desc_b, cross_check=True)
    if len(rows) == 0:
        return np.zeros((0, 2), dtype=np.int64)
    ia, ib = rows[:, 0].astype(np.int64), rows[:, 1].astype(np.int64)
    disp = np.linalg.norm(kps_a[ia] - kps_b[ib], axis=1)
    ok = (disp < window) & (rows[:, 2] <= max_dist)
    out = np.stack([ia[ok], ib[ok]], axis=1)
    return out[np.argsort(out[:, 0], kind="stable")]


def search_by_bow(nodes_a: np.ndarray, desc_a: np.ndarray, nodes_b: np.ndarray, desc_b: np.ndarray, ratio: float,
                  max_dist: int) -> np.ndarray:
    """ORB-SLAM ``SearchByBoW`` between two keypoint sets: only keypoints under the same vocabulary node
    (feature-vector node, ``nodes_*``; -1 = left out) are compared; for each of a the nearest of b, kept when its
    Hamming distance is <= ``max_dist`` and below ``ratio`` x the second nearest. Returns (K, 3) int rows (index in a,
    index in b, distance), one-to-one on b (the smallest distance wins)."""
    ia = np.flatnonzero(nodes_a >= 0)
    ib = np.flatnonzero(nodes_b >= 0)
    ia = ia[np.argsort(nodes_a[ia], kind="stable")]
    ib = ib[np.argsort(nodes_b[ib], kind="stable")]
    da = np.ascontiguousarray(desc_a[ia], dtype=np.uint8).reshape(-1, 32).view(np.uint64)
    db = np.ascontiguousarray(desc_b[ib], dtype=np.uint8).reshape(-1, 32).view(np.uint64)
    best, dist = _bow_nearest(np.ascontiguousarray(nodes_a[ia]), da, np.ascontiguousarray(nodes_b[ib]), db,
                              float(ratio), int(max_dist))
    ok = best >= 0
    rows = np.stack([ia[ok], ib[best[ok]], dist[ok]], axis=1).astype(np.int64)
    keep = unique_by_target(rows[:, 0], rows[:, 1], rows[:, 2].astype(np.float64))
    rows = rows[keep]
    return rows[np.argsort(rows[:, 0], kind="stable")]


@njit(cache=True, nogil=True)
def _bow_nearest(na, da, nb, db, ratio, max_dist):
    n = na.shape[0]
    best = np.full(n, -1, np.int64)
    dist = np.zeros(n, np.int64)
    j0 = 0
    for i in range(n):
        while j0 < nb.shape[0] and nb[j0] < na[i]:
            j0 += 1
        b1, d1, d2 = -1, 1 << 20, 1 << 20
        j = j0
        while j < nb.shape[0] and nb[j] == na[i]:
            d = hamming_at(da, i, db, j)
            if d < d1:
                d2 = d1
                b1, d1 = j, d
            elif d < d2:
                d2 = d
            j += 1
        if b1 >= 0 and d1 <= max_dist and d1 < ratio * d2:
            best[i], dist[i] = b1, d1
    return best, dist
