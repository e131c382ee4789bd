"""Loops against the ground truth: a detected loop is true when the relative pose of its two keyframes that the loop
closer estimated (``Loop.T_kf_loop``) is within ``EvalConfig.loop_true_max_m`` and ``loop_true_max_deg`` of the
ground truth's, false otherwise; a place-recognition candidate is wrong when the two ground-truth views do not overlap
(``loop_wrong_view_deg``, ``loop_wrong_view_m``). The closest call of a run is its wrong candidate that went furthest
(the stages of ``d2slam.slam.loop_closing.Candidate``) with the highest score relative to its keyframe's minimum
score.

Ground-truth poses are taken at the frames' timestamps (nearest sample within the evaluation's 0.02 s).
"""

from __future__ import annotations

import numpy as np

from d2slam.data.base import Trajectory
from d2slam.eval.config import EvalConfig
from d2slam.eval.trajectory import MAX_DIFF

STAGES = ("score", "group", "geometry", "loop")  # how far a candidate got, in order


def poses_at(groundtruth: Trajectory, times: np.ndarray, max_diff: float = MAX_DIFF) -> np.ndarray:
    """(N, 4, 4) ground-truth ``T_world_camera`` nearest to each time; NaN where none lies within ``max_diff``."""
    ts = np.asarray(groundtruth.timestamps, np.float64)
    times = np.asarray(times, np.float64)
    j = np.clip(np.searchsorted(ts, times), 1, max(len(ts) - 1, 1))
    j = np.where(np.abs(ts[j - 1] - times) <= np.abs(ts[np.minimum(j, len(ts) - 1)] - times), j - 1, j)
    j = np.minimum(j, len(ts) - 1)
    out = np.asarray(groundtruth.poses, np.float64)[j].copy()
    out[np.abs(ts[j] - times) > max_diff] = np.nan
    return out


def _rel(Ta: np.ndarray, Tb: np.ndarray) -> np.ndarray:
    """``Ta^-1 Tb`` for (N, 4, 4) T_world_camera: camera b in camera a (= Tcw_a Twc_b)."""
    Rt = np.transpose(Ta[:, :3, :3], (0, 2, 1))
    out = np.zeros_like(Ta)
    out[:, :3, :3] = Rt @ Tb[:, :3, :3]
    out[:, :3, 3] = np.einsum("nij,nj->ni", Rt, Tb[:, :3, 3] - Ta[:, :3, 3])
    out[:, 3, 3] = 1.0
    return out


def _angle_deg(R: np.ndarray) -> np.ndarray:
    cos = np.clip((np.trace(R, axis1=1, axis2=2) - 1.0) / 2.0, -1.0, 1.0)
    return np.degrees(np.arccos(cos))


def loop_errors(loops: list[dict], timestamps: np.ndarray, groundtruth: Trajectory) -> np.ndarray:
    """(N, 2) translation (m) and rotation (deg) error of each loop's relative pose against the ground truth (NaN
    without ground truth at a frame)."""
    if not loops:
        return np.zeros((0, 2))
    a = np.array([lp["frames"][0] for lp in loops])
    b = np.array([lp["frames"][1] for lp in loops])
    ts = np.asarray(timestamps, np.float64)
    truth = _rel(poses_at(groundtruth, ts[a]), poses_at(groundtruth, ts[b]))
    est = np.array([lp["T_kf_loop"] for lp in loops], np.float64)
    E = _rel(est, truth)  # est^-1 truth
    return np.stack([np.linalg.norm(E[:, :3, 3], axis=1), _angle_deg(E[:, :3, :3])], axis=1)


def classify_loops(loops: list[dict], timestamps: np.ndarray, groundtruth: Trajectory | None,
                   cfg: EvalConfig = EvalConfig()) -> dict:
    """The metrics JSON's loop fields: ``loops`` ([frame of keyframe a, frame of keyframe b] each) and, with ground
    truth, ``loops_true``, ``loops_false`` (same form) and ``loop_errors`` ([m, deg] per loop)."""
    out = {"loops": [list(lp["frames"]) for lp in loops]}
    if groundtruth is None:
        return out
    err = loop_errors(loops, timestamps, groundtruth)
    true = (err[:, 0] <= cfg.loop_true_max_m) & (err[:, 1] <= cfg.loop_true_max_deg)
    out["loops_true"] = [out["loops"][i] for i in np.flatnonzero(true)]
    out["loops_false"] = [out["loops"][i] for i in np.flatnonzero(~true)]
    out["loop_errors"] = np.round(err, 6).tolist()
    return out


def wrong_candidates(cands: list, timestamps: np.ndarray, groundtruth: Trajectory,
                     cfg: EvalConfig = EvalConfig()) -> np.ndarray:
    """(N,) bool: candidates (``Candidate``: ``frame``, ``cand_frame``) whose ground-truth views do not overlap."""
    if not cands:
        return np.zeros(0, bool)
    ts = np.asarray(timestamps, np.float64)
    A = poses_at(groundtruth, ts[[c.frame for c in cands]])
    B = poses_at(groundtruth, ts[[c.cand_frame for c in cands]])
    axes = np.degrees(np.arccos(np.clip(np.einsum("ni,ni->n", A[:, :3, 2], B[:, :3, 2]), -1.0, 1.0)))
    dist = np.linalg.norm(A[:, :3, 3] - B[:, :3, 3], axis=1)
    return (axes > cfg.loop_wrong_view_deg) | (dist > cfg.loop_wrong_view_m)


def closest_call(cands: list, timestamps: np.ndarray, groundtruth: Trajectory,
                 cfg: EvalConfig = EvalConfig()) -> dict | None:
    """The wrong candidate that got furthest (``STAGES``), then with the highest score relative to its keyframe's
    minimum score: ``{frames, stage, score, min_score, ratio, inliers}``; None when no candidate was wrong."""
    wrong = wrong_candidates(cands, timestamps, groundtruth, cfg)
    if not wrong.any():
        return None
    best = max((c for c, w in zip(cands, wrong) if w),
               key=lambda c: (STAGES.index(c.stage), c.score / max(c.min_score, 1e-12), c.inliers))
    return {"frames": [best.frame, best.cand_frame], "stage": best.stage, "score": round(best.score, 6),
            "min_score": round(best.min_score, 6), "ratio": round(best.score / max(best.min_score, 1e-12), 4),
            "inliers": best.inliers}


def loop_summary(result, timestamps: np.ndarray, groundtruth: Trajectory | None,
                 cfg: EvalConfig = EvalConfig()) -> dict:
    """The loop-closing fields of a run (``d2slam.run.record.EngineRun``) for its metrics JSON: ``loop_closing``, and
    when on ``loops`` ([frame of keyframe a, frame of keyframe b] each), with ground truth ``loops_true`` /
    ``loops_false`` / ``loop_errors`` ([m, deg]) and ``loop_closest_call`` (:func:`closest_call`), the median
    detection time per keyframe (ms) and each correction's time (s)."""
    if not result.loop_closing:
        return {"loop_closing": False}
    out = {"loop_closing": True, **classify_loops(result.loops, timestamps, groundtruth, cfg)}
    if groundtruth is not None:
        out["loop_closest_call"] = closest_call(result.loop_candidates, timestamps, groundtruth, cfg)
    out["loop_detect_ms"] = round(float(np.median(result.loop_detect_ms)), 3) if result.loop_detect_ms else None
    out["loop_correct_s"] = [lp["seconds"] for lp in result.loops]
    return out
