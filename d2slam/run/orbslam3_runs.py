"""The real ORB-SLAM3's runs as the run path records them: :func:`run_orbslam3` runs it
(:func:`d2slam.baselines.orbslam3.orbslam3_report`) and :func:`orbslam3_record` makes the :class:`RunRecord` of its
run JSON."""

from __future__ import annotations

from pathlib import Path

from d2slam.baselines.orbslam3 import orbslam3_report
from d2slam.config import DEFAULT, Config
from d2slam.data import read_tum_trajectory
from d2slam.eval.trajectory import Evaluation, TrajectoryMetrics, aligned_estimate
from d2slam.run.record import Orbslam3Run, RunRecord


def run_orbslam3(sequence_dir, out_traj, metrics_json=None, evaluate: bool = True, config: Config = DEFAULT,
                 **kwargs) -> RunRecord:
    """The real ORB-SLAM3 on ``sequence_dir`` (the arguments of :func:`~d2slam.baselines.orbslam3.orbslam3_report`),
    as a :class:`RunRecord` (the run JSON as its ``orbslam3``)."""
    report, seq = orbslam3_report(sequence_dir, out_traj, metrics_json, evaluate=evaluate, config=config, **kwargs)
    return orbslam3_record(report, seq, evaluate)


def orbslam3_record(report: dict, seq, evaluate: bool = True) -> RunRecord:
    """The :class:`RunRecord` of an ORB-SLAM3 run JSON (``report``) on ``seq``: its trajectory (read back), ORB-SLAM3's
    status (``unevaluated`` when it tracked but gave no metrics), the median ATE and RPE over the repeats with the
    ATE's range, and the aligned positions of the trajectory written (with ``evaluate`` and ground truth)."""
    status = report.get("status", "failed")
    metrics = report.get("metrics") or {}
    spread = (report.get("metrics_spread") or {}).get("ate_rmse_m")
    error = "" if status == "ok" else str(report.get("message") or report.get("metrics_error") or "")
    if not metrics:
        status = status if status in ("failed", "crashed", "timeout") else "unevaluated"
        error = error or str(report.get("metrics_error") or "no metrics")
    path = report.get("trajectory")
    traj = read_tum_trajectory(path) if path and Path(path).is_file() else None
    aligned = None
    if evaluate and traj is not None and seq.groundtruth is not None:
        try:
            aligned = aligned_estimate(seq.groundtruth, traj)[:2]
        except Exception:  # noqa: BLE001 - only the plot misses it
            aligned = None
    evaluation = Evaluation(TrajectoryMetrics(**metrics) if metrics else None, metrics.get("ate_rmse_m"),
                            str(report.get("metrics_error") or ""), aligned)
    ate = metrics.get("ate_rmse_m")
    run = Orbslam3Run(traj, report.get("frames"), report.get("tracked"), report.get("lost"), report.get("fps"),
                      report.get("ms_per_frame"), report)
    return RunRecord(
        method=report["method"], sequence=report.get("name", ""), run=run, config_hash=report["config_hash"],
        status=status, error=error, evaluation=evaluation if metrics or aligned is not None else None,
        masks=report.get("masks"), masks_origin=report.get("masks_origin"), repeats=int(report.get("repeats", 1)),
        ate_range=(spread["min"], spread["max"]) if spread else (ate, ate) if metrics else None,
        min_tracked_share=report.get("min_tracked_share", DEFAULT.evaluation.min_tracked_share))
