"""One run of the study grid, as a plain function of picklable arguments (so that any executor can call it: the
caller's process, a joblib/loky worker or a Dask worker): generate or reuse the sequence, run the engine with the
method's keypoint filter (or real ORB-SLAM3), evaluate with evo, classify keypoints against the synthetic truth.

:func:`execute_run` never raises: any failure becomes ``status="failed"`` with the error message in the row, so a
study records every run of its grid. Everything it returns is plain data (the trajectory as arrays), so a remote
Dask worker needs no access to the study's output folder.
"""

from __future__ import annotations

import dataclasses
import tempfile
from functools import lru_cache
import time
import traceback
from pathlib import Path

import numpy as np

from d2slam.errors import D2SlamError
from d2slam.pipeline import STAGES as ENGINE_STAGES
from d2slam.study.grid import LABELS, ORACLE, ORBSLAM3, ORBSLAM3_MASKED, REPEATED, STUDY_MASKS, RunSpec


def run_options(config=None, cache_root: str | None = None, tum_root: str | None = None, masks: str | None = None,
                orbslam3_repeats: int | None = None, orbslam3_timeout: float | None = None) -> dict:
    """The options every run of a study shares, as a picklable dict (``config`` as a nested dict; ``masks``: the
    study's masks, the real segmenter's unless given)."""
    from d2slam.config import DEFAULT

    config = config or DEFAULT
    return {"config": config.to_dict(), "cache_root": None if cache_root is None else str(cache_root),
            "tum_root": None if tum_root is None else str(tum_root), "masks": masks or STUDY_MASKS,
            "orbslam3_repeats": int(orbslam3_repeats or config.baseline.orbslam3_repeats),
            "orbslam3_timeout": orbslam3_timeout}


def prepare_sequence(key: tuple, options: dict) -> dict:
    """Generate (or find) the sequence of ``RunSpec.sequence_key``; returns ``{"key", "path", "error"}``."""
    source, scenario, seed, frames, twin = key
    try:
        with _single_threaded():
            path = _sequence_path(source, scenario, seed, frames, twin, options)
        return {"key": key, "path": str(path), "error": None}
    except Exception as exc:  # noqa: BLE001 - recorded, the runs on it fail with this message
        return {"key": key, "path": None, "error": _message(exc)}


def onnx_sequence_keys(specs, options: dict) -> list[tuple]:
    """The sequences (``RunSpec.sequence_key``) on which some run of ``specs`` reads the real segmenter's masks."""
    from d2slam.methods import get_method, mask_kind, methods

    keys = []
    for s in specs:
        if s.method not in methods():
            continue  # an unknown method's run records its own error
        method = get_method(s.method)
        if method.needs_masks and mask_kind(method, None if method.masks else options["masks"],
                                            synthetic=s.source == "synth") == "onnx":
            keys.append(s.sequence_key)
    return list(dict.fromkeys(keys))


def segment_sequence(key: tuple, options: dict) -> dict:
    """Segment every frame the runs read of the sequence ``key`` with the real segmenter into the mask cache, once per
    sequence before the runs (which then only read it, whichever worker runs them; two runs on one sequence at the
    same time would otherwise both segment it). Returns ``{"key", "error"}``; a failure is left to the runs,
    which meet it again and record it."""
    from d2slam.config import Config
    from d2slam.data import open_sequence
    from d2slam.segmentation import masks_for

    source, scenario, seed, frames, twin = key
    try:
        with _single_threaded():
            seq = open_sequence(_sequence_path(source, scenario, seed, frames, twin, options))
            config = Config.from_dict(options["config"])
            n = len(seq) if frames <= 0 else min(len(seq), frames)
            for i in range(n):
                masks_for(seq, i, "onnx", config)
        return {"key": key, "error": None}
    except Exception as exc:  # noqa: BLE001 - recorded; the runs on it fail with their own message
        return {"key": key, "error": _message(exc)}


def _sequence_path(source, scenario, seed, frames, twin, options) -> Path:
    if source == "tum":
        from d2slam.study.sequences import tum_sequence_dir

        if not options.get("tum_root"):
            raise D2SlamError("a TUM run needs tum_root (D2SLAM_TUM_ROOT)")
        return tum_sequence_dir(options["tum_root"], scenario)
    from d2slam.study.sequences import ensure_sequence

    return ensure_sequence(scenario, seed, frames, twin, root=options.get("cache_root"), progress=False)


def execute_run(spec: RunSpec | dict, options: dict) -> dict:
    """Run one grid cell. Returns ``{"row": {...}, "trajectory": (timestamps, poses) | None,
    "aligned": (gt_xyz, est_xyz) | None, "keypoints": per-module dict | None, "stage_ms": {...}}``; never raises."""
    if isinstance(spec, dict):
        spec = RunSpec(**spec)
    t0 = time.perf_counter()
    out = {"row": base_row(spec), "trajectory": None, "aligned": None, "keypoints": None, "stage_ms": {},
           "loops": None}
    try:
        with _single_threaded():
            path = _sequence_path(spec.source, spec.scenario, spec.seed, spec.frames, spec.twin, options)
            if spec.method in REPEATED:
                _run_orbslam3(spec, path, options, out)
            else:
                _run_engine(spec, path, options, out)
    except Exception as exc:  # noqa: BLE001 - a failed run is a row, not a crash of the study
        out["row"].update(status="failed", error=_message(exc))
    out["row"]["wall_s"] = time.perf_counter() - t0
    return out


def base_row(spec: RunSpec) -> dict:
    return {"scenario": spec.scenario, "sequence": LABELS.get(spec.scenario, spec.scenario), "twin": int(spec.twin),
            "method": spec.method, "seed": int(spec.seed), "frames": int(spec.frames), "source": spec.source,
            "loop_closing": int(spec.loop_closing), "status": "failed", "error": "",
            "deterministic": int(spec.method not in REPEATED), "repeats": 1}


def _config(spec: RunSpec, options: dict):
    from d2slam.config import Config

    config = Config.from_dict(options["config"])
    return dataclasses.replace(config, engine=dataclasses.replace(
        config.engine, ransac_seed=int(spec.seed), loop_closing=bool(config.engine.loop_closing and spec.loop_closing)))


class _Head:
    """The first ``n`` frames of a sequence (a real TUM folder cut to the study's ``--frames``)."""

    def __init__(self, seq, n: int):
        self._seq, self._n = seq, min(len(seq), int(n))

    def __len__(self) -> int:
        return self._n

    def _check(self, i: int) -> int:
        if not 0 <= i < self._n:
            raise IndexError(i)
        return i

    def __getitem__(self, i: int):
        return self._seq[self._check(i)]

    def depth_image(self, i: int):
        return self._seq.depth_image(self._check(i))

    def __getattr__(self, name):
        return getattr(self._seq, name)


def _run_engine(spec: RunSpec, path: Path, options: dict, out: dict) -> None:
    from d2slam.data import open_sequence
    from d2slam.eval.loops import loop_summary
    from d2slam.eval.trajectory import aligned_estimate, evaluate
    from d2slam.methods import get_method, run_method
    from d2slam.slam.engine import refills

    config = _config(spec, options)
    row = out["row"]
    row["config_hash"] = config.hash()
    row["loop_closing"] = int(config.engine.loop_closing)
    method = get_method(spec.method)
    seq = open_sequence(path)
    if spec.source == "synth" and len(seq) != spec.frames:
        raise D2SlamError(f"sequence has {len(seq)} frames, the study expects {spec.frames}", path=path)
    if spec.source == "tum" and spec.frames > 0:
        seq = _Head(seq, spec.frames)
    # a method with its own masks (oracle: truth) keeps them whatever the study's --masks
    requested = None if method.masks else options["masks"]
    mask_seq = None
    if method.needs_masks and spec.twin and spec.method == ORACLE:
        # the occluded twin: the oracle on a static twin reads its dynamic sibling's truth, so the silhouettes of
        # the people and moving objects are cut out of a scene where nothing moves
        mask_seq = open_sequence(_sequence_path(spec.source, spec.scenario, spec.seed, spec.frames, False, options))
    stored = {}

    def stored_features(kfilter):
        # A run whose extraction budget follows its filter extracts every frame itself: stored features have the
        # fixed one.
        stored["features"], stored["save_to"] = (_features(seq, path, config, options)
                                                 if not refills(config, kfilter) else (None, None))
        return stored["features"]

    run = run_method(seq, spec.method, config, masks=requested if method.needs_masks else None, mask_seq=mask_seq,
                     synthetic=spec.source == "synth", features=stored_features, progress=False)
    result, features, save_to = run.result, stored["features"], stored["save_to"]
    if save_to is not None:
        features.save(save_to)
    row["features_cached"] = int(save_to is None and features is not None)
    row.update(frames_tracked=result.tracked, frames_lost=result.lost, keyframes=result.keyframes,
               map_points=result.map_points, fps=result.fps,
               ms_per_frame=1000.0 * result.total_s / max(result.frames, 1))
    for k in ENGINE_STAGES:
        if k in result.stage_ms:
            row[f"ms_{k}"] = result.stage_ms[k]
    out["stage_ms"] = dict(result.stage_ms)
    traj = result.trajectory
    out["trajectory"] = (np.asarray(traj.timestamps), np.asarray(traj.poses))
    if run.keypoints is not None:
        kp = run.keypoints
        out["keypoints"] = kp
        final = kp["modules"].get("final", {})
        row.update(kp_precision=final.get("precision"), kp_recall=final.get("recall"), kp_f1=final.get("f1"),
                   kp_static_precision=final.get("static_precision"),
                   kp_object_recall=kp["moved_objects"]["recall"], kp_object_keypoints=kp["moved_objects"]["keypoints"])
    gt = seq.groundtruth
    loops = loop_summary(result, seq.timestamps, gt, config.evaluation)
    out["loops"] = loops
    if result.loop_closing:
        row["loops"] = len(loops["loops"])
        if gt is not None:
            row.update(loops_true=len(loops["loops_true"]), loops_false=len(loops["loops_false"]),
                       loop_closest_ratio=(loops["loop_closest_call"] or {}).get("ratio"))
    if gt is None:
        row.update(status="unevaluated", error="the sequence has no ground truth")
        return
    try:
        m = evaluate(gt, traj)
        out["aligned"] = tuple(np.asarray(a) for a in aligned_estimate(gt, traj)[:2])
    except Exception as exc:  # noqa: BLE001 - D2SlamError, or evo's own errors (degenerate alignment)
        msg = str(exc) if isinstance(exc, D2SlamError) else f"{type(exc).__name__}: {exc}"
        ate = _ate_only(gt, traj) if "RPE" in msg else None
        if ate is None:
            row.update(status="unevaluated", error=f"evaluation: {msg}")
            return
        out["aligned"], ate_m = ate
        row.update(status="partial", error=f"ATE only: {msg}", ate_rmse_m=ate_m)
        return
    row.update(status="ok", error="", ate_rmse_m=m.ate_rmse_m, rpe_trans_m=m.rpe_trans_m, rpe_rot_deg=m.rpe_rot_deg)


def features_path(seq, path: Path, config, options: dict) -> Path:
    """Where the study keeps a sequence's extracted features (``d2slam.slam.features``): named after the sequence
    folder, its frame count and a digest of what an extraction depends on (ORB and engine settings, camera, OpenCV
    version, the frame and data code), under ``<cache>/study/features`` (or ``<cache_root>/features``)."""
    import cv2

    cam = seq.camera
    ident = {"orb": dataclasses.asdict(config.orb), "engine": dataclasses.asdict(config.engine),
             "camera": [cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height, cam.bf, cam.depth_factor,
                        [float(d) for d in np.asarray(cam.dist).ravel()]],
             "cv2": cv2.__version__, "code": source_digest(("slam/frame.py", "slam/features.py", "data"))}
    key = _digest(ident)
    return features_dir(options) / f"{Path(path).resolve().name}_n{len(seq)}-{key}.npz"


def features_dir(options: dict) -> Path:
    """The folder of the study's feature files: ``<cache>/study/features`` (or ``<cache_root>/features``)."""
    from d2slam.paths import cache_dir

    return Path(options["cache_root"]) / "features" if options.get("cache_root") else cache_dir("study", "features")


def _features(seq, path: Path, config, options: dict):
    """(features for ``run_sequence``, where to save them afterwards or None): the cached features of the sequence
    when a run already saved them, else a recorder. A corrupt cache file is replaced."""
    from d2slam.slam.features import CachedFeatures, FeatureRecorder

    target = features_path(seq, path, config, options)
    if target.is_file():
        try:
            cached = CachedFeatures(target)
            cached.check(seq.timestamps[:len(seq)])
            return cached, None
        except D2SlamError:
            target.unlink(missing_ok=True)
    return FeatureRecorder(), target


def _ate_only(gt, traj):
    """When the tracked part is too short for a 1-second RPE pair: the ATE alone, from evo's association and
    SE(3) Umeyama alignment (``aligned_estimate``), RMSE of the position errors (= evo APE translation RMSE)."""
    from d2slam.eval.trajectory import aligned_estimate

    try:
        g, e, _ = aligned_estimate(gt, traj)
    except Exception:  # noqa: BLE001
        return None
    g, e = np.asarray(g), np.asarray(e)
    if len(g) < 3:
        return None
    return (g, e), float(np.sqrt(np.mean(np.sum((g - e) ** 2, axis=1))))


def _run_orbslam3(spec: RunSpec, path: Path, options: dict, out: dict) -> None:
    from d2slam.baselines.orbslam3 import run_orbslam3
    from d2slam.data import open_sequence, read_tum_trajectory
    from d2slam.eval.trajectory import aligned_estimate
    from d2slam.methods import get_method, mask_kind

    config = _config(spec, options)
    row = out["row"]
    repeats = int(options.get("orbslam3_repeats") or config.baseline.orbslam3_repeats)
    row.update(config_hash=config.hash(), repeats=repeats)
    masks = None
    if spec.method == ORBSLAM3_MASKED:  # the study's --masks, else the real segmenter's
        masks = mask_kind(get_method(spec.method), options["masks"], synthetic=spec.source == "synth")
    with tempfile.TemporaryDirectory(prefix="d2slam_study_orbslam3_") as tmp:
        traj_path = Path(tmp) / "orbslam3.txt"
        res = run_orbslam3(path, traj_path, repeats=repeats, config=config, progress=False,
                           max_frames=spec.frames if spec.source == "tum" else 0,
                           timeout=options.get("orbslam3_timeout"), masks=masks)
        traj = read_tum_trajectory(traj_path) if res.get("trajectory") and traj_path.is_file() else None
    status = res.get("status", "failed")
    metrics = res.get("metrics") or {}
    spread = res.get("metrics_spread") or {}
    row.update(error="" if status == "ok" else str(res.get("message") or res.get("metrics_error") or ""),
               frames_tracked=res.get("tracked"), frames_lost=res.get("lost"), fps=res.get("fps"),
               ms_per_frame=res.get("ms_per_frame"))
    if metrics:  # medians over the repeats; ORB-SLAM3's own status (ok / lost / reset / crashed ...) is kept
        ate = spread.get("ate_rmse_m")
        row.update(status=status, ate_rmse_m=metrics.get("ate_rmse_m"), rpe_trans_m=metrics.get("rpe_trans_m"),
                   rpe_rot_deg=metrics.get("rpe_rot_deg"),
                   ate_min_m=ate["min"] if ate else metrics.get("ate_rmse_m"),
                   ate_max_m=ate["max"] if ate else metrics.get("ate_rmse_m"))
    else:
        row["status"] = status if status in ("failed", "crashed", "timeout") else "unevaluated"
        row["error"] = row["error"] or str(res.get("metrics_error") or "no metrics")
    if traj is not None:
        out["trajectory"] = (np.asarray(traj.timestamps), np.asarray(traj.poses))
        seq = open_sequence(path)
        if seq.groundtruth is not None:
            try:
                out["aligned"] = tuple(np.asarray(a) for a in aligned_estimate(seq.groundtruth, traj)[:2])
            except Exception:  # noqa: BLE001 - only the plot misses it
                out["aligned"] = None


def _message(exc: BaseException) -> str:
    """One line: the D2SlamError text (it names the file), else the exception type, text and where it arose."""
    if isinstance(exc, D2SlamError):
        return str(exc)
    tb = traceback.extract_tb(exc.__traceback__)
    where = f" (at {Path(tb[-1].filename).name}:{tb[-1].lineno})" if tb else ""
    return f"{type(exc).__name__}: {exc}{where}".replace("\n", " ")


class _single_threaded:
    """OpenCV on one thread for the duration of a run (BLAS is single-threaded by ``d2slam/__init__`` and the
    executors' worker environments): the numbers do not depend on the executor, and two jobs do not
    oversubscribe the cores."""

    def __enter__(self):
        import cv2

        self._prev = cv2.getNumThreads()
        cv2.setNumThreads(1)
        return self

    def __exit__(self, *exc):
        import cv2

        cv2.setNumThreads(self._prev)
        return False


# ------------------------------------------------------------------------------------------------------------
# Identity of a run's result (for ``d2slam study --resume``)
# ------------------------------------------------------------------------------------------------------------
# Source that decides an engine run's numbers, and an ORB-SLAM3 run's (which never touches the engine or dynamics).
_ENGINE_CODE = ("slam", "dynamics", "segmentation", "data", "eval", "methods.py", "pipeline.py", "config.py",
                "study/runner.py")
_ORBSLAM3_CODE = ("baselines", "data", "eval", "config.py", "study/runner.py")
_ORBSLAM3_MASKED_CODE = _ORBSLAM3_CODE + ("segmentation",)  # ... and the masks it removes
_RUN_PACKAGES = ("numpy", "scipy", "opencv-python-headless", "onnxruntime", "gtsam", "g2opy", "evo", "pyorbslam3")


def code_text(source: str) -> str:
    """What a Python file *does*, without its comments and docstrings: ``ast.dump`` of the parsed module with every
    module, class and function docstring removed (``ast.dump`` leaves out line numbers, so layout does not count
    either). Used for the run keys: a documentation fix keeps the committed study resumable."""
    import ast

    tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                node.body = node.body[1:] or [ast.Pass()]
    return ast.dump(tree)


@lru_cache(maxsize=8)
def source_digest(parts: tuple) -> str:
    """sha256 (16 hex) of the package source files under ``parts`` (folders or files of ``d2slam/``), each read as
    ``code_text`` (comments, docstrings and layout do not count)."""
    import hashlib

    root = Path(__file__).resolve().parent.parent
    h = hashlib.sha256()
    for part in parts:
        p = root / part
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
        for f in files:
            if f.is_file():
                h.update(str(f.relative_to(root)).encode())
                h.update(code_text(f.read_text(encoding="utf-8")).encode())
    return h.hexdigest()[:16]


def run_key(spec: RunSpec, options: dict) -> str:
    """What a run's numbers depend on: the run, the config (seeded), the masks, the generator version, the source
    of the code that computes them and the versions of the numeric packages (and, for ORB-SLAM3, its repeats and
    vocabulary file). Equal keys => a finished run can be reused (``--resume``)."""
    orb = spec.method in REPEATED
    code = {ORBSLAM3: _ORBSLAM3_CODE, ORBSLAM3_MASKED: _ORBSLAM3_MASKED_CODE}.get(spec.method, _ENGINE_CODE)
    ident = {"spec": spec.to_dict(), "config": options["config"], "masks": options["masks"],
             "tum_root": options.get("tum_root"), "code": source_digest(code), "packages": _packages()}
    if spec.source == "synth":
        from d2slam.study.sequences import generator_version

        ident["generator"] = generator_version()
    if orb:
        ident["repeats"] = options.get("orbslam3_repeats")
        ident["vocabulary"] = _vocabulary_sha()
    elif spec.loop_closing and options["config"].get("engine", {}).get("loop_closing", True):
        vocab = options["config"].get("engine", {}).get("vocabulary")
        ident["vocabulary"] = _file_sha(vocab) if vocab else _vocabulary_sha()
    return _digest(ident)


def _file_sha(path: str):
    from d2slam.baselines.vocab import _sha256_file

    try:
        return _sha256_file(Path(path).expanduser())
    except OSError:
        return None


def _digest(ident: dict) -> str:
    """16 hex digits of sha256 over the canonical JSON of ``ident`` (the run key and the features file name)."""
    import hashlib
    import json

    return hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]


@lru_cache(maxsize=1)
def _packages() -> dict:
    from d2slam.study.manifest import package_versions

    return package_versions(_RUN_PACKAGES)


@lru_cache(maxsize=1)
def _vocabulary_sha():
    try:
        from d2slam.baselines.vocab import resolve_vocabulary

        return resolve_vocabulary(None, build=False, progress=False)["sha256"]
    except Exception:  # noqa: BLE001 - no vocabulary yet: the key says so
        return None
