"""ORB-SLAM's motion-only BA and local BA with its edge model (mono ``(u, v)`` and RGB-D stereo ``(u, v, u_R)``
observations, Huber kernels at sqrt(chi2 95 %), Levenberg-Marquardt), by default with the compiled kernels of
:mod:`d2slam.slam.lm`, or (``EngineConfig.optimizer = "g2o"``) with g2o (the ``g2opy`` wheel) and ORB-SLAM's own
edge types (``EdgeSE3ProjectXYZOnlyPose`` mono, ``EdgeStereoSE3ProjectXYZ`` stereo (the binding of the pose-only
stereo edge does not expose its intrinsics, so a fixed point vertex stands in for ``Xw``), ``EdgeSE3ProjectXYZ``).
``d2slam bench engine --compare-optimisers`` runs the same local-BA problem through both and gtsam.

Residual checks between outlier rounds are computed in numpy on all edges at once (no per-edge Python calls).
"""

from __future__ import annotations

import g2opy as g2o
import numpy as np
from scipy.sparse import coo_matrix, identity
from scipy.sparse.linalg import spsolve
from scipy.spatial.transform import Rotation

from d2slam.slam import lm
from d2slam.slam.config import EngineConfig


def _se3(Tcw: np.ndarray) -> "g2o.SE3Quat":
    return g2o.SE3Quat(np.ascontiguousarray(Tcw[:3, :3]), np.ascontiguousarray(Tcw[:3, 3]))


def _mat(se3) -> np.ndarray:
    return np.asarray(se3.matrix(), dtype=np.float64)


_KEEP_ALIVE: dict = {}  # terminate actions must outlive the call that registers them


def _optimizer(dense: bool, gain_threshold: float = 0.0):
    opt = g2o.SparseOptimizer()
    linear = g2o.LinearSolverDenseSE3() if dense else g2o.LinearSolverEigenSE3()
    opt.set_algorithm(g2o.OptimizationAlgorithmLevenberg(g2o.BlockSolverSE3(linear)))
    if gain_threshold > 0:  # stop a round once the relative chi2 decrease falls below the threshold
        term = g2o.SparseOptimizerTerminateAction()
        term.set_gain_threshold(gain_threshold)
        opt.add_post_iteration_action(term)
        _KEEP_ALIVE[id(opt)] = term
    return opt


def stereo_information(inv_sigma2: float, disparity_sigma: float) -> np.ndarray:
    """3x3 information of a stereo observation ``(u, v, u_R)``. ``disparity_sigma`` 0: ORB-SLAM's
    ``I * inv_sigma2`` (u_R as noisy as a stereo match). > 0 (RGB-D): ``u_R = u - bf / z`` is computed from the
    keypoint's own ``u``, so it carries u's error plus the depth sensor's disparity error ``disparity_sigma`` (px);
    the information of that model makes ``r^T I r = (r_u^2 + r_v^2) * inv_sigma2 + (r_u - r_uR)^2 /
    disparity_sigma^2``: the keypoint's position at its level's sigma, its disparity ``bf / z`` at the sensor's."""
    info = np.eye(3) * inv_sigma2
    if disparity_sigma > 0:
        w = 1.0 / disparity_sigma ** 2
        info[0, 0] += w
        info[0, 2] = info[2, 0] = -w
        info[2, 2] = w
    return info


def _infos(inv_sigma2: np.ndarray, disparity_sigma: float = 0.0) -> tuple[list, list]:
    """Information matrices per observation, built once per distinct value (one per pyramid level)."""
    vals, inv = np.unique(inv_sigma2, return_inverse=True)
    i2 = [np.eye(2) * v for v in vals]
    i3 = [stereo_information(v, disparity_sigma) for v in vals]
    return [i2[k] for k in inv], [i3[k] for k in inv]


def _edge_setup(uv: np.ndarray, ur: np.ndarray, inv_sigma2: np.ndarray, cfg: EngineConfig):
    """What both optimisations build their edges from: one Huber kernel per edge type (chi2 95 % thresholds),
    shared by the edges (g2o holds kernels by shared_ptr: fewer Python calls, and dropping the kernel is one call),
    the information matrices, the stereo flag (``u_R >= 0``) and the stereo measurements ``(u, v, u_R)``."""
    k_mono = g2o.RobustKernelHuber(np.sqrt(cfg.chi2_mono))
    k_stereo = g2o.RobustKernelHuber(np.sqrt(cfg.chi2_stereo))
    info2, info3 = _infos(inv_sigma2, cfg.disparity_sigma_px)
    return k_mono, k_stereo, info2, info3, ur >= 0, np.column_stack([uv, ur])


def _g2o_edge(e, measurement, information, kernel, intrinsics: tuple, bf: float | None = None):
    """A g2o projection edge ``e`` with its measurement, information, robust kernel, intrinsics (fx, fy, cx, cy) and,
    for a stereo edge, ``bf``; its vertices are the caller's."""
    e.set_measurement(measurement)
    e.set_information(information)
    if bf is not None:
        e.bf = bf
    e.set_robust_kernel(kernel)
    e.fx, e.fy, e.cx, e.cy = intrinsics
    return e


def reprojection_chi2(Tcw: np.ndarray, X: np.ndarray, uv: np.ndarray, ur: np.ndarray, inv_sigma2: np.ndarray,
                      K: np.ndarray, bf: float, disparity_sigma: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Chi2 of every observation (stereo where ``ur >= 0``, with the information of ``stereo_information``) and
    whether the point is in front of the camera."""
    Xc = X @ Tcw[:3, :3].T + Tcw[:3, 3]
    z = Xc[:, 2]
    zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
    u = K[0, 0] * Xc[:, 0] / zs + K[0, 2]
    v = K[1, 1] * Xc[:, 1] / zs + K[1, 2]
    return stereo_chi2(uv[:, 0] - u, uv[:, 1] - v, ur - (u - bf / zs), ur >= 0, inv_sigma2, disparity_sigma), z > 0


def image_chi2(Tcw: np.ndarray, X: np.ndarray, uv: np.ndarray, inv_sigma2: np.ndarray,
               K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Chi2 of the image part ``(u, v)`` of observations (each with its own pose: ``Tcw`` (M, 4, 4), points ``X``
    (M, 3)), whatever their depth says, and whether the point is in front of the camera."""
    Xc = np.einsum("nij,nj->ni", Tcw[:, :3, :3], X) + Tcw[:, :3, 3]
    z = Xc[:, 2]
    zs = np.where(np.abs(z) < 1e-9, 1e-9, z)
    du = uv[:, 0] - (K[0, 0] * Xc[:, 0] / zs + K[0, 2])
    dv = uv[:, 1] - (K[1, 1] * Xc[:, 1] / zs + K[1, 2])
    return (du ** 2 + dv ** 2) * inv_sigma2, z > 0


def stereo_chi2(du, dv, dur, stereo, inv_sigma2, disparity_sigma: float = 0.0):
    """``r^T I r`` for residuals (du, dv, du_R) with the information of ``stereo_information`` (du_R ignored where
    ``stereo`` is False: a monocular observation). Broadcasts."""
    e2 = (du ** 2 + dv ** 2) * inv_sigma2
    if disparity_sigma > 0:
        extra = (du - dur) ** 2 / disparity_sigma ** 2
    else:
        extra = dur ** 2 * inv_sigma2
    return e2 + np.where(stereo, extra, 0.0)


class _G2oPoseRounds:
    """The rounds of :func:`pose_optimization` with a g2o graph: one pose vertex, ORB-SLAM's edge types (fixed points
    for the stereo edges), one Huber kernel per edge type; outliers are switched off by edge level, the kernel
    dropped by an infinite delta (the binding has no null kernel)."""

    def __init__(self, Tcw, X, uv, ur, inv_sigma2, K, bf, cfg: EngineConfig, coarse: bool):
        m = len(X)
        self.cfg = cfg
        self.opt = _optimizer(dense=True, gain_threshold=cfg.tracking.pose_opt_gain_threshold)
        self.vpose = g2o.VertexSE3Expmap()
        self.vpose.set_estimate(_se3(Tcw))
        self.vpose.set_id(0)
        self.opt.add_vertex(self.vpose)
        fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
        self.kernels = _edge_setup(uv, ur, inv_sigma2, cfg)
        k_mono, k_stereo, info2, info3, self.stereo, meas3 = self.kernels
        self.info_fine, self.fine = info3, not coarse
        if coarse:  # the first rounds with ORB-SLAM's isotropic information
            info3 = _infos(inv_sigma2)[1]
        self.edges = []
        for i in range(m):
            if self.stereo[i]:
                vp = g2o.VertexPointXYZ()
                vp.set_id(i + 1)
                vp.set_estimate(X[i])
                vp.set_fixed(True)
                self.opt.add_vertex(vp)
                e = _g2o_edge(g2o.EdgeStereoSE3ProjectXYZ(), meas3[i], info3[i], k_stereo, (fx, fy, cx, cy), bf)
                e.set_vertex(0, vp)
                e.set_vertex(1, self.vpose)
            else:
                e = _g2o_edge(g2o.EdgeSE3ProjectXYZOnlyPose(), uv[i], info2[i], k_mono, (fx, fy, cx, cy))
                e.set_vertex(0, self.vpose)
                e.Xw = X[i]
            self.opt.add_edge(e)
            self.edges.append(e)
        self.level = np.zeros(m, dtype=np.int64)
        self.robust = True

    def round(self, rough: bool, inlier: np.ndarray, robust: bool) -> np.ndarray:
        if not rough and not self.fine:
            for i in np.flatnonzero(self.stereo):
                self.edges[i].set_information(self.info_fine[i])
            self.fine = True
        level = (~inlier).astype(np.int64)
        for i in np.flatnonzero(level != self.level):
            self.edges[i].set_level(int(level[i]))
        self.level = level
        if self.robust and not robust:
            self.kernels[0].set_delta(1e12)
            self.kernels[1].set_delta(1e12)
            self.robust = False
        self.opt.initialize_optimization(0)
        self.opt.optimize(self.cfg.tracking.pose_opt_iterations)
        return _mat(self.vpose.estimate())

    def close(self) -> None:
        _KEEP_ALIVE.pop(id(self.opt), None)


class _LmPoseRounds:
    """The rounds of :func:`pose_optimization` with the compiled LM (``d2slam.slam.lm.pose_lm``): the edges as
    arrays, outliers left out by mask."""

    def __init__(self, Tcw, X, uv, ur, inv_sigma2, K, bf, cfg: EngineConfig, coarse: bool):
        self.cfg, self.X, self.bf = cfg, X, float(bf)
        self.meas, self.stereo, self.info_fine, self.delta = _edges(uv, ur, inv_sigma2, cfg, cfg.disparity_sigma_px)
        self.info_coarse = edge_information(np.asarray(inv_sigma2, np.float64), self.stereo, 0.0) if coarse \
            else self.info_fine
        self.K = (K[0, 0], K[1, 1], K[0, 2], K[1, 2])
        self.T = np.ascontiguousarray(Tcw, dtype=np.float64)

    def round(self, rough: bool, inlier: np.ndarray, robust: bool) -> np.ndarray:
        cfg = self.cfg
        self.T = lm.pose_lm(self.T, self.X, self.meas, self.stereo, self.info_coarse if rough else self.info_fine,
                            inlier, self.delta, *self.K, self.bf, robust, cfg.tracking.pose_opt_iterations,
                            cfg.tracking.pose_opt_gain_threshold)
        return self.T

    def close(self) -> None:
        pass


def _local_bundle_adjustment_g2o(poses: np.ndarray, fixed: np.ndarray, X: np.ndarray, obs_cam: np.ndarray,
                                 obs_pt: np.ndarray, uv: np.ndarray, ur: np.ndarray, inv_sigma2: np.ndarray,
                                 K: np.ndarray, bf: float, cfg: EngineConfig, iterations: int):
    """``local_bundle_adjustment`` with a g2o graph (ORB-SLAM3's edge types, points marginalised): returns the
    optimised (poses, X)."""
    opt = _optimizer(dense=False)
    C, P = len(poses), len(X)
    vposes = []
    for c in range(C):
        v = g2o.VertexSE3Expmap()
        v.set_estimate(_se3(poses[c]))
        v.set_id(c)
        v.set_fixed(bool(fixed[c]))
        opt.add_vertex(v)
        vposes.append(v)
    vpts = []
    for p in range(P):
        v = g2o.VertexPointXYZ()
        v.set_estimate(X[p])
        v.set_id(C + p)
        v.set_marginalized(True)
        opt.add_vertex(v)
        vpts.append(v)
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    k_mono, k_stereo, info2, info3, stereo, meas3 = _edge_setup(uv, ur, inv_sigma2, cfg)
    for o in range(len(obs_cam)):
        if stereo[o]:
            e = _g2o_edge(g2o.EdgeStereoSE3ProjectXYZ(), meas3[o], info3[o], k_stereo, (fx, fy, cx, cy), bf)
        else:
            e = _g2o_edge(g2o.EdgeSE3ProjectXYZ(), uv[o], info2[o], k_mono, (fx, fy, cx, cy))
        e.set_vertex(0, vpts[obs_pt[o]])
        e.set_vertex(1, vposes[obs_cam[o]])
        opt.add_edge(e)
    opt.initialize_optimization(0)
    opt.optimize(iterations)
    new_poses = np.stack([_mat(v.estimate()) for v in vposes]) if C else poses.copy()
    new_X = np.stack([np.asarray(v.estimate(), dtype=np.float64) for v in vpts]) if P else X.copy()
    return new_poses, new_X


def _ba_outliers(poses, X, obs_cam, obs_pt, uv, ur, inv_sigma2, K, bf, cfg: EngineConfig) -> np.ndarray:
    """Observations above the chi2 thresholds or behind their camera (ORB-SLAM erases them after local BA)."""
    outlier = np.zeros(len(obs_cam), dtype=bool)
    stereo = ur >= 0
    for c in range(len(poses)):
        sel = obs_cam == c
        if not sel.any():
            continue
        chi2, front = reprojection_chi2(poses[c], X[obs_pt[sel]], uv[sel], ur[sel], inv_sigma2[sel], K, bf,
                                        cfg.disparity_sigma_px)
        th = np.where(stereo[sel], cfg.chi2_stereo, cfg.chi2_mono)
        outlier[sel] = (chi2 > th) | ~front
    return outlier


def edge_information(inv_sigma2: np.ndarray, stereo: np.ndarray, disparity_sigma: float) -> np.ndarray:
    """(M, 3, 3) information per observation: ``I2 inv_sigma2`` in the top-left block of a mono edge,
    ``stereo_information`` for a stereo one."""
    vals, level = np.unique(inv_sigma2, return_inverse=True)  # one matrix per pyramid level
    stereo_info = np.array([stereo_information(v, disparity_sigma) for v in vals]).reshape(-1, 3, 3)
    mono_info = np.array([np.diag([v, v, 0.0]) for v in vals]).reshape(-1, 3, 3)
    return np.where(np.asarray(stereo)[:, None, None], stereo_info[level], mono_info[level])


def _edges(uv, ur, inv_sigma2, cfg: EngineConfig, disparity_sigma: float):
    stereo = ur >= 0
    meas = np.ascontiguousarray(np.column_stack([uv, ur]), dtype=np.float64)
    delta = np.where(stereo, np.sqrt(cfg.chi2_stereo), np.sqrt(cfg.chi2_mono))
    return meas, stereo, edge_information(np.asarray(inv_sigma2, np.float64), stereo, disparity_sigma), delta


def pose_optimization(Tcw: np.ndarray, X: np.ndarray, uv: np.ndarray, ur: np.ndarray, inv_sigma2: np.ndarray,
                      K: np.ndarray, bf: float, cfg: EngineConfig) -> tuple[np.ndarray, np.ndarray]:
    """Motion-only BA (ORB-SLAM ``PoseOptimization``): returns the optimised ``Tcw`` and the inlier mask.

    ``pose_opt_rounds`` rounds of ``pose_opt_iterations`` LM iterations; after each round every edge is classified
    (chi2 against 5.991 mono / 7.815 stereo), outliers are left out of the next round and may come back; the robust
    kernel is dropped after the third round, as in ORB-SLAM. Each round stops early when the relative chi2
    decrease falls below ``pose_opt_gain_threshold``. The first ``pose_opt_coarse_rounds`` rounds (by default all,
    as ORB-SLAM3) use ORB-SLAM's isotropic information, the others the disparity model of ``stereo_information``.
    Each round continues from the last estimate (ORB-SLAM restarts from the initial pose: same fixed point, fewer
    iterations). ``EngineConfig.optimizer``: the compiled kernels of ``d2slam.slam.lm`` or g2o."""
    m = len(X)
    if m < 3:
        return Tcw.copy(), np.zeros(m, dtype=bool)
    X = np.ascontiguousarray(X, dtype=np.float64)
    coarse = cfg.disparity_sigma_px > 0 and cfg.tracking.pose_opt_coarse_rounds > 0
    rounds = (_G2oPoseRounds if cfg.optimizer == "g2o" else _LmPoseRounds)(Tcw, X, uv, ur, inv_sigma2, K, bf, cfg,
                                                                          coarse)
    th = np.where(rounds.stereo, cfg.chi2_stereo, cfg.chi2_mono)
    inlier, T = np.ones(m, dtype=bool), Tcw.copy()
    try:
        for it in range(cfg.tracking.pose_opt_rounds):
            rough = coarse and it < cfg.tracking.pose_opt_coarse_rounds
            T = rounds.round(rough, inlier, robust=it <= 2)  # ORB-SLAM drops the robust kernel after the third round
            chi2, front = reprojection_chi2(T, X, uv, ur, inv_sigma2, K, bf, 0.0 if rough else cfg.disparity_sigma_px)
            inlier = (chi2 <= th) & front
            if inlier.sum() < 10:
                break
    finally:
        rounds.close()
    return T, inlier


def local_bundle_adjustment(poses: np.ndarray, fixed: np.ndarray, X: np.ndarray, obs_cam: np.ndarray,
                            obs_pt: np.ndarray, uv: np.ndarray, ur: np.ndarray, inv_sigma2: np.ndarray,
                            K: np.ndarray, bf: float, cfg: EngineConfig, iterations: int | None = None):
    """Local BA (ORB-SLAM3 ``LocalBundleAdjustment``): keyframe poses ``poses`` (C, 4, 4) ``Tcw`` (``fixed`` (C,)
    bool held constant) and points ``X`` (P, 3) refined together over observations (obs_cam, obs_pt, uv, ur,
    inv_sigma2), Huber kernels, Schur complement on the points. Returns (poses, X, outlier (O,) bool): outliers
    are observations above the chi2 thresholds or behind the camera after optimisation (ORB-SLAM erases them).
    ``EngineConfig.optimizer``: the compiled kernels of ``d2slam.slam.lm`` or g2o."""
    n_it = cfg.mapping.local_ba_iterations if iterations is None else iterations
    if cfg.optimizer == "g2o":
        new_poses, new_X = _local_bundle_adjustment_g2o(poses, fixed, X, obs_cam, obs_pt, uv, ur, inv_sigma2, K, bf,
                                                        cfg, n_it)
    else:
        meas, stereo, info, delta = _edges(uv, ur, inv_sigma2, cfg, cfg.disparity_sigma_px)
        new_poses, new_X = lm.local_ba_lm(np.ascontiguousarray(poses, dtype=np.float64), np.asarray(fixed, bool),
                                          np.ascontiguousarray(X, dtype=np.float64),
                                          np.asarray(obs_cam, np.int64), np.asarray(obs_pt, np.int64), meas, stereo,
                                          info, delta, K[0, 0], K[1, 1], K[0, 2], K[1, 2], float(bf), n_it)
    return new_poses, new_X, _ba_outliers(new_poses, new_X, obs_cam, obs_pt, uv, ur, inv_sigma2, K, bf, cfg)


def se3_log(T: np.ndarray) -> np.ndarray:
    """(N, 6) twists ``(omega, upsilon)`` of (N, 4, 4) rigid transforms (the inverse of ``lm.se3_exp``)."""
    w = Rotation.from_matrix(T[:, :3, :3]).as_rotvec()
    th = np.linalg.norm(w, axis=1)
    W = _hat(w)
    small = th < 1e-6
    ths = np.where(small, 1.0, th)
    a = np.where(small, 1.0 / 12.0, (1.0 - ths * np.sin(ths) / (2.0 * (1.0 - np.cos(ths)))) / ths ** 2)
    Vinv = np.eye(3) - 0.5 * W + a[:, None, None] * (W @ W)
    return np.concatenate([w, np.einsum("nij,nj->ni", Vinv, T[:, :3, 3])], axis=1)


def se3_power(T: np.ndarray, a: float) -> np.ndarray:
    """The rigid transform ``T^a`` (4x4): ``exp(a log T)``, the same screw motion ``a`` times as far."""
    return lm.se3_exp(a * se3_log(T[None])[0])


def _hat(w: np.ndarray) -> np.ndarray:
    W = np.zeros((len(w), 3, 3))
    W[:, 0, 1], W[:, 0, 2], W[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    W[:, 1, 0], W[:, 2, 0], W[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    return W


def adjoint(T: np.ndarray) -> np.ndarray:
    """(N, 6, 6) adjoints of (N, 4, 4) transforms for twists ``(omega, upsilon)``: ``[[R, 0], [t^ R, R]]``."""
    R = T[:, :3, :3]
    A = np.zeros((len(T), 6, 6))
    A[:, :3, :3] = R
    A[:, 3:, 3:] = R
    A[:, 3:, :3] = _hat(T[:, :3, 3]) @ R
    return A


def inverse_batch(T: np.ndarray) -> np.ndarray:
    """The inverses of (N, 4, 4) rigid transforms."""
    out = np.zeros_like(T)
    Rt = np.transpose(T[:, :3, :3], (0, 2, 1))
    out[:, :3, :3] = Rt
    out[:, :3, 3] = -np.einsum("nij,nj->ni", Rt, T[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def pose_graph_optimization(poses: np.ndarray, fixed: np.ndarray, ei: np.ndarray, ej: np.ndarray,
                            meas: np.ndarray, iterations: int) -> np.ndarray:
    """Pose-graph optimisation (ORB-SLAM ``OptimizeEssentialGraph`` with the scale fixed, RGB-D): poses ``Tcw``
    (N, 4, 4), ``fixed`` (N,) held constant, edges ``(ei, ej)`` with measured relative poses ``meas`` = ``T_i
    T_j^-1`` (E, 4, 4), identity information (as ORB-SLAM's Sim3 edges). Error ``log(meas^-1 T_i T_j^-1)``,
    updates ``T <- exp(xi) T`` (``lm.update_pose``), first-order Jacobians ``Ad(meas^-1)`` and ``-Ad(meas^-1 T_i
    T_j^-1)`` (g2o's ``EdgeSE3Expmap``), g2o's Levenberg-Marquardt damping (``lm``) over a sparse system (SuperLU).
    Returns the optimised poses."""
    T = np.ascontiguousarray(poses, dtype=np.float64).copy()
    n, E = len(T), len(ei)
    col = np.full(n, -1, np.int64)
    free = np.flatnonzero(~np.asarray(fixed, bool))
    col[free] = np.arange(len(free))
    if E == 0 or len(free) == 0:
        return T
    Minv = inverse_batch(meas)
    Ji = adjoint(Minv)

    def residual(T):
        R = Minv @ T[ei] @ inverse_batch(T[ej])
        return se3_log(R), R

    e, R = residual(T)
    chi = float(np.sum(e * e))
    lam, nu = 0.0, 2.0
    size = 6 * len(free)
    for it in range(iterations):
        H, b = _pose_graph_system(Ji, -adjoint(R), e, ei, ej, col, size)
        if it == 0:
            lam = 1e-5 * float(H.diagonal().max())
        trials, rho = 0, 0.0
        while True:
            dx = spsolve((H + lam * identity(size, format="csc")).tocsc(), b)
            Tn = T.copy()
            for f, k in enumerate(free):
                Tn[k] = lm.update_pose(np.ascontiguousarray(dx[6 * f:6 * f + 6]), T[k])
            en, Rn = residual(Tn)
            new_chi = float(np.sum(en * en))
            rho = (chi - new_chi) / (float(dx @ (lam * dx + b)) + 1e-3)
            trials += 1
            kept, lam, nu = lm._damping(rho, new_chi, lam, nu)
            if kept:
                T, e, R, chi = Tn, en, Rn, new_chi
                break
            if trials >= lm.MAX_TRIALS:
                break
        if rho <= 0 or not np.isfinite(lam):
            break
    return T


def _pose_graph_system(Ji: np.ndarray, Jj: np.ndarray, e: np.ndarray, ei: np.ndarray, ej: np.ndarray,
                       col: np.ndarray, size: int):
    """The normal equations (H sparse CSC (size, size), b (size,)) of the pose graph: edge Jacobians ``Ji`` / ``Jj``
    (E, 6, 6) of the poses ``ei`` / ``ej``, residuals ``e`` (E, 6); ``col`` each pose's block (-1: fixed)."""
    r6 = np.arange(6)
    blocks, brow, bcol = [], [], []
    b = np.zeros(size)
    for Ja, a in ((Ji, ei), (Jj, ej)):
        ca = col[a]
        ok = ca >= 0
        np.add.at(b, (6 * ca[ok])[:, None] + r6, -np.einsum("eki,ek->ei", Ja[ok], e[ok]))
        for Jb, bb in ((Ji, ei), (Jj, ej)):
            cb = col[bb]
            both = ok & (cb >= 0)
            blocks.append(np.einsum("eki,ekj->eij", Ja[both], Jb[both]))
            brow.append(ca[both])
            bcol.append(cb[both])
    blk = np.concatenate(blocks)
    rr = (6 * np.concatenate(brow))[:, None, None] + r6[None, :, None]
    cc = (6 * np.concatenate(bcol))[:, None, None] + r6[None, None, :]
    H = coo_matrix((blk.ravel(), (np.broadcast_to(rr, blk.shape).ravel(), np.broadcast_to(cc, blk.shape).ravel())),
                   shape=(size, size)).tocsc()
    return H, b
