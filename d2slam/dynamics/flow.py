"""Sub-pixel correspondences for eq 4-6 by pyramidal Lucas-Kanade flow (ours; ``FlowConfig.enabled``).

    q_i = LK(I_t -> I_{t-1}) of keypoint p_i, started at its match q_j (or at p_i when unmatched)
    q_i kept when LK(I_{t-1} -> I_t) of q_i, started at q_i + p_i - q_j, returns within flow_fb_px of p_i
                                                                                     (forward-backward check)
    z(q_i) = robust depth of D_{t-1} at q_i for an unmatched p_i (new match), so the pose test runs on it
                                                                                     (flow_new_depth)

Eq 5 measures the distance of p to the epipolar line of its correspondence q. With ORB matches both p and q are FAST
corners at integer positions of their pyramid levels, so even a correct static match is off by about a pixel, which is
alpha's own size. The tracked position is sub-pixel: far fewer correct static matches exceed alpha, while dynamic ones
still do. LK also finds a correspondence for many keypoints the descriptor matching missed, which is where most of the
missed dynamic keypoints are (measured: docs/deviations.md, ``FlowConfig.enabled``). Notebook 03 shows the default
settings (11 x 11 window, 10 iterations) on a short sequence.

Without a depth a new match has eq 5 alone, which cannot see an object carried along its epipolar lines; with the
previous depth image's robust depth at q_i (``flow_new_depth``) the RGB-D pose test runs on it too (measured:
docs/deviations.md, ``FlowConfig.flow_new_depth``).

The cost is the flow itself (``d2slam bench dynamics --sequence DIR --method d2slam-flow`` prints it apart; figures
in docs/deviations.md, ``FlowConfig.enabled``). It tracks only the keypoints ``flow_area`` uses (LK tracks each
point on its own, so the others' tracks do not change). So it is an extension beside the paper's modules, outside
their 3 ms budget.
"""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.depth import keypoint_depth
from d2slam.errors import D2SlamError
from d2slam.slam.config import OrbConfig

_DEFAULT = DynamicsConfig()
FLOW_AREAS = ("all", "matched", "outside")  # FlowConfig.flow_area


def check_flow_area(area: str) -> str:
    if area not in FLOW_AREAS:
        raise D2SlamError(f"unknown flow_area {area!r}; choose one of {', '.join(FLOW_AREAS)}")
    return area


def flow_keypoints(in_area: np.ndarray, matches: np.ndarray, area: str) -> np.ndarray:
    """(N,) bool: the keypoints the flow tracks under ``FlowConfig.flow_area``; the others keep their ORB match.
    "all" tracks every keypoint; "matched" skips the unmatched keypoints in a mask area (``in_area``, eq 7's inside
    or uncertain); "outside" skips every keypoint in a mask area."""
    track = ~np.asarray(in_area, dtype=bool)
    if check_flow_area(area) == "all":
        track[:] = True
    elif area == "matched":
        track[np.asarray(matches, dtype=np.int64).reshape(-1, 2)[:, 0]] = True
    return track


def flow_correspondences(gray: np.ndarray, prev_gray: np.ndarray, kps: np.ndarray, prev_kps: np.ndarray,
                         matches: np.ndarray, cfg: DynamicsConfig = _DEFAULT,
                         track: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) position in ``prev_gray`` of each current keypoint ``kps`` (N, 2) of ``gray``, NaN where the flow
    failed (LK status, forward-backward check, non-finite keypoint) or was not asked for (``track`` (N,) bool, default
    all; ``flow_keypoints``). ``matches`` (K, 2) rows (current, previous) start the matched keypoints at their match
    in ``prev_kps``; the others start at their own position. LK tracks each point on its own, so leaving keypoints
    out does not change the others' tracks."""
    gray, prev_gray = np.asarray(gray), np.asarray(prev_gray)
    if gray.shape != prev_gray.shape or gray.ndim != 2:
        raise D2SlamError(f"flow needs two grey images of one size, got {gray.shape} and {prev_gray.shape}")
    kps = np.asarray(kps, dtype=np.float32).reshape(-1, 2)
    n = len(kps)
    q = np.full((n, 2), np.nan)
    use = np.isfinite(kps).all(axis=1)  # the keypoints to track
    if track is not None:
        track = np.asarray(track, dtype=bool).reshape(-1)
        if len(track) != n:
            raise D2SlamError(f"flow: track has {len(track)} entries for {n} keypoints")
        use &= track
    if not use.any():
        return q
    start = kps.copy()
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    if len(m):
        start[m[:, 0]] = np.asarray(prev_kps, dtype=np.float32).reshape(-1, 2)[m[:, 1]]
    bad_start = ~np.isfinite(start).all(axis=1)
    start[bad_start] = kps[bad_start]
    idx = np.flatnonzero(use)
    p0 = kps[idx].reshape(-1, 1, 2)
    fc = cfg.flow
    win = (int(fc.flow_window), int(fc.flow_window))
    crit = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, int(fc.flow_iterations), float(fc.flow_epsilon))
    q1, s1, _ = cv2.calcOpticalFlowPyrLK(gray, prev_gray, p0, start[idx].reshape(-1, 1, 2).copy(), winSize=win,
                                         maxLevel=int(fc.flow_levels), criteria=crit,
                                         flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    # backward, started at the forward track moved back by the start's offset (the match's motion, reversed)
    back = (q1.reshape(-1, 2) + (kps[idx] - start[idx])).reshape(-1, 1, 2)
    p1, s2, _ = cv2.calcOpticalFlowPyrLK(prev_gray, gray, q1, back, winSize=win, maxLevel=int(fc.flow_levels),
                                         criteria=crit, flags=cv2.OPTFLOW_USE_INITIAL_FLOW)
    q1, p1 = q1.reshape(-1, 2), p1.reshape(-1, 2)
    ok = (s1.reshape(-1) == 1) & (s2.reshape(-1) == 1) & np.isfinite(q1).all(axis=1)
    with np.errstate(invalid="ignore"):
        ok &= np.hypot(*(p1 - kps[idx]).T) <= fc.flow_fb_px
    q[idx[ok]] = q1[ok]
    return q


def flow_matches(q: np.ndarray, prev_kps: np.ndarray, prev_kp_depth: np.ndarray, prev_belief: np.ndarray,
                 matches: np.ndarray, prev_depth: np.ndarray | None = None, cfg: DynamicsConfig = _DEFAULT,
                 shape: tuple[int, int] | None = None, q_px: np.ndarray | None = None,
                 radius: int = OrbConfig().depth_patch_radius
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The geometric module's inputs with the flow's correspondences ``q`` (N, 2) (``flow_correspondences``) and the
    validated ``matches`` (K, 2) (``geometric.check_matches``).

    A matched keypoint that tracked takes its tracked position in place of its match's (the previous keypoint keeps
    its belief and depth). An unmatched keypoint that tracked becomes a match to a new previous point at its tracked
    position, with no belief (NaN) and not used to fit F (``fit`` False). Its depth is the robust depth of the
    previous depth image ``prev_depth`` (H, W) at the tracked position (``depth.keypoint_depth`` over the engine's patch
    ``radius``, ``FilterInput.depth_patch_radius``), so the pose test
    runs on it, when ``cfg.flow.flow_new_depth`` is on and the image is given; 0 (no pose test) otherwise. ``shape`` is
    the grey images' (H, W): a ``prev_depth`` of another size (or not 2-D) is a clear error, not silent 0 depths.
    ``q_px``: the tracked positions in the image, where the depth is read, when ``q`` holds them undistorted (a
    camera with lens distortion; default ``q``). Returns (prev_kps, prev_kp_depth, prev_belief, matches, fit (K',) bool, tracked (N,) bool)."""
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    if prev_depth is not None:
        prev_depth = np.asarray(prev_depth)
        if prev_depth.ndim != 2 or (shape is not None and prev_depth.shape != tuple(shape)):
            raise D2SlamError(f"the previous depth image has shape {prev_depth.shape}, the grey images "
                              f"{tuple(shape) if shape is not None else '(a 2-D image)'}; they must be one size")
    prev_kps = np.asarray(prev_kps, dtype=np.float64).reshape(-1, 2).copy()
    m = np.asarray(matches, dtype=np.int64).reshape(-1, 2)
    tracked = np.isfinite(q).all(axis=1)
    refine = m[tracked[m[:, 0]]]
    prev_kps[refine[:, 1]] = q[refine[:, 0]]
    is_matched = np.zeros(len(q), dtype=bool)
    is_matched[m[:, 0]] = True
    new = np.flatnonzero(tracked & ~is_matched)
    n_prev = len(prev_kps)
    q_px = q if q_px is None else np.asarray(q_px, dtype=np.float64).reshape(-1, 2)
    new_z = keypoint_depth(prev_depth, q_px[new], radius) \
        if prev_depth is not None and cfg.flow.flow_new_depth else np.zeros(len(new))
    prev_kps = np.concatenate([prev_kps, q[new]])
    prev_depth_kp = np.concatenate([np.asarray(prev_kp_depth, dtype=np.float64).reshape(-1), new_z])
    prev_belief = np.concatenate([np.asarray(prev_belief, dtype=np.float64).reshape(-1), np.full(len(new), np.nan)])
    matches = np.concatenate([m, np.stack([new, n_prev + np.arange(len(new))], axis=1)])
    fit = np.arange(len(matches)) < len(m)
    return prev_kps, prev_depth_kp, prev_belief, matches, fit, tracked
