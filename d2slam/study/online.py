"""The study's online runs (``RunSpec.online``): ``d2slam run --method M --online`` as a grid cell, its row and its
schedule.

An online run replays its sequence at the sensor's rate (``OnlineConfig.rate_hz``) with the segmenter in its own
thread and the frames the tracker cannot take in time dropped (:mod:`d2slam.run.online`; the real ORB-SLAM3 under the
same camera, ``d2slam.data.live``). Its figures depend on the machine and its load, so the study runs these runs
after every other run, one at a time, in its own process (``d2slam.study.core``: the online phase), never beside
its parallel workers or on a Dask cluster's. Its row says it is not deterministic; the engine's schedule
(:class:`d2slam.run.online.Schedule`) is kept beside its trajectory so that ``d2slam run --deterministic`` replays it.

:func:`execute_online_run` never raises: a failure is a row, as :func:`d2slam.study.runner.execute_run`'s.
"""

from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.run.online import online_report, run_online
from d2slam.run.orbslam3_runs import run_orbslam3
from d2slam.run.runner import run_config
from d2slam.study.grid import ORBSLAM3, RunSpec
from d2slam.study.runner import (RunOptions, base_row, failed_row, message, run_row, sequence_path,
                                 single_threaded)

# The online figures of a row: the share of frames processed, the frames dropped, the lag from a frame's arrival
# to its pose (median, 95th percentile, ms), the segmenter's frames per second (the engine's only); the keys of
# ``Schedule.summary`` and of the real ORB-SLAM3's online account they come from.
ONLINE_FIGURES = {"processed_share": "processed_share", "frames_dropped": "dropped", "lag_ms_median": "lag_ms_median",
                  "lag_ms_p95": "lag_ms_p95", "segmenter_fps": "segmenter_fps"}
SCHEDULE_SUFFIX = ".schedule.npz"  # trajectories/<run><suffix>: beside the run's trajectory


def schedule_path(out: Path, spec: RunSpec) -> Path:
    """Where a study keeps an online run's schedule (``d2slam run --deterministic`` replays it)."""
    return Path(out) / "trajectories" / f"{spec.run_id}{SCHEDULE_SUFFIX}"


def online_config(spec: RunSpec, options: RunOptions):
    """The config of an online run: the study's as its offline run reads it (seed, loop closing), with the
    ``online`` section as given (``OnlineConfig.rate_hz``: the rate the frames arrive at)."""
    return run_config(options.config, spec.seed, spec.loop_closing)


def execute_online_run(spec: RunSpec | dict, options: RunOptions) -> dict:
    """Run one online grid cell. Returns what :func:`d2slam.study.runner.execute_run` returns, with ``schedule``
    (the engine's :class:`~d2slam.run.online.Schedule`; None for ORB-SLAM3, whose threads are its own); never
    raises."""
    if isinstance(spec, dict):
        spec = RunSpec(**spec)
    t0 = time.perf_counter()
    try:
        with single_threaded():
            path = sequence_path(spec.source, spec.scenario, spec.seed, spec.frames, spec.twin, options)
            result = (_orbslam3_online(spec, path, options) if spec.method == ORBSLAM3 else
                      _engine_online(spec, path, options))
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, not a crash of the study
        return {"row": {**failed_row(spec, message(exc), time.perf_counter() - t0, options), **_marks()},
                "trajectory": None, "aligned": None, "keypoints": None, "stage_ms": {}, "loops": None,
                "schedule": None}
    result["row"]["wall_s"] = time.perf_counter() - t0
    return result


def _marks() -> dict:
    """What every online row says: an online run, not deterministic (it depends on timing)."""
    return {"online": 1, "deterministic": 0}


def online_columns(account: dict) -> dict:
    """The row's online figures (:data:`ONLINE_FIGURES`) of an online account (``Schedule.summary`` or the real
    ORB-SLAM3's ``online``)."""
    return {col: account.get(key) for col, key in ONLINE_FIGURES.items()}


def _engine_online(spec: RunSpec, path: Path, options: RunOptions) -> dict:
    """An online run of an engine method (``d2slam.run.online.run_online``) and its row: the figures of
    ``online_report`` (ATE and RPE over the processed frames, the share tracked among them)."""
    config = online_config(spec, options)
    seq = open_sequence(path)
    if spec.source == "synth" and len(seq) != spec.frames:
        raise D2SlamError(f"sequence has {len(seq)} frames, the study expects {spec.frames}", path=path)
    run = run_online(seq, spec.method, config, frames=spec.frames if spec.frames > 0 else None, progress=False)
    report = online_report(run, seq, config)
    s = run.schedule
    s.meta.update(seed=int(spec.seed), loop_closing=bool(spec.loop_closing), run=spec.run_id)
    metrics = report.get("metrics") or {}
    status = "ok" if "rpe_trans_m" in metrics else "partial" if metrics else "unevaluated"
    error = {"ok": ""}.get(status, report.get("metrics_error") or "ATE only: too short for a 1-second RPE pair")
    track_ms = 1000.0 * (np.asarray(s.done_s) - np.asarray(s.start_s))
    row = {**base_row(spec), **_marks(), "status": status, "error": error, "config_hash": config.hash(),
           "frames_tracked": run.tracked, "frames_lost": len(s.processed) - run.tracked, "keyframes": run.keyframes,
           "map_points": run.map_points, "tracked_share": report["tracked_share"],
           "fragment": int(report["fragment"]), **{k: metrics.get(k) for k in ("ate_rmse_m", "rpe_trans_m",
                                                                                 "rpe_rot_deg")},
           **online_columns(report["online"]),
           **({} if s.segmented else {"segmenter_fps": None}),  # no segmenter ran (none, or online.masks off)
           "fps": len(s.processed) / run.wall_s if run.wall_s > 0 else None,
           "ms_per_frame": float(track_ms.mean()) if len(track_ms) else None}
    traj = run.trajectory
    return {"row": row, "trajectory": (np.asarray(traj.timestamps), np.asarray(traj.poses)), "aligned": None,
            "keypoints": None, "stage_ms": {}, "loops": None, "schedule": s}


def _orbslam3_online(spec: RunSpec, path: Path, options: RunOptions) -> dict:
    """The real ORB-SLAM3 online at the same rate, repeated as its offline runs (``--orbslam3-repeats``: its
    figures are the medians, its online account the median-ATE repeat's), and its row."""
    config = online_config(spec, options)
    with tempfile.TemporaryDirectory(prefix="d2slam_study_orbslam3_online_") as tmp:
        record = run_orbslam3(path, Path(tmp) / "orbslam3.txt", repeats=int(options.orbslam3_repeats), config=config,
                              progress=False, max_frames=spec.frames if spec.source != "synth" else 0,
                              timeout=options.orbslam3_timeout, online_rate=float(config.online.rate_hz))
    traj = record.trajectory
    row = {**run_row(spec, record, 0.0), **_marks(), **online_columns(record.run.report.get("online") or {})}
    return {"row": row, "trajectory": None if traj is None else (np.asarray(traj.timestamps), np.asarray(traj.poses)),
            "aligned": None, "keypoints": None, "stage_ms": record.stage_ms, "loops": None, "schedule": None}


def load_average() -> list[float] | None:
    """The machine's load average (1, 5, 15 minutes), None where the system has none."""
    try:
        return [round(x, 2) for x in os.getloadavg()]
    except OSError:
        return None
