"""``run_study``: the whole grid, end to end.

1. expand the grid (:func:`d2slam.study.grid.expand_grid`) and remove what killed processes left half-written in the
   caches (:func:`remove_stale_temps`);
2. generate or reuse every sequence it needs (the cache of :mod:`d2slam.study.sequences`), on the executor;
3. segment the sequences whose runs read the real segmenter's masks into the mask cache, on the executor;
4. run every cell (:func:`d2slam.study.runner.execute_run`) on the executor (serial, joblib processes or Dask),
   the longest first (:func:`run_cost`; sequences by their frames), so that both cores stay busy to the end;
5. then the online runs (``RunSpec.online``, :func:`d2slam.study.online.execute_online_run`), one at a time in this
   process, whatever the executor: their figures depend on the machine's load, so they run alone, after the others,
   and never on a Dask cluster's workers (the load average at the phase's start goes into the manifest);
6. write ``runs.csv`` (grid order), ``summary.csv``, ``tables.md``, ``plots/*.png``, ``trajectories/<run>.txt``,
   ``runs/<run>.json`` (per-module keypoint metrics and stage timings), an online run's schedule
(``trajectories/<run>.schedule.npz``) and ``manifest.json``.

Each phase (sequences, segmentation, runs, online) says on stderr what it will do before it starts (how many items, how
many are cached, an estimate: :func:`phase_plans`) and is followed there (:mod:`d2slam.progress`: a line every few
seconds when stderr is not a terminal), unless ``progress`` is False.

Same inputs give the same deterministic columns whichever executor ran them (tests/test_study_run.py).
"""

from __future__ import annotations

import json
from collections import Counter
import math
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import pandas as pd

from d2slam.baselines.vocab import resolve_vocabulary
from d2slam.cachefiles import Damaged, load_npz, read_json, report_damaged, sealed, sha256_file, unsealed
from d2slam.config import DEFAULT
from d2slam.data import Trajectory, write_tum_trajectory
from d2slam.digests import digest
from d2slam.errors import D2SlamError
from d2slam.outputs import file_lock, remove_stale_temps as remove, staged_file, write_bytes
from d2slam.paths import cache_dir
from d2slam.progress import PROGRESS, announce
from d2slam.run.online import Schedule
from d2slam.run.warmup import warm_up
from d2slam.study import grid as G, plots as P, sequences, tables as T
from d2slam.study.executors import executor_name, map_ordered, on_dask_workers, process_cpu_s
from d2slam.study.grid import RunSpec, expand_grid
from d2slam.study.keys import (code_info, fingerprint_differences, key_parts, run_ident, why_changed,
                               worker_fingerprint)
from d2slam.study.manifest import build_manifest, git_info
from d2slam.study.online import execute_online_run, load_average, schedule_path
from d2slam.study.runner import (RunOptions, execute_run, failed_row, features_dir, onnx_sequence_keys,
                                 prepare_sequence, run_options, segment_sequence)
from d2slam.study.sequences import composite_dir, is_complete, real_sequence_dir, sequence_dir
from d2slam.synth.generate import estimated_seconds
from d2slam.synth.version import generator_version

RETRY = ("failed", "crashed", "timeout")  # statuses never reused by --resume


@dataclass
class StudyResult:
    out: Path
    runs: pd.DataFrame
    summary: pd.DataFrame
    manifest: dict
    files: dict = field(default_factory=dict)


LOCK = ".d2slam-study.lock"  # in the output folder: one study writes there at a time


def out_lock(out: Path) -> file_lock:
    """The output folder's lock: a second study (or ``--tables-only``) on the folder is refused in one line."""
    return file_lock(Path(out) / LOCK, refuse="another d2slam study is writing into this folder (it holds this "
                                              "lock); wait for it to end, or give another --out")


def run_study(out, *args, **kwargs) -> StudyResult:
    """Run the study grid and write its results into ``out`` (created), holding the folder's lock (:func:`out_lock`):
    see :func:`_run_study` for the arguments."""
    out = Path(out).expanduser()
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise D2SlamError(f"cannot create the output folder ({exc.strerror or exc})", path=out) from None
    with out_lock(out):
        return _run_study(out, *args, **kwargs)


def _run_study(out, scenarios=None, methods=None, seeds=None, frames: int | None = None, jobs: int = 1,
               scheduler=None, config=None, specs: list[RunSpec] | None = None, twin_methods=None,
               cache_root=None, tum_root=None, masks: str | None = None, orbslam3_repeats: int | None = None,
               orbslam3_timeout: float | None = None, plots: bool = True, progress: bool | None = None,
               resume: bool = False, online_methods=None) -> StudyResult:
    """Run the study grid and write its results into ``out`` (created). See the module docstring.

    ``resume``: reuse every run of ``out/runs/`` whose key (:func:`d2slam.study.keys.run_key`: the run, config,
    masks, generator version, the source of the code computing it, package versions; ORB-SLAM3: also its repeats
    and vocabulary) equals this study's, unless it failed; the manifest lists the reused runs. ``online_methods``:
    the methods also run online (default: as ``expand_grid``; ``()``: none), when ``specs`` is not given."""
    checkout, code = git_info(), code_info()  # the code that runs: taken now, not when the study ends
    config = config or DEFAULT
    if specs is None:
        specs = expand_grid(scenarios or G.default_scenarios(), methods, seeds or G.DEFAULT_SEEDS,
                            G.DEFAULT_FRAMES if frames is None else frames,
                            G.TWIN_METHODS if twin_methods is None else twin_methods,
                            source="tum" if tum_root else "synth",
                            online_methods=online_methods)
    if not specs:
        raise D2SlamError("the study grid is empty")
    out = Path(out).expanduser()
    out.mkdir(parents=True, exist_ok=True)
    options = run_options(config, cache_root=cache_root, tum_root=tum_root, masks=masks,
                          orbslam3_repeats=orbslam3_repeats, orbslam3_timeout=orbslam3_timeout)
    workers = None if scheduler is None else check_dask_workers(scheduler, worker_fingerprint(code))
    study = _Phases(out, options, jobs, scheduler, progress, workers)
    prep_error = study.sequences(specs)
    if any(s.method in G.REPEATED or (s.loop_closing and config.engine.loop_closing) for s in specs):
        _prepare_vocabulary(progress is not False)
    if study.executor["executor"] != "serial":
        _prepare_kernels()
    idents = {s.run_id: run_ident(s, options) for s in specs}
    keys_by_id = {i: digest(ident) for i, ident in idents.items()}
    reused, reasons = _reusable(out, specs, keys_by_id, idents) if resume else ({}, {})
    todo = [s for s in specs if s.sequence_key not in prep_error and s.run_id not in reused]
    if resume and progress is not False:
        announce(resume_plan(len(specs), len(reused), [reasons[s.run_id] for s in todo]))
    offline, online = [s for s in todo if not s.online], [s for s in todo if s.online]
    study.segmentation(offline)  # an online run segments its frames itself, in its own thread
    by_id = {**study.runs(offline, keys_by_id, idents, reused), **study.online(online, keys_by_id, idents),
             **reused}
    results = [by_id.get(s.run_id) or {"row": failed_row(s, f"sequence: {prep_error[s.sequence_key]}"),
                                       "trajectory": None, "aligned": None, "keypoints": None, "stage_ms": {}}
               for s in specs]
    for s in specs:
        if s.run_id in by_id:
            by_id[s.run_id]["key"] = keys_by_id[s.run_id]
    manifest = build_manifest(config, _grid(specs, options, masks, reused, [reasons.get(s.run_id) for s in todo]),
                              study.executor, generator_version(),
                              study.timing(), git=checkout, code=code)
    # the finished runs are on disk already (saved as they finished, or read from there by --resume)
    method_order = list(dict.fromkeys(s.method for s in specs))
    res = write_results(out, specs, results, method_order, manifest, plots=plots, saved=set(by_id))
    manifest["timing"]["total_s"] = round(time.perf_counter() - study.t0, 2)
    write_bytes(out / "manifest.json", json.dumps(manifest, indent=2, default=_json_default) + "\n")
    return res


class _Phases:
    """A study's three phases on its executor (``jobs`` processes or a Dask ``scheduler``): the sequences, their
    segmentation, the runs; each announced before it starts (``phase_plans``) and timed. An interrupted phase leaves
    nothing its killed workers were writing."""

    def __init__(self, out: Path, options: RunOptions, jobs: int, scheduler, progress: bool | None,
                 workers: int | None = None):
        self.out, self.options, self.jobs, self.scheduler, self.progress = out, options, jobs, scheduler, progress
        self.executor = {"executor": executor_name(jobs, scheduler), "jobs": int(jobs),
                         "scheduler": scheduler if isinstance(scheduler, str) else (None if scheduler is None
                                                                                   else "in-process")}
        if scheduler is not None:  # a Dask cluster: its workers, not --jobs, set how many calls run at once
            self.executor.update(jobs=None, workers=workers)
        remove_stale_temps(options, out)
        self.t0 = time.perf_counter()
        self.plans = phase_plans(options, int(jobs) if scheduler is None else workers)
        self.seconds = {"sequences_s": 0.0, "segmentation_s": 0.0, "runs_s": 0.0, "online_s": 0.0}  # each phase's own
        self.cpu = {"sequences": [], "segmentation": [], "runs": [], "online": []}  # each call's CPU seconds
        self.online_runs, self.online_load = 0, None  # online runs run, the load average when they started
        self.cpu0 = process_cpu_s(children=False)  # the executor's workers are children too: counted per call

    def _phase(self, fn, items, desc: str, unit: str, on_result=None, cost=None, alone: bool = False) -> list:
        """``fn`` over ``items`` on the study's executor, or (``alone``) one at a time in this process."""
        if self.progress is not False and items:
            announce(*self.plans[desc](items))
        t = time.perf_counter()
        jobs, scheduler = (1, None) if alone else (self.jobs, self.scheduler)
        try:
            return map_ordered(fn, items, (self.options,), jobs, scheduler, desc=desc,
                               progress=self.progress, on_result=on_result, cost=cost, unit=unit,
                               cpu=self.cpu[desc])
        except BaseException:
            remove_stale_temps(self.options, self.out)
            raise
        finally:
            self.seconds[f"{desc}_s"] += time.perf_counter() - t

    def sequences(self, specs) -> dict:
        """Generate (or find) every sequence of ``specs``; the key -> error of those that failed."""
        keys = list(dict.fromkeys(s.sequence_key for s in specs))
        prepared = self._phase(prepare_sequence, keys, "sequences", "sequence", cost=sequence_cost)
        return {p["key"]: p["error"] for p in prepared if p["error"]}

    def segmentation(self, todo) -> None:
        """The real segmenter's masks of the sequences some run of ``todo`` reads them of, into the mask cache."""
        self._phase(segment_sequence, onnx_sequence_keys(todo, self.options), "segmentation", "sequence",
                    cost=sequence_cost)

    def runs(self, todo, keys_by_id: dict, idents: dict, reused: dict) -> dict:
        """Run ``todo``, each saved as it finishes (so that --resume recovers an interrupted study); run id ->
        its result."""
        (self.out / "runs").mkdir(exist_ok=True)

        def checkpoint(i, r):
            rid = todo[i].run_id
            save_run(self.out, todo[i], {**r, "key": keys_by_id[rid], "key_parts": key_parts(idents[rid])})

        if self.progress is not False and reused:
            announce(f"runs: {len(reused)} reused from {self.out / 'runs'} (--resume)")
        done = self._phase(execute_run, todo, "runs", "run", on_result=checkpoint,
                           cost=lambda s: run_cost(s, self.options))
        return {s.run_id: r for s, r in zip(todo, done)}

    def online(self, todo, keys_by_id: dict, idents: dict) -> dict:
        """Run the online runs of ``todo`` after every other run, one at a time in this process, in grid order
        (never beside the executor's workers nor on a Dask cluster's: their figures depend on the machine's load),
        each saved as it finishes; run id -> its result."""
        if not todo:
            return {}
        self.online_runs, self.online_load = len(todo), load_average()

        def checkpoint(i, r):
            rid = todo[i].run_id
            save_run(self.out, todo[i], {**r, "key": keys_by_id[rid], "key_parts": key_parts(idents[rid])})

        done = self._phase(execute_online_run, todo, "online", "run", on_result=checkpoint, alone=True)
        return {s.run_id: r for s, r in zip(todo, done)}

    def timing(self) -> dict:
        """Wall seconds of the sequences, of the segmentation, of the online runs (when there were some: with the
        load average at their start) and of everything else up to now (the runs, with the vocabulary and the kernels
        prepared for them); beside each, the CPU seconds of its calls wherever they ran (``*_cpu_s``: the workers'
        and ORB-SLAM3's processes), and this process's own (``study_process_cpu_s``: scheduling, the vocabulary, the
        kernels, the tables; the serial executor's calls and the online runs too)."""
        s = self.seconds
        rest = time.perf_counter() - self.t0 - s["sequences_s"] - s["segmentation_s"] - s["online_s"]
        cpu = {f"{k}_cpu_s": round(sum(v), 2) for k, v in self.cpu.items()}
        online_cpu = cpu.pop("online_cpu_s")
        online = {"online_s": round(s["online_s"], 2), "online_cpu_s": online_cpu,
                  "online_load_average": self.online_load,
                  "online_where": "this process, one run at a time, after the other runs"} if self.online_runs else {}
        return {"sequences_s": round(s["sequences_s"], 2), "segmentation_s": round(s["segmentation_s"], 2),
                "runs_s": round(rest, 2), **cpu, **online,
                "study_process_cpu_s": round(process_cpu_s(children=False) - self.cpu0, 2)}


def check_dask_workers(scheduler, expected: dict) -> int:
    """The number of workers connected to the Dask ``scheduler``, each checked to compute what this process keys the
    runs by: its :func:`d2slam.study.keys.worker_fingerprint` (the methods' source, the numeric packages, the sequence
    generator) must be ``expected`` (this process's). A cluster with no worker, a worker that cannot import d2slam
    and a worker with other code or packages are refused in one line: its runs would carry this checkout's key and
    another's numbers. Workers that join later are not checked."""
    found = on_dask_workers(scheduler, worker_fingerprint)
    if not found:
        raise D2SlamError(f"the Dask scheduler at {scheduler} has no worker: start them first (`dask worker "
                          f"{scheduler if isinstance(scheduler, str) else 'tcp://HOST:PORT'} --nthreads 1`)")
    bad = []
    for name, got in sorted(found.items()):
        if isinstance(got, BaseException):
            bad.append(f"{name} cannot run d2slam ({type(got).__name__}: {got})")
        elif fingerprint_differences(expected, got):
            bad.append(f"{name} differs in {'; '.join(fingerprint_differences(expected, got))}")
    if bad:
        raise D2SlamError(f"{len(bad)} of the {len(found)} Dask workers would not compute what this checkout keys "
                          f"its runs by: {'; '.join(bad)}. Every worker needs this d2slam checkout and environment "
                          "(environment.txt), and a restart after either changes")
    return len(found)


def _reusable(out: Path, specs, keys_by_id: dict, idents: dict) -> tuple[dict, dict]:
    """The runs of ``out/runs`` --resume reuses (run id -> result: those whose key is this study's and that did not
    fail), and why each other run is run again (run id -> :func:`d2slam.study.keys.why_changed`)."""
    reused, reasons = {}, {}
    for s in specs:
        r = load_run(out, s, keys_by_id[s.run_id])
        if r is not None:
            reused[s.run_id] = r
            continue
        record = _saved_record(out, s)
        if record is None:
            reasons[s.run_id] = "no earlier result"
        elif record.get("key") == keys_by_id[s.run_id]:
            reasons[s.run_id] = f"it ended {(record.get('row') or {}).get('status')}"
        else:
            reasons[s.run_id] = why_changed(record.get("key_parts"), idents[s.run_id])
    return reused, reasons


def _saved_record(out: Path, spec: RunSpec) -> dict | None:
    """A saved run's record as it is on disk (None: none or unreadable; :func:`load_run` says when it is damaged)."""
    try:
        return read_json(out / "runs" / f"{spec.run_id}.json")
    except (OSError, ValueError, Damaged):
        return None


def resume_plan(total: int, reused: int, reasons: list[str]) -> str:
    """What ``--resume`` will do, said before it starts: how many runs it reuses and runs, and why those run."""
    counts = Counter(reasons)
    why = "; ".join(f"{n} {r}" for r, n in counts.most_common())
    return f"resume: {total} runs, {reused} reused, {len(reasons)} to run" + (f" ({why})" if why else "")


def _grid(specs, options: RunOptions, masks: str | None, reused: dict, reasons: list | None = None) -> dict:
    """The manifest's ``grid``: what the study ran."""
    return {"scenarios": list(dict.fromkeys(s.scenario for s in specs)),
            "methods": list(dict.fromkeys(s.method for s in specs)),
            "seeds": sorted({s.seed for s in specs}), "frames": sorted({s.frames for s in specs}),
            "twin_methods": list(dict.fromkeys(s.method for s in specs if s.twin)),
            "source": specs[0].source, "runs": len(specs), "orbslam3_repeats": options.orbslam3_repeats,
            "masks": masks, "reused_runs": sorted(reused),
            **({"online_runs": sum(s.online for s in specs), "online_rate_hz": options.config.online.rate_hz}
               if any(s.online for s in specs) else {}),
            **({"rerun_reasons": dict(Counter(r for r in reasons if r))} if reused or any(reasons or []) else {})}


def run_cost(spec: RunSpec, options: RunOptions) -> float:
    """Estimated cost of a run (ms): its frames x the method's ``StudyConfig.run_cost_ms`` (the real ORB-SLAM3's
    runs: x its repeats). Only the order of the runs depends on it (longest first)."""
    study = options.config.study
    ms = float(dict(study.run_cost_ms).get(spec.method, study.run_cost_default_ms))
    repeats = int(options.orbslam3_repeats or 1) if spec.method in G.REPEATED else 1
    frames = int(spec.frames) or (COMPOSITE_FRAMES if spec.source == "composite" else 1)  # 0: all of the recording
    return max(frames, 1) * ms * repeats


def phase_plans(options: RunOptions, workers: int | None) -> dict:
    """For each phase of the study (``sequences``, ``segmentation``, ``runs``), a function of its items giving what
    to announce before it starts: (what it will do, estimated seconds on ``workers`` processes, or None when the
    number of workers is not known). Estimates: ``ProgressConfig.synth_setup_s`` + frames x
    ``synth_frame_s`` per sequence to generate, frames x ``segment_frame_s`` to segment (an upper bound: masks
    already in the cache are read), :func:`run_cost` per run."""
    on = "" if workers is None else f" on {workers} worker{'s' if workers > 1 else ''}"

    def spread(seconds: list[float]) -> float | None:  # the longest item bounds it from below
        return None if workers is None or not seconds else max(sum(seconds) / max(workers, 1), max(seconds))

    def composite_frames(k) -> int:  # a composite's frames: the recording's when 0
        return int(k[3]) or COMPOSITE_FRAMES

    def sequences(keys):
        synth = [k for k in keys if k[0] == "synth"]
        todo = [k for k in synth if not is_complete(sequence_dir(*k[1:], root=options.cache_root))]
        comp = [k for k in keys if k[0] == "composite" and not k[4]]
        ctodo = [k for k in comp if not composite_cached(k, options.cache_root)]
        made = len(synth) + len(comp)
        what = (f"sequences: {len(todo) + len(ctodo)} to generate{on} "
                f"({sum(int(k[3]) for k in todo) + sum(composite_frames(k) for k in ctodo)} frames), "
                f"{made - len(todo) - len(ctodo)} cached" + (f", {len(keys) - made} real (TUM)" if made < len(keys)
                                                             else ""))
        return what, spread([estimated_seconds(int(k[3]), 1) for k in todo]
                            + [estimated_seconds(composite_frames(k), 1, scenario=k[1]) for k in ctodo])

    def segmentation(keys):
        frames = [int(k[3]) for k in keys]
        known = all(f > 0 for f in frames)  # a real sequence's frames may be "all" (0)
        return (f"segmentation: {len(keys)} sequence{'s' if len(keys) > 1 else ''} with the real segmenter{on}"
                + (f" ({sum(frames)} frames; masks already in the cache are read)" if known else ""),
                spread([f * PROGRESS.segment_frame_s for f in frames]) if known else None)

    def runs(specs):
        known = all(int(s.frames) > 0 for s in specs)
        return f"runs: {len(specs)}{on}", spread([run_cost(s, options) / 1e3 for s in specs]) if known else None

    def online(specs):
        load = load_average()
        return (f"online: {len(specs)} run{'s' if len(specs) > 1 else ''} one at a time in this process, after the "
                "others (their figures depend on the machine's load: never beside the workers, never on a Dask "
                "cluster's)" + (f"; load average now {', '.join(f'{x:.2f}' for x in load)}" if load else ""),
                sum(online_seconds(s, options) for s in specs))

    return {"sequences": sequences, "segmentation": segmentation, "runs": runs, "online": online}


def online_seconds(spec: RunSpec, options: RunOptions) -> float:
    """Estimated wall seconds of an online run: its frames arriving at ``OnlineConfig.rate_hz`` (0: at the
    synthetic camera's ``SynthConfig.fps``, as the frames' timestamps), the real ORB-SLAM3's once per repeat. A
    recording's frames (0: all) are counted as a composite's."""
    rate = float(options.config.online.rate_hz) or float(options.config.synth.fps)
    frames = int(spec.frames) or COMPOSITE_FRAMES
    return frames / rate * (int(options.orbslam3_repeats or 1) if spec.method in G.REPEATED else 1)


# The frames of a composite over the whole recording, for the phase's estimate (fr1/rpy: 694 associated frames).
COMPOSITE_FRAMES = 694


def composite_cached(key: tuple, cache_root=None) -> bool:
    """Whether the composite of ``key`` (``RunSpec.sequence_key``) is in the cache (of ``cache_root``, default the
    user's) (False when its recording is not: the run says why)."""
    try:
        rec = real_sequence_dir(G.COMPOSITE_RECORDING)
    except D2SlamError:
        return False
    return is_complete(composite_dir(key[1], key[2], key[3], rec, root=cache_root))


def sequence_cost(key: tuple) -> float:
    """Estimated cost of generating or segmenting a sequence (``RunSpec.sequence_key``): its frames (a composite's
    over its whole recording: its frames, each as costly as ``synth_composite_frame_s`` over ``synth_frame_s``)."""
    if key[0] == "composite":
        return float(int(key[3]) or COMPOSITE_FRAMES) * (1.0 if key[4] else PROGRESS.synth_composite_frame_s /
                                                          PROGRESS.synth_frame_s)
    return float(max(int(key[3]), 1))


def remove_stale_temps(options: RunOptions, out: Path | None = None) -> list[Path]:
    """Remove what killed processes left half-written in the caches a study writes (sequence folders, feature files,
    mask files: ``*.tmp-<pid>...``, :func:`d2slam.outputs.remove_stale_temps`) and in ``out/runs``; the temporaries
    of running processes (another study sharing the cache) stay."""
    outs = [] if out is None else [p for d in ("", "runs", "trajectories", "plots") for p in remove(Path(out) / d)]
    return (sequences.remove_stale_temps(options.cache_root) + remove(features_dir(options))
            + remove(cache_dir("masks"), "*/*/*.tmp-*") + outs)


def load_run(out: Path, spec: RunSpec, key: str) -> dict | None:
    """The result of a finished run in ``out/runs/`` when its key is ``key`` and it did not fail, else None. A
    record or array file that does not match its seal (:func:`d2slam.cachefiles.unsealed`) is damaged: said in one
    line, and the run is done again."""
    path = out / "runs" / f"{spec.run_id}.json"
    try:
        record = unsealed(read_json(path))
    except FileNotFoundError:
        return None
    except Damaged as exc:
        report_damaged(path, "study run record", exc, "running it again")
        return None
    row = record.get("row") or {}
    if record.get("key") != key or row.get("status") in RETRY:
        return None
    res = {"row": row, "trajectory": None, "aligned": None, "keypoints": record.get("keypoints"),
           "stage_ms": record.get("stage_ms") or {}, "loops": record.get("loops")}
    npz = out / "runs" / f"{spec.run_id}.npz"
    if npz.is_file() or record.get("arrays_sha256"):
        try:
            if record.get("arrays_sha256") not in (None, sha256_file(npz) if npz.is_file() else "missing"):
                raise Damaged("its sha256 is not the one its record holds")
            z = load_npz(npz)
        except (Damaged, OSError) as exc:
            report_damaged(npz, "study run arrays", exc, "running it again")
            return None
        if "timestamps" in z:
            res["trajectory"] = (z["timestamps"], z["poses"])
        if "gt_xyz" in z:
            res["aligned"] = (z["gt_xyz"], z["est_xyz"])
    if record.get("schedule_sha256") and not _schedule_intact(out, spec, record["schedule_sha256"]):
        return None
    return res


def _schedule_intact(out: Path, spec: RunSpec, sha: str) -> bool:
    """Whether an online run's schedule is there as its record holds it and reads as one; said in one line when
    not (the run is done again)."""
    path = schedule_path(out, spec)
    try:
        if not path.is_file() or sha256_file(path) != sha:
            raise Damaged("missing, or its sha256 is not the one its record holds")
        Schedule.load(path)
    except (Damaged, D2SlamError, OSError) as exc:
        report_damaged(path, "online run's schedule", exc, "running it again")
        return False
    return True


def _prepare_vocabulary(progress) -> None:
    """Build the ORB vocabulary once, here, before ORB-SLAM3 runs and the engine's loop closing start in parallel
    workers (each would otherwise build it on first use). A failure is left to the runs, which record it."""
    try:
        resolve_vocabulary(None, build=True, progress=bool(progress))
    except D2SlamError:
        pass


def _prepare_kernels() -> None:
    """Compile the engine's kernels here (or load them from numba's cache) before the workers start, so that they
    load them instead of each compiling the same ones at once (``d2slam.run.warmup``)."""
    warm_up()


def write_results(out: Path, specs: list[RunSpec], results: list[dict], method_order: list[str], manifest: dict,
                  plots: bool = True, saved: set[str] = frozenset()) -> StudyResult:
    """Write the study's files; runs whose id is in ``saved`` are already in ``out/runs`` and not written again."""
    files = {}
    for s, r in zip(specs, results):
        if s.run_id not in saved:
            save_run(out, s, r)
        else:  # its record is there; its trajectory file is written again (whatever became of it)
            write_trajectory(out, s, r)
    df = T.sort_runs(T.runs_frame([r["row"] for r in results]), method_order)
    T.write_runs_csv(df, out / "runs.csv")
    summary = T.summarise(df)
    T.write_summary_csv(summary, out / "summary.csv")
    write_bytes(out / "tables.md", T.tables_markdown(df, method_order, manifest))
    write_bytes(out / "manifest.json", json.dumps(manifest, indent=2, default=_json_default) + "\n")
    files.update(runs=out / "runs.csv", summary=out / "summary.csv", tables=out / "tables.md",
                 manifest=out / "manifest.json")
    if plots:
        files.update(make_plots(out, specs, results, df, summary, method_order))
    return StudyResult(out, df, summary, manifest, files)


def save_run(out: Path, s: RunSpec, r: dict) -> None:
    """Write one run: ``runs/<run>.json`` (run, key, row, keypoint metrics, stage timings), ``runs/<run>.npz``
    (trajectory and aligned positions) and ``trajectories/<run>.txt`` (TUM format)."""
    (out / "runs").mkdir(parents=True, exist_ok=True)
    write_trajectory(out, s, r)
    arrays = {}
    if r.get("trajectory") is not None:
        arrays.update(timestamps=r["trajectory"][0], poses=r["trajectory"][1])
    if r.get("aligned") is not None:
        arrays.update(gt_xyz=r["aligned"][0], est_xyz=r["aligned"][1])
    npz = out / "runs" / f"{s.run_id}.npz"
    if arrays:
        with staged_file(npz, ".npz") as tmp:
            np.savez_compressed(tmp, **arrays)
    else:
        npz.unlink(missing_ok=True)
    schedule = schedule_path(out, s)
    if r.get("schedule") is not None:  # an online run's: replayed by d2slam run --deterministic
        r["schedule"].save(schedule)
    elif s.online:
        schedule.unlink(missing_ok=True)
    # the record last, whole or not at all: --resume reuses a run only when its record is there; sealed with the
    # sha256 of its content, of the arrays and of an online run's schedule, so that a damaged one is not reused
    record = {"run": s.to_dict(), "key": r.get("key"), "key_parts": r.get("key_parts"), "row": r["row"],
              "keypoints": r.get("keypoints"),
              "stage_ms": r.get("stage_ms"), "loops": r.get("loops"),
              "arrays_sha256": sha256_file(npz) if arrays else None,
              **({"schedule_sha256": sha256_file(schedule) if r.get("schedule") is not None else None}
                 if s.online else {})}
    record = sealed(json.loads(json.dumps(record, default=_json_default)))  # sealed as it will be read back
    write_bytes(out / "runs" / f"{s.run_id}.json", json.dumps(record, indent=1) + "\n")


def write_trajectory(out: Path, s: RunSpec, r: dict) -> None:
    """``trajectories/<run>.txt`` (TUM format) of a run that has one."""
    if r.get("trajectory") is not None and len(r["trajectory"][0]):
        (out / "trajectories").mkdir(parents=True, exist_ok=True)
        ts, poses = r["trajectory"]
        write_tum_trajectory(out / "trajectories" / f"{s.run_id}.txt", Trajectory(ts, poses),
                             header=f"d2slam study {s.run_id}")


def module_f1(specs: list[RunSpec], results: list[dict]) -> pd.DataFrame:
    """Median F1 over the dynamic-sequence runs, per (method, classifier module)."""
    vals: dict = {}
    for s, r in zip(specs, results):
        kp = r.get("keypoints")
        if s.twin or not kp:
            continue
        for mod, m in kp.get("modules", {}).items():
            f1 = m.get("f1")
            if f1 is not None and math.isfinite(f1):
                vals.setdefault((s.method, mod), []).append(f1)
    rows = [{"method": m, "module": mod, "f1": float(np.median(v)), "runs": len(v)} for (m, mod), v in vals.items()]
    return pd.DataFrame(rows, columns=["method", "module", "f1", "runs"])


def make_plots(out: Path, specs, results, df, summary, method_order) -> dict:
    pdir = out / "plots"
    pdir.mkdir(exist_ok=True)
    files = {}
    # the offline runs: an online run's figures are the online table's
    keep = [i for i, s in enumerate(specs) if not s.online]
    specs, results = [specs[i] for i in keep], [results[i] for i in keep]
    df = T.offline_runs(df)
    summary = summary[summary["online"] == 0] if "online" in summary else summary
    if not specs:
        return files
    seed = min(s.seed for s in specs)
    aligned = {(s.scenario, s.twin, s.method + ("" if s.loop_closing else " (no loop closing)")): r["aligned"]
               for s, r in zip(specs, results) if s.seed == seed and r.get("aligned") is not None}
    for name, path in (("trajectories", P.plot_trajectories(aligned, pdir / "trajectories.png", seed)),
                       ("ate_bars", P.plot_ate_bars(summary, pdir / "ate_bars.png", method_order)),
                       ("keypoint_f1", P.plot_keypoint_f1(module_f1(specs, results), pdir / "keypoint_f1.png")),
                       ("runtime", P.plot_runtime(df, pdir / "runtime.png", method_order))):
        if path is not None:
            files[name] = path
    return files


def rebuild_tables(out) -> Path:
    """Re-render ``tables.md`` and ``summary.csv`` of a finished study from its ``runs.csv`` (and manifest)."""
    out = Path(out)
    with out_lock(out):
        return _rebuild_tables(out)


def _rebuild_tables(out: Path) -> Path:
    df = T.read_runs_csv(out / "runs.csv", online=True)
    manifest = json.loads((out / "manifest.json").read_text()) if (out / "manifest.json").is_file() else None
    methods = (manifest or {}).get("grid", {}).get("methods") or list(dict.fromkeys(df["method"]))
    T.write_summary_csv(T.summarise(df), out / "summary.csv")
    write_bytes(out / "tables.md", T.tables_markdown(df, methods, manifest))
    return out / "tables.md"


def _json_default(o):
    if isinstance(o, np.integer):
        return int(o)
    if isinstance(o, np.floating):
        return None if not np.isfinite(o) else float(o)
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, Path):
        return str(o)
    if isinstance(o, tuple):
        return list(o)
    raise TypeError(type(o).__name__)
