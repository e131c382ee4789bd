"""Local mapping (ORB-SLAM3 ``LocalMapping``) for a new keyframe, run synchronously (deterministic): the points'
descriptors, normals and distance ranges (``ProcessNewKeyFrame``), culling of recent points, new points triangulated
with the covisible keyframes (``CreateNewMapPoints``), the fusion of duplicate points with the neighbours
(``SearchInNeighbors``), local bundle adjustment, keyframe culling. Each ORB-SLAM3 step that our engine long did
without is a switch of ``EngineConfig``. An online run may solve the local BA beside tracking (``MappingThread``),
written back between frames."""

from __future__ import annotations

from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from d2slam.slam.config import EngineConfig, SlamConfig
from d2slam.slam import geometric_tools
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.matching import (CHECK_CHI2, rotation_consistent, search_by_projection, search_for_triangulation,
                                  unique_by_target)
from d2slam.slam.optimizer import image_chi2, local_bundle_adjustment
from d2slam.slam.projection import Projector, inv


@dataclass
class Adjustment:
    """A bundle adjustment posed on copies of the map's values (``LocalMapper.problem``): observation ``rows`` (their
    keyframes' places in ``cams``: ``obs_cam``), the points ``pts`` (``pinv``: each row's place in
    them), the measurements, the starting ``poses`` and positions ``X``. :meth:`solve` reads nothing else, so it may
    run beside tracking; ``LocalMapper.apply`` writes its solution back."""

    rows: np.ndarray
    cams: np.ndarray
    fixed: np.ndarray
    pts: np.ndarray
    pinv: np.ndarray
    obs_cam: np.ndarray
    uv: np.ndarray
    ur: np.ndarray
    inv_s2: np.ndarray
    poses: np.ndarray
    X: np.ndarray
    iterations: int
    erase_outliers: bool
    K: np.ndarray
    bf: float
    cfg: EngineConfig

    def solve(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(poses, points, outlier observations): ``optimizer.local_bundle_adjustment``."""
        return local_bundle_adjustment(self.poses, self.fixed, self.X, self.obs_cam, self.pinv, self.uv, self.ur,
                                       self.inv_s2, self.K, self.bf, self.cfg, self.iterations)


def _nothing() -> None:
    """The job of a local BA with nothing to adjust."""


class MappingThread:
    """Local BA beside tracking, in one worker thread (ORB-SLAM3 runs LocalMapping in its own thread; the compiled
    solver releases the interpreter's lock). A job's solution is written back between frames by
    ``LocalMapper.collect``: whether it is done by a given frame depends on timing, so an online run records the
    frames where it was written back and its replay gives them again (``d2slam.run.online``)."""

    def __init__(self):
        self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="d2slam-mapping")

    def start(self, fn) -> Future:
        return self._pool.submit(fn)

    @staticmethod
    def ready(job: Future) -> bool:
        return job.done()

    @staticmethod
    def result(job: Future):
        return job.result()

    def close(self) -> None:
        self._pool.shutdown(wait=True)


class LocalMapper:
    def __init__(self, map_: Map, proj: Projector, config: SlamConfig, vocabulary=None, background=None):
        self.map = map_
        self.proj = proj
        self.cfg = config.engine
        self.orb = config.orb
        self.vocabulary = vocabulary  # BowVocabulary: the feature-vector nodes of triangulation's search (or None)
        self.background = background  # solves local BA beside tracking (MappingThread), or None: at once
        self.pending: KeyFrame | None = None  # keyframe whose local BA and culling wait for an idle frame
        self.running: tuple | None = None  # (keyframe, Adjustment or None, job) of a local BA beside tracking

    def insert(self, kf: KeyFrame) -> list[int]:
        """Map the new keyframe ``kf``: recent points culled, neighbours searched, then (``MappingConfig.ba_when_idle``)
        its local BA and keyframe culling wait for ``idle`` (a waiting keyframe's are dropped, as ORB-SLAM3's local
        mapping skips them when the next keyframe is already queued), or run now. Returns the keyframes culled."""
        self.pending = None
        cfg = self.cfg
        if cfg.mapping.update_points:  # ProcessNewKeyFrame: the points the keyframe observes now
            self.map.update_points(kf.mp[kf.mp >= 0], self.proj.scales)
        self.map_point_culling(kf)
        if cfg.mapping.triangulate_neighbours:
            self.create_new_map_points(kf)
        if cfg.mapping.fuse_neighbours:
            self.search_in_neighbors(kf)
        if cfg.mapping.ba_when_idle:
            self.pending = kf
            return []
        return self.optimise(kf)

    def idle(self, now: bool = False) -> tuple[KeyFrame | None, list[int]]:
        """A frame without a new keyframe: the pending keyframe's local BA and keyframe culling run. With a
        ``background`` (and not ``now``) its local BA starts beside tracking instead, as in ORB-SLAM3's LocalMapping
        thread, and :meth:`collect` ends it. Returns (the keyframe whose mapping ended, or None; the keyframes
        culled)."""
        kf, self.pending = self.pending, None
        if kf is None:
            return None, []
        if self.background is None or now:
            return kf, self.optimise(kf)
        ba = self.local_ba_problem(kf)
        self.running = (kf, ba, self.background.start(ba.solve if ba is not None else _nothing))
        return None, []

    def collect(self, wait: bool) -> tuple[KeyFrame | None, list[int]]:
        """The local BA running beside tracking, if its background says it is done (``wait``: once it is done): its
        solution is written back and the keyframe culling runs. Called between frames only, so tracking never sees a
        map half written. Returns (its keyframe or None, the keyframes culled)."""
        if self.running is None or not (wait or self.background.ready(self.running[2])):
            return None, []
        (kf, ba, job), self.running = self.running, None
        solution = self.background.result(job)
        if ba is not None:
            self.apply(ba, solution)
        return kf, self.keyframe_culling(kf)

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
        """ORB-SLAM3 SearchInNeighbors: the targets are the new keyframe's best ``fuse_neighbours`` covisibles and
        their best ``fuse_second_neighbours`` covisibles; the new keyframe's points are fused into every target, then
        all the targets' points into the new keyframe (``fuse_into``: an observation where the keypoint is free, the
        two points merged into one where it has a point); then (``update_points``) the descriptors, normals and
        distance ranges of its points and of the merged ones. The reprojection test weighs u_R at 1 px x scale as
        ORB-SLAM3 (``fuse_disparity_model``: with ``disparity_sigma_px``)."""
        cfg = self.cfg
        first = self.covisible(kf.id, cfg.mapping.fuse_neighbours)
        targets = list(first)
        for k in first:
            targets += [c for c in self.covisible(k, cfg.mapping.fuse_second_neighbours) if c != kf.id]
        targets = list(dict.fromkeys(targets))
        if not targets:
            return
        sigma = cfg.disparity_sigma_px if cfg.mapping.fuse_disparity_model else 0.0
        own = kf.mp[kf.mp >= 0]
        merged = [self.fuse_into(self.map.keyframes[k], own, cfg.mapping.fuse_radius, sigma, merge_all=True) for k in targets]
        pts = np.concatenate([self.map.keyframes[k].mp for k in targets])
        merged.append(self.fuse_into(kf, pts[pts >= 0], cfg.mapping.fuse_radius, sigma, merge_all=True))
        if cfg.mapping.update_points:
            self.map.update_points(np.concatenate([kf.mp[kf.mp >= 0], *merged]), self.proj.scales)

    def fuse_into(self, kf: KeyFrame, pids: np.ndarray, th: float, disparity_sigma: float | None = None,
                  merge_all: bool = False) -> np.ndarray:
        """ORB-SLAM ORBmatcher::Fuse(pKF, points), vectorised: points not yet seen by ``kf`` are projected into it
        (depth, frustum, scale range, viewing angle), their predicted level gives the radius ``th`` x scale and the
        levels [level - 1, level]; the nearest (Hamming) static keypoint whose reprojection passes the chi-square
        test (u_R weighed with ``disparity_sigma``, default ``disparity_sigma_px``; 0: 1 px x scale) is the point's
        match when the distance is <= TH_LOW. The best point of each keypoint becomes an observation where the
        keypoint is free; where it has a point, the two are one point: the one with more observations survives (ties:
        the projected one, as ORB-SLAM3). ``merge_all``: the other points matched to the same keypoint merge into it
        too (ORB-SLAM3 fuses points one after the other, so a second point meets the first one there). Returns the
        surviving points of the merges."""
        cfg, proj = self.cfg, self.proj
        P = self.map.points
        pids = np.unique(pids)
        pids = pids[P.alive[pids] & (P.belief[pids] <= cfg.mappoint_belief_threshold)]
        seen = np.zeros(P.n, dtype=bool)
        seen[kf.mp[kf.mp >= 0]] = True
        pids = pids[~seen[pids]]
        if len(pids) == 0 or len(kf.kps) == 0:
            return np.zeros(0, dtype=np.int64)
        pids, u, v, z, level, _ = proj.in_frustum(P, kf.Tcw, pids)
        if len(pids) == 0:
            return np.zeros(0, dtype=np.int64)
        usable = np.ones(len(kf.kps), dtype=bool) if kf.dynamic is None else ~kf.dynamic
        sigma = cfg.disparity_sigma_px if disparity_sigma is None else disparity_sigma
        best, d1, _, _, _ = search_by_projection(kf.grid(cfg.search_grid_cell), np.c_[u, v], u - proj.bf / z,
                                                 th * proj.scales[level], level - 1, level, P.desc[pids], usable,
                                                 CHECK_CHI2, kf.inv_sigma2, sigma, cfg.chi2_mono, cfg.chi2_stereo)
        sel = (best >= 0) & (d1 <= cfg.desc_th_low)
        kp, pid, d = best[sel], pids[sel], d1[sel].astype(np.float64)
        keep = unique_by_target(pid, kp, d)
        free = kf.mp[kp[keep]] < 0
        self.map.add_observations(kf, kp[keep][free], pid[keep][free])
        if not merge_all:
            kp, pid = kp[keep], pid[keep]
        return self._merge_at_keypoints(kf, kp, pid)

    def _merge_at_keypoints(self, kf: KeyFrame, kp: np.ndarray, pid: np.ndarray) -> np.ndarray:
        """Each point ``pid`` matched to keypoint ``kp`` of ``kf`` (which has a point now) is one point with the point
        there: per keypoint the point with the most observations survives (ties: not the one already there), the
        others are replaced by it (``Map.replace_points``). Returns the survivors."""
        P = self.map.points
        there = kf.mp[kp]
        other = pid != there
        kp, pid, there = kp[other], pid[other], there[other]
        if len(kp) == 0:
            return np.zeros(0, dtype=np.int64)
        group = np.r_[kp, np.unique(kp)]
        member = np.r_[pid, kf.mp[np.unique(kp)]]
        is_there = np.r_[np.zeros(len(kp), bool), np.ones(len(group) - len(kp), bool)]
        order = np.lexsort((is_there, -P.nobs[member], group))
        group, member = group[order], member[order]
        head = np.r_[True, group[1:] != group[:-1]]
        survivor = member[head][np.cumsum(head) - 1]
        self.map.replace_points(member[~head], survivor[~head])
        return np.unique(member[head])

    # ------------------------------------------------------------------ CreateNewMapPoints
    def create_new_map_points(self, kf: KeyFrame) -> int:
        """ORB-SLAM3 CreateNewMapPoints: the new keyframe's keypoints without a point are matched with those of each
        of its best ``triangulate_neighbours`` covisibles (whose centre lies at least the baseline b away):
        ``triangulation_matches``; each match that passes ``geometric_tools.new_points`` becomes a point observed by
        both keyframes (descriptor, normal and distance range from its observations), on the recent list of
        MapPointCulling. Returns the points made."""
        cfg, made = self.cfg, 0
        C1 = inv(kf.Tcw)[:3, 3]
        for k in self.covisible(kf.id, cfg.mapping.triangulate_neighbours):
            kf2 = self.map.keyframes[k]
            if np.linalg.norm(inv(kf2.Tcw)[:3, 3] - C1) < self.proj.b:
                continue
            i1, i2 = self.triangulation_matches(kf, kf2)
            if len(i1) == 0:
                continue
            v1 = geometric_tools.View(kf.Tcw, kf.kps[i1], kf.ur[i1], kf.depth[i1], kf.octave[i1])
            v2 = geometric_tools.View(kf2.Tcw, kf2.kps[i2], kf2.ur[i2], kf2.depth[i2], kf2.octave[i2])
            X, ok = geometric_tools.new_points(v1, v2, self.proj, cfg.mapping.triangulation_max_cos_parallax,
                                               cfg.chi2_mono, cfg.chi2_stereo,
                                               cfg.mapping.triangulation_ratio_factor * self.orb.scale_factor)
            made += len(self._add_triangulated(kf, kf2, i1[ok], i2[ok], X[ok]))
        return made

    def triangulation_matches(self, kf1: KeyFrame, kf2: KeyFrame) -> tuple[np.ndarray, np.ndarray]:
        """ORB-SLAM3 ORBmatcher::SearchForTriangulation: the free static keypoints of ``kf1`` and ``kf2`` under the
        same vocabulary feature-vector node (every pair without a vocabulary) within Hamming ``desc_th_low``, the
        epipolar test at ``triangulation_epipolar_chi2`` x sigma^2 and, for two keypoints without depth, outside
        ``triangulation_epipole_px`` x sqrt(scale) of the epipole; the orientation check; one keypoint of ``kf2`` per
        keypoint of ``kf1`` and back (the nearest; ORB-SLAM3 1.0 lets two share one)."""
        cfg, proj = self.cfg, self.proj
        f1 = np.flatnonzero((kf1.mp < 0) & self._static(kf1))
        f2 = np.flatnonzero((kf2.mp < 0) & self._static(kf2))
        if len(f1) == 0 or len(f2) == 0:
            return f1[:0], f2[:0]
        rows = search_for_triangulation(self._nodes(kf1)[f1], kf1.kps[f1], kf1.ur[f1] >= 0, kf1.desc[f1],
                                        self._nodes(kf2)[f2], kf2.kps[f2], kf2.ur[f2] >= 0, kf2.octave[f2],
                                        kf2.desc[f2], geometric_tools.fundamental_matrix(kf1.Tcw, kf2.Tcw, proj.K),
                                        geometric_tools.epipole(kf1.Tcw, kf2.Tcw, proj.K), proj.scales ** 2,
                                        cfg.desc_th_low, cfg.mapping.triangulation_epipolar_chi2,
                                        cfg.mapping.triangulation_epipole_px ** 2, proj.scales)
        i1, i2 = f1[rows[:, 0]], f2[rows[:, 1]]
        if cfg.check_orientation and len(i1):
            ok = rotation_consistent(kf1.angle[i1], kf2.angle[i2], cfg.rotation_histogram_bins)
            i1, i2, rows = i1[ok], i2[ok], rows[ok]
        keep = unique_by_target(i1, i2, rows[:, 2].astype(np.float64))
        return i1[keep], i2[keep]

    @staticmethod
    def _static(kf: KeyFrame) -> np.ndarray:
        return np.ones(len(kf.kps), dtype=bool) if kf.dynamic is None else ~kf.dynamic

    def _nodes(self, kf: KeyFrame) -> np.ndarray:
        """The keypoints' vocabulary feature-vector nodes (ORB-SLAM3 ``ComputeBoW``), computed once per keyframe; all
        0 without a vocabulary."""
        if kf.fv_nodes is None:
            kf.fv_nodes = np.zeros(len(kf.kps), dtype=np.int64) if self.vocabulary is None else \
                self.vocabulary.transform(kf.desc, self.cfg.loops.bow_levelsup)[1]
        return kf.fv_nodes

    def _add_triangulated(self, kf1: KeyFrame, kf2: KeyFrame, i1: np.ndarray, i2: np.ndarray,
                          X: np.ndarray) -> np.ndarray:
        """New points at ``X`` observed by keypoints ``i1`` of ``kf1`` (their maker) and ``i2`` of ``kf2``, belief 0
        (both keypoints static), their descriptor, normal and distance range from the two observations."""
        M = self.map
        if len(i1) == 0:
            return i1
        C1 = inv(kf1.Tcw)[:3, 3]
        PO = X - C1
        dist = np.linalg.norm(PO, axis=1)
        dmax = dist * self.proj.scales[kf1.octave[i1]]
        ids = M.add_points(X, kf1.desc[i1], PO / dist[:, None], dmax / self.proj.scales[-1], dmax, np.zeros(len(i1)),
                           kf1.id, kf1.angle[i1], kf1.octave[i1])
        M.add_observations(kf1, i1, ids)
        M.add_observations(kf2, i2, ids)
        M.update_points(ids, self.proj.scales)
        return ids

    def local_bundle_adjustment(self, kf: KeyFrame) -> None:
        """ORB-SLAM3 LocalBundleAdjustment: the new keyframe and its best covisibles are optimised with all the
        points they see; other keyframes observing those points are fixed, at most ``local_ba_max_fixed`` of them
        (those with most observations of the local points; the others' observations are left out). Outlier
        observations are erased."""
        ba = self.local_ba_problem(kf)
        if ba is not None:
            self.apply(ba, ba.solve())

    def local_ba_problem(self, kf: KeyFrame) -> "Adjustment | None":
        """The local BA of :meth:`local_bundle_adjustment`, posed (None: nothing to adjust)."""
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
            return None
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
            return None
        keep = np.isin(obs_kf, cams)
        return self.problem(rows[keep], obs_kf[keep], cams, fixed, cfg.mapping.local_ba_iterations,
                            erase_outliers=True)

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
        observation ``rows`` (their keyframes ``obs_kf``), written back to the map (:meth:`problem`, :meth:`apply`)."""
        ba = self.problem(rows, obs_kf, cams, fixed, iterations, erase_outliers)
        self.apply(ba, ba.solve())

    def problem(self, rows: np.ndarray, obs_kf: np.ndarray, cams: np.ndarray, fixed: np.ndarray, iterations: int,
                erase_outliers: bool) -> "Adjustment":
        """The bundle adjustment of :meth:`adjust`, its inputs copied out of the map: it can be solved beside
        tracking (:class:`Adjustment`)."""
        M = self.map
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
        return Adjustment(rows, cams, fixed, pts, pinv, cam_of[obs_kf], uv, ur, inv_s2, poses, P.pos[pts],
                          iterations, erase_outliers, self.proj.K, self.proj.bf, self.cfg)

    def apply(self, ba: "Adjustment", solution: tuple) -> None:
        """Write a solved :class:`Adjustment` back: the free keyframes' poses, the points; with ``erase_outliers``
        the observations above the chi2 thresholds are erased, except (``lba_depth_outliers_mono``) those whose image
        residual alone passes the monocular test: their keyframe's depth at the keypoint is dropped
        (``Map.drop_depth``) and they stay as monocular observations. Observations erased since the problem was
        posed stay erased."""
        M, cfg = self.map, self.cfg
        new_poses, new_X, outlier = solution
        for i, c in enumerate(ba.cams):
            if not ba.fixed[i]:
                M.keyframes[c].Tcw = new_poses[i]
        M.points.pos[ba.pts] = new_X
        if ba.erase_outliers:
            out = np.flatnonzero(outlier)
            if cfg.mapping.lba_depth_outliers_mono:  # only the depth disagrees: the image observation stays
                chi2, front = image_chi2(new_poses[ba.obs_cam[out]], new_X[ba.pinv[out]], ba.uv[out],
                                         ba.inv_s2[out], self.proj.K)
                depth_only = (ba.ur[out] >= 0) & (chi2 <= cfg.chi2_mono) & front
                M.drop_depth(ba.rows[out[depth_only]])
                out = out[~depth_only]
            M.erase_observations(ba.rows[out])

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
