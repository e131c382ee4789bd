"""Geometric module of D2SLAM (eq 4-6): fundamental matrix between frames t-1 and t, epipolar error, P_g.

    l = F q~                                      epipolar line of the previous keypoint q in frame t   (eq 4)
    err = |p~^T F q~| / sqrt(l_x^2 + l_y^2)       distance (px) of the current keypoint p to that line  (eq 5)
    err > alpha(z_p)  ->  dynamic, P_g = p_exceed (the paper: 1; ours: 0.7, see below)
    otherwise         ->  P_g = 1 - exp(-err^2 / (2 sigma^2))                                          (eq 6)

Deviation: the paper's P_g = 1 above alpha makes a single exceedance certain, and eq 8 then gives a belief of ~1
whatever the keypoint's history, so its map point is culled. With ORB keypoints at integer positions of their
pyramid level, alpha = 0.5-0.9 px is close to the noise floor of the test: correct static matches exceed it in a
sizeable share of frames. An exceedance is therefore evidence, not certainty: P_g = P(dynamic | err > alpha) with
equal priors = r_dyn / (r_dyn + r_static), r_dyn and r_static the shares of matched dynamic and static keypoints
that exceed alpha; ``OursConfig.p_g_exceed`` = 0.7 (1.0 restores the paper; measured: docs/deviations.md,
``OursConfig.p_g_exceed``).

Deviation (ours, ``OursConfig.noise_widening``): every threshold of this module (alpha(z) and eq 6's sigma, the
pose test's reprojection and depth thresholds) is widened in each frame to the noise of that frame's static
residuals, so that it is at least their ``noise_confidence`` (95 %) quantile (``widening``). alpha(z) keeps its
depth-adaptive shape; on a sensor whose static residuals are narrower the paper's values hold. Why: on real Kinect
frames the static residuals are wider than on the synthetic sensor and vary with the motion (blur, the depth image's
own capture time); the fixed thresholds flagged 30-80 % of static matches and tracking was lost (docs/real_data.md).

Eq 6 as printed is a Gaussian *density* of the error (largest at zero error); our reading
(docs/design.md#geometric-module-eq-4-6) makes it a probability of being dynamic that is 0 at zero error and grows
with the error, which is what eq 7 needs. Like alpha, its sigma is
taken at the keypoint's detection scale, sigma x 1.2^octave (``OursConfig.sigma_at_scale``; measured:
docs/deviations.md): otherwise a match below its scaled threshold could still get P_g > 0.5.

F is estimated by RANSAC (``cv2.findFundamentalMat``, FM_RANSAC, seeded with ``cv2.setRNGSeed``) on the matches
currently believed static (belief of the previous keypoint <= 0.5) when there are at least ``f_min_static_matches``
of them, else on all matches. With fewer than ``f_min_matches`` (8) usable matches, or when OpenCV finds no
(finite, 3x3) F, there is no F: P_g is undefined (NaN) and eq 7 treats every keypoint as *unmatched*.
A match whose epipolar line is degenerate (q at the epipole, l_x = l_y = 0) is unmatched as well.

Extension (ours, RGB-D; ``PoseTestConfig.enabled``): the pose test beside eq 5.

    (R, t)  = relative pose t-1 -> t: PnP-RANSAC (SQPnP) on the matches RANSAC used for F with a previous depth
    X'      = R X_q + t,  X_q the previous keypoint back-projected with its depth
    e_r     = |p - pi(X')|                                                  reprojection error, px  (pose_residuals)
    e_z     = (z_p - z_X') / sqrt(sigma(z_p)^2 + sigma(z_X')^2)             depth residual          (pose_residuals)
    e_r > pose_reproj_px 1.2^octave  or  |e_z| > pose_depth_sigmas  ->  dynamic, P_g = max(P_g, p_pose_exceed)

The epipolar error measures only the motion across the epipolar line; a point moving along its line (an object
carried away from or towards the camera, or sliding along the line under rotation) passes eq 5 whatever its speed;
the pose test sees that motion (measured: docs/deviations.md, ``PoseTestConfig.enabled``). Without a pose (fewer
than ``pnp_min_matches`` matches with a previous depth, or no PnP solution) the test is skipped and eq 5 decides
alone.
"""

from __future__ import annotations

from concurrent.futures import Executor
from dataclasses import dataclass
from functools import lru_cache

import cv2
import numpy as np

from scipy.special import gammaincinv

from d2slam.data.config import DepthNoise
from d2slam.dynamics.config import DynamicsConfig
from d2slam.dynamics.depth import depth_sigma, valid_depth
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
                       seed: int = 0) -> tuple[np.ndarray | None, np.ndarray]:
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
    cv2.setRNGSeed(int(seed))
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


def back_project(px: np.ndarray, z: np.ndarray, K: np.ndarray) -> np.ndarray:
    """(K, 3) camera-frame points of pixels ``px`` (K, 2) at depths ``z`` (K,) with intrinsics ``K`` (3, 3)."""
    px = np.asarray(px, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(z, dtype=np.float64).reshape(-1)
    K = np.asarray(K, dtype=np.float64)
    return np.stack([(px[:, 0] - K[0, 2]) / K[0, 0] * z, (px[:, 1] - K[1, 2]) / K[1, 1] * z, z], axis=1)


def relative_pose(X: np.ndarray, p: np.ndarray, K: np.ndarray, cfg: DynamicsConfig = _DEFAULT,
                  seed: int = 0) -> tuple[np.ndarray, np.ndarray] | None:
    """Pose test (ours): (R (3, 3), t (3,)) with p ~ K (R X + t), from 3-D points ``X`` (K, 3) of frame t-1 to their
    matched pixels ``p`` (K, 2) in frame t.

    ``cv2.solvePnPRansac`` with SQPnP (threshold ``pnp_ransac_px``, ``pnp_iterations``, ``pnp_confidence``; seeded
    with ``cv2.setRNGSeed``; OpenCV re-estimates the pose on the inliers). None with fewer than ``pnp_min_matches``
    points or inliers, or when OpenCV finds no finite pose."""
    X = np.ascontiguousarray(X, dtype=np.float64).reshape(-1, 3)
    p = np.ascontiguousarray(p, dtype=np.float64).reshape(-1, 2)
    need = max(cfg.pose_test.pnp_min_matches, 6)
    ok = np.all(np.isfinite(X), axis=1) & np.all(np.isfinite(p), axis=1)
    if not ok.all():
        X, p = np.ascontiguousarray(X[ok]), np.ascontiguousarray(p[ok])
    if len(X) < need:
        return None
    K = np.asarray(K, dtype=np.float64)
    cv2.setRNGSeed(int(seed))
    try:
        pt = cfg.pose_test
        found, rv, tv, inl = cv2.solvePnPRansac(X, p, K, None, iterationsCount=pt.pnp_iterations,
                                                reprojectionError=pt.pnp_ransac_px, confidence=pt.pnp_confidence,
                                                flags=cv2.SOLVEPNP_SQPNP)
    except cv2.error:  # degenerate point sets OpenCV refuses: no pose, eq 5 decides alone
        return None
    if not found or inl is None or len(inl) < need:
        return None
    R, _ = cv2.Rodrigues(rv)
    t = np.asarray(tv, dtype=np.float64).reshape(3)
    if not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
        return None
    return R, t


def pose_residuals(X: np.ndarray, p: np.ndarray, z: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray,
                   noise: DepthNoise = DepthNoise()) -> tuple[np.ndarray, np.ndarray]:
    """Pose test (ours): (reprojection error (K,) px, normalised depth residual (K,)) of points ``X`` (K, 3) of frame
    t-1 moved by (R, t), against their matches: pixels ``p`` (K, 2) and measured depths ``z`` (K,) in frame t. The depth
    residual is (z - z_pred) / sqrt(sigma(z)^2 + sigma(z_pred)^2) with sigma the camera's depth noise (``noise``). NaN
    where X is not finite or lies behind the camera; the depth residual also where z is invalid.

    Why: eq 5 cannot see a point that moves along its epipolar line (an object carried away from the camera, or slid
    along its lines under rotation); the reprojection and depth residuals of the relative pose do. A flag is evidence
    with the reliability P(dynamic | flagged), ``p_pose_exceed`` (measured: docs/deviations.md,
    ``PoseTestConfig.enabled`` and ``PoseTestConfig.p_pose_exceed``)."""
    X = np.asarray(X, dtype=np.float64).reshape(-1, 3)
    p = np.asarray(p, dtype=np.float64).reshape(-1, 2)
    z = np.asarray(z, dtype=np.float64).reshape(-1)
    K = np.asarray(K, dtype=np.float64)
    Xc = X @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64).reshape(3)
    with np.errstate(invalid="ignore", divide="ignore"):
        ok = Xc[:, 2] > 0  # False for NaN: X not finite
        zc = np.where(ok, Xc[:, 2], np.nan)
        reproj = np.hypot(K[0, 0] * Xc[:, 0] / zc + K[0, 2] - p[:, 0], K[1, 1] * Xc[:, 1] / zc + K[1, 2] - p[:, 1])
        z = np.where(valid_depth(z), z, np.nan)
        dres = (z - zc) / np.hypot(depth_sigma(z, noise), depth_sigma(zc, noise))
    return reproj, dres


def widening(r: np.ndarray, threshold: np.ndarray | float, dof: int, cfg: DynamicsConfig = _DEFAULT) -> float:
    """Noise widening (ours, ``OursConfig.noise_widening``): the factor kappa >= 1 by which a test's threshold
    grows so that it is at least the ``noise_confidence`` quantile of this frame's static residuals.

        sigma = median(r) / chi_dof^-1(0.5)                  the residuals' robust scale, r ~ sigma chi_dof if static
        kappa = max(1, sigma chi_dof^-1(noise_confidence) / median(threshold))

    ``r``: residuals of the matches F is fitted on (believed static), each in units of its keypoint's detection scale;
    ``threshold``: their thresholds in the same units (alpha(z), a fixed alpha, or a scalar); ``dof`` 1 for a distance
    to a line (eq 5) or a normalised depth residual, 2 for a reprojection error. 1 with fewer than
    ``f_min_static_matches`` finite residuals, or with ``noise_widening`` off (the paper).

    Why: alpha(z) (0.5-0.9 px) sits at the noise floor of a sharp sensor whose depth and colour are taken at the same
    instant. On a real Kinect the static residuals are wider and change from frame to frame with the motion (blur, the
    depth image's own capture time): a fixed threshold then flags most static matches of a fast frame and tracking is
    lost (measured: docs/real_data.md). Widened, a static match exceeds the threshold with about the same small
    probability in every frame, and the depth-adaptive shape of alpha(z) (eq 5) is kept."""
    if not cfg.ours.noise_widening:
        return 1.0
    r = np.asarray(r, dtype=np.float64)
    ok = np.isfinite(r)
    if int(ok.sum()) < cfg.f_min_static_matches:
        return 1.0
    th = float(np.median(np.broadcast_to(np.asarray(threshold, dtype=np.float64), r.shape)[ok]))
    if not th > 0:  # a test turned off (threshold 0) is not widened
        return 1.0
    return max(1.0, float(chi_quantile_over_median(cfg.ours.noise_confidence, dof) * np.median(r[ok]) / th))


@lru_cache(maxsize=None)
def chi_quantile_over_median(confidence: float, dof: int) -> float:
    """chi_dof^-1(confidence) / chi_dof^-1(0.5): the ``confidence`` quantile of a chi distribution in units of its
    median (1.96 / 0.674 = 2.91 for one degree of freedom)."""
    return float(np.sqrt(gammaincinv(dof / 2, confidence) / gammaincinv(dof / 2, 0.5)))  # chi2 = 2 Gamma(dof / 2)


@dataclass
class GeometricResult:
    F: np.ndarray | None  # (3, 3) or None (no F: every keypoint is treated as unmatched)
    n_used: int  # matches given to RANSAC
    used_static: bool  # True when only static-believed matches were used
    err: np.ndarray  # (N,) eq 5 epipolar error of each current keypoint, NaN when unmatched / no F
    p_g: np.ndarray  # (N,) eq 6, NaN when unobserved
    observed: np.ndarray  # (N,) bool: matched, F found and finite error (P_g defined)
    dynamic: np.ndarray  # (N,) bool: err > alpha(z), or the pose test's flag (the flag the OIM uses)
    # The pose test's outputs: None when it is not asked for (no depths or K, or ``pose_test`` off); when asked for,
    # arrays on every frame, NaN / False where it could not test (no F, no pose, unmatched keypoint).
    reproj_err: np.ndarray | None = None  # (N,) reprojection error (px)
    depth_err: np.ndarray | None = None  # (N,) normalised depth residual
    pose_dynamic: np.ndarray | None = None  # (N,) bool: the pose test's flag (observed keypoints only)
    # Noise widening (ours, ``widening``) of the thresholds of eq 5, the reprojection and the depth test; 1 = none.
    widening: tuple[float, float, float] = (1.0, 1.0, 1.0)


@dataclass
class PoseInputs:
    """What the pose test (ours) reads beside the matches: the keypoints' robust depths in both frames, (N,) and (M,),
    the intrinsics ``K``, the camera's depth noise, and where a depth was read across a depth edge (current (N,),
    previous (M,) bool: the depth residual is not tested there; None: nowhere)."""

    kp_depth: np.ndarray
    prev_kp_depth: np.ndarray
    K: np.ndarray
    noise: DepthNoise = DepthNoise()
    depth_edge: np.ndarray | None = None
    prev_depth_edge: np.ndarray | None = None

    def depths(self, n: int, n_prev: int) -> tuple[np.ndarray, np.ndarray]:
        """(current, previous) depths as float arrays; a clear error when their lengths differ from the keypoints'."""
        z_cur = np.asarray(self.kp_depth, dtype=np.float64).reshape(-1)
        z_prev = np.asarray(self.prev_kp_depth, dtype=np.float64).reshape(-1)
        if len(z_cur) != n or len(z_prev) != n_prev:
            raise D2SlamError(f"keypoint depths ({len(z_cur)}, {len(z_prev)}) do not match the keypoints ({n}, "
                              f"{n_prev})")
        return z_cur, z_prev

    def edges(self):
        """(current, previous) depth-edge flags, or None when either is not given."""
        return None if self.depth_edge is None or self.prev_depth_edge is None else (self.depth_edge,
                                                                                     self.prev_depth_edge)


def geometric_module(kps: np.ndarray, prev_kps: np.ndarray, matches: np.ndarray, prev_belief: np.ndarray,
                     a: np.ndarray, cfg: DynamicsConfig = _DEFAULT, seed: int = 0,
                     scale: np.ndarray | float = 1.0, fit: np.ndarray | None = None,
                     pose: PoseInputs | None = None, executor: Executor | None = None) -> GeometricResult:
    """eq 4-6 for the current keypoints ``kps`` (N, 2) given ``matches`` (K, 2) to ``prev_kps`` (M, 2).

    ``a`` (N,) is the threshold of each current keypoint (alpha(z_p), or ``fixed_alpha`` for the `geometric`
    ablation). Matches with non-finite coordinates are ignored. A previous belief that is NaN counts as the prior
    (0.5, static since "dynamic" means > 0.5). With ``pose`` given and ``cfg.pose_test.enabled``, the pose test
    (module docstring, :func:`pose_test`) runs on the matches that have eq 5's error, with the pose from the matches
    RANSAC used for F (those with a valid previous depth). ``scale`` (N,) or scalar is each keypoint's detection scale
    1.2^octave (``depth.octave_factor``), for eq 6's sigma and the reprojection threshold. ``fit`` (K,) bool: the
    matches F may be fitted on (default all; ``flow.flow_matches``). ``seed``: the RANSACs' (the run's seed).

    ``executor``: where the pose test's PnP-RANSAC runs while RANSAC fits F on the calling thread (None: after it, on
    the calling thread). The PnP needs the matches F is fitted on, not F, and OpenCV releases the GIL in both, so with
    a second core the two overlap; the results are the same (each RANSAC seeds its own thread's generator, and
    neither draws from it)."""
    kps = np.asarray(kps, dtype=np.float64).reshape(-1, 2)
    prev_kps = np.asarray(prev_kps, dtype=np.float64).reshape(-1, 2)
    n = len(kps)
    pose = pose if cfg.pose_test.enabled else None
    depths = pose.depths(n, len(prev_kps)) if pose is not None else None
    err = np.full(n, np.nan)
    res = GeometricResult(None, 0, False, err, np.full(n, np.nan), np.zeros(n, bool), np.zeros(n, bool))
    if depths is not None:
        res.reproj_err, res.depth_err, res.pose_dynamic = np.full(n, np.nan), np.full(n, np.nan), np.zeros(n, bool)
    m, fit = _finite_matches(kps, prev_kps, matches, fit)
    if len(m) == 0:
        return res
    p, q = kps[m[:, 0]], prev_kps[m[:, 1]]
    sel, res.used_static = _fit_set(m, prev_belief, fit, len(prev_kps), cfg)
    res.n_used = int(sel.sum())
    fitting = executor.submit(pose_fit, m, p, q, sel, depths[1], pose, cfg, seed) \
        if depths is not None and executor is not None else None
    res.F, _ = fundamental_matrix(q[sel], p[sel], cfg, seed)
    fitted = fitting.result() if fitting is not None else None
    if res.F is None:
        return res
    e_m = epipolar_error(res.F, p, q)
    err[m[:, 0]] = e_m
    a = np.broadcast_to(np.asarray(a, dtype=np.float64), (n,))
    scale = np.broadcast_to(np.asarray(scale, dtype=np.float64), (n,))
    s_fit = scale[m[sel, 0]]
    k_e = widening(e_m[sel] / s_fit, a[m[sel, 0]] / s_fit, 1, cfg)  # eq 5-6 at this frame's noise (ours)
    res.p_g, res.dynamic = geometric_probability(err, a * k_e, k_e * (cfg.sigma * scale if cfg.ours.sigma_at_scale
                                                                       else cfg.sigma), cfg.ours.p_g_exceed)
    res.observed = np.isfinite(err)
    res.widening = (k_e, 1.0, 1.0)
    if depths is not None:
        X, rt = fitted if fitted is not None else pose_fit(m, p, q, sel, depths[1], pose, cfg, seed)
        pose_test(res, m, p, sel, scale, depths[0], X, rt, pose, cfg)
    return res


def _finite_matches(kps: np.ndarray, prev_kps: np.ndarray, matches, fit) -> tuple[np.ndarray, np.ndarray]:
    """The checked matches (K', 2) whose two keypoints are finite, and their ``fit`` flags (default all True)."""
    m = check_matches(matches, len(kps), len(prev_kps))
    fit = np.ones(len(m), dtype=bool) if fit is None else np.asarray(fit, dtype=bool).reshape(-1)
    if len(fit) != len(m):
        raise D2SlamError(f"fit has {len(fit)} entries for {len(m)} matches")
    ok = np.isfinite(kps[m[:, 0]]).all(axis=1) & np.isfinite(prev_kps[m[:, 1]]).all(axis=1)
    return m[ok], fit[ok]


def _fit_set(m: np.ndarray, prev_belief, fit: np.ndarray, n_prev: int, cfg: DynamicsConfig) -> tuple[np.ndarray,
                                                                                                      bool]:
    """(the matches F is fitted on, whether they are the static-believed ones): the matches ``fit`` allows whose
    previous keypoint is believed static (a NaN belief counts as the prior), when there are at least
    ``f_min_static_matches`` of them, else every match ``fit`` allows."""
    pb = np.asarray(prev_belief, dtype=np.float64).reshape(-1)
    if len(pb) != n_prev:
        raise D2SlamError(f"prev_belief has {len(pb)} entries for {n_prev} previous keypoints")
    bel_q = pb[m[:, 1]]
    with np.errstate(invalid="ignore"):
        static = (np.where(np.isnan(bel_q), cfg.prior, bel_q) <= cfg.dynamic_threshold) & fit
    used_static = int(static.sum()) >= cfg.f_min_static_matches
    return (static if used_static else fit), used_static


def pose_fit(m: np.ndarray, p: np.ndarray, q: np.ndarray, sel: np.ndarray, z_prev: np.ndarray, pose: PoseInputs,
             cfg: DynamicsConfig = _DEFAULT, seed: int = 0) -> tuple[np.ndarray, tuple[np.ndarray, np.ndarray] | None]:
    """The pose test's (ours, module docstring) points and pose for the matches ``m`` (K, 2) with pixels ``p`` / ``q``:
    (X (K, 3), the previous keypoints back-projected with their depth ``z_prev`` (NaN rows without one); the relative
    pose by PnP (``relative_pose``) from the fit set ``sel`` with a previous depth, or None)."""
    zq = z_prev[m[:, 1]]
    has_z = valid_depth(zq)
    X = back_project(q, np.where(has_z, zq, np.nan), pose.K)
    return X, relative_pose(X[sel & has_z], p[sel & has_z], pose.K, cfg, seed)


def pose_test(res: GeometricResult, m: np.ndarray, p: np.ndarray, sel: np.ndarray, scale: np.ndarray,
              z_cur: np.ndarray, X: np.ndarray, rt: tuple[np.ndarray, np.ndarray] | None, pose: PoseInputs,
              cfg: DynamicsConfig = _DEFAULT) -> None:
    """The pose test (ours, module docstring) on the matches ``m`` (K, 2) with current pixels ``p``, filling ``res``:
    with the points ``X`` and the relative pose ``rt`` of ``pose_fit``, the residuals of every match, the flags
    (reprojection above ``pose_reproj_px`` x scale, depth residual above ``pose_depth_sigmas``, both widened to the
    frame's noise; the depth residual not tested where ``pose``'s depth-edge flags say a depth was read across an
    edge) on the observed keypoints, P_g raised to ``p_pose_exceed`` where flagged."""
    n = len(res.err)
    K, pc, edges = pose.K, cfg.pose_test, pose.edges()
    k_r = k_z = 1.0
    if rt is not None:
        r_m, z_m = pose_residuals(X, p, z_cur[m[:, 0]], rt[0], rt[1], K, pose.noise)
        res.reproj_err[m[:, 0]], res.depth_err[m[:, 0]] = r_m, z_m
        k_r = widening(r_m[sel] / scale[m[sel, 0]], pc.pose_reproj_px, 2, cfg)
        k_z = widening(np.abs(z_m[sel]), pc.pose_depth_sigmas, 1, cfg)
    flag = np.zeros(n, dtype=bool)
    with np.errstate(invalid="ignore"):
        if pc.pose_reproj_px > 0:
            flag |= res.reproj_err > pc.pose_reproj_px * scale * k_r
        if pc.pose_depth_sigmas > 0:
            dz_flag = np.abs(res.depth_err) > pc.pose_depth_sigmas * k_z
            if edges is not None:
                at_edge = np.asarray(edges[0], dtype=bool).copy()
                at_edge[m[:, 0]] |= np.asarray(edges[1], dtype=bool)[m[:, 1]]
                dz_flag &= ~at_edge
            flag |= dz_flag
    res.pose_dynamic = res.observed & flag
    res.p_g = np.where(res.pose_dynamic, np.maximum(res.p_g, pc.p_pose_exceed), res.p_g)
    res.dynamic = res.dynamic | res.pose_dynamic
    res.widening = (res.widening[0], k_r, k_z)
