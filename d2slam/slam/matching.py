"""Descriptor matching, vectorised: Hamming distance by XOR + popcount on uint8 descriptors, search by projection
with a k-d tree of keypoints (fixed-size candidate sets, no Python loop over points), ORB-SLAM's ratio test and
rotation-consistency histogram, and OpenCV brute-force matching for reference-keyframe tracking, relocalisation and
the filter's frame-to-frame matches."""

from __future__ import annotations

import cv2
import numpy as np
from scipy.spatial import cKDTree


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
    counts = np.bincount(idx, minlength=bins)
    order = np.argsort(-counts, kind="stable")[:3]
    top = counts[order]
    keep_bins = [order[0]]
    if top[1] >= 0.1 * top[0]:
        keep_bins.append(order[1])
        if top[2] >= 0.1 * top[0]:
            keep_bins.append(order[2])
    return np.isin(idx, keep_bins)


class KeypointIndex:
    """k-d trees over a frame's keypoints, one per pyramid level, queried with per-query radii and level windows
    (ORB-SLAM's ``GetFeaturesInArea(u, v, r, minLevel, maxLevel)``, vectorised per level: the k nearest keypoints
    *of each allowed level*, so crowded other levels never push the right candidate out of the set)."""

    def __init__(self, kps: np.ndarray, octave: np.ndarray | None = None):
        self.n = len(kps)
        self.tree = cKDTree(kps) if self.n else None
        self.levels: list[tuple[int, np.ndarray, cKDTree]] = []
        if self.n and octave is not None:
            for lv in np.unique(octave):
                members = np.flatnonzero(octave == lv)
                self.levels.append((int(lv), members, cKDTree(kps[members])))

    def candidates(self, uv: np.ndarray, radius: np.ndarray, k: int, lo: np.ndarray | None = None,
                   hi: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """(Q, K) candidate indices (``n`` = none) and their distances for queries ``uv`` within ``radius``; with
        level windows ``lo``/``hi`` (and per-level trees) the k nearest of every level in the window."""
        q = len(uv)
        if self.n == 0 or q == 0:
            return np.full((q, k), self.n, dtype=np.int64), np.full((q, k), np.inf)
        rmax = float(np.max(radius))
        if lo is None or not self.levels:
            kk = min(k, self.n)
            dist, idx = self.tree.query(uv, k=kk, distance_upper_bound=rmax)
            if kk == 1:
                dist, idx = dist[:, None], idx[:, None]
            bad = dist > radius[:, None]
            return np.where(bad, self.n, idx), dist
        blocks_i, blocks_d = [], []
        for lv, members, tree in self.levels:
            sel = np.flatnonzero((lo <= lv) & (hi >= lv))
            if len(sel) == 0:
                continue
            kk = min(k, len(members))
            dist, idx = tree.query(uv[sel], k=kk, distance_upper_bound=rmax)
            if kk == 1:
                dist, idx = dist[:, None], idx[:, None]
            ok = dist <= radius[sel, None]
            gi = np.full((q, kk), self.n, dtype=np.int64)
            gd = np.full((q, kk), np.inf)
            gi[sel] = np.where(ok, members[np.minimum(idx, len(members) - 1)], self.n)
            gd[sel] = np.where(ok, dist, np.inf)
            blocks_i.append(gi)
            blocks_d.append(gd)
        if not blocks_i:
            return np.full((q, 1), self.n, dtype=np.int64), np.full((q, 1), np.inf)
        idx, dist = np.concatenate(blocks_i, axis=1), np.concatenate(blocks_d, axis=1)
        keep = (idx < self.n).any(axis=0)  # drop all-empty columns
        if not keep.any():
            keep[0] = True
        return idx[:, keep], dist[:, keep]


def search_candidates(index: KeypointIndex, uv: np.ndarray, radius: np.ndarray, q_desc: np.ndarray,
                      kp_desc: np.ndarray, kp_octave: np.ndarray, min_level: np.ndarray, max_level: np.ndarray,
                      available: np.ndarray, k: int, extra_ok: np.ndarray | None = None,
                      cand: np.ndarray | None = None):
    """Best and second-best candidate per query: returns (best_idx (-1 none), best_dist, second_dist,
    best_level, second_level). ``available`` (N,) bool masks keypoints that may be matched; ``extra_ok`` (Q, k)
    optional additional per-candidate test (e.g. the virtual-right coordinate check); ``cand`` precomputed
    ``index.candidates(uv, radius, k)[0]``."""
    q = len(uv)
    idx = index.candidates(uv, radius, k)[0] if cand is None else cand
    n = index.n
    valid = idx < n
    safe = np.where(valid, idx, 0)
    if n:
        lvl = kp_octave[safe]
        valid &= available[safe] & (lvl >= min_level[:, None]) & (lvl <= max_level[:, None])
    if extra_ok is not None:
        valid &= extra_ok
    if q == 0 or n == 0:
        empty = np.full(q, -1, dtype=np.int64)
        return empty, np.full(q, 1 << 20), np.full(q, 1 << 20), empty, empty
    d = hamming(kp_desc[safe], q_desc[:, None, :])
    d = np.where(valid, d, 1 << 20)
    order = np.argsort(d, axis=1, kind="stable")
    rows = np.arange(q)
    b1 = order[:, 0]
    best_dist = d[rows, b1]
    best_idx = np.where(best_dist < (1 << 20), idx[rows, b1], -1)
    if d.shape[1] > 1:
        b2 = order[:, 1]
        second_dist = d[rows, b2]
        second_level = np.where(second_dist < (1 << 20), kp_octave[safe[rows, b2]], -1)
    else:
        second_dist = np.full(q, 1 << 20)
        second_level = np.full(q, -1)
    best_level = np.where(best_idx >= 0, kp_octave[np.maximum(best_idx, 0)], -1)
    return best_idx, best_dist, second_dist, best_level, second_level


def search_by_projection(target, uv: np.ndarray, ur_proj: np.ndarray, radius: np.ndarray, lo: np.ndarray,
                         hi: np.ndarray, desc: np.ndarray, available: np.ndarray, k: int):
    """ORB-SLAM ``SearchByProjection``'s candidate search, shared by every projection search: best and second-best
    keypoint of ``target`` (a frame: ``kps``, ``octave``, ``desc``, ``ur``, ``kp_index``) for each projected point
    ``uv`` with descriptor ``desc``: candidates within ``radius`` on levels [lo, hi], ``available``, and consistent
    in ``u_R`` (no check where the projected ``ur_proj`` is NaN: a point without depth). Returns what
    :func:`search_candidates` returns."""
    index = target.kp_index
    cand, _ = index.candidates(uv, radius, k, lo, hi)
    safe = np.minimum(cand, max(len(target.kps) - 1, 0))
    stereo_ok = np.isnan(ur_proj)[:, None] | (target.ur[safe] < 0) | \
        (np.abs(ur_proj[:, None] - target.ur[safe]) < radius[:, None])
    return search_candidates(index, uv, radius, desc, target.desc, target.octave, lo, hi, available, k,
                             extra_ok=stereo_ok, cand=cand)


def unique_by_target(query: np.ndarray, target: np.ndarray, dist: np.ndarray) -> np.ndarray:
    """Boolean mask keeping, for every target index, only the query with the smallest distance (one-to-one)."""
    if len(query) == 0:
        return np.zeros(0, dtype=bool)
    order = np.lexsort((dist, target))
    first = np.r_[True, target[order][1:] != target[order][:-1]]
    keep = np.zeros(len(query), dtype=bool)
    keep[order[first]] = True
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
