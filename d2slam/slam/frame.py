"""Frames: bucketed ORB features (ORB-SLAM settings), per-keypoint depth and the RGB-D "virtual stereo" coordinate.

ORB-SLAM distributes features over the image with a per-level quadtree and re-runs FAST at 7 in cells where the
20 threshold finds nothing. Our equivalent: OpenCV's ORB detects ``oversample`` times more corners
than needed at FAST 20 (plus FAST 7 when the image yields fewer than ``n_features`` corners at 20), the corners
are binned in a grid per pyramid level (cells ``cell_size * scale^level`` pixels), and the features are taken
round-robin over cells by decreasing Harris response (each cell's best, then each cell's second best, ...) until
the level's ORB-SLAM quota ``n_l ∝ scale^-l`` is filled (a compiled kernel). Only the kept corners get a descriptor.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from operator import attrgetter

import cv2
import numpy as np
from numba import njit

from d2slam.data.base import Camera
from d2slam.slam.config import EngineConfig, OrbConfig
from d2slam.slam.depth import keypoint_depth
from d2slam.slam.matching import Gridded, bucket_order


@dataclass
class Frame(Gridded):
    """One tracked frame (arrays indexed by keypoint). ``Tcw`` is world-to-camera (ORB-SLAM convention)."""

    index: int
    timestamp: float
    kps: np.ndarray  # (N, 2) float64 undistorted pixel coordinates
    kps_raw: np.ndarray  # (N, 2) float64 detected (distorted) coordinates
    octave: np.ndarray  # (N,) int
    angle: np.ndarray  # (N,) float32 degrees
    desc: np.ndarray  # (N, 32) uint8
    depth: np.ndarray  # (N,) float64 metres, 0 = invalid
    ur: np.ndarray  # (N,) float64 virtual right coordinate u - bf/z for close points, -1 otherwise
    inv_sigma2: np.ndarray  # (N,) 1 / scale^(2 octave)
    mp: np.ndarray = field(default=None)  # (N,) int map point id, -1 none
    outlier: np.ndarray = field(default=None)  # (N,) bool
    belief: np.ndarray | None = None  # (N,) dynamic belief from the hook (None: no filter)
    Tcw: np.ndarray | None = None
    ref_kf: int = -1  # reference keyframe of a tracked frame (ORB-SLAM mpReferenceKF) ...
    Tcr: np.ndarray | None = None  # ... and the frame's pose relative to it
    grids: dict = field(default_factory=dict, repr=False)  # cell size -> KeypointGrid (``Gridded.grid``)

    def __post_init__(self):
        n = len(self.kps)
        if self.mp is None:
            self.mp = np.full(n, -1, dtype=np.int64)
        if self.outlier is None:
            self.outlier = np.zeros(n, dtype=bool)

    @property
    def n(self) -> int:
        return len(self.kps)

    @property
    def dynamic(self) -> np.ndarray:
        if self.belief is None:
            return np.zeros(self.n, dtype=bool)
        return self.belief > 0.5


def level_quotas(orb: OrbConfig, n_features: int | None = None) -> np.ndarray:
    """ORB-SLAM's features per level: geometric with ratio 1/scale, summing to ``n_features`` (default
    ``orb.n_features``)."""
    n = orb.n_features if n_features is None else int(n_features)
    f = 1.0 / orb.scale_factor
    n0 = n * (1 - f) / (1 - f ** orb.n_levels)
    q = np.round(n0 * f ** np.arange(orb.n_levels)).astype(int)
    q[-1] = max(n - q[:-1].sum(), 0)
    return q


def bucket_select(pts: np.ndarray, level: np.ndarray, response: np.ndarray, orb: OrbConfig,
                  width: int, height: int, n_features: int | None = None) -> np.ndarray:
    """Indices of the kept corners (ascending): per level, round-robin over grid cells by decreasing response. The
    corners of each cell are ranked by decreasing response (equal responses: by index); each level then takes its
    cells' first corners, then their second, ... (within one round by decreasing response, then by cell, then by
    index) until its quota is filled (``_round_robin``). ``level`` must lie in [0, ``orb.n_levels``)."""
    if len(pts) == 0:
        return np.zeros(0, dtype=np.int64)
    level = np.asarray(level, dtype=np.int64)
    if level.min() < 0 or level.max() >= orb.n_levels:
        raise ValueError(f"keypoint levels must lie in [0, {orb.n_levels}), got [{level.min()}, {level.max()}]")
    quotas = level_quotas(orb, n_features)
    cell = orb.cell_size * orb.scale_factor ** level.astype(np.float64)
    ncols = np.ceil(width / cell).astype(np.int64)
    cx = np.minimum((pts[:, 0] / cell).astype(np.int64), ncols - 1)
    cy = (pts[:, 1] / cell).astype(np.int64)
    cells, cell_of = np.unique((level << 32) | (cy * ncols + cx), return_inverse=True)  # ordered by (level, cell)
    return _round_robin(cell_of.astype(np.int64).reshape(-1), len(cells), level,
                        np.ascontiguousarray(response, dtype=np.float64), quotas.astype(np.int64))


@njit(cache=True, nogil=True)
def _round_robin(cell, n_cells, level, response, quotas):
    """``bucket_select``'s choice given each corner's cell (``cell`` (N,), dense ids ordered by level): a counting
    sort by cell with an insertion sort by decreasing response in each (cells hold a few corners), then per level
    the rounds (rank in the cell) in turn, whole while they fit in the quota, the last one by decreasing response."""
    n = len(cell)
    order, start = bucket_order(cell, n_cells)  # corners by cell, then (below) by decreasing response, then index
    rank = np.empty(n, np.int64)  # of order[j] in its cell
    rounds = 0
    for c in range(n_cells):
        a, b = start[c], start[c + 1]
        for j in range(a + 1, b):
            k, t = order[j], j
            while t > a and response[order[t - 1]] < response[k]:
                order[t] = order[t - 1]
                t -= 1
            order[t] = k
        for j in range(a, b):
            rank[j] = j - a
        rounds = max(rounds, b - a)
    gstart = np.zeros(len(quotas) * rounds + 1, np.int64)  # positions j grouped by (level, rank), j ascending
    for j in range(n):
        gstart[level[order[j]] * rounds + rank[j] + 1] += 1
    for g in range(len(quotas) * rounds):
        gstart[g + 1] += gstart[g]
    gfill = gstart[:-1].copy()
    pos = np.empty(n, np.int64)
    for j in range(n):
        g = level[order[j]] * rounds + rank[j]
        pos[gfill[g]] = j
        gfill[g] += 1
    keep = np.zeros(n, np.bool_)
    for lv in range(len(quotas)):
        left = quotas[lv]
        for r in range(rounds):
            a, b = gstart[lv * rounds + r], gstart[lv * rounds + r + 1]
            if left <= 0:
                break
            if b - a <= left:
                for t in range(a, b):
                    keep[order[pos[t]]] = True
                left -= b - a
            else:  # the last round: by decreasing response, then position (stable)
                grp = pos[a:b]
                best = np.argsort(-response[order[grp]], kind="mergesort")
                for t in range(left):
                    keep[order[grp[best[t]]]] = True
                left = 0
    return np.flatnonzero(keep)


class OrbExtractor:
    """Bucketed ORB with ORB-SLAM's settings; returns arrays (no per-keypoint Python objects kept)."""

    def __init__(self, orb: OrbConfig, engine: EngineConfig, camera: Camera):
        self.cfg = orb
        self.engine = engine
        self.camera = camera
        n_detect = int(orb.n_features * orb.oversample)

        def make(th):
            return cv2.ORB_create(nfeatures=n_detect, scaleFactor=orb.scale_factor, nlevels=orb.n_levels,
                                  edgeThreshold=orb.edge_threshold, firstLevel=0, WTA_K=2,
                                  scoreType=cv2.ORB_HARRIS_SCORE, patchSize=orb.patch_size, fastThreshold=th)

        self._orb_high = make(orb.fast_threshold)
        self._orb_low = make(orb.fast_min_threshold)
        self.scales = orb.scale_factor ** np.arange(orb.n_levels)
        self.inv_level_sigma2 = 1.0 / self.scales ** 2
        self.th_depth_m = close_depth(camera, engine)

    def detect(self, gray: np.ndarray, n_features: int):
        n_detect = int(n_features * self.cfg.oversample)
        for orb in (self._orb_high, self._orb_low):
            orb.setMaxFeatures(n_detect)
        kps = self._orb_high.detect(gray, None)
        if len(kps) < n_features:
            kps = self._orb_low.detect(gray, None)
        return kps

    def __call__(self, gray: np.ndarray, depth: np.ndarray, index: int = 0, timestamp: float = 0.0,
                 n_features: int | None = None) -> Frame:
        h, w = gray.shape[:2]
        n_features = self.cfg.n_features if n_features is None else int(n_features)
        kps = self.detect(gray, n_features)
        if kps:
            pts, response, octave = keypoint_fields(kps, "response", "octave")
            keep = bucket_select(pts, octave.astype(np.int64), response, self.cfg, w, h, n_features)
            kps = [kps[i] for i in keep]
        desc = None
        if kps:
            kps, desc = self._orb_high.compute(gray, kps)
        if not kps or desc is None:
            return empty_frame(index, timestamp)
        raw, octave, angle = keypoint_fields(kps, "octave", "angle")
        octave = octave.astype(np.int64)
        angle = angle.astype(np.float32)
        pts = undistort(raw, self.camera)
        z = keypoint_depth(depth, raw, self.cfg.depth_patch_radius).astype(np.float64)
        z[(z < self.engine.min_depth) | (z > self.engine.max_depth)] = 0.0  # outside the sensor's range: no depth
        ur = virtual_right(pts[:, 0], z, self.camera.bf,
                           np.inf if self.engine.stereo_far_points else self.th_depth_m)
        return Frame(index=index, timestamp=timestamp, kps=pts, kps_raw=raw, octave=octave, angle=angle,
                     desc=np.ascontiguousarray(desc), depth=z, ur=ur, inv_sigma2=self.inv_level_sigma2[octave])


def keypoint_fields(kps, *names: str) -> tuple[np.ndarray, ...]:
    """The positions (N, 2) of OpenCV keypoints and their fields ``names`` (N,), all float64 (exact: OpenCV keeps
    them as float32 or int). One pass per field over the keypoints: reading them into one array of tuples costs
    three times more."""
    pts = np.asarray(cv2.KeyPoint_convert(kps), dtype=np.float64).reshape(-1, 2)
    return (pts, *(np.fromiter(map(attrgetter(f), kps), np.float64, len(kps)) for f in names))


def empty_frame(index: int, timestamp: float) -> Frame:
    z = np.zeros(0)
    return Frame(index=index, timestamp=timestamp, kps=np.zeros((0, 2)), kps_raw=np.zeros((0, 2)),
                 octave=np.zeros(0, dtype=np.int64), angle=np.zeros(0, dtype=np.float32),
                 desc=np.zeros((0, 32), dtype=np.uint8), depth=z, ur=z.copy(), inv_sigma2=z.copy())


def undistort(pts: np.ndarray, camera: Camera) -> np.ndarray:
    """Undistorted pixel coordinates (identity when the camera has no distortion)."""
    if not camera.has_distortion or len(pts) == 0:
        return pts.copy()
    out = cv2.undistortPoints(pts.reshape(-1, 1, 2).astype(np.float64), camera.K, np.asarray(camera.dist),
                              P=camera.K)
    return out.reshape(-1, 2)


def close_depth(camera: Camera, engine: EngineConfig) -> float:
    """ORB-SLAM's close-point depth ``th_depth * b`` with baseline ``b = bf / fx`` (40 * 40 / 535.4 ≈ 3 m)."""
    return engine.th_depth * camera.bf / camera.fx


def virtual_right(u: np.ndarray, z: np.ndarray, bf: float, th_depth_m: float) -> np.ndarray:
    """``u_R = u - bf / z`` for keypoints with depth below ``th_depth_m`` (stereo edges); -1 marks the others
    (monocular edges), as ORB-SLAM's ``mvuRight < 0``. ORB-SLAM's ``ComputeStereoFromRGBD`` sets ``u_R`` for every
    valid depth (``th_depth_m = inf``, ``EngineConfig.stereo_far_points``); with it off only close points
    (``th_depth * b``) get stereo edges."""
    close = (z > 0) & (z < th_depth_m)
    ur = np.full(len(u), -1.0)
    ur[close] = u[close] - bf / z[close]
    return ur
