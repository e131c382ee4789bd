"""Loop closing (ORB-SLAM3 ``LoopClosing``, RGB-D: the scale is known), run synchronously on each new keyframe after
local mapping (deterministic).

Detection (ORB-SLAM2/3 ``DetectLoop``): the keyframe enters the keyframe database (``keyframe_database.py``); its
candidates are the keyframes it is not connected to that score at least the lowest score of its covisible
keyframes, by ORB-SLAM's candidate rules (common words, group scores); a candidate must be consistent over
``loop_consistency`` consecutive keyframes (its group shares a keyframe with a group of the keyframe before).

Geometry (``ComputeSim3`` with the scale fixed): the keyframe's static keypoints with depth, back-projected (the 3D
measurement of the current view), matched to the candidate's static map points; a seeded 3-point RANSAC of the
rigid transform with ORB-SLAM's inlier test (reprojection in both keyframes, 9.21 sigma^2); the keyframe's pose in
the candidate's map optimised (motion-only BA), the points of the candidate's covisible window projected with it,
and the pose optimised again with all matches.

Correction (``CorrectLoop``): the keyframe and its connected keyframes are moved by the loop's correction with their
points; the loop's matched points replace the keyframe's and the window's points are fused into the connected
keyframes (``LocalMapper.fuse_into``); the essential graph (spanning tree, strong covisibility, loop edges) is
optimised (``optimizer.pose_graph_optimization``) with the loop keyframe fixed, every point follows its reference
keyframe, then a full bundle adjustment.

Dynamics: the keypoints the hook flagged when the keyframe was made (``KeyFrame.dynamic``) give no word and take no
3D-3D match; the map points the hook marked dynamic (belief above ``mappoint_belief_threshold``) are left out of the
window. Without a filter every keypoint and point takes part (and with ``LoopConfig.loop_dynamic_keypoints``, an
ablation, every keypoint).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field

import numpy as np
from scipy.sparse import csr_matrix

from d2slam.slam.config import SlamConfig
from d2slam.slam.keyframe_database import KeyFrameDatabase
from d2slam.slam.local_mapping import LocalMapper
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.matching import rotation_consistent, search_by_bow, search_by_projection, unique_by_target
from d2slam.slam.optimizer import inverse_batch, pose_graph_optimization, pose_optimization
from d2slam.slam.orb_vocabulary import BowVocabulary
from d2slam.slam.projection import Projector, inv


@dataclass
class Loop:
    """A closed loop: the current keyframe ``kf`` and the loop keyframe ``loop_kf`` (ids and frame indices), the
    current keyframe's pose in the loop's map that the geometry found, the relative pose ``T_kf_loop``
    (``Tcw_kf Twc_loop`` at detection, what the truth is compared with), matches and inliers, the correction's time,
    and the keyframes' poses just before and after it."""

    kf: int
    loop_kf: int
    frame: int
    loop_frame: int
    score: float
    inliers: int
    matches: int
    T_kf_loop: np.ndarray
    seconds: float = 0.0
    # every good keyframe's Tcw just before and just after the correction (keyframe id -> 4x4; not in to_dict)
    poses_before: dict = field(default_factory=dict, repr=False)
    poses_after: dict = field(default_factory=dict, repr=False)

    def to_dict(self) -> dict:
        return {"frames": [self.frame, self.loop_frame], "keyframes": [self.kf, self.loop_kf],
                "score": round(self.score, 6), "inliers": self.inliers, "matches": self.matches,
                "T_kf_loop": np.round(self.T_kf_loop, 9).tolist(), "seconds": round(self.seconds, 4)}


@dataclass
class Geometry:
    Tcw: np.ndarray  # the current keyframe's pose in the loop's map
    kp: np.ndarray  # matched keypoints of the current keyframe
    pts: np.ndarray  # their map points (of the loop window)
    window_pts: np.ndarray  # the window's usable points
    inliers: int


@dataclass
class Candidate:
    """One place-recognition candidate of a keyframe (``LoopCloser.log``): how far it got (``stage``: "score"
    passed the score rule, "group" a group's best, "geometry" consistent over consecutive keyframes but failed the
    geometric check, "loop" closed), its score, the keyframe's minimum score and the count of the last geometric
    step it reached (matches or inliers)."""

    frame: int
    cand_frame: int
    score: float
    min_score: float
    stage: str
    inliers: int = 0


class LoopCloser:
    def __init__(self, map_: Map, proj: Projector, config: SlamConfig, vocabulary: BowVocabulary, mapper: LocalMapper):
        self.map = map_
        self.proj = proj
        self.cfg = config.engine
        self.mapper = mapper
        self.db = KeyFrameDatabase(vocabulary, map_, self.cfg)
        self.groups: list[tuple[set[int], int]] = []  # ORB-SLAM's consistent groups: (keyframes, consistency)
        self.last_loop_kf = -(10 ** 9)
        self.loops: list[Loop] = []
        self.loop_edges: list[tuple[int, int]] = []
        self.log: list[Candidate] = []
        self.detect_s: list[float] = []  # per keyframe: database entry and detection (without the correction)
        self.detect_cpu_s: list[float] = []  # ... the same in this thread's CPU time (steadier on a busy machine)

    # ================================================================== per keyframe
    def insert(self, kf: KeyFrame) -> Loop | None:
        """Enter ``kf`` in the database and look for a loop; close it when one is found (returns it)."""
        t0, c0 = time.perf_counter(), time.thread_time()
        self.db.add(kf)
        found = self.detect(kf)
        self.detect_s.append(time.perf_counter() - t0)
        self.detect_cpu_s.append(time.thread_time() - c0)
        if found is None:
            return None
        cand, score, geo = found
        t1 = time.perf_counter()
        loop = Loop(kf.id, cand.id, kf.frame_index, cand.frame_index, score, geo.inliers, len(geo.kp),
                    geo.Tcw @ inv(cand.Tcw), poses_before=self._poses())
        self.correct(kf, cand, geo)
        loop.seconds = time.perf_counter() - t1
        loop.poses_after = self._poses()
        self.loops.append(loop)
        self.last_loop_kf = kf.id
        return loop

    def _poses(self) -> dict:
        return {k.id: k.Tcw.copy() for k in self.map.keyframes if not k.bad}

    # ================================================================== detection
    def detect(self, kf: KeyFrame):
        """ORB-SLAM ``DetectLoop`` + ``ComputeSim3``: (loop keyframe, score, Geometry) or None."""
        cfg, db = self.cfg, self.db
        if len(self.map.keyframes) < cfg.loops.loop_min_keyframes or kf.id < self.last_loop_kf + cfg.loops.loop_gap:
            return None
        connected = db.connected(kf.id)
        if not connected:
            self.groups = []
            return None
        min_score = float(db.scores(db.bows[kf.id], np.array(connected)).min())
        cands, passed = db.loop_candidates(kf.id, min_score)
        best_of = {c: s for c, _, s in cands}
        for k, s in passed:
            if k not in best_of:
                self.log.append(Candidate(kf.frame_index, self.map.keyframes[k].frame_index, s, min_score, "score"))
        if not cands:
            self.groups = []
            return None
        consistent = self.consistent([c for c, _, _ in cands])
        for c, _, s in cands:
            if c not in consistent:
                self.log.append(Candidate(kf.frame_index, self.map.keyframes[c].frame_index, s, min_score, "group"))
        for c in consistent:
            cand = self.map.keyframes[c]
            geo, count = self.geometry(kf, cand)
            ok = geo is not None and geo.inliers >= cfg.loops.loop_min_matches
            self.log.append(Candidate(kf.frame_index, cand.frame_index, best_of[c], min_score,
                                      "loop" if ok else "geometry", count))
            if ok:
                return cand, best_of[c], geo
        return None

    def consistent(self, cands: list[int]) -> list[int]:
        """ORB-SLAM's covisibility consistency: each candidate's group (itself and its connected keyframes) is
        consistent with a previous group when they share a keyframe, and carries its consistency + 1; candidates
        reaching ``loop_consistency`` are returned (in candidate order). The groups are kept for the next
        keyframe."""
        out, current = [], []
        taken = [False] * len(self.groups)
        for c in cands:
            group = {c, *self.db.connected(c)}
            enough, some = False, False
            for g, (prev, n) in enumerate(self.groups):
                if group & prev:
                    some = True
                    if not taken[g]:
                        current.append((group, n + 1))
                        taken[g] = True
                    if n + 1 >= self.cfg.loops.loop_consistency and not enough:
                        out.append(c)
                        enough = True
            if not some:
                current.append((group, 0))
        self.groups = current
        return out

    # ================================================================== geometry
    def usable_points(self, kf_ids: list[int]) -> np.ndarray:
        """The points of these keyframes that take part in the loop: alive, not marked dynamic."""
        P = self.map.points
        pts = np.unique(np.concatenate([self.map.keyframes[k].mp for k in kf_ids] + [np.zeros(0, np.int64)]))
        pts = pts[pts >= 0]
        return pts[P.alive[pts] & (P.belief[pts] <= self.cfg.mappoint_belief_threshold)]

    def geometry(self, kf: KeyFrame, cand: KeyFrame) -> tuple[Geometry | None, int]:
        """The keyframe's pose in the candidate's map (see module docstring), or None when a step has too few
        matches, and the count of the last step reached (the final inliers, which the caller compares with
        ``loop_min_matches``). The initial matches are ORB-SLAM's ``SearchByBoW`` (same vocabulary node, ratio
        ``loop_nn_ratio``, Hamming <= ``desc_th_low``, orientation check)."""
        cfg, proj, P = self.cfg, self.proj, self.map.points
        static = np.ones(len(kf.kps), bool)
        if kf.dynamic is not None and not cfg.loops.loop_dynamic_keypoints:
            static = ~kf.dynamic
        own = kf.mp[kf.mp >= 0]
        # the keyframe's static keypoints with depth (3D) against the candidate's usable points it does not see
        na = np.where(static & (kf.depth > 0), self.db.bows[kf.id].kp_nodes, -1)
        usable = np.zeros(len(cand.kps), bool)
        has = np.flatnonzero(cand.mp >= 0)
        pts_ok = self.usable_points([cand.id])
        usable[has] = np.isin(cand.mp[has], pts_ok) & ~np.isin(cand.mp[has], own)
        nb = np.where(usable, self.db.bows[cand.id].kp_nodes, -1)
        m = search_by_bow(na, kf.desc, nb, cand.desc, cfg.loops.loop_nn_ratio, cfg.desc_th_low)
        if cfg.check_orientation and len(m):
            m = m[rotation_consistent(kf.angle[m[:, 0]], cand.angle[m[:, 1]], cfg.rotation_histogram_bins)]
        if len(m) < cfg.loops.loop_min_inliers:
            return None, len(m)
        a, b = m[:, 0], m[:, 1]
        T, inl = self.ransac(kf, cand, a, b)
        if T is None or inl.sum() < cfg.loops.loop_min_inliers:
            return None, int(inl.sum())
        a, pts = a[inl], cand.mp[b[inl]]
        T, good = pose_optimization(T, P.pos[pts], kf.kps[a], kf.ur[a], kf.inv_sigma2[a], proj.K, proj.bf, cfg)
        if good.sum() < cfg.loops.loop_min_inliers:
            return None, int(good.sum())
        # guided: the window's points projected with that pose
        window = self.usable_points([cand.id] + self.db.best_covisibles(cand.id, cfg.loops.loop_window))
        window = window[~np.isin(window, own)]
        kp, pid = self.search(kf, T, window, static, a[good], pts[good])
        T, good = pose_optimization(T, P.pos[pid], kf.kps[kp], kf.ur[kp], kf.inv_sigma2[kp], proj.K, proj.bf, cfg)
        n = int(good.sum())
        return Geometry(T, kp[good], pid[good], window, n), n

    def ransac(self, kf: KeyFrame, cand: KeyFrame, a: np.ndarray, b: np.ndarray):
        """Rigid ``Tcw`` of ``kf`` in the candidate's map from 3-point samples of the matches (keypoint ``a`` of
        ``kf`` with depth, point of keypoint ``b`` of ``cand``): Kabsch on all hypotheses at once; inliers project
        within ``loop_ransac_chi2`` sigma^2 in both keyframes (ORB-SLAM ``Sim3Solver::CheckInliers``); the best
        hypothesis (first on ties) is refitted to its inliers. Seeded by ``EngineConfig.seed`` and the frame index."""
        cfg, proj = self.cfg, self.proj
        Pc = proj.backproject(kf.kps[a], kf.depth[a])  # in the current camera
        X = self.map.points.pos[cand.mp[b]]  # in the loop's map
        m = len(a)
        rng = np.random.default_rng([int(cfg.seed), int(kf.frame_index)])
        s = rng.integers(0, m, size=(cfg.loops.loop_ransac_iterations, 3))
        s = s[(s[:, 0] != s[:, 1]) & (s[:, 0] != s[:, 2]) & (s[:, 1] != s[:, 2])]
        if len(s) == 0:
            return None, np.zeros(m, bool)
        R, t = kabsch(X[s], Pc[s])
        inl = self._inliers(R, t, X, Pc, kf, cand, a, b)
        best = int(np.argmax(inl.sum(axis=1)))
        if inl[best].sum() < 3:
            return None, np.zeros(m, bool)
        sel = inl[best]
        R1, t1 = kabsch(X[sel][None], Pc[sel][None])
        inl1 = self._inliers(R1, t1, X, Pc, kf, cand, a, b)[0]
        if inl1.sum() < sel.sum():
            R1, t1, inl1 = R[best][None], t[best][None], sel
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = R1[0], t1[0]
        return T, inl1

    def _inliers(self, R, t, X, Pc, kf, cand, a, b) -> np.ndarray:
        """(H, M) inlier masks of hypotheses ``Pc = R X + t``: X projected into ``kf`` and ``Pc`` mapped back into
        the candidate, both within ``loop_ransac_chi2`` x sigma^2 pixels^2 of their keypoints."""
        K, th = self.proj.K, self.cfg.loops.loop_ransac_chi2
        Xc = np.einsum("hij,mj->hmi", R, X) + t[:, None, :]
        e1 = _sq_error(Xc, kf.kps[a], K) * kf.inv_sigma2[a]
        Xw = np.einsum("hji,hmj->hmi", R, Pc[None] - t[:, None, :])  # R^T (Pc - t)
        Xk = Xw @ cand.Tcw[:3, :3].T + cand.Tcw[:3, 3]
        e2 = _sq_error(Xk, cand.kps[b], K) * cand.inv_sigma2[b]
        return (e1 < th) & (e2 < th) & (Xc[..., 2] > 0) & (Xk[..., 2] > 0)

    def search(self, kf: KeyFrame, Tcw: np.ndarray, window: np.ndarray, static: np.ndarray, kp0: np.ndarray,
               pts0: np.ndarray):
        """ORB-SLAM ``SearchByProjection`` for loops: the window's points not yet matched projected into ``kf``
        with ``Tcw`` (frustum and scale prediction), the best static free keypoint within ``loop_search_radius`` x
        scale on the predicted level and the one below, Hamming <= ``desc_th_low``. Returns the matches with the
        given ones (keypoints, points)."""
        cfg, proj, P = self.cfg, self.proj, self.map.points
        pids = window[~np.isin(window, pts0)]
        free = static.copy()
        free[kp0] = False
        kp, pid = kp0, pts0
        if len(pids):
            pids, u, v, z, level, _ = proj.in_frustum(P, Tcw, pids)
            if len(pids):
                radius = cfg.loops.loop_search_radius * proj.scales[level]
                best, d1, _, _, _ = search_by_projection(kf.grid(cfg.search_grid_cell), np.c_[u, v], u - proj.bf / z,
                                                         radius, level - 1, level, P.desc[pids], free)
                ok = (best >= 0) & (d1 <= cfg.desc_th_low)
                k2, p2, d2 = best[ok], pids[ok], d1[ok].astype(np.float64)
                keep = unique_by_target(p2, k2, d2)
                kp, pid = np.r_[kp0, k2[keep]], np.r_[pts0, p2[keep]]
        return kp, pid

    # ================================================================== correction
    def correct(self, kf: KeyFrame, loop_kf: KeyFrame, geo: Geometry) -> None:
        """ORB-SLAM ``CorrectLoop`` (see module docstring)."""
        M, P, db, cfg = self.map, self.map.points, self.db, self.cfg
        kfs = M.keyframes
        group = [kf.id] + db.connected(kf.id)
        before = {k: kfs[k].Tcw.copy() for k in group}
        Twc_old = inv(kf.Tcw)
        corrected = {k: before[k] @ Twc_old @ geo.Tcw for k in group}  # T_iw_corr = T_ik T_kw_corr
        # the group's points follow the first keyframe of the group that sees them
        by = np.full(P.n, -1, np.int64)
        for k in group:
            pts = kfs[k].mp[kfs[k].mp >= 0]
            pts = pts[P.alive[pts] & (by[pts] < 0)]
            by[pts] = k
        for k in group:
            pts = np.flatnonzero(by == k)
            if len(pts):
                D = inv(corrected[k]) @ before[k]  # world -> world correction of the points seen from k
                P.pos[pts] = P.pos[pts] @ D[:3, :3].T + D[:3, 3]
                P.normal[pts] = P.normal[pts] @ D[:3, :3].T
            kfs[k].Tcw = corrected[k]
        # the loop's matches: the current keyframe's points are replaced by the loop's
        here = kf.mp[geo.kp]
        same = here == geo.pts
        fresh = here < 0
        self.map.add_observations(kf, geo.kp[fresh], geo.pts[fresh])
        rep = ~fresh & ~same & P.alive[np.maximum(here, 0)]
        self.map.replace_points(here[rep], geo.pts[rep])
        # the window's points fused into the group (corrected poses)
        for k in group:
            if not kfs[k].bad:
                self.mapper.fuse_into(kfs[k], geo.window_pts[P.alive[geo.window_pts]], cfg.loops.loop_fuse_radius)
        # new connections made by the fusion: the loop edges of the essential graph
        previous = {k: set(db.weights.get(k, {})) for k in group}
        links = []
        for k in group:
            db.update_connections(k)
            for c in db.connected(k):
                if c not in previous[k] and c not in group:
                    links.append((k, c))
        self.loop_edges.append((kf.id, loop_kf.id))
        self.optimise(loop_kf, before, corrected, by, links)

    def optimise(self, loop_kf: KeyFrame, before: dict, corrected: dict, by: np.ndarray, links: list) -> None:
        """Pose-graph optimisation of the essential graph, the points moved with their reference keyframes, then a
        full bundle adjustment."""
        M, P, db, cfg = self.map, self.map.points, self.db, self.cfg
        kfs = M.keyframes
        good = np.array([k.id for k in kfs if not k.bad], np.int64)
        idx = np.full(len(kfs), -1, np.int64)
        idx[good] = np.arange(len(good))
        start = np.stack([kfs[k].Tcw for k in good])  # corrected for the group, as they were for the others
        uncorrected = np.stack([before.get(int(k), kfs[k].Tcw) for k in good])
        edges: dict[tuple[int, int], bool] = {}  # (i, j) -> measured from the corrected poses (new loop links)
        for i, j in links:
            edges[(min(i, j), max(i, j))] = True
        for i, j in self.loop_edges:
            edges.setdefault((min(i, j), max(i, j)), False)
        for k in good.tolist():
            p = db.tree_parent(k)
            if p is not None:
                edges.setdefault((min(k, p), max(k, p)), False)
        W = covisibility_matrix(M)
        ii, jj = np.nonzero(np.triu(W >= cfg.loops.essential_min_shared, 1))
        for i, j in zip(ii.tolist(), jj.tolist()):
            if idx[i] >= 0 and idx[j] >= 0:
                edges.setdefault((i, j), False)
        pairs = [(i, j, c) for (i, j), c in edges.items() if idx[i] >= 0 and idx[j] >= 0]
        ei = idx[np.array([p[0] for p in pairs], np.int64)]
        ej = idx[np.array([p[1] for p in pairs], np.int64)]
        from_corr = np.array([p[2] for p in pairs], bool)
        src = np.where(from_corr[:, None, None], start[ei], uncorrected[ei]), \
            np.where(from_corr[:, None, None], start[ej], uncorrected[ej])
        meas = src[0] @ inverse_batch(src[1])  # T_i T_j^-1
        fixed = np.zeros(len(good), bool)
        fixed[idx[loop_kf.id]] = True
        poses = pose_graph_optimization(start, fixed, ei, ej, meas, cfg.loops.loop_pgo_iterations)
        # every point follows its reference keyframe: the group keyframe that corrected it, else its first good
        # observer
        ref = by.copy()
        obs = np.flatnonzero(M.obs.view("valid"))
        first = np.full(P.n, np.iinfo(np.int64).max)
        np.minimum.at(first, M.obs.pt[obs], M.obs.kf[obs])
        ref[ref < 0] = first[ref < 0]
        alive = np.flatnonzero(P.view("alive") & (ref < len(kfs)) & (ref >= 0))
        alive = alive[idx[ref[alive]] >= 0]
        r = idx[ref[alive]]
        D = inverse_batch(poses[r]) @ start[r]
        P.pos[alive] = np.einsum("nij,nj->ni", D[:, :3, :3], P.pos[alive]) + D[:, :3, 3]
        P.normal[alive] = np.einsum("nij,nj->ni", D[:, :3, :3], P.normal[alive])
        for n, k in enumerate(good.tolist()):
            kfs[k].Tcw = poses[n]
        self.mapper.global_bundle_adjustment(cfg.loops.loop_full_ba_iterations)


def covisibility_matrix(map_: Map) -> np.ndarray:
    """(n_keyframes, n_keyframes) shared points of every pair of good keyframes (alive points), by one sparse
    product of the keyframe-point incidence."""
    M = map_
    rows = np.flatnonzero(M.obs.view("valid"))
    pt, kf = M.obs.pt[rows], M.obs.kf[rows]
    keep = M.points.alive[pt] & ~np.array([k.bad for k in M.keyframes])[kf]
    n = len(M.keyframes)
    A = csr_matrix((np.ones(int(keep.sum()), np.float64), (kf[keep], pt[keep])), shape=(n, M.points.n))
    W = (A @ A.T).toarray()
    np.fill_diagonal(W, 0)
    return W.astype(np.int64)


def kabsch(X: np.ndarray, Y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Rigid (R, t) with ``Y = R X + t`` in least squares for each of H sets of (M, 3) points (``X``, ``Y`` of shape
    (H, M, 3)); returns (H, 3, 3), (H, 3)."""
    mx, my = X.mean(axis=1), Y.mean(axis=1)
    H = np.einsum("hmi,hmj->hij", X - mx[:, None], Y - my[:, None])
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(np.einsum("hji,hkj->hik", Vt, U)))  # det(V U^T)
    D = np.zeros_like(H)
    D[:, 0, 0] = D[:, 1, 1] = 1.0
    D[:, 2, 2] = np.where(d == 0, 1.0, d)
    R = np.einsum("hji,hjk,hlk->hil", Vt, D, U)  # V D U^T
    return R, my - np.einsum("hij,hj->hi", R, mx)


def _sq_error(Xc: np.ndarray, uv: np.ndarray, K: np.ndarray) -> np.ndarray:
    z = np.where(Xc[..., 2] > 1e-9, Xc[..., 2], 1e-9)
    du = K[0, 0] * Xc[..., 0] / z + K[0, 2] - uv[:, 0]
    dv = K[1, 1] * Xc[..., 1] / z + K[1, 2] - uv[:, 1]
    return du * du + dv * dv
