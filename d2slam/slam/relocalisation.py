"""Relocalisation (ORB-SLAM3 ``Tracking::Relocalization``): candidate keyframes from the keyframe database (DBoW2,
``keyframe_database.py``) when the engine has one (loop closing on), else the recent keyframes; shortlisted by
descriptor votes, 2-NN matching, seeded EPnP RANSAC, motion-only BA and a projection search for more inliers."""

from __future__ import annotations

import cv2
import numpy as np

from d2slam.slam.frame import Frame
from d2slam.slam.map import KeyFrame
from d2slam.slam.matching import nearest_matches


def relocalise(tracker, frame: Frame) -> bool:
    """Candidates: the keyframe database's relocalisation candidates of the frame's static keypoints (ORB-SLAM
    ``DetectRelocalizationCandidates``), or without a database the recent keyframes and the reference keyframe; the
    best few by votes (``shortlist``) tried in turn: matches, PnP RANSAC (seeded by the frame index), pose
    optimisation, a projection search of the candidate's points when inliers are few. The first candidate with
    ``relocalisation_min_inliers`` wins and becomes the reference keyframe. ``tracker``: the engine's
    ``d2slam.slam.tracking.Tracker`` (which calls this module)."""
    cfg, map_ = tracker.cfg, tracker.map
    kfs = map_.good_keyframes()
    if not kfs or frame.n == 0:
        return False
    if tracker.keyframe_db is not None:
        cands = [map_.keyframes[k] for k in tracker.keyframe_db.relocalisation_candidates(frame.desc, ~frame.dynamic)]
    else:
        cands = sorted(kfs, key=lambda k: -k.id)[: cfg.relocalisation.relocalisation_candidates]
        ref = tracker.ref_kf
        if ref is not None and not ref.bad and ref not in cands:
            cands = [ref] + cands
    if not cands:
        frame.mp[:] = -1
        return False
    for kf in shortlist(tracker, frame, cands):
        frame.mp[:] = -1
        n = tracker.match_keyframe(frame, kf, cfg.relocalisation.nn_ratio_relocalisation)
        if n < cfg.tracking.reference_min_matches:
            continue
        sel = np.flatnonzero(frame.mp >= 0)
        obj = map_.points.pos[frame.mp[sel]].astype(np.float64)
        img = frame.kps[sel].astype(np.float64)
        cv2.setRNGSeed(int(cfg.seed) + int(frame.index))
        try:
            rl = cfg.relocalisation
            ok, rvec, tvec, inliers = cv2.solvePnPRansac(
                obj, img, tracker.proj.K, None, iterationsCount=rl.relocalisation_pnp_iterations,
                reprojectionError=rl.relocalisation_pnp_px, confidence=rl.relocalisation_pnp_confidence,
                flags=cv2.SOLVEPNP_EPNP)
        except cv2.error:
            continue
        if not ok or inliers is None or len(inliers) < cfg.tracking.tracking_min_inliers:
            continue
        keep = np.zeros(len(sel), dtype=bool)
        keep[inliers.ravel()] = True
        frame.mp[sel[~keep]] = -1
        T = np.eye(4)
        T[:3, :3] = cv2.Rodrigues(rvec)[0]
        T[:3, 3] = tvec.ravel()
        frame.Tcw = T
        n_good = tracker.optimize_pose(frame)
        if n_good < cfg.tracking.tracking_min_inliers:
            continue
        tracker.discard_outliers(frame)
        if n_good < cfg.relocalisation.relocalisation_min_inliers:
            tracker.search_local_points(frame, map_.points_of([kf.id]), cfg.relocalisation.search_radius_relocalisation)
            n_good = tracker.optimize_pose(frame)
            tracker.discard_outliers(frame)
        if n_good >= cfg.relocalisation.relocalisation_min_inliers:
            tracker.ref_kf = kf
            return True
    frame.mp[:] = -1
    return False


def shortlist(tracker, frame: Frame, cands: list[KeyFrame]) -> list[KeyFrame]:
    """The candidates worth a PnP attempt (our stand-in for DBoW2's candidate scoring): one nearest-neighbour
    search of the frame's static descriptors against the points of all candidates at once; each keyframe gets a
    vote per keypoint whose nearest point descriptor (Hamming <= TH_LOW) is one of its points. The best
    ``relocalisation_pnp_candidates`` keyframes with at least ``reference_min_matches`` votes are kept, best
    first (ties: newest first)."""
    cfg, alive = tracker.cfg, tracker.map.points.alive
    fsel = np.flatnonzero(~frame.dynamic)
    sels = []
    for kf in cands:
        ks = np.flatnonzero(kf.mp >= 0)
        sels.append(ks[alive[kf.mp[ks]]])
    sizes = np.array([len(x) for x in sels])
    if len(fsel) == 0 or sizes.sum() < 2:
        return []
    desc = np.concatenate([kf.desc[x] for kf, x in zip(cands, sels)])
    owner = np.repeat(np.arange(len(cands)), sizes)
    best = nearest_matches(frame.desc[fsel], desc)
    ok = best[:, 2] <= cfg.desc_th_low
    votes = np.bincount(owner[best[ok, 1].astype(np.int64)], minlength=len(cands))
    order = np.argsort(-votes, kind="stable")[: cfg.relocalisation.relocalisation_pnp_candidates]
    return [cands[i] for i in order if votes[i] >= cfg.tracking.reference_min_matches]
