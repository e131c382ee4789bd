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
from d2slam.slam.config import OrbConfig, SlamConfig
from d2slam.slam.frame import Frame
from d2slam.slam.map import Map
from d2slam.slam.matching import rotation_consistent, search_by_projection, unique_by_target, window_cross_match
from d2slam.slam.projection import EPS_Z, Projector

_ORB = OrbConfig()


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
    # the geometric module to express alpha(z) at the keypoint's detection scale (OursConfig.alpha_at_scale).
    octave: np.ndarray | None = None
    # (H, W) uint8 grey image of the previous frame, None on the first frame or when it came as stored features. Used
    # by the optional flow correspondences of the geometric module (FlowConfig, d2slam.dynamics.flow).
    prev_gray: np.ndarray | None = None
    # (H, W) depth image (metres) of the previous frame, None on the first frame: the depth of the flow's new matches
    # for the pose test (FlowConfig.flow_new_depth; the flow itself needs ``prev_gray``).
    prev_depth: np.ndarray | None = None
    # Where the keypoints are in the images (detected, distorted pixel coordinates), (N, 2) and (M, 2), for whatever
    # reads the images, the depth maps or the masks at a keypoint; ``kps`` and ``prev_kps`` are undistorted, for
    # geometry. None when the camera has no lens distortion (then they are ``kps`` and ``prev_kps``).
    kps_px: np.ndarray | None = None
    prev_kps_px: np.ndarray | None = None
    # The camera (its lens distortion turns image positions into the undistorted coordinates of ``kps``; its depth
    # noise scales the pose test's depth residual).
    camera: Camera | None = None
    # How the engine measured the keypoints: its pyramid's scale (an octave k is scale_factor^k px wide at level 0)
    # and the patch its robust keypoint depth is the median of ((2 r + 1)^2 pixels).
    scale_factor: float = _ORB.scale_factor
    depth_patch_radius: int = _ORB.depth_patch_radius
    # The run's seed (EngineConfig.seed): the filter's RANSACs draw from it.
    seed: int = 0

    def pixels(self) -> tuple[np.ndarray, np.ndarray]:
        """(current, previous) keypoints where they are in the images: ``kps_px`` and ``prev_kps_px``, or the
        keypoints themselves for a camera without distortion."""
        return (self.kps if self.kps_px is None else self.kps_px,
                self.prev_kps if self.prev_kps_px is None else self.prev_kps_px)


class KeypointFilter(Protocol):
    """Anything callable on a FilterInput returning (N,) float beliefs in [0, 1] (dynamic probability)."""
    def __call__(self, inp: FilterInput) -> np.ndarray: ...
    def reset(self) -> None: ...


@dataclass
class HookFrame:
    """A frame as the hook sees it: the engine's features of it and the images they came from (``gray`` None when the
    frame came as stored features; ``depth`` None when none was given)."""

    frame: Frame
    gray: np.ndarray | None
    depth: np.ndarray | None


class FilterHook:
    """Calls a keypoint filter on each frame: frame-to-frame matches of all keypoints, the previous frame's
    keypoints, beliefs and images, the beliefs of the map points the matches lead to; writes ``frame.belief``.
    ``last_input`` is the last ``FilterInput`` (for notebooks and benchmarks)."""

    def __init__(self, keypoint_filter: KeypointFilter, proj: Projector, config: SlamConfig):
        self.filter = keypoint_filter
        self.proj = proj
        self.cfg = config.engine
        self.orb = config.orb
        self.last_input: FilterInput | None = None

    def reset(self) -> None:
        self.filter.reset()
        self.last_input = None

    def __call__(self, current: HookFrame, masks: np.ndarray | None, prev: HookFrame | None, map_: Map,
                 velocity: np.ndarray | None) -> None:
        """``prev``: the last processed frame (None on the first); ``masks``: the current frame's person masks;
        ``velocity``: the motion model's prediction T_frame_prev when ``prev`` is the last tracked frame (for guided
        matching), else None."""
        frame = current.frame
        inp = self.filter_input(current, masks, prev, map_, velocity)
        belief = np.asarray(self.filter(inp), dtype=np.float64)
        n = frame.n
        if belief.shape != (n,) or not np.all(np.isfinite(belief)) or belief.min(initial=0) < 0 or \
                belief.max(initial=0) > 1:
            raise D2SlamError(f"frame {frame.index}: the keypoint filter returned beliefs of shape {belief.shape} "
                              f"(expected ({n},) finite values in [0, 1])")
        frame.belief = belief
        self.last_input = inp

    def filter_input(self, current: HookFrame, masks, prev: HookFrame | None, map_: Map, velocity) -> FilterInput:
        """The filter's input for ``current`` against ``prev`` (see ``__call__``)."""
        frame, camera = current.frame, self.proj.camera
        p = prev.frame if prev is not None else None
        if p is None or p.n == 0 or frame.n == 0:
            matches = np.zeros((0, 2), dtype=np.int64)
            prev_kps, prev_kp_depth = np.zeros((0, 2), np.float32), np.zeros(0, np.float32)
            prev_px = prev_kps
            prev_belief = np.zeros(0)
        else:
            matches = self.matches(frame, p, velocity)
            prev_kps, prev_kp_depth = p.kps.astype(np.float32), p.depth.astype(np.float32)
            prev_px = p.kps_raw.astype(np.float32)
            prev_belief = p.belief if p.belief is not None else np.full(p.n, 0.5)
        distorted = camera.has_distortion
        return FilterInput(frame_index=frame.index, timestamp=frame.timestamp, gray=current.gray, depth=current.depth,
                           K=self.proj.K, kps=frame.kps.astype(np.float32), kp_depth=frame.depth.astype(np.float32),
                           prev_kps=prev_kps, prev_kp_depth=prev_kp_depth, prev_belief=np.asarray(prev_belief),
                           matches=matches, mappoint_belief=_mappoint_belief(frame, p, matches, map_), masks=masks,
                           octave=frame.octave, prev_gray=prev.gray if prev is not None else None,
                           prev_depth=prev.depth if prev is not None else None,
                           kps_px=frame.kps_raw.astype(np.float32) if distorted else None,
                           prev_kps_px=prev_px if distorted else None, camera=camera,
                           scale_factor=self.orb.scale_factor, depth_patch_radius=self.orb.depth_patch_radius,
                           seed=self.cfg.seed)

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


def _mappoint_belief(frame: Frame, prev: Frame | None, matches: np.ndarray, map_: Map) -> np.ndarray:
    """(N,) the belief of the live map point each current keypoint's match observed in ``prev``, NaN where none."""
    mp_belief = np.full(frame.n, np.nan)
    if len(matches) and prev is not None:
        pm = prev.mp[matches[:, 1]]
        has = pm >= 0
        alive = np.zeros(len(pm), dtype=bool)
        alive[has] = map_.points.alive[pm[has]]
        mp_belief[matches[alive, 0]] = map_.points.belief[pm[alive]]
    return mp_belief


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
