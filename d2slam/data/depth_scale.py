"""Is the depth in metres? A check of the depth factor against the scene's geometry, before a run.

A depth factor off by a constant (millimetres read with TUM's 5000: every depth x 0.2) leaves each image pair
self-consistent: a scene s times larger seen by a camera moving s times farther gives the same images. What fixes the
scale is the ground truth, in metres. So the check compares the camera's motion measured through the depth with the
ground truth's: on a few frame pairs whose ground-truth poses are some centimetres apart and look at the same scene,
ORB keypoints with depth are matched, the relative pose is estimated by a 3-D/3-D RANSAC (Kabsch on three matches,
residuals relative to the depth, so the fit does not depend on the scale) and the ratio of its translation to the
ground truth's is the factor the depth is off by (1 when right, 0.2 for millimetres read as 1/5000 m, 5 the other
way). The median over the pairs decides (``DepthCheckConfig.depth_*``). It takes a few images and well under a second.

Without ground truth, or when the camera never moves enough (a camera held still), the depth of the first frames is
checked against what an RGB-D camera sees indoors instead: a median within ``DataConfig.depth_median_range`` and
something farther than ``DepthCheckConfig.depth_far_min_m``. That catches a factor of 5 either way in a room, but a
close-up scene (everything within a metre) looks like millimetres read as 1/5000 m.
"""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.data.config import DataConfig, DepthCheckConfig
from d2slam.ranges import AnyConfig, part_of


def candidate_pairs(poses: np.ndarray, check: DepthCheckConfig = DepthCheckConfig()) -> list[tuple[int, int]]:
    """Frame pairs (i, j) to measure the depth's scale on, from the frames' ground-truth poses (N, 4, 4; NaN where
    there is none): among ``depth_candidate_frames`` frames spread over the sequence, each first frame's partner with
    the largest baseline in [depth_min_baseline_m, depth_max_baseline_m] and a rotation of at most
    depth_max_rotation_deg; up to ``depth_pairs`` of these pairs, spread over the sequence."""
    n = len(poses)
    idx = np.unique(np.linspace(0, n - 1, min(n, max(2, int(check.depth_candidate_frames)))).round().astype(int))
    idx = idx[np.isfinite(poses[idx]).all(axis=(1, 2))]
    if len(idx) < 2:
        return []
    R, c = poses[idx, :3, :3], poses[idx, :3, 3]
    baseline = np.linalg.norm(c[:, None] - c[None], axis=2)
    cos = (np.einsum("aji,bji->ab", R, R) - 1.0) / 2.0  # trace(R_a^T R_b) = cos of the relative angle
    angle = np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))
    ok = ((baseline >= check.depth_min_baseline_m) & (baseline <= check.depth_max_baseline_m)
          & (angle <= check.depth_max_rotation_deg) & (idx[None, :] > idx[:, None]))
    firsts = np.flatnonzero(ok.any(axis=1))
    if len(firsts) == 0:
        return []
    partner = np.argmax(np.where(ok, baseline, -1.0), axis=1)
    pick = firsts[np.unique(np.linspace(0, len(firsts) - 1, min(len(firsts), int(check.depth_pairs))).round()
                            .astype(int))]
    return [(int(idx[a]), int(idx[partner[a]])) for a in pick]


def _keypoints_3d(gray: np.ndarray, depth: np.ndarray, camera, orb) -> tuple[np.ndarray, np.ndarray]:
    """(M, 3) camera-frame points and (M, 32) descriptors of the ORB keypoints with a valid depth."""
    kps, desc = orb.detectAndCompute(gray, None)
    if desc is None or not kps:
        return np.zeros((0, 3)), np.zeros((0, 32), np.uint8)
    uv = np.array([k.pt for k in kps], dtype=np.float64)
    col = np.clip(np.rint(uv[:, 0]).astype(int), 0, depth.shape[1] - 1)
    row = np.clip(np.rint(uv[:, 1]).astype(int), 0, depth.shape[0] - 1)
    z = depth[row, col].astype(np.float64)
    ok = z > 0
    x = (uv[ok, 0] - camera.cx) / camera.fx * z[ok]
    y = (uv[ok, 1] - camera.cy) / camera.fy * z[ok]
    return np.stack([x, y, z[ok]], axis=1), desc[ok]


def _kabsch(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid (R, t) with B ~ R A + t for batches of point sets (..., M, 3): (..., 3, 3), (..., 3)."""
    ca, cb = A.mean(axis=-2), B.mean(axis=-2)
    H = np.swapaxes(A - ca[..., None, :], -1, -2) @ (B - cb[..., None, :])
    U, _, Vt = np.linalg.svd(H)
    V = np.swapaxes(Vt, -1, -2)
    d = np.sign(np.linalg.det(V @ np.swapaxes(U, -1, -2)))
    D = np.broadcast_to(np.eye(3), H.shape).copy()
    D[..., 2, 2] = np.where(d == 0, 1.0, d)
    R = V @ D @ np.swapaxes(U, -1, -2)
    return R, cb - np.einsum("...ij,...j->...i", R, ca)


def rigid_ransac(P: np.ndarray, Q: np.ndarray, check: DepthCheckConfig = DepthCheckConfig(),
                 seed: int = 0) -> tuple[np.ndarray | None, int]:
    """Translation of the rigid motion Q ~ R P + t of matched points (M, 3), by RANSAC over triples (seeded, all
    hypotheses at once) with residuals relative to the depth of Q, refitted on the inliers; (None, inliers) when
    fewer than ``depth_min_inliers`` agree."""
    m = len(P)
    if m < max(3, int(check.depth_min_inliers)):
        return None, 0
    rng = np.random.default_rng(int(seed))
    triples = np.argpartition(rng.random((int(check.depth_ransac_iterations), m)), 3, axis=1)[:, :3]
    R, t = _kabsch(P[triples], Q[triples])
    tol = check.depth_inlier_rel * Q[:, 2]
    res = np.linalg.norm(np.einsum("kij,mj->kmi", R, P) + t[:, None, :] - Q[None], axis=2)
    inliers = res < tol[None]
    best = inliers[np.argmax(inliers.sum(axis=1))]
    for _ in range(2):  # refit on the inliers, then take the inliers of the refit
        if best.sum() < 3:
            break
        R1, t1 = _kabsch(P[best], Q[best])
        best = np.linalg.norm(P @ R1.T + t1 - Q, axis=1) < tol
    count = int(best.sum())
    if count < check.depth_min_inliers:
        return None, count
    return _kabsch(P[best], Q[best])[1], count


def translation_ratios(seq, check: DepthCheckConfig = DepthCheckConfig(), seed: int = 0) -> list[float]:
    """Per frame pair of :func:`candidate_pairs`: the camera translation measured through the depth divided by the
    ground truth's (1 when the depth is in metres); empty when there is no ground truth, no pair with enough camera
    motion, or too few matches."""
    if getattr(seq, "groundtruth", None) is None or len(seq) < 2:
        return []
    poses = seq.frame_gt_poses()
    pairs = candidate_pairs(poses, check)
    if not pairs:
        return []
    orb = cv2.ORB_create(nfeatures=int(check.depth_orb_features))
    matcher = cv2.BFMatcher(cv2.NORM_HAMMING, crossCheck=True)
    cache: dict[int, tuple[np.ndarray, np.ndarray]] = {}

    def points(i: int):
        if i not in cache:
            frame = seq[i]
            gray = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY)
            cache[i] = _keypoints_3d(gray, frame.depth, seq.camera, orb)
        return cache[i]

    ratios = []
    for i, j in pairs:
        (Pi, Di), (Pj, Dj) = points(i), points(j)
        if len(Pi) < 3 or len(Pj) < 3:
            continue
        matches = [mt for mt in matcher.match(Dj, Di) if mt.distance <= check.depth_max_hamming]
        if not matches:
            continue
        qj = np.array([mt.queryIdx for mt in matches])
        ti = np.array([mt.trainIdx for mt in matches])
        t, _ = rigid_ransac(Pj[qj], Pi[ti], check, seed)  # frame j's points into frame i: t = c_j - c_i in frame i
        if t is None:
            continue
        truth = float(np.linalg.norm(poses[j, :3, 3] - poses[i, :3, 3]))
        ratios.append(float(np.linalg.norm(t)) / truth)
    return ratios


def _window_warning(seq, cfg: DataConfig, check: DepthCheckConfig) -> str | None:
    """The fallback: the median valid depth of the first frames against ``DataConfig.depth_median_range``, and their far
    depth (``depth_far_percentile``) against ``DepthCheckConfig.depth_far_min_m`` (a camera sees something farther than
    that in any room; millimetres read as 1/5000 m put a room's far wall within a metre)."""
    n = min(len(seq), max(1, int(cfg.depth_check_frames)))
    values = [d[d > 0] for d in (seq.depth_image(i) for i in range(n))]
    values = np.concatenate(values) if values else np.zeros(0)
    if values.size == 0:
        return None
    median, far = (float(v) for v in np.percentile(values, [50.0, check.depth_far_percentile]))
    lo, hi = cfg.depth_median_range

    def plausible(scale: float) -> bool:
        return lo <= median * scale <= hi and far * scale >= check.depth_far_min_m

    if plausible(1.0):
        return None
    factor = seq.camera.depth_factor
    raw = median * factor
    target = np.sqrt(lo * hi)
    fits = [f for f in cfg.depth_factor_candidates if f != factor and plausible(factor / f)]
    hint = (f"the images look like depth factor {min(fits, key=lambda f: abs(np.log(raw / f / target))):g} "
            if fits else "check the depth factor ")
    return (f"the depth of the first {n} frames is {median:.3g} m at the median and {far:.3g} m at the "
            f"{check.depth_far_percentile:g}th percentile with depth factor {factor:g} (raw median {raw:.0f}); an "
            f"RGB-D camera indoors sees a median of {lo:g}-{hi:g} m and something beyond {check.depth_far_min_m:g} m: "
            f"{hint}(set DepthMapFactor in a --camera settings file)")


def depth_scale_warning(seq, config: AnyConfig | DataConfig | None = None, check: DepthCheckConfig = DepthCheckConfig(),
                        seed: int = 0) -> str | None:
    """A one-line message when the depth of ``seq`` is not in metres with its camera's depth factor, naming the factor
    that would make it so; None when it looks right. Against the ground truth's camera motion when the sequence has
    it (module docstring), else the median-depth window."""
    ratios = translation_ratios(seq, check, seed)
    if not ratios:
        return _window_warning(seq, part_of(config, "data", DataConfig), check)
    ratio = float(np.median(ratios))
    tol = float(check.depth_ratio_tolerance)
    if 1.0 / tol <= ratio <= tol:
        return None
    factor = seq.camera.depth_factor
    wanted = factor * ratio
    candidates = part_of(config, "data", DataConfig).depth_factor_candidates
    near = [f for f in candidates if abs(np.log(wanted / f)) < np.log(tol)]
    best = min(near, key=lambda f: abs(np.log(wanted / f))) if near else float(f"{wanted:.2g}")
    return (f"the depth does not match the ground truth's camera motion: with depth factor {factor:g} the camera "
            f"moves {ratio:.2g} times as far as in groundtruth.txt (median of {len(ratios)} frame pairs), so the "
            f"depth is off by that factor: the images look like depth factor {best:g} (set DepthMapFactor in a "
            "--camera settings file)")
