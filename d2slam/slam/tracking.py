"""Tracking (ORB-SLAM3 ``Tracking``, RGB-D): initialisation from depth, the constant-velocity motion model, the
reference keyframe, tracking the local map, the keyframe decision and the creation of keyframes.

Keypoints the hook flagged dynamic (``Frame.dynamic``) take no match and make no point, as if never extracted.
"""

from __future__ import annotations

import numpy as np

from d2slam.slam import relocalisation
from d2slam.slam.config import SlamConfig
from d2slam.slam.frame import Frame
from d2slam.slam.map import KeyFrame, Map
from d2slam.slam.matching import knn_ratio_match, rotation_consistent, search_by_projection, unique_by_target
from d2slam.slam.optimizer import pose_optimization, se3_power
from d2slam.slam.projection import Projector, inv

OK, LOST, NOT_INITIALIZED = "ok", "lost", "not_initialized"


def make_keyframe(map_: Map, frame: Frame) -> KeyFrame:
    """A keyframe of ``frame`` (its pose and features; no observations yet), added to the map."""
    kf = KeyFrame(id=len(map_.keyframes), frame_index=frame.index, timestamp=frame.timestamp, Tcw=frame.Tcw.copy(),
                  kps=frame.kps, octave=frame.octave, angle=frame.angle, desc=frame.desc, depth=frame.depth,
                  ur=frame.ur.copy(), inv_sigma2=frame.inv_sigma2, mp=np.full(frame.n, -1, dtype=np.int64),
                  dynamic=frame.dynamic.copy() if frame.belief is not None else None)
    map_.add_keyframe(kf)
    return kf


def points_from_depth(map_: Map, proj: Projector, kf: KeyFrame, idx: np.ndarray, belief: np.ndarray | None):
    """Map points from depth for keypoints ``idx`` of ``kf`` (back-projection, normal, scale range), observed by
    ``kf``; each starts with its keypoint's dynamic belief (0 without a filter)."""
    if len(idx) == 0:
        return idx
    Twc = inv(kf.Tcw)
    Xw = proj.backproject(kf.kps[idx], kf.depth[idx]) @ Twc[:3, :3].T + Twc[:3, 3]
    PO = Xw - Twc[:3, 3]
    dist = np.linalg.norm(PO, axis=1)
    dmax = dist * proj.scales[kf.octave[idx]]
    dmin = dmax / proj.scales[-1]
    b = np.zeros(len(idx)) if belief is None else belief[idx]
    ids = map_.add_points(Xw, kf.desc[idx], PO / dist[:, None], dmin, dmax, b, kf.id, kf.angle[idx], kf.octave[idx])
    map_.add_observations(kf, idx, ids)
    return ids


class Tracker:
    """Per-frame pose estimation against the map, and the state it carries from frame to frame."""

    def __init__(self, map_: Map, proj: Projector, config: SlamConfig):
        self.map = map_
        self.proj = proj
        self.cfg = config.engine
        self.orb = config.orb
        # new points of a keyframe: every untracked keypoint closer than this (see create_keyframe)
        self.new_points_depth_m = max(proj.th_depth_m, self.cfg.keyframes.kf_new_points_depth)
        self.state = NOT_INITIALIZED
        self.last_tracked: Frame | None = None
        self.velocity: np.ndarray | None = None  # the constant-velocity model's motion over one frame step
        self.ref_kf: KeyFrame | None = None
        self.keyframe_db = None  # the loop closer's KeyFrameDatabase (relocalisation candidates), None without it
        self.last_kf_frame = -(10 ** 9)
        self.last_reloc_frame = -(10 ** 9)
        self.n_inliers = 0

    # ------------------------------------------------------------------ per frame
    def track(self, frame: Frame) -> tuple[bool, str]:
        """Estimate ``frame.Tcw``; returns (tracked, how: "init" | "motion" | "reference" | "relocalisation")."""
        if self.state == NOT_INITIALIZED:
            ok = self.initialize(frame)
            return ok, "init" if ok else ""
        if self.state == OK:
            ok, how = False, ""
            if self.velocity is not None and frame.index - self.last_reloc_frame > 1:
                ok, how = self.track_with_motion_model(frame), "motion"
            if not ok:
                frame.mp[:] = -1
                ok, how = self.track_reference_keyframe(frame), "reference"
        else:
            ok, how = relocalisation.relocalise(self, frame), "relocalisation"
            if ok:
                self.last_reloc_frame = frame.index
        if ok:
            ok = self.track_local_map(frame)
        return ok, how

    def motion(self, index: int) -> np.ndarray | None:
        """The constant-velocity model's prediction ``T_frame_last`` for frame ``index``: ``velocity`` over the frame
        steps since the last tracked frame (more than one where an online run dropped frames; None: no model)."""
        if self.velocity is None or self.last_tracked is None:
            return None
        steps = index - self.last_tracked.index
        return self.velocity if steps == 1 else se3_power(self.velocity, steps)

    def finish(self, frame: Frame, ok: bool) -> None:
        """After tracking (and mapping): the motion model and the last tracked frame, or the loss. The model is the
        motion since the last tracked frame per frame step: across frames never given to the tracker (an online run's
        dropped frames) the motion is shared evenly among them; after a loss there is none."""
        if ok:
            steps = frame.index - self.last_tracked.index if self.last_tracked is not None else 0
            motion = frame.Tcw @ inv(self.last_tracked.Tcw) if steps > 0 else None
            if steps != 1:
                motion = se3_power(motion, 1.0 / steps) if motion is not None and self.state == OK else None
            self.velocity = motion
            self.state = OK
            frame.ref_kf = self.ref_kf.id
            frame.Tcr = frame.Tcw @ inv(self.ref_kf.Tcw)
            frame.mp[frame.outlier] = -1
            frame.outlier[:] = False
            self.last_tracked = frame
        else:
            if self.state == OK:
                self.state = LOST
            self.velocity = None
            frame.Tcw = None

    # ------------------------------------------------------------------ initialisation
    def initialize(self, frame: Frame) -> bool:
        """ORB-SLAM StereoInitialization: first keyframe at the origin, a map point per keypoint with depth."""
        usable = (frame.depth > 0) & ~frame.dynamic
        if usable.sum() < self.cfg.tracking.init_min_keypoints:
            return False
        frame.Tcw = np.eye(4)
        kf = make_keyframe(self.map, frame)
        points_from_depth(self.map, self.proj, kf, np.flatnonzero(usable), frame.belief)
        self.ref_kf = kf
        self.last_kf_frame = frame.index
        frame.mp[:] = kf.mp
        return True

    # ------------------------------------------------------------------ motion model and reference keyframe
    def optimize_pose(self, frame: Frame) -> int:
        """Motion-only BA on the frame's static matches; returns the inliers (outliers are marked)."""
        sel = np.flatnonzero((frame.mp >= 0) & ~frame.dynamic)
        X = self.map.points.pos[frame.mp[sel]]
        T, inl = pose_optimization(frame.Tcw, X, frame.kps[sel], frame.ur[sel], frame.inv_sigma2[sel], self.proj.K,
                                   self.proj.bf, self.cfg)
        frame.Tcw = T
        frame.outlier[:] = False
        frame.outlier[sel[~inl]] = True
        frame.outlier[(frame.mp >= 0) & frame.dynamic] = True  # matched but excluded: not counted as inliers
        return int(inl.sum())

    @staticmethod
    def discard_outliers(frame: Frame) -> None:
        frame.mp[frame.outlier & ~frame.dynamic] = -1
        frame.outlier[:] = False

    def assign(self, frame: Frame, kp: np.ndarray, pid: np.ndarray, dist: np.ndarray, ref_angle: np.ndarray) -> int:
        """One-to-one assignment of points to keypoints, then ORB-SLAM's rotation-consistency check."""
        keep = unique_by_target(pid, kp, dist)
        kp, pid, ref_angle = kp[keep], pid[keep], ref_angle[keep]
        if self.cfg.check_orientation and len(kp):
            ok = rotation_consistent(ref_angle, frame.angle[kp], self.cfg.rotation_histogram_bins)
            kp, pid = kp[ok], pid[ok]
        frame.mp[kp] = pid
        return len(kp)

    def search_projected(self, frame: Frame, uv, ur_proj, radius, lo, hi, desc):
        """Best and second-best free, static keypoint of ``frame`` per projected point (``search_by_projection``)."""
        available = (frame.mp < 0) & ~frame.dynamic  # dynamic keypoints take no match (as if never extracted)
        return search_by_projection(frame.grid(self.cfg.search_grid_cell), uv, ur_proj, radius, lo, hi, desc,
                                    available)

    def search_last_frame(self, frame: Frame, last: Frame, th: float) -> int:
        """ORB-SLAM ``SearchByProjection(CurrentFrame, LastFrame)``: the last frame's points projected with the
        predicted pose, searched on the levels the camera's forward/backward motion allows, orientation check."""
        sel = np.flatnonzero(last.mp >= 0)
        sel = sel[self.map.points.alive[last.mp[sel]]]
        if len(sel) == 0 or frame.n == 0:
            return 0
        pid = last.mp[sel]
        u, v, z = self.proj.project(frame.Tcw, self.map.points.pos[pid])
        ok = (z > 0) & self.proj.in_image(u, v)
        sel, pid, u, v, z = sel[ok], pid[ok], u[ok], v[ok], z[ok]
        Twc = inv(frame.Tcw)
        tlc = last.Tcw[:3, :3] @ Twc[:3, 3] + last.Tcw[:3, 3]
        forward, backward = tlc[2] > self.proj.b, -tlc[2] > self.proj.b
        oct_last = last.octave[sel]
        radius = th * self.proj.scales[oct_last]
        if forward:
            lo, hi = oct_last, np.full_like(oct_last, self.orb.n_levels - 1)
        elif backward:
            lo, hi = np.zeros_like(oct_last), oct_last
        else:
            lo, hi = oct_last - 1, oct_last + 1
        best, d1, _, _, _ = self.search_projected(frame, np.c_[u, v], u - self.proj.bf / z, radius, lo, hi,
                                                  self.map.points.desc[pid])
        ok = (best >= 0) & (d1 <= self.cfg.desc_th_high)
        return self.assign(frame, best[ok], pid[ok], d1[ok], last.angle[sel][ok])

    def track_with_motion_model(self, frame: Frame) -> bool:
        """ORB-SLAM3 TrackWithMotionModel: the last frame follows its reference keyframe (``UpdateLastFrame``: local
        BA may have moved it since), the constant velocity predicts the pose, the last frame's points are searched
        (twice the radius when few match), motion-only BA."""
        last = self.last_tracked
        last.Tcw = last.Tcr @ self.map.keyframes[last.ref_kf].Tcw
        frame.Tcw = self.motion(frame.index) @ last.Tcw
        frame.mp[:] = -1
        th = self.cfg.tracking.search_radius_last_frame
        n = self.search_last_frame(frame, last, th)
        if n < self.cfg.tracking.tracking_min_matches:
            frame.mp[:] = -1
            n = self.search_last_frame(frame, last, 2 * th)
        if n < self.cfg.tracking.tracking_min_matches:
            return False
        n_in = self.optimize_pose(frame)
        self.discard_outliers(frame)
        return n_in >= self.cfg.tracking.tracking_min_inliers

    def track_reference_keyframe(self, frame: Frame) -> bool:
        """Descriptor matching against the reference keyframe's points (ORB-SLAM uses BoW; we use cv2 2-NN)."""
        kf = self.ref_kf
        if kf is None or self.last_tracked is None or frame.n == 0:
            return False
        n = self.match_keyframe(frame, kf, self.cfg.tracking.nn_ratio_reference)
        if n < self.cfg.tracking.reference_min_matches:
            return False
        frame.Tcw = self.last_tracked.Tcw.copy()
        n_in = self.optimize_pose(frame)
        self.discard_outliers(frame)
        return n_in >= self.cfg.tracking.tracking_min_inliers

    def match_keyframe(self, frame: Frame, kf: KeyFrame, ratio: float) -> int:
        """2-NN descriptor matching of the frame's free static keypoints against ``kf``'s live points."""
        ksel = np.flatnonzero(kf.mp >= 0)
        ksel = ksel[self.map.points.alive[kf.mp[ksel]]]
        fsel = np.flatnonzero(~frame.dynamic & (frame.mp < 0))
        if len(ksel) < 2 or len(fsel) == 0:
            return 0
        m = knn_ratio_match(frame.desc[fsel], kf.desc[ksel], ratio, self.cfg.desc_th_low)
        if len(m) == 0:
            return 0
        kp, kk = fsel[m[:, 0]], ksel[m[:, 1]]
        return self.assign(frame, kp, kf.mp[kk], m[:, 2].astype(np.float64), kf.angle[kk])

    # ------------------------------------------------------------------ local map
    def local_keyframes(self, frame: Frame) -> list[int]:
        """ORB-SLAM UpdateLocalKeyFrames: keyframes observing the frame's points (best first) + their neighbours;
        the best becomes the reference keyframe."""
        cfg = self.cfg
        pts = frame.mp[(frame.mp >= 0) & ~frame.outlier]
        pts = pts[self.map.points.alive[pts]]
        counts = self.map.keyframe_counts(pts)
        order = np.argsort(-counts, kind="stable")
        first = [int(k) for k in order[: cfg.tracking.local_map_max_keyframes] if counts[k] > 0
                 and not self.map.keyframes[k].bad]
        if first:
            self.ref_kf = self.map.keyframes[first[0]]
        out = list(first)
        seen = set(out)
        for k in first[: cfg.tracking.local_map_neighbour_sources]:
            for c in self.map.covisible(k, cfg.tracking.local_map_neighbours, cfg.covisibility_min_shared):
                if c not in seen:
                    seen.add(c)
                    out.append(c)
        return out

    def search_local_points(self, frame: Frame, pids: np.ndarray, th: float) -> int:
        """ORB-SLAM SearchLocalPoints: frustum check (isInFrustum), scale prediction, search by projection with the
        ratio test on the same level and no orientation check."""
        cfg = self.cfg
        P = self.map.points
        pids = pids[P.alive[pids]]
        already = np.zeros(P.n, dtype=bool)
        already[frame.mp[frame.mp >= 0]] = True
        pids = pids[~already[pids]]
        if len(pids) == 0 or frame.n == 0:
            return 0
        pids, u, v, z, level, view_cos = self.proj.in_frustum(P, frame.Tcw, pids)
        P.visible[pids] += 1
        if len(pids) == 0:
            return 0
        widen = np.where(view_cos > cfg.tracking.local_map_frontal_cos, cfg.tracking.local_map_radius_frontal,
                         cfg.tracking.local_map_radius_oblique)
        radius = th * widen * self.proj.scales[level]
        best, d1, d2, l1, l2 = self.search_projected(frame, np.c_[u, v], u - self.proj.bf / z, radius, level - 1,
                                                     level, P.desc[pids])
        ok = (best >= 0) & (d1 <= cfg.desc_th_high) & ~((l1 == l2) & (d1 > cfg.tracking.nn_ratio_local_map * d2))
        kp, p, d = best[ok], pids[ok], d1[ok]
        keep = unique_by_target(p, kp, d)
        frame.mp[kp[keep]] = p[keep]
        return int(keep.sum())

    def track_local_map(self, frame: Frame) -> bool:
        """ORB-SLAM TrackLocalMap: the local keyframes' points searched by projection, motion-only BA; enough
        inliers (more just after a relocalisation) keep the frame tracked."""
        cfg = self.cfg
        matched = frame.mp[frame.mp >= 0]
        self.map.points.visible[matched[self.map.points.alive[matched]]] += 1  # seen, as ORB-SLAM3 counts them
        local = self.local_keyframes(frame)
        if local:
            pts = self.map.points_of(local)
            th = cfg.tracking.search_radius_local_map
            if frame.index == self.last_reloc_frame:
                th = cfg.relocalisation.search_radius_relocalised
            elif frame.index - self.last_reloc_frame < 2:
                th = cfg.relocalisation.search_radius_after_relocalisation
            self.search_local_points(frame, pts, th)
        n_in = self.optimize_pose(frame)
        inl = (frame.mp >= 0) & ~frame.outlier
        self.map.points.found[frame.mp[inl]] += 1
        self.n_inliers = n_in
        need = cfg.tracking.local_map_min_inliers
        if frame.index - self.last_reloc_frame < cfg.keyframes.kf_max_frames:
            need = max(need, cfg.relocalisation.relocalisation_min_inliers) if self.last_reloc_frame >= 0 else need
        return n_in >= need

    # ------------------------------------------------------------------ keyframes
    def need_new_keyframe(self, frame: Frame) -> bool:
        """ORB-SLAM3 NeedNewKeyFrame for RGB-D (local mapping is synchronous; its busy time is emulated)."""
        cfg = self.cfg
        n_kfs = len(self.map.good_keyframes())
        if frame.index - self.last_reloc_frame < cfg.keyframes.kf_max_frames and n_kfs > cfg.keyframes.kf_max_frames:
            return False
        min_obs = cfg.keyframes.kf_ref_min_obs if n_kfs > 2 else cfg.keyframes.kf_ref_min_obs_first
        ref = self.ref_kf
        rp = ref.mp[ref.mp >= 0]
        rp = rp[self.map.points.alive[rp]]
        n_ref = int((self.map.points.nobs[rp] >= min_obs).sum())
        close = (frame.depth > 0) & (frame.depth < self.proj.th_depth_m) & ~frame.dynamic
        tracked = (frame.mp >= 0) & ~frame.outlier
        n_tracked_close = int((close & tracked).sum())
        n_untracked_close = int((close & ~tracked).sum())
        kfc = cfg.keyframes
        need_close = n_tracked_close < kfc.kf_close_tracked and n_untracked_close > kfc.kf_close_untracked
        ratio = cfg.keyframes.kf_tracked_ratio if n_kfs >= 2 else cfg.keyframes.kf_tracked_ratio_first
        inl = self.n_inliers
        c1a = frame.index >= self.last_kf_frame + cfg.keyframes.kf_max_frames
        # c1b needs local mapping idle: ours runs synchronously (always idle), so "idle" is emulated as
        # kf_mapping_busy_frames frames after the last keyframe (ORB-SLAM3 maps in its own thread while tracking
        # goes on); c1c (tracking weak) inserts a keyframe even when busy, as ORB-SLAM3 does for RGB-D.
        c1b = frame.index >= self.last_kf_frame + max(cfg.keyframes.kf_min_frames, cfg.keyframes.kf_mapping_busy_frames)
        c1c = inl < n_ref * cfg.keyframes.kf_weak_ratio or need_close
        c2 = (inl < n_ref * ratio or need_close) and inl > cfg.keyframes.kf_min_inliers
        return bool((c1a or c1b or c1c) and c2)

    def create_keyframe(self, frame: Frame) -> KeyFrame:
        """ORB-SLAM CreateNewKeyFrame (RGB-D): observations of the tracked points, new points from depth for the
        closest untracked keypoints: all closer than ``max(th_depth * b, kf_new_points_depth)`` (ours: up to the
        Kinect range, in place of ORB-SLAM3's triangulation of far points, see ``EngineConfig``), and at least
        ``kf_new_points_min`` (tracked ones counted). The new keyframe becomes the reference."""
        kf = make_keyframe(self.map, frame)
        tracked = (frame.mp >= 0) & ~frame.outlier & ~frame.dynamic
        tidx = np.flatnonzero(tracked)
        tidx = tidx[self.map.points.alive[frame.mp[tidx]]]
        self.map.add_observations(kf, tidx, frame.mp[tidx])
        cand = np.flatnonzero((frame.depth > 0) & ~frame.dynamic)
        cand = cand[np.argsort(frame.depth[cand], kind="stable")]
        has = kf.mp[cand] >= 0
        count = np.cumsum(np.ones(len(cand), dtype=np.int64))
        stop = (frame.depth[cand] > self.new_points_depth_m) & (count > self.cfg.keyframes.kf_new_points_min)
        if stop.any():
            cand, has = cand[: np.argmax(stop)], has[: np.argmax(stop)]
        new = cand[~has & (frame.mp[cand] < 0)]
        ids = points_from_depth(self.map, self.proj, kf, new, frame.belief)
        frame.mp[new] = ids
        frame.outlier[new] = False
        self.ref_kf = kf
        self.last_kf_frame = frame.index
        return kf
