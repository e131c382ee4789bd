"""Geometric module of D2SLAM (eq 4-6): fundamental matrix between frames t-1 and t, epipolar error, P_g.

    l = F q~                                      epipolar line of the previous keypoint q in frame t   (eq 4)
    err = |p~^T F q~| / sqrt(l_x^2 + l_y^2)       distance (px) of the current keypoint p to that line  (eq 5)
    err > alpha(z_p)  ->  dynamic, P_g = p_exceed (the paper: 1; ours: 0.7, measured, see below)
    otherwise         ->  P_g = 1 - exp(-err^2 / (2 sigma^2))                                          (eq 6)

Deviation (measured): the paper's P_g = 1 above alpha makes a single exceedance certain, and eq 8 then gives a
belief of ~1 whatever the keypoint's history, so its map point is culled. With ORB keypoints at integer positions
of their pyramid level, alpha = 0.5-0.9 px is close to the noise floor of the test: against the ground-truth F the
error of correct static matches at level 0 has median 0.29 px and 90th percentile 0.91 px, and with the RANSAC F
23-35 % of matched static keypoints exceed alpha in a frame (62-76 % of matched dynamic ones), on synthetic dev
seed 3. An exceedance is therefore evidence, not certainty: P_g = P(dynamic | err > alpha) with equal priors
= r_dyn / (r_dyn + r_static) = 0.68-0.73, ``DynamicsConfig.p_g_exceed`` = 0.7 (1.0 restores the paper). Measured on
the four walking scenarios (dev seed 3, 300 frames, d2slam): frames tracked 121 / 300 / 87 / 300 with 1.0 and
153 / 300 / 156 / 300 with 0.7 (xyz / static / rpy / halfsphere), keypoint precision 0.36 / 0.18 / 0.32 / 0.34 ->
0.41 / 0.20 / 0.37 / 0.38 at about the same recall (0.87 / 0.76 / 0.90 / 0.86 -> 0.87 / 0.75 / 0.89 / 0.86).

Eq 6 as printed is a Gaussian *density* of the error (largest at zero error); DESIGN.md reads it as a probability
of being dynamic that is 0 at zero error and grows with the error, which is what eq 7 needs.

F is estimated by RANSAC (``cv2.findFundamentalMat``, FM_RANSAC, seeded with ``cv2.setRNGSeed``) on the matches
currently believed static (belief of the previous keypoint <= 0.5) when there are at least ``f_min_static_matches``
of them, else on all matches. With fewer than ``f_min_matches`` (8) usable matches, or when OpenCV finds no
(finite, 3x3) F, there is no F: P_g is undefined (NaN) and eq 7 treats every keypoint as *unmatched*.
A match whose epipolar line is degenerate (q at the epipole, l_x = l_y = 0) is unmatched as well.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from d2slam.config import DynamicsConfig
from d2slam.errors import D2SlamError

_DEFAULT = DynamicsConfig()
# RANSAC flavours of cv2.findFundamentalMat (DynamicsConfig.f_ransac_method).
_METHODS = {"ransac": cv2.FM_RANSAC, "magsac": cv2.USAC_MAGSAC, "usac_accurate": cv2.USAC_ACCURATE}


def check_matches(matches: np.ndarray, n_cur: int, n_prev: int) -> np.ndarray:
    """(K, 2) int64 matches (current index, previous index); a clear error when indices are out of range."""
    m = np.asarray(matches)
    if m.size == 0:
        return np.zeros((0, 2), dtype=np.int64)
    if m.ndim != 2 or m.shape[1] != 2:
        raise D2SlamError(f"matches must be a (K, 2) array of (current, previous) indices, got shape {m.shape}")
    m = m.astype(np.int64, copy=False)
    lo, hi = m.min(axis=0), m.max(axis=0)
    if lo[0] < 0 or hi[0] >= n_cur or lo[1] < 0 or hi[1] >= n_prev:
        raise D2SlamError(f"match indices out of range ({n_cur} current and {n_prev} previous keypoints)")
    return m


def fundamental_matrix(q: np.ndarray, p: np.ndarray, cfg: DynamicsConfig = _DEFAULT,
                       seed: int | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """eq 4: F with p~^T F q~ = 0 from matched pixels ``q`` (frame t-1) and ``p`` (frame t), (K, 2) each.

    RANSAC (OpenCV FM_RANSAC, threshold ``f_ransac_threshold_px``, confidence, max iterations from the config),
    seeded with ``cv2.setRNGSeed(seed)`` before the call so the result is deterministic. Returns (F or None, (K,) bool
    inliers). None when there are fewer than ``f_min_matches`` points, or OpenCV returns no finite 3x3 matrix.
    """
    q = np.ascontiguousarray(q, dtype=np.float64).reshape(-1, 2)
    p = np.ascontiguousarray(p, dtype=np.float64).reshape(-1, 2)
    k = len(q)
    none = (None, np.zeros(k, dtype=bool))
    if k < max(cfg.f_min_matches, 8):
        return none
    if cfg.f_ransac_method not in _METHODS:
        raise D2SlamError(f"unknown f_ransac_method {cfg.f_ransac_method!r}; choose one of {', '.join(_METHODS)}")
    cv2.setRNGSeed(int(cfg.f_ransac_seed if seed is None else seed))
    try:
        F, inl = cv2.findFundamentalMat(q, p, _METHODS[cfg.f_ransac_method], cfg.f_ransac_threshold_px,
                                        cfg.f_ransac_confidence, cfg.f_ransac_max_iters)
    except cv2.error:  # degenerate configurations OpenCV refuses (documented: no F)
        return none
    if F is None or F.shape != (3, 3) or not np.all(np.isfinite(F)):
        return none
    return F, (inl.reshape(-1) != 0) if inl is not None else np.ones(k, dtype=bool)


def epipolar_error(F: np.ndarray, p: np.ndarray, q: np.ndarray) -> np.ndarray:
    """eq 5: distance (px) of each current point ``p`` to the epipolar line l = F q~ of its previous match ``q``.

    (K, 2) arrays -> (K,) errors; NaN where the line is degenerate (l_x = l_y = 0)."""
    p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
    q = np.asarray(q, dtype=np.float64).reshape(-1, 2)
    qh = np.concatenate([q, np.ones((len(q), 1))], axis=1)
    ph = np.concatenate([p, np.ones((len(p), 1))], axis=1)
    lines = qh @ np.asarray(F, dtype=np.float64).T  # rows l = F q~   (eq 4)
    num = np.abs(np.einsum("ij,ij->i", ph, lines))
    den = np.hypot(lines[:, 0], lines[:, 1])
    with np.errstate(divide="ignore", invalid="ignore"):
        return np.where(den > 1e-12, num / den, np.nan)


def geometric_probability(err: np.ndarray, a: np.ndarray, sigma: float = 1.0,
                          p_exceed: float = 1.0) -> tuple[np.ndarray, np.ndarray]:
    """eq 5-6: (P_g, dynamic) from epipolar errors ``err`` and thresholds ``a`` (alpha(z) or a fixed value).

    dynamic = err > a -> P_g = ``p_exceed`` (the paper: 1; the config's 0.7, see the module docstring); otherwise
    P_g = 1 - exp(-err^2 / (2 sigma^2)). NaN errors give NaN, not dynamic."""
    err = np.asarray(err, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        dyn = err > a
        p = np.where(dyn, p_exceed, -np.expm1(-(err ** 2) / (2.0 * sigma ** 2)))
    return p, dyn


@dataclass
class GeometricResult:
    F: np.ndarray | None  # (3, 3) or None (no F: every keypoint is treated as unmatched)
    n_used: int  # matches given to RANSAC
    used_static: bool  # True when only static-believed matches were used
    err: np.ndarray  # (N,) eq 5 epipolar error of each current keypoint, NaN when unmatched / no F
    p_g: np.ndarray  # (N,) eq 6, NaN when unobserved
    observed: np.ndarray  # (N,) bool: matched, F found and finite error (P_g defined)
    dynamic: np.ndarray  # (N,) bool: err > alpha(z) (the flag the OIM uses)


def geometric_module(kps: np.ndarray, prev_kps: np.ndarray, matches: np.ndarray, prev_belief: np.ndarray,
                     a: np.ndarray, cfg: DynamicsConfig = _DEFAULT, seed: int | None = None) -> GeometricResult:
    """eq 4-6 for the current keypoints ``kps`` (N, 2) given ``matches`` (K, 2) to ``prev_kps`` (M, 2).

    ``a`` (N,) is the threshold of each current keypoint (alpha(z_p), or ``fixed_alpha`` for the `geometric`
    ablation). Matches with non-finite coordinates are ignored. A previous belief that is NaN counts as the prior
    (0.5, static since "dynamic" means > 0.5)."""
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    prev_kps = np.asarray(prev_kps, dtype=np.float64).reshape(-1, 2)
    n = len(kps)
    m = check_matches(matches, n, len(prev_kps))
    err = np.full(n, np.nan)
    empty = GeometricResult(None, 0, False, err, np.full(n, np.nan), np.zeros(n, bool), np.zeros(n, bool))
    if len(m) == 0:
        return empty
    p, q = kps[m[:, 0]], prev_kps[m[:, 1]]
    ok = np.isfinite(p[:, 0]) & np.isfinite(p[:, 1]) & np.isfinite(q[:, 0]) & np.isfinite(q[:, 1])
    if not ok.all():
        m, p, q = m[ok], p[ok], q[ok]
    pb = np.asarray(prev_belief, dtype=np.float64).reshape(-1)
    if len(pb) != len(prev_kps):
        raise D2SlamError(f"prev_belief has {len(pb)} entries for {len(prev_kps)} previous keypoints")
    bel_q = pb[m[:, 1]]
    with np.errstate(invalid="ignore"):
        static = np.where(np.isnan(bel_q), cfg.prior, bel_q) <= cfg.dynamic_threshold  # NaN belief = the prior
    used_static = int(static.sum()) >= cfg.f_min_static_matches
    sel = static if used_static else np.ones(len(m), dtype=bool)
    F, _ = fundamental_matrix(q[sel], p[sel], cfg, seed)
    if F is None:
        empty.n_used, empty.used_static = int(sel.sum()), used_static
        return empty
    err[m[:, 0]] = epipolar_error(F, p, q)
    a = np.broadcast_to(np.asarray(a, dtype=np.float64), (n,))
    p_g, dyn = geometric_probability(err, a, cfg.sigma, cfg.p_g_exceed)
    return GeometricResult(F, int(sel.sum()), used_static, err, p_g, np.isfinite(err), dyn)
