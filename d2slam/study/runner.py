"""One run of the study grid, as a plain function of picklable arguments (so that any executor can call it: the
caller's process, a joblib/loky worker or a Dask worker): generate or reuse the sequence, run the engine with the
method's keypoint filter (or real ORB-SLAM3), evaluate with evo, classify keypoints against the synthetic truth.

:func:`execute_run` never raises: any failure becomes ``status="failed"`` with the error message in the row, so a
study records every run of its grid. Everything it returns is plain data (the trajectory as arrays), so a remote
Dask worker needs no access to the study's output folder.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
import tempfile
import time
import traceback
from pathlib import Path

import cv2
import numpy as np

from d2slam.cachefiles import Damaged, report_damaged
from d2slam.config import DEFAULT, Config
from d2slam.data import open_sequence
from d2slam.digests import digest, source_digest
from d2slam.errors import D2SlamError
from d2slam.paths import cache_dir
from d2slam.run.methods import get_method, mask_kind, masks_read, methods
from d2slam.run.orbslam3_runs import run_orbslam3
from d2slam.run.record import RunRecord
from d2slam.run.runner import run_config, run_method
from d2slam.run.sequence import STAGES as ENGINE_STAGES
from d2slam.segmentation import masks_for
from d2slam.slam.engine import refills
from d2slam.slam.features import CachedFeatures, FeatureRecorder
from d2slam.study.grid import COMPOSITE_RECORDING, LABELS, ORACLE, ORBSLAM3_MASKED, REPEATED, STUDY_MASKS, RunSpec
from d2slam.study.sequences import ensure_composite, ensure_sequence, real_sequence_dir, tum_sequence_dir


@dataclass(frozen=True)
class RunOptions:
    """What every run of a study shares (picklable: a worker process or a Dask worker gets it with each run): the
    config, the sequence cache's folder (None: the user's cache), the TUM folder of a TUM study, the study's masks
    (the real segmenter's unless given), ORB-SLAM3's repeats and time limit per repeat (None: its budget)."""

    config: Config = DEFAULT
    cache_root: str | None = None
    tum_root: str | None = None
    masks: str = STUDY_MASKS
    orbslam3_repeats: int = DEFAULT.baseline.orbslam3_repeats
    orbslam3_timeout: float | None = None


def run_options(config: Config | None = None, cache_root: str | None = None, tum_root: str | None = None,
                masks: str | None = None, orbslam3_repeats: int | None = None,
                orbslam3_timeout: float | None = None) -> RunOptions:
    """The :class:`RunOptions` of a study (defaults: the config's repeats, the real segmenter's masks)."""
    config = config or DEFAULT
    return RunOptions(config, None if cache_root is None else str(cache_root), None if tum_root is None else
                      str(tum_root), masks or STUDY_MASKS, int(orbslam3_repeats or config.baseline.orbslam3_repeats),
                      orbslam3_timeout)


def prepare_sequence(key: tuple, options: RunOptions) -> dict:
    """Generate (or find) the sequence of ``RunSpec.sequence_key``; returns ``{"key", "path", "error"}``."""
    source, scenario, seed, frames, twin = key
    try:
        with single_threaded():
            path = sequence_path(source, scenario, seed, frames, twin, options)
        return {"key": key, "path": str(path), "error": None}
    except Exception as exc:  # noqa: BLE001 - recorded, the runs on it fail with this message
        return {"key": key, "path": None, "error": message(exc)}


def onnx_sequence_keys(specs, options: RunOptions) -> list[tuple]:
    """The sequences (``RunSpec.sequence_key``) on which some run of ``specs`` reads the real segmenter's masks."""
    keys = []
    for s in specs:
        if s.method not in methods():
            continue  # an unknown method's run records its own error
        method = get_method(s.method)
        if masks_read(method, options.masks, synthetic=_has_truth(s)) == "onnx":
            keys.append(s.sequence_key)
    return list(dict.fromkeys(keys))


def segment_sequence(key: tuple, options: RunOptions) -> dict:
    """Segment every frame the runs read of the sequence ``key`` with the real segmenter into the mask cache, once per
    sequence before the runs (which then only read it, whichever worker runs them; two runs on one sequence at the
    same time would otherwise both segment it). Returns ``{"key", "error"}``; a failure is left to the runs,
    which meet it again and record it."""
    source, scenario, seed, frames, twin = key
    try:
        with single_threaded():
            seq = open_sequence(sequence_path(source, scenario, seed, frames, twin, options))
            config = options.config
            n = len(seq) if frames <= 0 else min(len(seq), frames)
            for i in range(n):
                masks_for(seq, i, "onnx", config)
        return {"key": key, "error": None}
    except Exception as exc:  # noqa: BLE001 - recorded; the runs on it fail with their own message
        return {"key": key, "error": message(exc)}


def _has_truth(spec: RunSpec) -> bool:
    """Whether the run's masks can come from a synthetic truth: a synthetic sequence or a composite (its twin, the
    real recording, reads the composite's)."""
    return spec.source in ("synth", "composite")


def sequence_path(source, scenario, seed, frames, twin, options) -> Path:
    if source == "composite":
        recording = real_sequence_dir(COMPOSITE_RECORDING)
        if twin:  # the twin of a composite is its real recording
            return recording
        return ensure_composite(scenario, seed, frames, recording, root=options.cache_root, progress=False)
    if source == "real":
        return real_sequence_dir(scenario)
    if source == "tum":
        if not options.tum_root:
            raise D2SlamError("a TUM run needs tum_root (D2SLAM_TUM_ROOT)")
        return tum_sequence_dir(options.tum_root, scenario)

    return ensure_sequence(scenario, seed, frames, twin, root=options.cache_root, progress=False)


def execute_run(spec: RunSpec | dict, options: RunOptions) -> dict:
    """Run one grid cell. Returns ``{"row": {...}, "trajectory": (timestamps, poses) | None,
    "aligned": (gt_xyz, est_xyz) | None, "keypoints": per-module dict | None, "stage_ms": {...}, "loops": {...} |
    None}``; never raises."""
    if isinstance(spec, dict):
        spec = RunSpec(**spec)
    t0 = time.perf_counter()
    features_cached = None
    try:
        with single_threaded():
            path = sequence_path(spec.source, spec.scenario, spec.seed, spec.frames, spec.twin, options)
            if spec.method in REPEATED:
                record = _run_orbslam3(spec, path, options)
            else:
                record, features_cached = _run_engine(spec, path, options)
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, not a crash of the study
        return {"row": failed_row(spec, message(exc), time.perf_counter() - t0, options), "trajectory": None,
                "aligned": None, "keypoints": None, "stage_ms": {}, "loops": None}
    traj, ev = record.trajectory, record.evaluation
    return {"row": run_row(spec, record, time.perf_counter() - t0, features_cached),
            "trajectory": None if traj is None else (np.asarray(traj.timestamps), np.asarray(traj.poses)),
            "aligned": None if ev is None or ev.aligned is None else tuple(np.asarray(a) for a in ev.aligned),
            "keypoints": record.keypoints, "stage_ms": record.stage_ms, "loops": record.loops}


def base_row(spec: RunSpec) -> dict:
    return {"scenario": spec.scenario, "sequence": LABELS.get(spec.scenario, spec.scenario), "twin": int(spec.twin),
            "method": spec.method, "seed": int(spec.seed), "frames": int(spec.frames), "source": spec.source,
            "loop_closing": int(spec.loop_closing), "status": "failed", "error": "",
            "deterministic": int(spec.method not in REPEATED), "repeats": 1}


def failed_row(spec: RunSpec, error: str, wall_s: float | None = None, options: RunOptions | None = None) -> dict:
    """The row of a run that failed (``error``: why), with its config's hash when the options give one and its
    time when it ran."""
    extra = {}
    if options is not None:
        try:
            extra["config_hash"] = _config(spec, options).hash()
        except Exception:  # noqa: BLE001 - the config itself is what failed: the error says so
            pass
    if wall_s is not None:
        extra["wall_s"] = wall_s
    return {**base_row(spec), "error": error, **extra}


def run_row(spec: RunSpec, record: RunRecord, wall_s: float, features_cached: bool | None = None) -> dict:
    """The ``runs.csv`` row of a finished run: the grid cell, how the run ended (``RunRecord.status``), its figures
    and timings (columns: :data:`d2slam.study.tables.RUN_COLUMNS`)."""
    return {**base_row(spec), "loop_closing": int(record.loop_closing), "status": record.status,
            "error": record.error, "repeats": record.repeats, "config_hash": record.config_hash,
            "tracked_share": record.tracked_share, "fragment": int(record.fragment),
            **(_engine_columns(record, features_cached) if record.engine is not None else
               {"frames_tracked": record.tracked, "frames_lost": record.lost, "fps": record.fps,
                "ms_per_frame": record.ms_per_frame}),
            **_metric_columns(record), "wall_s": wall_s}


def _engine_columns(record: RunRecord, features_cached: bool | None) -> dict:
    """Tracking, timing, keypoint and loop columns of an engine run."""
    kp = record.keypoints
    final = kp["modules"].get("final", {}) if kp is not None else {}
    loops = record.loops or {}
    return {"features_cached": int(bool(features_cached)), "frames_tracked": record.tracked,
            "frames_lost": record.lost, "keyframes": record.keyframes, "map_points": record.map_points,
            "fps": record.fps, "ms_per_frame": record.ms_per_frame,
            **{f"ms_{k}": record.stage_ms[k] for k in ENGINE_STAGES if k in record.stage_ms},
            **({"kp_precision": final.get("precision"), "kp_recall": final.get("recall"), "kp_f1": final.get("f1"),
                "kp_static_precision": final.get("static_precision"),
                "kp_object_recall": kp["moved_objects"]["recall"],
                "kp_object_keypoints": kp["moved_objects"]["keypoints"]} if kp is not None else {}),
            **({"loops": len(loops["loops"])} if record.loop_closing else {}),
            **({"loops_true": len(loops["loops_true"]), "loops_false": len(loops["loops_false"]),
                "loop_closest_ratio": (loops["loop_closest_call"] or {}).get("ratio")}
               if record.loop_closing and "loops_true" in loops else {})}


def _metric_columns(record: RunRecord) -> dict:
    """ATE and RPE (the ATE alone for a partial run; the ATE's range over ORB-SLAM3's repeats)."""
    ev = record.evaluation
    if ev is None or ev.ate_rmse_m is None:
        return {}
    if ev.metrics is None:
        return {"ate_rmse_m": ev.ate_rmse_m}
    m = ev.metrics
    out = {"ate_rmse_m": m.ate_rmse_m, "rpe_trans_m": m.rpe_trans_m, "rpe_rot_deg": m.rpe_rot_deg}
    if record.ate_range is not None:
        out.update(ate_min_m=record.ate_range[0], ate_max_m=record.ate_range[1])
    return out


def _config(spec: RunSpec, options: RunOptions) -> Config:
    return run_config(options.config, spec.seed, spec.loop_closing)


def _run_engine(spec: RunSpec, path: Path, options: RunOptions) -> tuple[RunRecord, bool]:
    """The run of an engine method and whether it read the sequence's stored features."""
    config = _config(spec, options)
    method = get_method(spec.method)
    seq = open_sequence(path)
    if spec.source == "synth" and len(seq) != spec.frames:
        raise D2SlamError(f"sequence has {len(seq)} frames, the study expects {spec.frames}", path=path)
    frames = len(seq) if spec.source == "synth" or spec.frames <= 0 else min(len(seq), spec.frames)
    # a method with its own masks (oracle: truth) keeps them whatever the study's --masks
    requested = None if method.masks else options.masks
    mask_seq = None
    if method.needs_masks and spec.twin and spec.method == ORACLE:
        # the occluded twin: the oracle on a static twin reads its dynamic sibling's truth, so the silhouettes of
        # the people and moving objects are cut out of a scene where nothing moves (a composite's twin: the real
        # recording, the composite's silhouettes cut out of its real frames)
        mask_seq = open_sequence(sequence_path(spec.source, spec.scenario, spec.seed, spec.frames, False, options))
    stored = {}

    def stored_features(kfilter):
        # A run whose extraction budget follows its filter extracts every frame itself: stored features have the
        # fixed one.
        stored["features"], stored["save_to"] = (_features(seq, path, config, options, frames)
                                                 if not refills(config, kfilter) else (None, None))
        return stored["features"]

    record = run_method(seq, spec.method, config, masks=requested if method.needs_masks else None,
                        mask_seq=mask_seq, synthetic=_has_truth(spec), features=stored_features, progress=False,
                        frames=frames)
    features, save_to = stored["features"], stored["save_to"]
    if save_to is not None:
        features.save(save_to)
    return record, save_to is None and features is not None


# Source that decides a frame's extracted features (``features_path``).
FEATURES_CODE = ("slam/frame.py", "slam/depth.py", "slam/features.py", "data")


def features_path(seq, path: Path, config, options: RunOptions, frames: int | None = None) -> Path:
    """Where the study keeps the extracted features of a sequence's first ``frames`` frames (default: all;
    ``d2slam.slam.features``): named after the sequence folder, its frame count and a digest of what an extraction
    depends on (ORB and engine settings, camera, OpenCV version, the frame and data code), under
    ``<cache>/study/features`` (or ``<cache_root>/features``)."""
    cam = seq.camera
    ident = {"orb": dataclasses.asdict(config.orb), "engine": dataclasses.asdict(config.engine),
             "camera": [cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, cam.bf, cam.depth_factor,
                        [float(d) for d in np.asarray(cam.dist).ravel()]],
             "cv2": cv2.__version__, "code": source_digest(FEATURES_CODE)}
    n = len(seq) if frames is None else frames
    return features_dir(options) / f"{Path(path).resolve().name}_n{n}-{digest(ident)}.npz"


def features_dir(options: RunOptions) -> Path:
    """The folder of the study's feature files: ``<cache>/study/features`` (or ``<cache_root>/features``)."""
    return Path(options.cache_root) / "features" if options.cache_root else cache_dir("study", "features")


def _features(seq, path: Path, config, options: RunOptions, frames: int | None = None):
    """(features for ``run_sequence``, where to save them afterwards or None): the cached features of the sequence's
    first ``frames`` frames when a run already saved them, else a recorder. A damaged cache file is said (one line)
    and replaced."""
    n = len(seq) if frames is None else frames
    target = features_path(seq, path, config, options, n)
    if target.is_file():
        try:
            cached = CachedFeatures(target)
            cached.check(seq.timestamps[:n])
            return cached, None
        except Damaged as exc:
            report_damaged(target, "feature file", exc, "extracting the features again")
            target.unlink(missing_ok=True)
    return FeatureRecorder(), target


def _run_orbslam3(spec: RunSpec, path: Path, options: RunOptions) -> RunRecord:
    config = _config(spec, options)
    repeats = int(options.orbslam3_repeats or config.baseline.orbslam3_repeats)
    masks = None
    if spec.method == ORBSLAM3_MASKED:  # the study's --masks, else the real segmenter's
        masks = mask_kind(get_method(spec.method), options.masks, synthetic=_has_truth(spec))
    with tempfile.TemporaryDirectory(prefix="d2slam_study_orbslam3_") as tmp:
        return run_orbslam3(path, Path(tmp) / "orbslam3.txt", repeats=repeats, config=config, progress=False,
                            max_frames=spec.frames if spec.source != "synth" else 0,
                            timeout=options.orbslam3_timeout, masks=masks)


def message(exc: BaseException) -> str:
    """One line: the D2SlamError text (it names the file), else the exception type, text and where it arose."""
    if isinstance(exc, D2SlamError):
        return str(exc)
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
    return f"{type(exc).__name__}: {exc}{where}".replace("\n", " ")


class single_threaded:
    """OpenCV on one thread for the duration of a run (BLAS is single-threaded by ``d2slam/__init__`` and the
    executors' worker environments): the numbers do not depend on the executor, and two jobs do not
    oversubscribe the cores."""

    def __enter__(self):
        self._prev = cv2.getNumThreads()
        cv2.setNumThreads(1)
        return self

    def __exit__(self, *exc):
        cv2.setNumThreads(self._prev)
        return False
