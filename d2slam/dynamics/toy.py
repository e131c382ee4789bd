"""Small seeded two-view scenes for the dynamics tests and ``d2slam bench dynamics`` (not the synthetic benchmark).

A camera (TUM fr3 intrinsics) moves between frame t-1 and t in front of a smooth static depth field; person-like
ellipse masks at their own depths move sideways by a few centimetres (1 m/s at 30 fps); each keypoint of frame t is
back-projected with the true depth, moved with its object, and projected into frame t-1 with pixel noise to give
its match. Everything is vectorised and deterministic in ``seed``.
"""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.data.intrinsics import FREIBURG3
from d2slam.dynamics.depth import keypoint_depth
from d2slam.slam.config import OrbConfig
from d2slam.slam.hook import FilterInput

K_FR3 = FREIBURG3.K


def person_masks(shape: tuple[int, int], n: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """(n, H, W) bool ellipse "people" (about 120 x 340 px at 640x480) and their depths (n,) in [1.5, 3.5] m."""
    h, w = shape
    masks = np.zeros((n, h, w), dtype=bool)
    depths = rng.uniform(1.5, 3.5, n)
    for k in range(n):  # loop over people, not pixels
        img = np.zeros((h, w), np.uint8)
        cx = int(w * (k + 0.5) / max(n, 1) + rng.integers(-30, 30))
        cy = int(h * 0.55 + rng.integers(-20, 20))
        ax = int(w * 0.09 * 2.5 / depths[k])
        ay = int(h * 0.35 * 2.5 / depths[k])
        cv2.ellipse(img, (cx, cy), (ax, ay), 0, 0, 360, 1, -1)
        cv2.circle(img, (cx, cy - ay - ax // 2), max(ax // 2, 2), 1, -1)  # head
        masks[k] = img.astype(bool)
    return masks, depths


def _project(X: np.ndarray, K: np.ndarray) -> np.ndarray:
    y = X @ K.T
    return y[:, :2] / y[:, 2:3]


def two_view_scene(seed: int = 0, n_kps: int = 1000, n_matches: int = 800, n_persons: int = 2,
                   shape: tuple[int, int] = (480, 640), pixel_noise: float = 0.25,
                   person_speed: float = 0.035, frame_index: int = 1) -> tuple[FilterInput, np.ndarray]:
    """A FilterInput (masks = the true person masks) and the (N,) bool truth "on a moving person"."""
    rng = np.random.default_rng(seed)
    h, w = shape
    vv, uu = np.mgrid[0:h, 0:w].astype(np.float32)
    depth = (2.6 + 0.9 * np.sin(uu / 97.0 + rng.uniform(0, 6)) * np.cos(vv / 71.0)).astype(np.float32)
    masks, pdepth = person_masks(shape, n_persons, rng)
    owner = np.full((h, w), -1, np.int64)
    for k in range(n_persons):  # later people in front
        depth[masks[k]] = pdepth[k] + 0.05 * np.sin(uu[masks[k]] / 13.0)
        owner[masks[k]] = k
    holes = rng.random((h, w)) < 0.01
    depth[holes] = 0.0
    # Keypoints: a third on people when there are people, the rest anywhere.
    n_on = n_kps // 3 if n_persons else 0
    on_idx = np.flatnonzero(owner.ravel() >= 0)
    pick = rng.choice(on_idx, size=min(n_on, len(on_idx)), replace=False) if len(on_idx) else np.zeros(0, int)
    kps = np.concatenate([
        np.stack([pick % w, pick // w], axis=1) + rng.uniform(-0.5, 0.5, (len(pick), 2)),
        rng.uniform([0, 0], [w - 1, h - 1], (n_kps - len(pick), 2)),
    ]).astype(np.float32)
    kp_depth = keypoint_depth(depth, kps, OrbConfig().depth_patch_radius)
    pix = np.rint(kps).astype(np.int64)
    who = owner[pix[:, 1], pix[:, 0]]
    truth = who >= 0
    # Camera motion t-1 -> t (T_prev_cur) and person motion (in the current camera frame).
    R, _ = cv2.Rodrigues(rng.normal(0, 0.004, 3))
    t = rng.normal(0, 0.01, 3)
    v_person = np.column_stack([rng.choice([-1, 1], n_persons) * person_speed, rng.normal(0, 0.005, n_persons),
                                rng.normal(0, 0.01, n_persons)]) if n_persons else np.zeros((0, 3))
    z = np.where(kp_depth > 0, kp_depth, 2.5).astype(np.float64)
    Xc = np.column_stack([(kps[:, 0] - K_FR3[0, 2]) * z / K_FR3[0, 0], (kps[:, 1] - K_FR3[1, 2]) * z / K_FR3[1, 1], z])
    if n_persons:
        Xc = Xc - np.where(truth[:, None], v_person[np.maximum(who, 0)], 0.0)  # where the point was at t-1
    q = _project(Xc @ R.T + t, K_FR3) + rng.normal(0, pixel_noise, (n_kps, 2))
    # Previous frame: the matched keypoints (shuffled order) plus unmatched ones.
    n_matches = min(n_matches, n_kps)
    cur = np.sort(rng.choice(n_kps, n_matches, replace=False))
    n_prev = n_kps
    prev_order = rng.permutation(n_prev)[:n_matches]
    prev_kps = rng.uniform([0, 0], [w - 1, h - 1], (n_prev, 2)).astype(np.float32)
    prev_kps[prev_order] = q[cur]
    prev_depth = np.zeros(n_prev, np.float32)
    prev_depth[prev_order] = kp_depth[cur]
    prev_belief = np.full(n_prev, 0.5)
    prev_belief[prev_order] = np.where(truth[cur], 0.85, 0.15)
    matches = np.column_stack([cur, prev_order]).astype(np.int64)
    mp = np.full(n_kps, np.nan)
    inp = FilterInput(frame_index=frame_index, timestamp=frame_index / 30.0, gray=np.zeros(shape, np.uint8),
                      depth=depth, K=K_FR3.copy(), kps=kps, kp_depth=kp_depth, prev_kps=prev_kps,
                      prev_kp_depth=prev_depth, prev_belief=prev_belief, matches=matches, mappoint_belief=mp,
                      masks=masks if n_persons else None)
    return inp, truth
