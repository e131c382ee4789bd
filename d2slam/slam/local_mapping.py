"""Local mapping (ORB-SLAM3 ``LocalMapping``) for a new keyframe, run synchronously (deterministic): culling of
recent points, the observation part of SearchInNeighbors, local bundle adjustment, keyframe culling."""

from __future__ import annotations

import numpy as np

from d2slam.slam.config import SlamConfig
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.matching import CHECK_CHI2, search_by_projection, unique_by_target
from d2slam.slam.optimizer import image_chi2, local_bundle_adjustment
from d2slam.slam.projection import Projector


class LocalMapper:
    def __init__(self, map_: Map, proj: Projector, config: SlamConfig):
        self.map = map_
        self.proj = proj
        self.cfg = config.engine
        self.pending: KeyFrame | None = None  # keyframe whose local BA and culling wait for an idle frame

    def insert(self, kf: KeyFrame) -> list[int]:
        """Map the new keyframe ``kf``: recent points culled, neighbours searched, then (``MappingConfig.ba_when_idle``)
        its local BA and keyframe culling wait for ``idle`` (a waiting keyframe's are dropped, as ORB-SLAM3's local
        mapping skips them when the next keyframe is already queued), or run now. Returns the keyframes culled."""
        self.pending = None
        self.map_point_culling(kf)
        if self.cfg.mapping.fuse_neighbours:
            self.search_in_neighbors(kf)
        if self.cfg.mapping.ba_when_idle:
            self.pending = kf
            return []
        return self.optimise(kf)

    def idle(self) -> tuple[KeyFrame | None, list[int]]:
        """A frame without a new keyframe: the pending keyframe's local BA and keyframe culling run. Returns (that
        keyframe or None, the keyframes culled)."""
        kf, self.pending = self.pending, None
        return (kf, self.optimise(kf)) if kf is not None else (None, [])

    def optimise(self, kf: KeyFrame) -> list[int]:
        self.local_bundle_adjustment(kf)
        return self.keyframe_culling(kf)

    def covisible(self, kf_id: int, n: int) -> list[int]:
        return self.map.covisible(kf_id, n, self.cfg.covisibility_min_shared)

    def map_point_culling(self, kf: KeyFrame) -> None:
        """ORB-SLAM MapPointCulling over the recently created points: found in too few of the frames that should
        have seen them, or too few observations once ``mappoint_cull_age`` keyframes old; points leave the recent
        list at ``mappoint_recent_age`` keyframes."""
        mc = self.cfg.mapping
        P = self.map.points
        r = self.map.recent_points
        r = r[P.alive[r]]
        ratio = P.found[r] / np.maximum(P.visible[r], 1)
        age = kf.id - P.first_kf[r]
        bad = (ratio < mc.mappoint_found_ratio) | ((age >= mc.mappoint_cull_age) & (P.nobs[r] <= mc.mappoint_min_obs))
        self.map.cull_points(r[bad])
        self.map.recent_points = r[~bad & (age < mc.mappoint_recent_age)]

    def search_in_neighbors(self, kf: KeyFrame) -> None:
        """ORB-SLAM SearchInNeighbors (observation part): the new keyframe's points are searched in its covisible
        keyframes and their neighbours, and those keyframes' points in the new keyframe, so that points seen but not
        tracked gain observations (and survive MapPointCulling); a keypoint that already has another point merges the
        two (``fuse_into``). Off by default (``fuse_neighbours = 0``, see ``EngineConfig``)."""
        first = self.covisible(kf.id, self.cfg.mapping.fuse_neighbours)
        targets = list(first)
        for k in first:
            targets += [c for c in self.covisible(k, self.cfg.mapping.fuse_second_neighbours) if c != kf.id]
        targets = list(dict.fromkeys(targets))
        if not targets:
            return
        th = self.cfg.mapping.fuse_radius
        own = kf.mp[kf.mp >= 0]
        for k in targets:
            self.fuse_into(self.map.keyframes[k], own, th)
        pts = np.concatenate([self.map.keyframes[k].mp for k in targets])
        self.fuse_into(kf, pts[pts >= 0], th)

    def fuse_into(self, kf: KeyFrame, pids: np.ndarray, th: float) -> int:
        """ORB-SLAM ORBmatcher::Fuse(pKF, points), observation part, vectorised: points not yet seen by ``kf`` are
        projected into it (depth, frustum, scale range, viewing angle), their predicted level gives the radius
        ``th`` x scale and the levels [level - 1, level]; a free, static keypoint whose reprojection (with u_R when it
        has depth) passes the chi-square test and whose Hamming distance is <= TH_LOW becomes an observation, one
        point per keypoint. Returns the number of observations added."""
        cfg, proj = self.cfg, self.proj
        P = self.map.points
        pids = np.unique(pids)
        pids = pids[P.alive[pids] & (P.belief[pids] <= cfg.mappoint_belief_threshold)]
        seen = np.zeros(P.n, dtype=bool)
        seen[kf.mp[kf.mp >= 0]] = True
        pids = pids[~seen[pids]]
        if len(pids) == 0 or len(kf.kps) == 0:
            return 0
        pids, u, v, z, level, _ = proj.in_frustum(P, kf.Tcw, pids)
        if len(pids) == 0:
            return 0
        usable = np.ones(len(kf.kps), dtype=bool) if kf.dynamic is None else ~kf.dynamic
        best, d1, _, _, _ = search_by_projection(kf.grid(cfg.search_grid_cell), np.c_[u, v], u - proj.bf / z,
                                                 th * proj.scales[level], level - 1, level, P.desc[pids], usable,
                                                 CHECK_CHI2, kf.inv_sigma2, cfg.disparity_sigma_px, cfg.chi2_mono,
                                                 cfg.chi2_stereo)
        sel = (best >= 0) & (d1 <= cfg.desc_th_low)
        kp, pid, d = best[sel], pids[sel], d1[sel].astype(np.float64)
        keep = unique_by_target(pid, kp, d)
        kp, pid = kp[keep], pid[keep]
        there = kf.mp[kp]
        free = there < 0
        self.map.add_observations(kf, kp[free], pid[free])
        # The keypoint already has a point: the two are one (ORB-SLAM keeps the one with more observations).
        a, b = pid[~free], there[~free]
        b_wins = P.nobs[b] > P.nobs[a]
        self.map.replace_points(np.r_[a[b_wins], b[~b_wins]], np.r_[b[b_wins], a[~b_wins]])
        return len(kp)

    def local_bundle_adjustment(self, kf: KeyFrame) -> None:
        """ORB-SLAM3 LocalBundleAdjustment: the new keyframe and its best covisibles are optimised with all the
        points they see; other keyframes observing those points are fixed, at most ``local_ba_max_fixed`` of them
        (those with most observations of the local points; the others' observations are left out). Outlier
        observations are erased."""
        cfg, M = self.cfg, self.map
        local = [kf.id] + self.covisible(kf.id, cfg.mapping.local_ba_window)
        P = M.points
        pmask = np.zeros(P.n, dtype=bool)
        for k in local:
            m = M.keyframes[k].mp
            pmask[m[m >= 0]] = True
        pmask &= P.view("alive") & (P.view("belief") <= cfg.mappoint_belief_threshold)
        rows = M.observation_rows(pmask)
        if len(rows) == 0:
            return
        obs_kf = M.obs.kf[rows]
        cams = np.unique(obs_kf)
        cams = cams[[not M.keyframes[c].bad for c in cams]]
        is_local = np.isin(cams, local)
        pos = np.minimum(np.searchsorted(cams, obs_kf), len(cams) - 1)
        n_obs = np.bincount(pos[cams[pos] == obs_kf], minlength=len(cams))
        outside = np.flatnonzero(~is_local)
        if len(outside) > cfg.mapping.local_ba_max_fixed:
            drop = outside[np.argsort(-n_obs[outside], kind="stable")[cfg.mapping.local_ba_max_fixed:]]
            cams = np.delete(cams, drop)
            is_local = np.isin(cams, local)
        fixed = ~is_local | (cams == 0)
        if fixed.all():
            return
        keep = np.isin(obs_kf, cams)
        self.adjust(rows[keep], obs_kf[keep], cams, fixed, cfg.mapping.local_ba_iterations, erase_outliers=True)

    def global_bundle_adjustment(self, iterations: int) -> None:
        """ORB-SLAM ``GlobalBundleAdjustemnt``: every good keyframe (the first one fixed) and every live point not
        marked dynamic, over all their observations; no observation is erased."""
        M, cfg = self.map, self.cfg
        P = M.points
        pmask = P.view("alive") & (P.view("belief") <= cfg.mappoint_belief_threshold)
        rows = M.observation_rows(pmask)
        obs_kf = M.obs.kf[rows]
        good = np.array([not k.bad for k in M.keyframes])
        rows, obs_kf = rows[good[obs_kf]], obs_kf[good[obs_kf]]
        cams = np.unique(obs_kf)
        if len(cams) < 2:
            return
        self.adjust(rows, obs_kf, cams, cams == cams[0], iterations, erase_outliers=False)

    def adjust(self, rows: np.ndarray, obs_kf: np.ndarray, cams: np.ndarray, fixed: np.ndarray, iterations: int,
               erase_outliers: bool) -> None:
        """Bundle adjustment of the keyframes ``cams`` (sorted; ``fixed`` held constant) and the points of the
        observation ``rows`` (their keyframes ``obs_kf``), written back to the map; with ``erase_outliers`` the
        observations above the chi2 thresholds afterwards are erased, except (``lba_depth_outliers_mono``) those whose
        image residual alone passes the monocular test: their keyframe's depth at the keypoint is dropped
        (``Map.drop_depth``) and they stay as monocular observations."""
        M, cfg = self.map, self.cfg
        P = M.points
        cam_of = np.full(len(M.keyframes), -1)
        cam_of[cams] = np.arange(len(cams))
        pts, pinv = np.unique(M.obs.pt[rows], return_inverse=True)
        kp = M.obs.kp[rows]
        uv = np.zeros((len(rows), 2))
        ur = np.zeros(len(rows))
        inv_s2 = np.zeros(len(rows))
        for c in cams:
            s = obs_kf == c
            k = M.keyframes[c]
            uv[s], ur[s], inv_s2[s] = k.kps[kp[s]], k.ur[kp[s]], k.inv_sigma2[kp[s]]
        poses = np.stack([M.keyframes[c].Tcw for c in cams])
        new_poses, new_X, outlier = local_bundle_adjustment(poses, fixed, P.pos[pts], cam_of[obs_kf], pinv, uv, ur,
                                                            inv_s2, self.proj.K, self.proj.bf, cfg, iterations)
        for i, c in enumerate(cams):
            if not fixed[i]:
                M.keyframes[c].Tcw = new_poses[i]
        P.pos[pts] = new_X
        if erase_outliers:
            out = np.flatnonzero(outlier)
            if cfg.mapping.lba_depth_outliers_mono:  # only the depth disagrees: the image observation stays
                chi2, front = image_chi2(new_poses[cam_of[obs_kf[out]]], new_X[pinv[out]], uv[out], inv_s2[out],
                                         self.proj.K)
                depth_only = (ur[out] >= 0) & (chi2 <= cfg.chi2_mono) & front
                M.drop_depth(rows[out[depth_only]])
                out = out[~depth_only]
            M.erase_observations(rows[out])

    def keyframe_culling(self, kf: KeyFrame) -> list[int]:
        """ORB-SLAM3 KeyFrameCulling: a covisible keyframe whose close points are ``keyframe_redundancy`` seen by
        more than ``keyframe_redundant_obs`` other keyframes at the same or a finer scale is redundant (the first
        keyframe is never culled). Returns the culled keyframes."""
        cfg, M = self.cfg, self.map
        P = M.points
        culled = []
        for k in self.covisible(kf.id, 10 ** 6):
            if k == 0 or k == kf.id:
                continue
            K_ = M.keyframes[k]
            sel = np.flatnonzero((K_.mp >= 0) & (K_.depth > 0) & (K_.depth < self.proj.th_depth_m))
            sel = sel[P.alive[K_.mp[sel]]]
            if len(sel) == 0:
                continue
            pts = K_.mp[sel]
            cand = P.nobs[pts] > cfg.mapping.keyframe_redundant_obs
            oct_here = np.full(P.n, -1)
            oct_here[pts[cand]] = K_.octave[sel[cand]]
            rows = M.observation_rows(oct_here >= 0)
            rows = rows[M.obs.kf[rows] != k]
            ok = M.obs.octave[rows] <= oct_here[M.obs.pt[rows]] + 1
            cnt = np.bincount(M.obs.pt[rows][ok], minlength=P.n)
            redundant = int((cnt[pts] > cfg.mapping.keyframe_redundant_obs).sum())
            if redundant > cfg.mapping.keyframe_redundancy * len(sel):
                M.set_keyframe_bad(k)
                culled.append(k)
        return culled
