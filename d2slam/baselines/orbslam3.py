"""The real ORB-SLAM3 (PyPI wheel ``pyorbslam3``, GPL-3.0) in RGB-D mode, as a baseline.

``orbslam3_report(sequence_dir, out_traj, metrics_json=None, repeats=1, ...)``:

1. resolves the vocabulary (argument, ``$PYORBSLAM3_VOCAB`` = e.g. the official ORBvoc.txt, or the one the project
   builds, :mod:`d2slam.baselines.vocab`) and checks its structure (ORB-SLAM3's loader accepts garbage and crashes
   later; a file the project built is known by its manifest); never downloads;
2. writes an ORB-SLAM3 1.0 settings YAML from the sequence's camera (fr3 from the TUM folder name, synthetic
   sequences from ``scene.json``) and the ORB / engine constants of :mod:`d2slam.config`;
3. runs ORB-SLAM3 in a child process (:mod:`d2slam.baselines._orbslam3_worker`, a fresh one per run) with a time
   limit: a crash, an ``exit(-1)`` on a bad settings file or a hang never takes the caller down; repeated runs read
   the frames decoded once (a frame store, ``BaselineConfig.orbslam3_frame_store_dir``); the run JSON says where
   each run's seconds went (``seconds``, ``cpu_s``);
4. writes the trajectory in TUM format (``T_world_camera`` of the *tracked* frames: ORB-SLAM3's final, BA-refined
   ``SaveTrajectoryTUM`` poses at the frames whose state was OK; the online poses if that file is missing) and a run
   JSON with the keys of the engine's run JSON (``frames``, ``tracked``, ``lost``, ``fps``, ``ms_per_frame``, ...),
   ``method: "orbslam3"``, the ``vocabulary`` used (path, sha256, kind built/official/external), ``resets`` and a
   ``status``: ``ok`` | ``lost`` (frames lost, one map) | ``reset`` (ORB-SLAM3 started a new map: the trajectory
   spans several maps) | ``failed`` (vocabulary, settings or sequence rejected) | ``crashed`` | ``timeout``.

``masks="sim" | "gt" | "truth" | "onnx"``: the ``orbslam3-masked`` baseline. Each frame's person masks (the masks the
engine's methods get, :func:`d2slam.segmentation.masks_for`; ``onnx`` masks are computed into the mask cache before
ORB-SLAM3 starts) are removed from both images by :func:`d2slam.baselines.masking.mask_frame` (depth 0, RGB filled)
before ORB-SLAM3 sees them; the per-frame milliseconds then include the masking (``stage_ms``: ``segment`` = reading
the masks, ``mask`` = removing them, ``track`` = ORB-SLAM3).

ORB-SLAM3 is not deterministic (its local-mapping and loop-closing threads): ``repeats=N`` runs it N times and
reports the median and the spread (min, max) of each figure; the trajectory written is the median-ATE repeat when
the sequence has ground truth (else the first successful one).
"""

from __future__ import annotations

import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np
from tqdm import tqdm

from d2slam.baselines import child_env
from d2slam.baselines._orbslam3_worker import STORE_META, write_frame_store
from d2slam.baselines.config import BaselineConfig
from d2slam.baselines.vocab import resolve_vocabulary
from d2slam.data import SyntheticSequence, Trajectory, open_sequence, read_tum_trajectory, write_tum_trajectory
from d2slam.data.intrinsics import is_camera_file, read_camera_file
from d2slam.errors import D2SlamError
from d2slam.eval.fragment import fragment_fields
from d2slam.eval.trajectory import evaluate
from d2slam.outputs import check_output_file, write_bytes
from d2slam.ranges import AnyConfig, overridden, part_of
from d2slam.segmentation import KINDS, masks_for, masks_origin
from d2slam.slam.config import EngineConfig, OrbConfig

METHOD = "orbslam3"
MASKED_METHOD = "orbslam3-masked"
STATE_OK = (2, 5)  # TrackingState.OK, OK_KLT
STATE_RECENTLY_LOST = 3
STATE_LOST = 4
SETTINGS_REQUIRED = (
    "File.version", "Camera.type", "Camera1.fx", "Camera1.fy", "Camera1.cx", "Camera1.cy", "Camera.width",
    "Camera.height", "Camera.fps", "Camera.RGB", "Stereo.ThDepth", "Stereo.b", "RGBD.DepthMapFactor",
    "ORBextractor.nFeatures", "ORBextractor.scaleFactor", "ORBextractor.nLevels", "ORBextractor.iniThFAST",
    "ORBextractor.minThFAST", "Viewer.KeyFrameSize", "Viewer.KeyFrameLineWidth", "Viewer.GraphLineWidth",
    "Viewer.PointSize", "Viewer.CameraSize", "Viewer.CameraLineWidth", "Viewer.ViewpointX", "Viewer.ViewpointY",
    "Viewer.ViewpointZ", "Viewer.ViewpointF",
)


# --------------------------------------------------------------------------------------------------
# Settings
# --------------------------------------------------------------------------------------------------
def settings_yaml(camera, config: AnyConfig | None = None) -> str:
    """ORB-SLAM3 1.0 settings (``File.version: "1.0"``) for an RGB-D camera: intrinsics and distortion, the virtual
    baseline ``Stereo.b = bf / fx`` (fr3: 40 / 535.4 = 0.0747 m), ``Stereo.ThDepth`` (ORB-SLAM3's TUM value 40: close
    points within ThDepth * b), ``RGBD.DepthMapFactor``, the ORB extractor (1000 features, 1.2, 8 levels, FAST 20/7).
    Images are given in RGB order (``Camera.RGB: 1``). The Viewer keys are required by ORB-SLAM3 even without a viewer.
    ``config``: a whole config (its ``orb`` and ``baseline`` sections and ``engine.th_depth``: ORB-SLAM3's ThDepth is
    the engine's), defaults when None."""
    orb, baseline = part_of(config, "orb", OrbConfig), part_of(config, "baseline", BaselineConfig)
    th_depth = part_of(config, "engine", EngineConfig).th_depth
    k1, k2, p1, p2, k3 = (float(c) for c in camera.dist)
    lines = [
        "%YAML:1.0",
        "# Generated by d2slam (d2slam.baselines.orbslam3.settings_yaml) for ORB-SLAM3 1.0, RGB-D.",
        'File.version: "1.0"',
        'Camera.type: "PinHole"',
        f"Camera1.fx: {camera.fx:.6f}",
        f"Camera1.fy: {camera.fy:.6f}",
        f"Camera1.cx: {camera.cx:.6f}",
        f"Camera1.cy: {camera.cy:.6f}",
        f"Camera1.k1: {k1:.9f}",
        f"Camera1.k2: {k2:.9f}",
        f"Camera1.p1: {p1:.9f}",
        f"Camera1.p2: {p2:.9f}",
        *([f"Camera1.k3: {k3:.9f}"] if k3 != 0.0 else []),
        f"Camera.width: {int(camera.width)}",
        f"Camera.height: {int(camera.height)}",
        f"Camera.fps: {int(round(baseline.orbslam3_fps))}",
        "Camera.RGB: 1",
        f"Stereo.ThDepth: {th_depth:.6f}",
        f"Stereo.b: {camera.bf / camera.fx:.6f}",
        f"RGBD.DepthMapFactor: {camera.depth_factor:.6f}",
        f"ORBextractor.nFeatures: {orb.n_features}",
        f"ORBextractor.scaleFactor: {orb.scale_factor:.6f}",
        f"ORBextractor.nLevels: {orb.n_levels}",
        f"ORBextractor.iniThFAST: {orb.fast_threshold}",
        f"ORBextractor.minThFAST: {orb.fast_min_threshold}",
        "Viewer.KeyFrameSize: 0.05",
        "Viewer.KeyFrameLineWidth: 1.0",
        "Viewer.GraphLineWidth: 0.9",
        "Viewer.PointSize: 2.0",
        "Viewer.CameraSize: 0.08",
        "Viewer.CameraLineWidth: 3.0",
        "Viewer.ViewpointX: 0.0",
        "Viewer.ViewpointY: -0.7",
        "Viewer.ViewpointZ: -1.8",
        "Viewer.ViewpointF: 500.0",
    ]
    return "\n".join(lines) + "\n"


def check_settings(path: str | Path) -> None:
    """Fail with a clear message where ORB-SLAM3 would ``exit(-1)`` (or silently misread): not an OpenCV YAML,
    not the 1.0 format, a required key missing or not a number."""
    path = Path(path)
    if not path.is_file():
        raise D2SlamError("ORB-SLAM3 settings file not found", path=path)
    head = path.read_text(errors="replace")[:64]
    if not head.startswith("%YAML"):
        raise D2SlamError("ORB-SLAM3 settings must be an OpenCV YAML starting with '%YAML:1.0'", path=path, line=1)
    try:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    except cv2.error as exc:
        raise D2SlamError(f"ORB-SLAM3 settings are not valid OpenCV YAML: {str(exc).strip()}", path=path) from None
    try:
        if not fs.isOpened():
            raise D2SlamError("ORB-SLAM3 settings could not be opened as OpenCV YAML", path=path)
        if fs.getNode("File.version").string() != "1.0":
            raise D2SlamError('ORB-SLAM3 settings need File.version: "1.0" (the format d2slam writes)', path=path)
        for key in SETTINGS_REQUIRED:
            node = fs.getNode(key)
            if node.empty() or (key not in ("File.version", "Camera.type") and not node.isReal() and not node.isInt()):
                raise D2SlamError(f"ORB-SLAM3 settings lack a numeric {key} (ORB-SLAM3 would abort)", path=path)
    finally:
        fs.release()


# --------------------------------------------------------------------------------------------------
# One run in a child process
# --------------------------------------------------------------------------------------------------
def _read_progress(path: Path) -> dict:
    """Per-frame records of the worker: index, timestamp, state, ms, tracked points, pose (NaN if none)."""
    idx, ts, state, ms, npts, poses = [], [], [], [], [], []
    if path.is_file():
        for line in path.read_text().splitlines():
            parts = line.split()
            if len(parts) not in (6, 21):
                continue  # a line cut by a crash
            idx.append(int(parts[0]))
            ts.append(float(parts[1]))
            state.append(int(parts[2]))
            ms.append(float(parts[3]))
            npts.append(int(parts[4]))
            poses.append(np.array(parts[5:], float).reshape(4, 4) if len(parts) == 21 else np.full((4, 4), np.nan))
    return {"index": np.array(idx, int), "timestamp": np.array(ts, float), "state": np.array(state, int),
            "ms": np.array(ms, float), "n_tracked_points": np.array(npts, int),
            "pose": np.array(poses, float).reshape(-1, 4, 4)}


def _map_segments(state: np.ndarray) -> np.ndarray:
    """Map index of each frame: a new map starts when tracking is OK again after LOST or after being
    uninitialised (ORB-SLAM3 resets the active map or creates a new one); RECENTLY_LOST -> OK is a relocalisation
    in the same map. -1 before the first initialisation."""
    ok = np.isin(state, STATE_OK)
    prev = np.concatenate([[1], state[:-1]])
    starts = ok & ~np.isin(prev, STATE_OK + (STATE_RECENTLY_LOST,))
    seg = np.cumsum(starts) - 1
    return np.where(np.cumsum(ok) > 0, seg, -1)


def _log_tail(log: Path, n: int = 6) -> str:
    if not log.is_file():
        return ""
    lines = [ln.strip() for ln in log.read_text(errors="replace").splitlines() if ln.strip()]
    keys = ("error", "abort", "fail", "wrong", "not found", "exception", "does not exist", "worker:")
    hits = [ln for ln in lines if any(k in ln.lower() for k in keys)]
    return " | ".join((hits or lines)[-n:])


def _run_child(sequence_dir: Path, vocab_path: str, settings_path: Path, work: Path, camera: str | None,
               max_frames: int, n_frames: int, timeout: float | None, config: AnyConfig, progress: bool,
               masks: str | None = None, store: Path | None = None, online_rate: float | None = None) -> dict:
    """Start the worker, follow its progress, enforce the time limits. Returns raw outcome fields."""

    cfg = config.baseline
    log = work / "orbslam3.log"
    cmd = [sys.executable, "-m", "d2slam.baselines._orbslam3_worker", "--vocab", vocab_path, "--settings",
           str(settings_path), "--work", str(work)]
    if store is not None:  # frames decoded (and people removed) once by the caller
        cmd += ["--frames", str(store)] + ([] if online_rate is None else ["--online-rate", f"{online_rate:g}"])
    else:
        cmd += ["--sequence", str(sequence_dir), "--max-frames", str(max_frames)] + (["--camera", camera] if camera
                                                                                     else [])
    if masks and store is None:
        config_path = work / "config.json"
        config_path.write_text(json.dumps({"segmentation": dataclasses.asdict(config.segmentation),
                                           "masking": dataclasses.asdict(config.masking)}, default=list))
        cmd += ["--masks", masks, "--config", str(config_path)]

    env = child_env()
    env.pop("DISPLAY", None)  # headless: Pangolin is never started (use_viewer=False)
    if timeout is None:
        timeout = cfg.orbslam3_load_timeout_s + cfg.orbslam3_frame_timeout_s * n_frames
    stall = max(30.0, 30.0 * cfg.orbslam3_frame_timeout_s)
    t0 = time.monotonic()
    outcome = {"returncode": None, "timed_out": None}
    with open(log, "wb") as logf:
        proc = subprocess.Popen(cmd, stdout=logf, stderr=subprocess.STDOUT, env=env, start_new_session=True)
        bar = tqdm(total=n_frames, desc="ORB-SLAM3", unit="frame", disable=None if progress else True)
        last_change, last_count = time.monotonic(), 0
        prog = work / "progress.txt"
        try:
            while True:
                try:
                    proc.wait(timeout=0.5)
                    break
                except subprocess.TimeoutExpired:
                    pass
                count = prog.read_text().count("\n") if prog.is_file() else 0
                now = time.monotonic()
                if count != last_count:
                    bar.update(count - last_count)
                    last_count, last_change = count, now
                limit_stall = cfg.orbslam3_load_timeout_s if count == 0 else stall
                if now - t0 > timeout or now - last_change > limit_stall:
                    outcome["timed_out"] = (f"no progress for {now - last_change:.0f} s" if now - t0 <= timeout
                                            else f"over the {timeout:g} s limit")
                    _kill(proc)
                    break
        finally:
            if proc.poll() is None:  # KeyboardInterrupt or an error here: never leave ORB-SLAM3 running
                _kill(proc)
            bar.close()
    outcome["returncode"] = proc.returncode
    outcome["wall_s"] = time.monotonic() - t0
    return outcome


def _seconds(wall_s: float, done: dict, ms: np.ndarray) -> dict:
    """Where a run's wall-clock seconds went: ``track`` (the frames' ``track_rgbd`` calls, with the masking),
    ``load`` (ORB-SLAM3's construction: the vocabulary), ``decode`` (reading the frames in the worker: mapping a
    frame store, or decoding PNGs), ``loop`` (the whole frame loop, ``track`` and ``decode`` included), ``save``
    (shutdown and SaveTrajectoryTUM), ``process`` (the rest: interpreter start, imports, exit)."""
    parts = {"track": float(ms.sum()) / 1000.0 if len(ms) else 0.0}
    for key, name in (("load_s", "load"), ("io_s", "decode"), ("loop_s", "loop")):
        parts[name] = float(done.get(name + "_s", done.get(key, 0.0)) or 0.0)
    parts["save"] = float(done.get("shutdown_s", 0.0)) + float(done.get("save_s", 0.0))
    parts["process"] = max(0.0, wall_s - parts["load"] - parts["loop"] - parts["save"])
    return {k: round(v, 3) for k, v in parts.items()}


def _kill(proc: subprocess.Popen) -> None:
    """End the worker we started (its own process group, by id) and reap it."""
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    try:
        proc.wait(timeout=10)
    except subprocess.TimeoutExpired:  # pragma: no cover
        pass


@dataclasses.dataclass(frozen=True)
class Attempt:
    """One ORB-SLAM3 run of a sequence (a repeat of :func:`orbslam3_report`), as its run JSON lists it (``runs``):
    frames run and expected, tracked / lost / not initialised, the maps it started (``resets`` = maps - 1), its
    timings (per frame, the worker's load, wall, the split of ``_seconds``, CPU, per stage), the log kept (None:
    removed), its outcome (``status``, ``message``: see the module docstring) and the trajectory written."""

    method: str
    sequence: str
    frames: int
    frames_expected: int
    tracked: int
    lost: int
    not_initialized: int
    resets: int
    maps: int
    ms_per_frame: float | None
    ms_per_frame_median: float | None
    fps: float | None
    load_s: float | None
    wall_s: float
    seconds: dict
    cpu_s: float | None
    stage_ms: dict
    log: str | None
    status: str
    message: str
    trajectory: str | None  # the TUM file written (None: no frame tracked)
    trajectory_source: str | None  # "SaveTrajectoryTUM" (ORB-SLAM3's final poses) or "online" (track_rgbd's)
    trajectory_poses: int
    repeat: int = 0
    evaluation: dict | None = None  # ``evaluate_trajectory``'s {"metrics": ...} or {"metrics_error": ...}
    online: dict | None = None  # an online run's frames processed and dropped and its lag (:func:`_online_summary`)

    def to_dict(self) -> dict:
        out = {f.name: getattr(self, f.name) for f in dataclasses.fields(self) if f.name != "evaluation"}
        return {**out, **(self.evaluation or {})}


def _run_once(sequence_dir: Path, out_traj: Path, vocab: dict, settings_path: Path, camera: str | None,
              max_frames: int, n_frames: int, timeout: float | None, config: AnyConfig, progress: bool,
              work: Path, masks: str | None = None, store: Path | None = None, repeat: int = 0,
              online_rate: float | None = None) -> Attempt:
    work.mkdir(parents=True, exist_ok=True)
    for name in ("progress.txt", "final.txt", "done.json", "loaded", "orbslam3.log", "online.txt"):
        (work / name).unlink(missing_ok=True)
    raw = _run_child(sequence_dir, vocab["path"], settings_path, work, camera, max_frames, n_frames, timeout,
                     config, progress, masks, store, online_rate)
    rec = _read_progress(work / "progress.txt")
    online = _online_summary(work / "online.txt", n_frames, online_rate) if online_rate is not None else None
    expected = online["processed"] if online and online.get("complete") else n_frames  # dropped frames: not a crash
    done = {}
    if (work / "done.json").is_file():
        try:
            done = json.loads((work / "done.json").read_text())
        except json.JSONDecodeError:
            done = {}
    stages = done  # per-frame stage times: the worker's, or the frame store's (decoded once, people removed once)
    if store is not None:
        stages = json.loads((store / STORE_META).read_text())
        if len(rec["ms"]):  # the masking time of each frame joins its tracking time, as when the worker masks
            rec["ms"] = rec["ms"] + np.load(store / "mask_ms.npy")[rec["index"]]
    log = work / "orbslam3.log"
    state = rec["state"]
    frames = int(len(state))
    ok = np.isin(state, STATE_OK)
    lost_state = np.isin(state, (STATE_RECENTLY_LOST, STATE_LOST))
    seg = _map_segments(state)
    maps = max(log.read_text(errors="replace").count("Creation of new map with id") if log.is_file() else 0,
               int(seg.max() + 1) if frames and seg.max() >= 0 else 0)
    tracked, lost, resets = int(ok.sum()), int(lost_state.sum()), maps - 1 if frames else 0
    status, message = _outcome(raw, done, work, log, frames, expected, tracked, lost, resets)
    traj, source = _trajectory(rec, ok, work / "final.txt", out_traj, sequence_dir)
    ms = rec["ms"]
    return Attempt(
        method=MASKED_METHOD if masks else METHOD, sequence=str(sequence_dir), frames=frames,
        frames_expected=int(n_frames), tracked=tracked, lost=lost, not_initialized=int((~ok & ~lost_state).sum()),
        resets=resets, maps=maps, ms_per_frame=float(ms.mean()) if frames else None,
        ms_per_frame_median=float(np.median(ms)) if frames else None,
        fps=float(1000.0 / ms.mean()) if frames and ms.mean() > 0 else None, load_s=done.get("load_s"),
        wall_s=raw["wall_s"], seconds=_seconds(raw["wall_s"], done, ms), cpu_s=done.get("cpu_s"),
        stage_ms=_stage_ms(stages, frames, ms, masks), log=str(log), status=status, message=message,
        trajectory=str(out_traj) if traj is not None else None, trajectory_source=source,
        trajectory_poses=int(len(traj)) if traj is not None else 0, repeat=repeat, online=online)


def _online_summary(path: Path, n_frames: int, rate_hz: float) -> dict:
    """An online run's account (the worker's ``online.txt``): frames processed and dropped, the lag from a frame's
    arrival to ORB-SLAM3's pose (median, 95th percentile, ms), whether the run reached the last frame."""
    rows, complete = [], False
    if path.is_file():
        for line in path.read_text().splitlines():
            parts = line.split()
            if len(parts) == 4:
                rows.append([float(x) for x in parts])
            elif len(parts) == 2 and parts[0] == "frames":
                complete = True
    a = np.array(rows, dtype=np.float64).reshape(-1, 4)
    lag = 1000.0 * (a[:, 3] - a[:, 1])
    return {"rate_hz": rate_hz, "frames": int(n_frames), "processed": int(len(a)), "dropped": int(n_frames - len(a)),
            "processed_share": round(len(a) / max(n_frames, 1), 4),
            "lag_ms_median": round(float(np.median(lag)), 2) if len(lag) else None,
            "lag_ms_p95": round(float(np.percentile(lag, 95)), 2) if len(lag) else None, "complete": complete}


def _stage_ms(stages: dict, frames: int, ms: np.ndarray, masks: str | None) -> dict:
    """Milliseconds per frame of loading (the worker's I/O) and tracking; with masks, of segmenting and masking too
    (the per-frame ``ms`` hold the masking and ORB-SLAM3's tracking)."""
    n_stage = max(1, int(stages.get("frames") or frames))
    out = {"load": round(1000.0 * stages["io_s"] / n_stage, 3) if frames and "io_s" in stages else None,
           "track": round(float(ms.mean()), 3) if frames else None}
    if masks and frames and "mask_s" in stages:
        mask_ms = 1000.0 * stages["mask_s"] / n_stage
        out.update(segment=round(1000.0 * stages["segment_s"] / n_stage, 3), mask=round(mask_ms, 3),
                   track=round(float(ms.mean()) - mask_ms, 3))
    return out


def _outcome(raw: dict, done: dict, work: Path, log: Path, frames: int, n_frames: int, tracked: int, lost: int,
             resets: int) -> tuple[str, str]:
    """(status, message) of one run (the module docstring lists the statuses)."""
    if raw["timed_out"]:
        status, message = "timeout", f"ORB-SLAM3 stopped: {raw['timed_out']} (after {frames} frames)"
    elif "error" in done:
        status, message = "failed", done["error"]
    elif raw["returncode"] != 0 and "loaded" not in [p.name for p in work.iterdir()]:
        status = "failed"
        message = f"ORB-SLAM3 did not start (exit {raw['returncode']}): {_log_tail(log)}"
    elif frames < n_frames:
        status = "crashed"
        message = (f"ORB-SLAM3 died after {frames} of {n_frames} frames (exit {raw['returncode']}): "
                   f"{_log_tail(log)}")
    elif resets > 0:
        status = "reset"
        message = (f"ORB-SLAM3 lost tracking and started {resets} new map(s); the trajectory spans "
                   f"several maps (tracked {tracked}/{frames})")
    elif lost > 0 or tracked == 0:
        status = "lost"
        message = f"ORB-SLAM3 lost tracking on {lost} frames (tracked {tracked}/{frames})"
    else:
        status, message = "ok", f"tracked {tracked}/{frames} frames"
    if raw["returncode"] not in (0, None) and status in ("ok", "lost", "reset"):
        message += f"; ORB-SLAM3 exited with {raw['returncode']} after the last frame"
    return status, message


def _trajectory(rec: dict, ok: np.ndarray, final_path: Path, out_traj: Path, sequence_dir: Path):
    """Write the tracked frames' poses to ``out_traj`` (ORB-SLAM3's final poses where it saved them, else the
    online ones) and the online poses beside it (``.online.txt``); returns (the trajectory or None, its source)."""
    source, traj = None, None
    tracked_ts = rec["timestamp"][ok]
    if tracked_ts.size and final_path.is_file() and final_path.stat().st_size > 0:
        try:
            final = read_tum_trajectory(final_path)
            j = np.searchsorted(final.timestamps, tracked_ts)
            j = np.clip(j, 0, len(final.timestamps) - 1)
            jm = np.clip(j - 1, 0, len(final.timestamps) - 1)
            near = np.where(np.abs(final.timestamps[jm] - tracked_ts) < np.abs(final.timestamps[j] - tracked_ts),
                            jm, j)
            hit = np.abs(final.timestamps[near] - tracked_ts) < 5e-6
            if hit.any():
                traj = Trajectory(tracked_ts[hit], final.poses[near[hit]])
                source = "SaveTrajectoryTUM"
        except D2SlamError:
            traj = None
    if traj is None and tracked_ts.size:
        traj = Trajectory(tracked_ts, rec["pose"][ok])
        source = "online"
    if traj is not None:
        write_tum_trajectory(out_traj, traj, header=f"d2slam orbslam3 ({source} poses of tracked frames) "
                                                     f"{sequence_dir}")
        online = Trajectory(tracked_ts, rec["pose"][ok])
        write_tum_trajectory(out_traj.with_name(out_traj.stem + ".online.txt"), online,
                             header="d2slam orbslam3 online poses (track_rgbd) of tracked frames")
    return traj, source


# --------------------------------------------------------------------------------------------------
# Public entry point
# --------------------------------------------------------------------------------------------------
def orbslam3_report(sequence_dir: str | Path, out_traj: str | Path, metrics_json: str | Path | None = None,
                 repeats: int = 1, vocab: str | Path | None = None, settings: str | Path | None = None,
                 camera: str | None = None, max_frames: int = 0, timeout: float | None = None,
                 config: AnyConfig = None, progress: bool = True, evaluate: bool = True,
                 keep_work: bool = False, masks: str | None = None,
                 online_rate: float | None = None) -> tuple[dict, object]:
    """Run the real ORB-SLAM3 RGB-D on ``sequence_dir`` ``repeats`` times; write ``out_traj`` (TUM) and the run
    JSON (``metrics_json``); return the run JSON and the sequence read (``d2slam.run.orbslam3_runs.run_orbslam3`` makes
    the run's ``RunRecord`` of them). Never raises for an
    ORB-SLAM3 failure: the record's ``status`` says what happened and ``error`` why (see the module docstring).
    Bad arguments (no sequence, repeats < 1) raise :class:`D2SlamError`.

    ``vocab``: a DBoW2 text file (default ``$PYORBSLAM3_VOCAB``, else the project-built vocabulary, built on first
    use); ``settings``: an ORB-SLAM3 1.0 YAML (default: generated from the sequence's camera); ``camera``: override
    the sequence's camera (``fr1``/``fr2``/``fr3``); ``max_frames``: first N frames only (0 = all); ``timeout``:
    seconds per repeat (default load + per-frame budget of :class:`~d2slam.config.BaselineConfig`); ``masks``: the
    person masks to remove from the frames (``orbslam3-masked``, module docstring; they must exist: a synthetic
    sequence's ``sim`` / ``gt`` / ``truth``, or an ONNX model for ``onnx``, else :class:`D2SlamError`); ``config``:
    the run's whole config (``d2slam.config.Config``, required: its ``orb``, ``baseline``, ``masking``,
    ``segmentation`` and ``evaluation`` sections, and its hash); ``online_rate``: replay the frames as a live camera
    at this rate (0: their timestamps; ``d2slam.data.live``), dropping those that arrive while ORB-SLAM3 is busy (each
    run's ``online``: frames processed, dropped, lag)."""
    if config is None:
        raise TypeError("orbslam3_report needs the run's config")
    out_traj = Path(out_traj).expanduser()
    report, seq = _report(sequence_dir, out_traj, metrics_json, repeats, vocab, settings, camera, max_frames, timeout,
                          config, progress, evaluate, keep_work, masks, online_rate)
    return report, seq


def _report(sequence_dir, out_traj: Path, metrics_json, repeats: int, vocab, settings, camera, max_frames: int,
            timeout, config: AnyConfig, progress: bool, evaluate: bool, keep_work: bool, masks,
            online_rate: float | None = None) -> tuple[dict, object]:
    """:func:`orbslam3_report`'s runs: (the run JSON, the sequence)."""
    sequence_dir = Path(sequence_dir).expanduser().resolve()
    if repeats < 1:
        raise D2SlamError(f"repeats must be >= 1, got {repeats}")
    check_output_file(out_traj, "trajectory")
    if metrics_json is not None:
        check_output_file(metrics_json, "metrics JSON")
    for stale in [out_traj, out_traj.with_name(out_traj.stem + ".online.txt")]:
        stale.unlink(missing_ok=True)  # a failed run must not leave an older trajectory behind
    config, seq, base = _open(sequence_dir, camera, max_frames, repeats, config, masks, progress)
    n_frames = base["frames_expected"]
    work_root = Path(tempfile.mkdtemp(prefix="d2slam_orbslam3_", dir=out_traj.parent))
    store = None
    try:
        # vocabulary and settings problems: recorded, not raised
        try:
            vinfo = resolve_vocabulary(vocab, build=True, progress=progress)
        except D2SlamError as exc:
            return _finish(dict(base, status="failed", message=f"vocabulary: {exc}", vocabulary=None),
                           metrics_json, config), seq
        base["vocabulary"] = vinfo
        if settings is None:
            settings_path = out_traj.with_name(out_traj.stem + ".orbslam3.yaml")
            settings_path.write_text(settings_yaml(seq.camera, config))
        else:
            settings_path = Path(settings)
        base["settings"] = str(settings_path)
        try:
            check_settings(settings_path)
        except D2SlamError as exc:
            return _finish(dict(base, status="failed", message=f"settings: {exc}"), metrics_json, config), seq
        store = _frame_store_root(seq, n_frames, repeats, config, work_root, force=online_rate is not None)
        if store is not None:
            t0 = time.perf_counter()
            meta = write_frame_store(seq, n_frames, store, masks, config, progress)
            base["frame_store"] = dict(meta, wall_s=round(time.perf_counter() - t0, 3),
                                       bytes=sum(f.stat().st_size for f in store.iterdir()))
        repeat = _Repeats(seq, sequence_dir, out_traj, vinfo, settings_path, camera, max_frames, n_frames, timeout,
                          config, progress, work_root, masks, store, keep_work, evaluate, repeats, online_rate)
        runs = [repeat(r) for r in range(repeats)]
        return _finish(_summarise(base, runs, out_traj), metrics_json, config), seq
    finally:
        shutil.rmtree(work_root, ignore_errors=True)
        if store is not None:
            shutil.rmtree(store.parent, ignore_errors=True)


def _open(sequence_dir: Path, camera, max_frames: int, repeats: int, config: AnyConfig, masks,
          progress: bool) -> tuple[AnyConfig, object, dict]:
    """(the config, with a camera settings file's ThDepth; the sequence through its camera; the run JSON's common
    fields: the sequence, the frames to run, the camera and where it came from, the masks removed and where they come
    from, the config's hash)."""
    camera_file = read_camera_file(camera) if is_camera_file(camera) else None  # read once (the worker reads its own)
    if camera_file is not None and camera_file.th_depth is not None:
        # a settings YAML's own close-point threshold replaces the TUM value (the engine's ThDepth is ORB-SLAM3's)
        config = overridden(config, {"engine": {"th_depth": camera_file.th_depth}})
    seq_camera = camera_file.camera if camera_file is not None else camera
    seq = open_sequence(sequence_dir, camera=seq_camera) if seq_camera else open_sequence(sequence_dir)
    n_frames = len(seq) if max_frames <= 0 else min(len(seq), max_frames)
    camera_source = (str(Path(camera).expanduser().resolve()) if camera_file is not None else
                     "scene.json" if isinstance(seq, SyntheticSequence) else camera or "folder name")
    base = {"method": METHOD, "sequence": str(sequence_dir), "name": seq.name, "frames_expected": n_frames,
            "repeats": repeats,
            "camera": seq.camera.name, "camera_source": camera_source,
            "camera_settings": dataclasses.asdict(seq.camera), "config_hash": config.hash()}
    if masks is not None:
        origin = _prepare_masks(seq, masks, n_frames, config, progress)
        base.update(method=MASKED_METHOD, masks=masks, masks_origin=origin,
                    masking=dataclasses.asdict(config.masking))
    return config, seq, base


@dataclasses.dataclass
class _Repeats:
    """What every repeat of a run shares; ``repeat(r)`` runs repeat ``r``."""

    seq: object
    sequence_dir: Path
    out_traj: Path
    vinfo: dict
    settings_path: Path
    camera: object
    max_frames: int
    n_frames: int
    timeout: float | None
    config: AnyConfig
    progress: bool
    work_root: Path
    masks: str | None
    store: Path | None
    keep_work: bool
    evaluate: bool
    repeats: int
    online_rate: float | None

    def __call__(self, r: int) -> dict:
        """Repeat ``r``'s run (its own trajectory file when there are several), its log kept when asked to or when
        the run did not end well, evaluated against the ground truth when asked to; as the run JSON records it."""
        out = self.out_traj
        traj_r = out if self.repeats == 1 else out.with_name(f"{out.stem}.rep{r}{out.suffix}")
        run = _run_once(self.sequence_dir, traj_r, self.vinfo, self.settings_path, self.camera, self.max_frames,
                        self.n_frames, self.timeout, self.config, self.progress, self.work_root / f"rep{r}",
                        self.masks, self.store, repeat=r, online_rate=self.online_rate)
        kept = None
        if self.keep_work or run.status not in ("ok", "lost"):
            kept = str(out.with_name(f"{out.stem}.rep{r}.orbslam3.log"))
            if Path(run.log).is_file():
                shutil.copyfile(run.log, kept)
        run = dataclasses.replace(run, log=kept)
        if self.evaluate and run.trajectory and self.seq.groundtruth is not None:
            t0 = time.perf_counter()
            evaluation = evaluate_trajectory(self.seq, run.trajectory)
            run = dataclasses.replace(run, evaluation=evaluation,
                                      seconds={**run.seconds, "evaluate": round(time.perf_counter() - t0, 3)})
        return run.to_dict()


def _frame_store_root(seq, n_frames: int, repeats: int, config: AnyConfig, work_root: Path,
                      force: bool = False) -> Path | None:
    """Where the frames of a repeated run are decoded once (:func:`~d2slam.baselines._orbslam3_worker.
    write_frame_store`): a new folder in ``BaselineConfig.orbslam3_frame_store_dir`` (memory-backed ``/dev/shm``)
    when it has room, else in the run's work folder; None (every worker decodes its frames) for a single run or when
    the frames would exceed ``orbslam3_frame_store_mb``. ``force`` (an online run: its frames are decoded before the
    camera starts): always a store."""
    size = n_frames * int(seq.camera.height) * int(seq.camera.width) * (3 + 4)  # RGB uint8 + depth float32
    if not force and (repeats < 2 or size > config.baseline.orbslam3_frame_store_mb * 2**20):
        return None
    parent = Path(config.baseline.orbslam3_frame_store_dir)
    try:
        if not (parent.is_dir() and os.access(parent, os.W_OK) and shutil.disk_usage(parent).free > 2 * size):
            parent = work_root
    except OSError:
        parent = work_root
    return Path(tempfile.mkdtemp(prefix="d2slam_orbslam3_frames_", dir=parent)) / "frames"


def _prepare_masks(seq, kind: str, n_frames: int, config: AnyConfig, progress: bool) -> str:
    """Check that the ``kind`` masks of the first ``n_frames`` frames can be had before ORB-SLAM3 starts (a clear
    :class:`D2SlamError` otherwise: no ``mask_sim/`` on a real sequence, no ONNX model; the fill and dilation are
    checked by ``MaskingConfig``'s ranges); the
    ``onnx`` ones are segmented into the mask cache here (announced, :func:`d2slam.segmentation.masks_origin`), so
    the worker only reads them. Returns where the masks come from."""
    if kind not in KINDS:
        raise D2SlamError(f"unknown masks {kind!r}; choose one of {', '.join(KINDS)}")
    if kind != "onnx" and n_frames:
        masks_for(seq, 0, kind, config)  # the label folder is there
    return masks_origin(seq, kind, config, frames=n_frames, progress=progress)


def evaluate_trajectory(seq, traj_path: str) -> dict:
    """``{"metrics": {ate_rmse_m, rpe_trans_m, rpe_rot_deg, ...}}`` with :mod:`d2slam.eval.trajectory` (evo), as in
    the engine's run JSON; ``{"metrics_error": ...}`` when the trajectory cannot be evaluated."""
    try:
        return {"metrics": evaluate(seq.groundtruth, read_tum_trajectory(traj_path)).to_dict()}
    except D2SlamError as exc:
        return {"metrics_error": str(exc)}
    except Exception as exc:  # noqa: BLE001 - evo's own errors (e.g. a degenerate, straight-line alignment)
        return {"metrics_error": f"{type(exc).__name__}: {exc}"}


_SPREAD_KEYS = ("tracked", "lost", "resets", "ms_per_frame", "ms_per_frame_median", "fps", "load_s")
_METRIC_KEYS = ("ate_rmse_m", "rpe_trans_m", "rpe_rot_deg")


def _spread(values: list) -> dict:
    return {"min": float(min(values)), "max": float(max(values)), "values": values}


def _summarise(base: dict, runs: list[dict], out_traj: Path) -> dict:
    """One run: its figures. Several: the median of each figure (spread = min, max, per-repeat values), the
    trajectory of the median-ATE repeat (or the first that tracked) copied to ``out_traj``."""
    if len(runs) == 1:
        out = dict(base, **runs[0])
        out["runs"] = runs
        return out
    out = dict(base)
    out["runs"] = runs
    statuses = [r["status"] for r in runs]
    out["statuses"] = statuses
    for key in _SPREAD_KEYS:
        vals = [r[key] for r in runs if isinstance(r.get(key), (int, float))]
        if vals:
            out[key] = float(np.median(vals))
            out[f"{key}_spread"] = _spread(vals)
    metrics, mspread = {}, {}
    for key in _METRIC_KEYS:
        vals = [r["metrics"][key] for r in runs if isinstance(r.get("metrics", {}).get(key), (int, float))]
        if vals:
            metrics[key], mspread[key] = float(np.median(vals)), _spread(vals)
    if metrics:
        out["metrics"], out["metrics_spread"] = metrics, mspread
    out["frames"] = int(np.median([r["frames"] for r in runs]))
    usable = [r for r in runs if r.get("trajectory")]
    if usable:
        if all(isinstance(r.get("metrics", {}).get("ate_rmse_m"), (int, float)) for r in usable):
            order = sorted(usable, key=lambda r: r["metrics"]["ate_rmse_m"])
            pick = order[(len(order) - 1) // 2]
        else:
            pick = usable[0]
        shutil.copyfile(pick["trajectory"], out_traj)
        out["trajectory"] = str(out_traj)
        out["trajectory_repeat"] = pick["repeat"]
        if pick.get("online"):  # an online run: the account of the repeat whose trajectory is kept
            out["online"] = pick["online"]
    else:
        out["trajectory"] = None
    worst = ("failed", "timeout", "crashed", "reset", "lost", "ok")
    out["status"] = next((s for s in worst if s in statuses), "ok") if len(set(statuses)) > 1 else statuses[0]
    out["message"] = "; ".join(f"rep{r['repeat']}: {r['status']} ({r['message']})" for r in runs
                               if r["status"] != "ok") or f"all {len(runs)} repeats ok"
    return out


def _finish(result: dict, metrics_json, config: AnyConfig) -> dict:
    """The run JSON as written: its status, the share of frames tracked (``d2slam.run.record.fragment_fields``: whether
    the run is a fragment by ``EvalConfig.min_tracked_share``; a run that failed before its frames has none) and
    when it was made."""
    result.setdefault("status", "ok")
    if result.get("tracked") is not None:
        result.update(fragment_fields(result["tracked"], result.get("frames"), config.evaluation.min_tracked_share))
    result["created"] = time.strftime("%Y-%m-%dT%H:%M:%S")
    if metrics_json:
        path = Path(metrics_json)
        path.parent.mkdir(parents=True, exist_ok=True)
        write_bytes(path, json.dumps(result, indent=2, default=_json_default))
    return result


def _json_default(o):
    if isinstance(o, (np.integer,)):
        return int(o)
    if isinstance(o, (np.floating,)):
        return float(o)
    if isinstance(o, Path):
        return str(o)
    raise TypeError(type(o).__name__)
