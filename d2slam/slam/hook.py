"""The engine's only contact with dynamics: one keypoint-filter hook, called once per frame.

The engine computes frame-to-frame descriptor matches for *all* keypoints (not only mapped ones), builds a
``FilterInput`` and calls the hook before tracking. The hook returns a per-keypoint dynamic belief in [0, 1];
keypoints above ``EngineConfig.mappoint_belief_threshold`` (0.5) take no part in pose optimisation and create no
map points; the belief is written to the map points they observe, and map points above 0.5 are culled.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol

import numpy as np

from d2slam.data.base import Camera
from d2slam.errors import D2SlamError
from d2slam.slam.config import EngineConfig
from d2slam.slam.frame import Frame
from d2slam.slam.map import Map
from d2slam.slam.matching import rotation_consistent, search_by_projection, unique_by_target, window_cross_match
from d2slam.slam.projection import EPS_Z, Projector


@dataclass
class FilterInput:
    frame_index: int
    timestamp: float
    gray: np.ndarray | None  # (H, W) uint8; None when the run reads stored features (d2slam.slam.features)
    depth: np.ndarray  # (H, W) float32 metres, 0 = invalid
    K: np.ndarray  # (3, 3)
    kps: np.ndarray  # (N, 2) float32 pixel coordinates (u, v) of the current keypoints (level-0 image)
    kp_depth: np.ndarray  # (N,) float32 metres, 0 = invalid (robust per-keypoint depth used by the engine)
    prev_kps: np.ndarray  # (M, 2) keypoints of the previous frame ((0, 2) on the first frame)
    prev_kp_depth: np.ndarray  # (M,)
    prev_belief: np.ndarray  # (M,) beliefs the hook returned for the previous frame
    matches: np.ndarray  # (K, 2) int: rows (current index, previous index), one-to-one
    mappoint_belief: np.ndarray  # (N,) belief carried by the map point each keypoint was associated to, NaN if none
    masks: np.ndarray | None  # (n, H, W) bool person masks, or None when the run has no segmenter
    # (N,) int pyramid level (ORB octave) of each current keypoint, or None when the engine does not give it. Used by
    # the geometric module to express alpha(z) at the keypoint's detection scale (DynamicsConfig.alpha_octave_scale).
    octave: np.ndarray | None = None
    # (H, W) uint8 grey image of the previous frame, None on the first frame or when it came as stored features. Used
    # by the optional flow correspondences of the geometric module (DynamicsConfig.flow, d2slam.dynamics.flow).
    prev_gray: np.ndarray | None = None
    # (H, W) depth image (metres) of the previous frame, None on the first frame: the depth of the flow's new matches
    # for the pose test (DynamicsConfig.flow_new_depth; the flow itself needs ``prev_gray``).
    prev_depth: np.ndarray | None = None
    # Where the keypoints are in the images (detected, distorted pixel coordinates), (N, 2) and (M, 2), for whatever
    # reads the images, the depth maps or the masks at a keypoint; ``kps`` and ``prev_kps`` are undistorted, for
    # geometry. None when the camera has no lens distortion (then they are ``kps`` and ``prev_kps``).
    kps_px: np.ndarray | None = None
    prev_kps_px: np.ndarray | None = None
    # The camera (its lens distortion turns image positions into the undistorted coordinates of ``kps``).
    camera: Camera | None = None

    def pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """(current, previous) keypoints where they are in the images: ``kps_px`` and ``prev_kps_px``, or the
        keypoints themselves for a camera without distortion."""
        return (self.kps if self.kps_px is None else self.kps_px,
                self.prev_kps if self.prev_kps_px is None else self.prev_kps_px)


class KeypointFilter(Protocol):
    """Anything callable on a FilterInput returning (N,) float beliefs in [0, 1] (dynamic probability)."""
    def __call__(self, inp: FilterInput) -> np.ndarray: ...
    def reset(self) -> None: ...


class FilterHook:
    """Calls a keypoint filter on each frame: frame-to-frame matches of all keypoints, the previous frame's
    keypoints, beliefs and images, the beliefs of the map points the matches lead to; writes ``frame.belief``.
    ``last_input`` is the last ``FilterInput`` (for notebooks and benchmarks)."""

    def __init__(self, keypoint_filter: KeypointFilter, proj: Projector, cfg: EngineConfig):
        self.filter = keypoint_filter
        self.proj = proj
        self.cfg = cfg
        self.last_input: FilterInput | None = None

    def reset(self) -> None:
        self.filter.reset()
        self.last_input = None

    def __call__(self, frame: Frame, gray, depth, masks, prev: Frame | None, prev_gray, prev_depth, map_: Map,
                 velocity: np.ndarray | None, prev_tracked: bool) -> None:
        """``prev``: the last processed frame (None on the first), with its images; ``velocity``: the motion model's
        prediction T_frame_prev, usable for guided matching when ``prev_tracked`` (``prev`` is the last tracked
        frame)."""
        n = frame.n
        camera = self.proj.camera
        if prev is None or prev.n == 0 or n == 0:
            matches = np.zeros((0, 2), dtype=np.int64)
            prev_kps, prev_kp_depth = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
            prev_px = prev_kps
            prev_belief = np.zeros(0)
        else:
            matches = self.matches(frame, prev, velocity if prev_tracked else None)
            prev_kps, prev_kp_depth = prev.kps.astype(np.float32), prev.depth.astype(np.float32)
            prev_px = prev.kps_raw.astype(np.float32)
            prev_belief = prev.belief if prev.belief is not None else np.full(prev.n, 0.5)
        mp_belief = np.full(n, np.nan)
        if len(matches) and prev is not None:
            pm = prev.mp[matches[:, 1]]
            has = pm >= 0
            alive = np.zeros(len(pm), dtype=bool)
            alive[has] = map_.points.alive[pm[has]]
            mp_belief[matches[alive, 0]] = map_.points.belief[pm[alive]]
        inp = FilterInput(frame_index=frame.index, timestamp=frame.timestamp, gray=gray, depth=depth, K=self.proj.K,
                          kps=frame.kps.astype(np.float32), kp_depth=frame.depth.astype(np.float32),
                          prev_kps=prev_kps, prev_kp_depth=prev_kp_depth, prev_belief=np.asarray(prev_belief),
                          matches=matches, mappoint_belief=mp_belief, masks=masks, octave=frame.octave,
                          prev_gray=prev_gray if prev is not None else None,
                          prev_depth=prev_depth if prev is not None else None,
                          kps_px=frame.kps_raw.astype(np.float32) if camera.has_distortion else None,
                          prev_kps_px=prev_px if camera.has_distortion else None, camera=camera)
        belief = np.asarray(self.filter(inp), dtype=np.float64)
        if belief.shape != (n,) or not np.all(np.isfinite(belief)) or belief.min(initial=0) < 0 or \
                belief.max(initial=0) > 1:
            raise D2SlamError(f"frame {frame.index}: the keypoint filter returned beliefs of shape {belief.shape} "
                              f"(expected ({n},) finite values in [0, 1])")
        frame.belief = belief
        self.last_input = inp

    def matches(self, frame: Frame, prev: Frame, velocity: np.ndarray | None) -> np.ndarray:
        """(K, 2) one-to-one matches (keypoint of ``frame``, keypoint of ``prev``) given to the filter.

        Guided (ORB-SLAM ``SearchByProjection`` applied to keypoints instead of map points): when ``prev`` was tracked
        and the constant-velocity model predicts the frame's pose (``velocity``), every previous keypoint is moved by
        that motion (back-projected with its depth; at infinity, i.e. rotated only, without depth) and searched
        within ``filter_match_radius`` x scale on its level +-1: best Hamming <= ``desc_th_high`` with the ratio test
        and the orientation check. The unguided mutual-nearest matching within ``filter_match_window`` is the
        fallback (first frames, after a loss, or fewer than ``filter_guided_min_matches`` guided matches)."""
        cfg = self.cfg
        if cfg.filter_match_guided and velocity is not None and prev.Tcw is not None and prev.n and frame.n:
            m = self.guided_matches(frame, prev, velocity)
            if len(m) >= cfg.filter_guided_min_matches:
                return m
        return window_cross_match(frame.kps, frame.desc, prev.kps, prev.desc, cfg.filter_match_window,
                                  cfg.desc_th_high)

    def guided_matches(self, frame: Frame, prev: Frame, V: np.ndarray) -> np.ndarray:
        cfg, proj = self.cfg, self.proj
        z = prev.depth.astype(np.float64)
        has = z > 0
        K = proj.K
        rays = np.stack([(prev.kps[:, 0] - K[0, 2]) / K[0, 0], (prev.kps[:, 1] - K[1, 2]) / K[1, 1], np.ones(prev.n)],
                        axis=1)
        X = rays * np.where(has, z, 1.0)[:, None]
        Xn = X @ V[:3, :3].T + np.where(has[:, None], V[:3, 3], 0.0)
        u, v, zn = proj.pixels(Xn)
        zs = np.where(zn > EPS_Z, zn, EPS_Z)
        sel = np.flatnonzero((zn > EPS_Z) & proj.in_image(u, v))
        if len(sel) == 0:
            return np.zeros((0, 2), dtype=np.int64)
        uv = np.stack([u[sel], v[sel]], axis=1)
        octv = prev.octave[sel]
        radius = cfg.filter_match_radius * proj.scales[octv]
        ur_proj = np.where(has[sel], u[sel] - proj.bf / zs[sel], np.nan)  # NaN: no depth, no u_R check
        available = (frame.mp < 0) & ~frame.dynamic
        best, d1, d2, l1, l2 = search_by_projection(frame.grid(cfg.search_grid_cell), uv, ur_proj, radius, octv - 1,
                                                    octv + 1, prev.desc[sel], available)
        ok = (best >= 0) & (d1 <= cfg.desc_th_high) & ~((l1 == l2) & (d1 > cfg.filter_match_nn_ratio * d2))
        cur, pv, dist = best[ok], sel[ok], d1[ok]
        keep = unique_by_target(pv, cur, dist.astype(np.float64))
        cur, pv = cur[keep], pv[keep]
        if cfg.check_orientation and len(cur):
            rot = rotation_consistent(prev.angle[pv], frame.angle[cur], cfg.rotation_histogram_bins)
            cur, pv = cur[rot], pv[rot]
        out = np.stack([cur, pv], axis=1).astype(np.int64)
        return out[np.argsort(out[:, 0], kind="stable")]


def update_point_beliefs(map_: Map, frame: Frame, threshold: float) -> None:
    """Map points take the belief of the keypoint that observes them; above ``threshold`` they are culled."""
    if frame.belief is None:
        return
    sel = np.flatnonzero(frame.mp >= 0)
    pts = frame.mp[sel]
    map_.points.belief[pts] = frame.belief[sel]
    bad = frame.belief[sel] > threshold
    if bad.any():
        map_.cull_points(np.unique(pts[bad]))
        frame.mp[sel[bad]] = -1
