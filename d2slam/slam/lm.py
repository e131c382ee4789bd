"""Compiled Levenberg-Marquardt for ORB-SLAM's two optimisations, the same model as g2o's edges
(``EdgeSE3ProjectXYZOnlyPose`` / ``EdgeStereoSE3ProjectXYZOnlyPose``, ``EdgeSE3ProjectXYZ`` /
``EdgeStereoSE3ProjectXYZ``) and the same algorithm as g2o's ``OptimizationAlgorithmLevenberg``:

- error ``e = measurement - project(Tcw X)``, with ``project = (fx x/z + cx, fy y/z + cy[, u - bf/z])``;
- pose update ``Tcw <- exp(xi) Tcw``, ``xi = (omega, upsilon)`` (g2o ``SE3Quat::exp``), the rotation kept on SO(3)
  (``update_pose``), point update ``X <- X + dx``;
- Huber kernel: weight ``rho'(chi2) = min(1, delta / sqrt(chi2))`` on the information, robust chi2
  ``2 delta sqrt(chi2) - delta^2`` above ``delta^2``;
- Levenberg-Marquardt: ``lambda_0 = 1e-5 max diag(H)``; a step is kept when the robust chi2 falls
  (``lambda *= max(1/3, min(2/3, 1 - (2 rho - 1)^3))``), otherwise undone (``lambda *= nu``, ``nu *= 2``), at most
  10 failed trials per iteration;
- local BA marginalises the points (Schur complement on the 3x3 point blocks), solving for the free poses first.

Why not g2o itself: building its graph from Python (one pybind call per edge and setting) cost three times its
optimisation; these kernels take the edges as arrays. ``EngineConfig.optimizer = "g2o"`` runs g2o instead
(``d2slam.slam.optimizer``); the tests check both give the same poses.
"""

from __future__ import annotations

import numpy as np
from numba import njit

TAU = 1e-5  # g2o's initial lambda factor
GOOD_STEP_LOWER, GOOD_STEP_UPPER = 1.0 / 3.0, 2.0 / 3.0  # g2o's bounds of the lambda decrease after a good step
MAX_TRIALS = 10  # g2o's failed trials per iteration before it gives up


@njit(cache=True, nogil=True)
def se3_exp(xi):
    """4x4 transform of the twist ``xi = (omega, upsilon)`` (g2o ``SE3Quat::exp``)."""
    w = xi[:3]
    theta = np.sqrt(w[0] * w[0] + w[1] * w[1] + w[2] * w[2])
    W = np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])
    W2 = W @ W
    eye = np.eye(3)
    if theta < 1e-5:
        R = eye + W + W2
        V = R
    else:
        R = eye + np.sin(theta) / theta * W + (1 - np.cos(theta)) / (theta * theta) * W2
        V = eye + (1 - np.cos(theta)) / (theta * theta) * W + (theta - np.sin(theta)) / (theta ** 3) * W2
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = V @ xi[3:]
    return T


@njit(cache=True, nogil=True)
def update_pose(xi, T):
    """``exp(xi) T`` with its rotation projected back onto SO(3) (the nearest rotation, by SVD), as g2o's
    ``SE3Quat`` keeps a unit quaternion: without it rounding and the small-angle ``exp`` leave the rotation slightly
    non-orthonormal, and the constant-velocity model (``T_i T_{i-1}^-1``, inverted as a rigid transform) compounds
    that from frame to frame."""
    Tn = se3_exp(xi) @ T
    U, _, Vt = np.linalg.svd(Tn[:3, :3])
    R = U @ Vt
    Tn[:3, :3] = R
    return Tn


@njit(cache=True, nogil=True, inline="always")
def _edge(T, Xw, meas, stereo, fx, fy, cx, cy, bf, e, A, B):
    """Fills the error ``e`` (3,), ``A`` = d e / d xi (3, 6) for the left perturbation ``exp(xi) Tcw``, and ``B`` =
    d e / d X (3, 3) of one observation; a mono edge has 0 in the third row of each (and of its information), so
    every edge is handled as 3-dimensional. With ``Jp`` = d project / d Xc: ``A = [Jp [Xc]x | -Jp]``,
    ``B = -Jp R``. Returns the camera depth z."""
    x = T[0, 0] * Xw[0] + T[0, 1] * Xw[1] + T[0, 2] * Xw[2] + T[0, 3]
    y = T[1, 0] * Xw[0] + T[1, 1] * Xw[1] + T[1, 2] * Xw[2] + T[1, 3]
    z = T[2, 0] * Xw[0] + T[2, 1] * Xw[1] + T[2, 2] * Xw[2] + T[2, 3]
    iz = 1.0 / z
    iz2 = iz * iz
    u = fx * x * iz + cx
    e[0] = meas[0] - u
    e[1] = meas[1] - (fy * y * iz + cy)
    e[2] = meas[2] - (u - bf * iz) if stereo else 0.0
    for r in range(3):
        if r == 0:
            a, b, c = fx * iz, 0.0, -fx * x * iz2
        elif r == 1:
            a, b, c = 0.0, fy * iz, -fy * y * iz2
        elif stereo:
            a, b, c = fx * iz, 0.0, -fx * x * iz2 + bf * iz2
        else:
            a, b, c = 0.0, 0.0, 0.0
        A[r, 0] = b * z - c * y
        A[r, 1] = c * x - a * z
        A[r, 2] = a * y - b * x
        A[r, 3] = -a
        A[r, 4] = -b
        A[r, 5] = -c
        for j in range(3):
            B[r, j] = -(a * T[0, j] + b * T[1, j] + c * T[2, j])
    return z


@njit(cache=True, nogil=True, inline="always")
def _chi2(e, Om):
    s = 0.0
    for i in range(3):
        for j in range(3):
            s += e[i] * Om[i, j] * e[j]
    return s


@njit(cache=True, nogil=True, inline="always")
def _robust(chi2, delta, robust):
    """(robust chi2, weight) of the Huber kernel (``robust`` False: plain least squares)."""
    if not robust or chi2 <= delta * delta:
        return chi2, 1.0
    s = np.sqrt(chi2)
    return 2.0 * delta * s - delta * delta, delta / s


@njit(cache=True, nogil=True, inline="always")
def _weighted(w, Om, J, out):
    """out = w Om J for J (3, n)."""
    for i in range(3):
        for j in range(J.shape[1]):
            out[i, j] = w * (Om[i, 0] * J[0, j] + Om[i, 1] * J[1, j] + Om[i, 2] * J[2, j])


@njit(cache=True, nogil=True, inline="always")
def _add_JtWJ(H, J1, WJ2, sign):
    """H += sign J1^T WJ2."""
    for i in range(J1.shape[1]):
        for j in range(WJ2.shape[1]):
            H[i, j] += sign * (J1[0, i] * WJ2[0, j] + J1[1, i] * WJ2[1, j] + J1[2, i] * WJ2[2, j])


@njit(cache=True, nogil=True, inline="always")
def _sub_Jte(b, WJ, e):
    """b -= WJ^T e."""
    for i in range(WJ.shape[1]):
        b[i] -= WJ[0, i] * e[0] + WJ[1, i] * e[1] + WJ[2, i] * e[2]


@njit(cache=True, nogil=True, inline="always")
def _damping(rho, new_chi, lam, nu):
    """g2o's Levenberg-Marquardt damping after a trial step: (step kept, lambda, nu)."""
    if rho > 0 and np.isfinite(new_chi):
        return True, lam * max(GOOD_STEP_LOWER, min(1.0 - (2.0 * rho - 1.0) ** 3, GOOD_STEP_UPPER)), 2.0
    return False, lam * nu, nu * 2.0


@njit(cache=True, nogil=True)
def pose_chi2(T, X, meas, stereo, info, active, delta, fx, fy, cx, cy, bf, robust):
    """Robust chi2 of the active edges of a pose."""
    e, A, B = np.zeros(3), np.zeros((3, 6)), np.zeros((3, 3))
    total = 0.0
    for i in range(X.shape[0]):
        if active[i]:
            _edge(T, X[i], meas[i], stereo[i], fx, fy, cx, cy, bf, e, A, B)
            total += _robust(_chi2(e, info[i]), delta[i], robust)[0]
    return total


@njit(cache=True, nogil=True)
def pose_lm(T0, X, meas, stereo, info, active, delta, fx, fy, cx, cy, bf, robust, iterations, gain_threshold):
    """Motion-only LM from ``T0`` over the active edges; returns the pose. ``gain_threshold`` > 0: stop once an
    iteration's relative chi2 decrease falls below it (g2o's terminate action)."""
    T = T0.copy()
    e, A, B, WA = np.zeros(3), np.zeros((3, 6)), np.zeros((3, 3)), np.zeros((3, 6))
    H, b = np.zeros((6, 6)), np.zeros(6)
    last_chi, lam, nu = 0.0, 0.0, 2.0
    for it in range(iterations):
        H[:] = 0.0
        b[:] = 0.0
        chi = 0.0
        for i in range(X.shape[0]):
            if not active[i]:
                continue
            _edge(T, X[i], meas[i], stereo[i], fx, fy, cx, cy, bf, e, A, B)
            rc, w = _robust(_chi2(e, info[i]), delta[i], robust)
            chi += rc
            _weighted(w, info[i], A, WA)
            _add_JtWJ(H, A, WA, 1.0)
            _sub_Jte(b, WA, e)
        if it == 0:
            lam = TAU * np.max(np.diag(H))
            nu = 2.0
        trials, rho = 0, 0.0
        while True:
            dx = np.linalg.solve(H + lam * np.eye(6), b)
            Tn = update_pose(dx, T)
            new_chi = pose_chi2(Tn, X, meas, stereo, info, active, delta, fx, fy, cx, cy, bf, robust)
            rho = (chi - new_chi) / (dx @ (lam * dx + b) + 1e-3)
            trials += 1
            kept, lam, nu = _damping(rho, new_chi, lam, nu)
            if kept:
                T = Tn
                chi = new_chi
                break
            if trials >= MAX_TRIALS:
                break
        if rho <= 0 or not np.isfinite(lam):
            break
        if gain_threshold > 0 and it > 0:
            gain = (last_chi - chi) / chi if chi > 0 else 0.0
            if 0 <= gain < gain_threshold:
                break
        last_chi = chi
    return T


@njit(cache=True, nogil=True)
def ba_chi2(poses, X, obs_cam, obs_pt, meas, stereo, info, delta, fx, fy, cx, cy, bf):
    e, A, B = np.zeros(3), np.zeros((3, 6)), np.zeros((3, 3))
    total = 0.0
    for o in range(obs_cam.shape[0]):
        _edge(poses[obs_cam[o]], X[obs_pt[o]], meas[o], stereo[o], fx, fy, cx, cy, bf, e, A, B)
        total += _robust(_chi2(e, info[o]), delta[o], True)[0]
    return total


@njit(cache=True, nogil=True, inline="always")
def _inv3(M, lam, out):
    """out = (M + lam I)^-1 for a symmetric 3x3 M (cofactors)."""
    a, b, c = M[0, 0] + lam, M[0, 1], M[0, 2]
    d, f = M[1, 1] + lam, M[1, 2]
    g = M[2, 2] + lam
    c00, c01, c02 = d * g - f * f, c * f - b * g, b * f - c * d
    det = a * c00 + b * c01 + c * c02
    idet = 1.0 / det
    out[0, 0], out[0, 1], out[0, 2] = c00 * idet, c01 * idet, c02 * idet
    out[1, 0], out[1, 1], out[1, 2] = c01 * idet, (a * g - c * c) * idet, (b * c - a * f) * idet
    out[2, 0], out[2, 1], out[2, 2] = c02 * idet, (b * c - a * f) * idet, (a * d - b * b) * idet


@njit(cache=True, nogil=True)
def _ba_layout(fixed, obs_pt, P):
    """The free poses' indices (-1: fixed) and their count, and the observations grouped by point (CSR: point p's
    are ``by_pt[pstart[p]:pstart[p + 1]]``)."""
    C, O = fixed.shape[0], obs_pt.shape[0]
    free = np.full(C, -1, np.int64)
    F = 0
    for c in range(C):
        if not fixed[c]:
            free[c] = F
            F += 1
    by_pt = np.argsort(obs_pt, kind="mergesort")
    pstart = np.zeros(P + 1, np.int64)
    for o in range(O):
        pstart[obs_pt[o] + 1] += 1
    for p in range(P):
        pstart[p + 1] += pstart[p]
    return free, F, by_pt, pstart


@njit(cache=True, nogil=True)
def _ba_normal_equations(poses, X, free, obs_cam, obs_pt, meas, stereo, info, delta, fx, fy, cx, cy, bf,
                         Hcc, bc, Hpp, bp, Hcp):
    """Fill the blocks of the robust normal equations (poses ``Hcc``/``bc``, points ``Hpp``/``bp``, pose-point
    ``Hcp`` per observation); returns the robust chi2."""
    e, A, B = np.zeros(3), np.zeros((3, 6)), np.zeros((3, 3))
    WA, WB = np.zeros((3, 6)), np.zeros((3, 3))
    Hcc[:] = 0.0
    bc[:] = 0.0
    Hpp[:] = 0.0
    bp[:] = 0.0
    chi = 0.0
    for o in range(obs_cam.shape[0]):
        c, p = obs_cam[o], obs_pt[o]
        _edge(poses[c], X[p], meas[o], stereo[o], fx, fy, cx, cy, bf, e, A, B)
        rc, w = _robust(_chi2(e, info[o]), delta[o], True)
        chi += rc
        _weighted(w, info[o], B, WB)
        _add_JtWJ(Hpp[p], B, WB, 1.0)
        _sub_Jte(bp[p], WB, e)
        f = free[c]
        if f >= 0:
            _weighted(w, info[o], A, WA)
            _add_JtWJ(Hcc[f], A, WA, 1.0)
            _sub_Jte(bc[f], WA, e)
            Hcp[o, :, :] = 0.0
            _add_JtWJ(Hcp[o], A, WB, 1.0)
    return chi


@njit(cache=True, nogil=True)
def _ba_max_diagonal(Hcc, Hpp):
    mx = 0.0
    for f in range(Hcc.shape[0]):
        for k in range(6):
            mx = max(mx, Hcc[f, k, k])
    for p in range(Hpp.shape[0]):
        for k in range(3):
            mx = max(mx, Hpp[p, k, k])
    return mx


@njit(cache=True, nogil=True)
def _ba_reduced_system(Hcc, bc, Hpp, bp, Hcp, lam, free, obs_cam, by_pt, pstart, Hinv):
    """The damped pose system with the points eliminated (Schur complement): (S, rhs); ``Hinv`` receives the
    damped inverse point blocks."""
    F, P = Hcc.shape[0], Hpp.shape[0]
    Y = np.zeros((6, 3))
    S = np.zeros((6 * F, 6 * F))
    rhs = np.zeros(6 * F)
    for f in range(F):
        for i in range(6):
            rhs[6 * f + i] = bc[f, i]
            for j in range(6):
                S[6 * f + i, 6 * f + j] = Hcc[f, i, j]
            S[6 * f + i, 6 * f + i] += lam
    for p in range(P):
        _inv3(Hpp[p], lam, Hinv[p])
        for a in range(pstart[p], pstart[p + 1]):
            oa = by_pt[a]
            fa = free[obs_cam[oa]]
            if fa < 0:
                continue
            for i in range(6):  # Y = Hcp[oa] Hinv[p]
                for j in range(3):
                    Y[i, j] = Hcp[oa, i, 0] * Hinv[p, 0, j] + Hcp[oa, i, 1] * Hinv[p, 1, j] + \
                        Hcp[oa, i, 2] * Hinv[p, 2, j]
                rhs[6 * fa + i] -= Y[i, 0] * bp[p, 0] + Y[i, 1] * bp[p, 1] + Y[i, 2] * bp[p, 2]
            for b_ in range(pstart[p], pstart[p + 1]):
                ob = by_pt[b_]
                fb = free[obs_cam[ob]]
                if fb < 0:
                    continue
                for i in range(6):
                    for j in range(6):
                        S[6 * fa + i, 6 * fb + j] -= Y[i, 0] * Hcp[ob, j, 0] + Y[i, 1] * Hcp[ob, j, 1] + \
                            Y[i, 2] * Hcp[ob, j, 2]
    return S, rhs


@njit(cache=True, nogil=True)
def _ba_point_steps(dc, bp, Hcp, Hinv, free, obs_cam, by_pt, pstart):
    """Back-substitution: each point's step given the poses' ``dc``."""
    P = bp.shape[0]
    dxp = np.zeros((P, 3))
    for p in range(P):
        r0, r1, r2 = bp[p, 0], bp[p, 1], bp[p, 2]
        for a in range(pstart[p], pstart[p + 1]):
            oa = by_pt[a]
            fa = free[obs_cam[oa]]
            if fa >= 0:
                for i in range(6):
                    d = dc[6 * fa + i]
                    r0 -= Hcp[oa, i, 0] * d
                    r1 -= Hcp[oa, i, 1] * d
                    r2 -= Hcp[oa, i, 2] * d
        for i in range(3):
            dxp[p, i] = Hinv[p, i, 0] * r0 + Hinv[p, i, 1] * r1 + Hinv[p, i, 2] * r2
    return dxp


@njit(cache=True, nogil=True)
def _ba_predicted_gain(dc, bc, dxp, bp, lam):
    """g2o's scale of the gain ratio: ``1e-3 + dx^T (lam dx + b)`` over the poses and the points."""
    scale = 1e-3
    for f in range(bc.shape[0]):
        for i in range(6):
            x = dc[6 * f + i]
            scale += x * (lam * x + bc[f, i])
    for p in range(bp.shape[0]):
        for i in range(3):
            scale += dxp[p, i] * (lam * dxp[p, i] + bp[p, i])
    return scale


@njit(cache=True, nogil=True)
def local_ba_lm(poses0, fixed, X0, obs_cam, obs_pt, meas, stereo, info, delta, fx, fy, cx, cy, bf, iterations):
    """Local BA: LM over the free poses and every point (Huber on all edges), points marginalised (Schur
    complement). Returns (poses, points)."""
    poses, X = poses0.copy(), X0.copy()
    C, P, O = poses.shape[0], X.shape[0], obs_cam.shape[0]
    free, F, by_pt, pstart = _ba_layout(fixed, obs_pt, P)
    Hcc, bc = np.zeros((F, 6, 6)), np.zeros((F, 6))
    Hpp, bp = np.zeros((P, 3, 3)), np.zeros((P, 3))
    Hcp = np.zeros((O, 6, 3))
    Hinv = np.zeros((P, 3, 3))
    lam, nu = 0.0, 2.0
    for it in range(iterations):
        chi = _ba_normal_equations(poses, X, free, obs_cam, obs_pt, meas, stereo, info, delta, fx, fy, cx, cy, bf,
                                   Hcc, bc, Hpp, bp, Hcp)
        if it == 0:
            lam = TAU * _ba_max_diagonal(Hcc, Hpp)
            nu = 2.0
        trials, rho = 0, 0.0
        while True:
            S, rhs = _ba_reduced_system(Hcc, bc, Hpp, bp, Hcp, lam, free, obs_cam, by_pt, pstart, Hinv)
            dc = np.linalg.solve(S, rhs) if F else np.zeros(0)
            dxp = _ba_point_steps(dc, bp, Hcp, Hinv, free, obs_cam, by_pt, pstart)
            new_poses = poses.copy()
            for c in range(C):
                f = free[c]
                if f >= 0:
                    new_poses[c] = update_pose(dc[6 * f:6 * f + 6], poses[c])
            new_X = X + dxp
            new_chi = ba_chi2(new_poses, new_X, obs_cam, obs_pt, meas, stereo, info, delta, fx, fy, cx, cy, bf)
            rho = (chi - new_chi) / _ba_predicted_gain(dc, bc, dxp, bp, lam)
            trials += 1
            kept, lam, nu = _damping(rho, new_chi, lam, nu)
            if kept:
                poses, X = new_poses, new_X
                break
            if trials >= MAX_TRIALS:
                break
        if rho <= 0 or not np.isfinite(lam):
            break
    return poses, X
