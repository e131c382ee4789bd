"""Trajectory metrics with evo (docs/design.md#evaluation): ATE RMSE after SE(3) Umeyama alignment with 0.02 s
association (TUM ``evaluate_ate.py`` convention), RPE translational (m) and rotational (deg) over all 1-second pairs
(TUM ``evaluate_rpe.py --fixed_delta --delta 1 --delta_unit s``), both as RMSE.

evo's library API does the association, the Umeyama alignment and the ATE (``PoseTrajectory3D``,
``sync.associate_trajectories``, ``metrics.APE``). evo 1.38's RPE has no ``seconds`` delta unit (its
``id_pairs_from_delta`` raises "unsupported delta unit"), so the 1-second pairs are selected here from the
timestamps (TUM's rule) and the relative errors computed with evo's RPE formula, vectorised; a test checks them
against ``evo.core.metrics.RPE`` with a frame delta on a constant-rate trajectory (same pairs).
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass

import numpy as np
from evo.core import metrics, sync
from evo.core.geometry import GeometryException
from evo.core.metrics import PoseRelation
from evo.core.trajectory import PoseTrajectory3D

from d2slam.data.base import Trajectory
from d2slam.errors import D2SlamError

MAX_DIFF = 0.02  # association tolerance (s)
RPE_DELTA_S = 1.0  # RPE pairs 1 second apart


@dataclass
class TrajectoryMetrics:
    ate_rmse_m: float
    rpe_trans_m: float
    rpe_rot_deg: float
    n_matched: int | None = None  # estimated poses associated with ground truth (None: medians over repeats)
    n_estimated: int | None = None
    n_rpe_pairs: int | None = None

    def to_dict(self) -> dict:
        return asdict(self)


class NoRpePairs(D2SlamError):
    """The estimate has no pair of matched poses 1 second apart (too short, or tracking gaps): no RPE."""


@dataclass
class Evaluation:
    """A run's trajectory against its ground truth (:func:`evaluate_run`)."""

    metrics: TrajectoryMetrics | None = None  # ATE and 1-second RPE
    ate_rmse_m: float | None = None  # the ATE, also when the estimate is too short for the RPE
    error: str = ""  # why there are no metrics ("" when there are)
    aligned: tuple[np.ndarray, np.ndarray] | None = None  # matched ground-truth and aligned estimated positions

    @property
    def status(self) -> str:
        """``ok`` (ATE and RPE), ``partial`` (the ATE alone) or ``unevaluated``."""
        return "ok" if self.metrics is not None else "partial" if self.ate_rmse_m is not None else "unevaluated"


def to_evo(traj: Trajectory, what: str):

    ts = np.asarray(traj.timestamps, dtype=np.float64)
    poses = np.asarray(traj.poses, dtype=np.float64)
    if len(ts) == 0:
        raise D2SlamError(f"{what} is empty (no poses)", path=traj.meta.get("path"))
    if poses.shape != (len(ts), 4, 4) or not np.isfinite(poses).all():
        raise D2SlamError(f"{what}: poses must be finite (N, 4, 4) arrays", path=traj.meta.get("path"))
    return PoseTrajectory3D(poses_se3=list(poses), timestamps=ts)


def evaluate(groundtruth: Trajectory, estimate: Trajectory, max_diff: float = MAX_DIFF,
             delta_s: float = RPE_DELTA_S) -> TrajectoryMetrics:
    """ATE / RPE of ``estimate`` against ``groundtruth`` (both T_world_camera). Raises ``D2SlamError`` when a
    trajectory is empty, when fewer than 3 poses associate within ``max_diff`` seconds, or when the estimate is
    too short for one RPE pair."""

    ref = to_evo(groundtruth, "ground truth")
    est = to_evo(estimate, "estimated trajectory")
    try:
        ref_a, est_a = sync.associate_trajectories(ref, est, max_diff=max_diff)
    except Exception as exc:  # evo raises SyncException when nothing matches
        raise D2SlamError(f"ground truth and estimate do not overlap in time (no timestamps within {max_diff} s): "
                          f"{exc}", path=estimate.meta.get("path")) from None
    n = ref_a.num_poses
    if n < 3:
        raise D2SlamError(f"only {n} estimated poses match ground-truth timestamps within {max_diff} s "
                          "(need >= 3 for an SE(3) alignment)", path=estimate.meta.get("path"))
    est_aligned = copy.deepcopy(est_a)
    _align(est_aligned, ref_a, estimate)
    ape = metrics.APE(PoseRelation.translation_part)
    ape.process_data((ref_a, est_aligned))
    ate = float(ape.get_statistic(metrics.StatisticsType.rmse))

    pairs = second_pairs(ref_a.timestamps, delta_s)
    if len(pairs) == 0:
        ts = np.asarray(ref_a.timestamps)
        span = ts[-1] - ts[0]
        why = (f"the matched estimate spans only {span:.2f} s" if span < delta_s - max_diff else
               f"no two matched poses are {delta_s} +- {max_diff} s apart (the estimate spans {span:.2f} s with "
               f"tracking gaps; longest gap {np.diff(ts).max():.2f} s)")
        raise NoRpePairs(f"cannot compute RPE over {delta_s} s pairs: {why}", path=estimate.meta.get("path"))
    t_err, r_err = relative_errors(np.asarray(ref_a.poses_se3), np.asarray(est_a.poses_se3), pairs)
    return TrajectoryMetrics(
        ate_rmse_m=ate,
        rpe_trans_m=float(np.sqrt(np.mean(t_err ** 2))),
        rpe_rot_deg=float(np.sqrt(np.mean(r_err ** 2))),
        n_matched=int(n), n_estimated=int(len(estimate.timestamps)), n_rpe_pairs=int(len(pairs)))


def evaluate_run(groundtruth: Trajectory, estimate: Trajectory) -> Evaluation:
    """:func:`evaluate` and the aligned positions (for plots), never raising: when the estimate is too short for an
    RPE pair, the ATE alone (:func:`ate_rmse`); when it cannot be evaluated at all, the reason (``error``)."""
    try:
        m = evaluate(groundtruth, estimate)
        return Evaluation(m, m.ate_rmse_m, aligned=aligned_estimate(groundtruth, estimate)[:2])
    except NoRpePairs as exc:
        try:
            gt_xyz, est_xyz, _ = aligned_estimate(groundtruth, estimate)
        except Exception:  # noqa: BLE001 - no ATE either
            return Evaluation(error=str(exc))
        return Evaluation(ate_rmse_m=ate_rmse(gt_xyz, est_xyz), error=str(exc), aligned=(gt_xyz, est_xyz))
    except Exception as exc:  # noqa: BLE001 - D2SlamError, or evo's own errors (degenerate alignment)
        return Evaluation(error=str(exc) if isinstance(exc, D2SlamError) else f"{type(exc).__name__}: {exc}")


def ate_rmse(gt_xyz: np.ndarray, est_xyz: np.ndarray) -> float:
    """RMSE of the position errors of matched, aligned positions (= evo's APE translation RMSE)."""
    return float(np.sqrt(np.mean(np.sum((np.asarray(gt_xyz) - np.asarray(est_xyz)) ** 2, axis=1))))


def second_pairs(ts: np.ndarray, delta_s: float, tol_s: float = MAX_DIFF) -> np.ndarray:
    """(K, 2) index pairs (i, j) with t_j the timestamp closest to t_i + delta_s (TUM ``evaluate_rpe.py
    --fixed_delta --delta_unit s``, all pairs), kept when |t_j - t_i - delta_s| <= tol_s (the association
    tolerance: a tracking gap or the end of the sequence does not turn a 0.9 s or 3 s pair into a 1 s one). evo's RPE has no seconds unit, hence this selection;
    the errors themselves follow evo's RPE definition (:func:`relative_errors`)."""
    ts = np.asarray(ts, dtype=np.float64)
    if len(ts) < 2:
        return np.zeros((0, 2), dtype=np.int64)
    target = ts + delta_s
    j = np.clip(np.searchsorted(ts, target), 1, len(ts) - 1)
    j = np.where(np.abs(ts[j - 1] - target) <= np.abs(ts[j] - target), j - 1, j)
    i = np.arange(len(ts))
    ok = (j > i) & (np.abs(ts[j] - target) <= tol_s)
    return np.stack([i[ok], j[ok]], axis=1)


def relative_errors(ref: np.ndarray, est: np.ndarray, pairs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Translational (m) and rotational (deg) RPE per pair, evo's definition vectorised:
    ``E = (Q_i^-1 Q_j)^-1 (P_i^-1 P_j)``, errors ``|t(E)|`` and the angle of ``R(E)``."""
    def rel(T, a, b):
        Ta, Tb = T[a], T[b]
        Ra_t = np.transpose(Ta[:, :3, :3], (0, 2, 1))
        R = Ra_t @ Tb[:, :3, :3]
        t = np.einsum("nij,nj->ni", Ra_t, Tb[:, :3, 3] - Ta[:, :3, 3])
        return R, t

    i, j = pairs[:, 0], pairs[:, 1]
    Rq, tq = rel(ref, i, j)
    Rp, tp = rel(est, i, j)
    Rq_t = np.transpose(Rq, (0, 2, 1))
    RE = Rq_t @ Rp
    tE = np.einsum("nij,nj->ni", Rq_t, tp - tq)
    cos = (np.trace(RE, axis1=1, axis2=2) - 1.0) / 2.0
    axis = np.stack([RE[:, 2, 1] - RE[:, 1, 2], RE[:, 0, 2] - RE[:, 2, 0], RE[:, 1, 0] - RE[:, 0, 1]], 1)
    sin = np.linalg.norm(axis, axis=1) / 2.0
    return np.linalg.norm(tE, axis=1), np.degrees(np.arctan2(sin, cos))  # well conditioned near 0


def aligned_estimate(groundtruth: Trajectory, estimate: Trajectory, max_diff: float = MAX_DIFF):
    """(gt positions (M, 3), aligned estimated positions (M, 3), timestamps (M,)) of the associated poses."""
    ref_a, est_a = sync.associate_trajectories(to_evo(groundtruth, "ground truth"),
                                               to_evo(estimate, "estimated trajectory"), max_diff=max_diff)
    _align(est_a, ref_a, estimate)
    return ref_a.positions_xyz, est_a.positions_xyz, ref_a.timestamps


def _align(est, ref, estimate: Trajectory) -> None:
    """evo's SE(3) Umeyama alignment of ``est`` onto ``ref`` in place; a :class:`D2SlamError` when the matched
    positions are degenerate (all on one line or at one point: no rotation can be fitted)."""
    try:
        est.align(ref, correct_scale=False)
    except GeometryException as exc:
        raise D2SlamError(f"cannot align the trajectories ({exc}): the matched positions lie on a straight line or "
                          "at one point", path=estimate.meta.get("path")) from None
