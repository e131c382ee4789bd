"""Study end to end on a tiny grid (sitting_static, 40 frames, seed 101, methods none + d2slam, no twins): the
same deterministic numbers from the serial, joblib (2 processes) and Dask (LocalCluster on loopback) executors;
failed runs (unknown method, corrupt sequence) recorded with their error; output files, manifest and CLI."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest

from d2slam.study import run_study
from d2slam.study import tables as T
from d2slam.study.grid import RunSpec
from d2slam.study.sequences import ensure_sequence

FRAMES = 40
GRID = dict(scenarios=["sitting_static"], methods=["none", "d2slam"], seeds=[101], frames=FRAMES, twin_methods=())
# deterministic columns compared between executors: everything but the timing columns
COMPARE = [c for c in T.RUN_COLUMNS if c not in T.TIMING_COLUMNS]


@pytest.fixture(scope="module")
def serial(tmp_path_factory):
    # the sequence lives in the study cache (generated once per generator version, reused by later test runs)
    ensure_sequence("sitting_static", 101, FRAMES, False)
    return run_study(tmp_path_factory.mktemp("serial"), jobs=1, progress=False, **GRID)


def _same(a: pd.DataFrame, b: pd.DataFrame) -> None:
    pd.testing.assert_frame_equal(a[COMPARE].reset_index(drop=True), b[COMPARE].reset_index(drop=True),
                                  check_exact=True)


def test_serial_outputs(serial):
    df = serial.runs
    assert df["method"].tolist() == ["none", "d2slam"]
    assert (df["frames"] == FRAMES).all() and (df["seed"] == 101).all()
    # none runs through the engine and is evaluated; every row has a status and either metrics or an error
    assert df.loc[0, "status"] == "ok" and np.isfinite(df.loc[0, "ate_rmse_m"]) and df.loc[0, "frames_tracked"] > 0
    for _, r in df.iterrows():
        assert r["status"] in ("ok", "partial", "unevaluated") and (r["status"] == "ok") == (r["error"] == "")
    assert np.isfinite(df.loc[1, "kp_f1"])  # d2slam classifies keypoints against the synthetic truth
    assert np.isfinite(df["fps"]).all()
    out = serial.out
    for name in ("runs.csv", "summary.csv", "tables.md", "manifest.json", "plots/runtime.png",
                 "plots/keypoint_f1.png", "runs/sitting_static_s101_n40_d2slam.json"):
        assert (out / name).is_file(), name
    assert (out / "trajectories" / "sitting_static_s101_n40_none.txt").is_file()
    assert (out / "plots" / "trajectories.png").is_file() and (out / "plots" / "ate_bars.png").is_file()
    _same(T.read_runs_csv(out / "runs.csv"), df)
    m = json.loads((out / "manifest.json").read_text())
    assert m["grid"]["seeds"] == [101] and m["grid"]["frames"] == [FRAMES]
    assert m["grid"]["methods"] == ["none", "d2slam"] and m["executor"]["executor"] == "serial"
    assert len(m["git"]["commit"]) == 40 and m["machine"]["cores"] >= 1 and m["packages"]["evo"]
    kp = json.loads((out / "runs" / "sitting_static_s101_n40_d2slam.json").read_text())["keypoints"]
    assert "final" in kp["modules"] and kp["frames"] == FRAMES
    md = (out / "tables.md").read_text()
    assert "## Table 1: ATE (m), improvement over `none`" in md and "| s/static |" in md


def test_joblib_and_dask_reproduce_serial(serial, tmp_path):
    par = run_study(tmp_path / "joblib", jobs=2, progress=False, plots=False, **GRID)
    _same(par.runs, serial.runs)
    assert par.manifest["executor"]["executor"] == "joblib"

    from distributed import LocalCluster

    # a real TCP scheduler on loopback (workers in this process), reached by address like a remote cluster
    with LocalCluster(n_workers=1, threads_per_worker=2, processes=False, protocol="tcp://", host="127.0.0.1",
                      dashboard_address=":0") as cluster:
        assert cluster.scheduler_address.startswith("tcp://127.0.0.1:")
        dk = run_study(tmp_path / "dask", scheduler=cluster.scheduler_address, progress=False, plots=False, **GRID)
    _same(dk.runs, serial.runs)
    assert dk.manifest["executor"]["executor"] == "dask" and dk.manifest["executor"]["workers"] == 1
    assert _tables(tmp_path / "dask") == _tables(serial.out)


def _tables(out) -> list[str]:
    """tables.md without its provenance line (the git commit moves while others commit)."""
    return [ln for ln in (out / "tables.md").read_text().splitlines() if not ln.startswith("Config hash")]


def _fails_here():
    raise ModuleNotFoundError("No module named 'd2slam'")


def test_dask_workers_are_checked_before_the_study(tmp_path):
    from distributed import LocalCluster

    from d2slam.errors import D2SlamError
    from d2slam.study.core import check_dask_workers
    from d2slam.study.executors import on_dask_workers
    from d2slam.study.keys import worker_fingerprint

    here = worker_fingerprint()
    kw = dict(threads_per_worker=1, processes=False, protocol="tcp://", host="127.0.0.1", dashboard_address=":0")
    with LocalCluster(n_workers=0, **kw) as empty:  # nothing to run on: said at once, not a study waiting forever
        with pytest.raises(D2SlamError, match="has no worker: start them first"):
            check_dask_workers(empty.scheduler_address, here)
    with LocalCluster(n_workers=1, **kw) as cluster:
        address = cluster.scheduler_address
        assert check_dask_workers(address, here) == 1
        # a worker on another checkout (other code, another numpy) would give other numbers under this one's keys
        other = {**here, "code": {**here["code"], "none": "0" * 16},
                 "packages": {**here["packages"], "numpy": "1.0"}}
        with pytest.raises(D2SlamError, match=r"1 of the 1 Dask workers .* differs in the code of none; "
                                              r"numpy .* \(here 1.0\)") as err:
            check_dask_workers(address, other)
        assert "environment.txt" in str(err.value)
        # what a worker raises (one without d2slam cannot unpickle the probe) is its answer, not the caller's error
        got = on_dask_workers(address, _fails_here)
        assert [type(v) for v in got.values()] == [ModuleNotFoundError]


def test_failed_runs_are_recorded(tmp_path):
    # a corrupt sequence of the user's (a TUM copy whose rgb.txt is garbage: not the cache's, which would be made
    # again) and an unknown method
    src = ensure_sequence("sitting_static", 101, FRAMES, False)
    tum = tmp_path / "tum"
    from d2slam.study.grid import TUM_FOLDERS

    bad = tum / TUM_FOLDERS["sitting_static"]
    shutil.copytree(src, bad)
    (bad / "scene.json").unlink()  # a TUM folder
    (bad / "rgb.txt").write_text("# header\n1.0 rgb/missing.png\nnot-a-number rgb/x.png\n")
    res = run_study(tmp_path / "out", scenarios=["sitting_static"], methods=["none", "no-such-method"], seeds=[101],
                    frames=FRAMES, twin_methods=(), tum_root=tum, progress=False, plots=False)
    df = res.runs
    assert len(df) == 2 and (df["status"] == "failed").all()
    assert "rgb.txt" in df.loc[0, "error"]  # the error names the corrupt file
    assert "unknown method 'no-such-method'" in df.loc[1, "error"]
    md = (tmp_path / "out" / "tables.md").read_text()
    assert "no-such-method" in md and "## Runs without metrics" in md


def test_cli_dry_run_tables_only_and_bad_args(serial, tmp_path, capsys):
    from d2slam.cli import main

    assert main(["study", "--out", str(tmp_path), "--scenarios", "sitting_static", "--methods", "none",
                 "--seeds", "101", "--frames", "40", "--dry-run"]) == 0
    out = capsys.readouterr().out
    assert "2 runs on 2 sequences" in out and "sitting_static_twin_s101_n40_none" in out  # none on the twin too
    assert main(["study", "--out", str(tmp_path), "--methods", "bogus", "--frames", "40"]) == 2
    assert "unknown method" in capsys.readouterr().err
    assert main(["study", "--out", str(tmp_path), "--frames", "10"]) == 2
    assert main(["study", "--out", str(tmp_path), "--tables-only"]) == 2  # no runs.csv there
    shutil.copy(serial.out / "runs.csv", tmp_path / "runs.csv")
    shutil.copy(serial.out / "manifest.json", tmp_path / "manifest.json")
    assert main(["study", "--out", str(tmp_path), "--tables-only"]) == 0
    assert (tmp_path / "tables.md").read_text() == (serial.out / "tables.md").read_text()  # same manifest


def test_oracle_on_a_twin_is_the_occluded_twin():
    """The oracle is a default twin method, and on a twin it reads the dynamic sibling's truth: the keypoints inside
    the people's silhouettes are flagged (false positives against the twin's own truth, where nothing moves)."""
    from d2slam.study.grid import TWIN_METHODS, expand_grid
    from d2slam.study.runner import execute_run, run_options

    assert TWIN_METHODS == ("none", "d2slam", "oracle")
    twins = [s.method for s in expand_grid(["sitting_static"], ["none", "oracle", "semantic"], [101], FRAMES) if s.twin]
    assert twins == ["none", "oracle"]
    ensure_sequence("sitting_static", 101, FRAMES, False)
    ensure_sequence("sitting_static", 101, FRAMES, True)
    out = execute_run(RunSpec("sitting_static", "oracle", 101, FRAMES, True), run_options())
    assert out["row"]["status"] == "ok", out["row"]["error"]
    final = out["keypoints"]["modules"]["final"]
    assert final["fp"] > 0 and final["tp"] == 0 and out["row"]["frames_tracked"] == FRAMES


def test_runspec_roundtrip():
    s = RunSpec("walking_rpy", "d2slam", 102, 300, True)
    assert RunSpec(**s.to_dict()) == s and s.run_id == "walking_rpy_twin_s102_n300_d2slam"


def test_resume_reuses_matching_runs_only(serial, tmp_path, monkeypatch):
    import d2slam.study.core as core
    import d2slam.study.manifest as manifest
    from d2slam.study.core import load_run
    from d2slam.study.keys import code_info, run_key
    from d2slam.study.runner import run_options

    out = tmp_path / "resumed"
    shutil.copytree(serial.out, out)
    # a commit made while the study runs: the checkout reads "b" once the runs have started (here: reused)
    started = []
    real_load = core.load_run
    monkeypatch.setattr(core, "load_run", lambda *a: started.append(1) or real_load(*a))
    monkeypatch.setattr(core, "git_info",
                        lambda: {"commit": ("b" if started else "a") * 40, "dirty": bool(started)})
    res = run_study(out, progress=False, plots=False, resume=True, **GRID)
    assert started
    assert res.manifest["grid"]["reused_runs"] == ["sitting_static_s101_n40_d2slam", "sitting_static_s101_n40_none"]
    # the manifest records the checkout and the run keys' code digests as they were when the study started
    m = json.loads((out / "manifest.json").read_text())
    assert m["git"] == {"commit": "a" * 40, "dirty": False}
    assert m["code"] == code_info() and m["code"]["none"] != m["code"]["d2slam"] != m["code"]["orbslam3"]
    pd.testing.assert_frame_equal(res.runs, serial.runs, check_exact=True)  # timings too: nothing re-ran
    spec = RunSpec("sitting_static", "none", 101, FRAMES)
    key = run_key(spec, run_options())
    assert load_run(out, spec, key)["trajectory"][1].shape[1:] == (4, 4)
    assert load_run(out, spec, "another-key") is None  # a changed config / code / generator is rerun
    rec = json.loads((out / "runs" / f"{spec.run_id}.json").read_text())
    rec["row"]["status"] = "failed"
    (out / "runs" / f"{spec.run_id}.json").write_text(json.dumps(rec))
    assert load_run(out, spec, key) is None  # failed runs are redone


def test_interrupted_study_keeps_finished_runs_for_resume(serial, tmp_path, monkeypatch):
    """Each run is saved as it finishes: a study killed after its first run leaves that run in runs/, and --resume
    reuses it and computes only the rest (same numbers as an uninterrupted study)."""
    import d2slam.study.core as core

    real = core.execute_run
    calls = []

    def dies_on_second(spec, options):
        calls.append(spec.run_id)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(spec, options)

    monkeypatch.setattr(core, "execute_run", dies_on_second)
    out = tmp_path / "interrupted"
    with pytest.raises(KeyboardInterrupt):
        run_study(out, jobs=1, progress=False, plots=False, **GRID)
    assert not (out / "runs.csv").exists()
    saved = sorted(p.stem for p in (out / "runs").glob("*.json"))
    assert saved == [calls[0]]
    monkeypatch.setattr(core, "execute_run", real)
    res = run_study(out, jobs=1, progress=False, plots=False, resume=True, **GRID)
    assert res.manifest["grid"]["reused_runs"] == [calls[0]]
    _same(res.runs, serial.runs)


def test_study_phases_say_what_they_do_on_stderr_without_a_terminal(serial, tmp_path, capsys, monkeypatch):
    """Without a terminal (CI, nohup, a pipe: pytest's captured stderr here) each phase says what it will do, with
    an estimate, and then logs its progress and its end on stderr; stdout stays for the results."""
    import dataclasses

    import d2slam.progress

    monkeypatch.setattr(d2slam.progress, "PROGRESS", dataclasses.replace(d2slam.progress.PROGRESS, progress_log_s=0.0))
    capsys.readouterr()
    run_study(tmp_path / "out", jobs=1, plots=False, **GRID)
    cap = capsys.readouterr()
    err = cap.err.splitlines()

    def at(prefix: str) -> int:
        found = [k for k, line in enumerate(err) if line.startswith(prefix)]
        assert found, (prefix, err)
        return found[0]

    order = [at("d2slam: sequences: 0 to generate on 1 worker (0 frames), 1 cached"),
             at("d2slam: sequences: 1/1 sequences in "),
             at("d2slam: segmentation: 1 sequence with the real segmenter on 1 worker (40 frames; masks already "
                "in the cache are read) (about "),
             at("d2slam: segmentation: 1/1 sequences in "),
             at("d2slam: runs: 2 on 1 worker (about "),
             at("d2slam: runs: 1/2 runs, "),
             at("d2slam: runs: 2/2 runs in ")]
    assert order == sorted(order)
    assert "d2slam:" not in cap.out


def test_phase_plans_count_what_is_to_do_and_estimate_it(tmp_path):
    from d2slam.progress import PROGRESS
    from d2slam.study.core import phase_plans, run_cost
    from d2slam.study.runner import run_options
    from d2slam.synth.generate import estimated_seconds

    options = run_options(cache_root=tmp_path)  # an empty sequence cache
    keys = [("synth", "walking_xyz", 101, 300, False), ("synth", "walking_xyz", 102, 300, False),
            ("tum", "walking_xyz", 0, 0, False)]
    what, seconds = phase_plans(options, 2)["sequences"](keys)
    assert what == "sequences: 2 to generate on 2 workers (600 frames), 0 cached, 1 real (TUM)"
    assert seconds == pytest.approx(estimated_seconds(300, 1))  # one each on the two workers
    what, seconds = phase_plans(options, 2)["segmentation"](keys[:2])
    assert "2 sequences" in what and "600 frames" in what and seconds == pytest.approx(300 * PROGRESS.segment_frame_s)
    assert phase_plans(options, 2)["segmentation"](keys)[1] is None  # all frames of a real sequence: unknown
    specs = [RunSpec("walking_xyz", m, 101, 300) for m in ("none", "d2slam", "none")]
    what, seconds = phase_plans(options, 2)["runs"](specs)
    assert what == "runs: 3 on 2 workers"
    assert seconds == pytest.approx(sum(run_cost(s, options) for s in specs) / 2e3)
    assert phase_plans(options, None)["runs"](specs) == ("runs: 3", None)  # workers unknown: no estimate


def test_map_ordered_reports_each_result(tmp_path):
    from d2slam.study.executors import map_ordered

    for jobs in (1, 2):
        seen = []
        out = map_ordered(abs, [-3, 1, -2], jobs=jobs, progress=False, on_result=lambda i, r: seen.append((i, r)))
        assert out == [3, 1, 2] and sorted(seen) == [(0, 3), (1, 1), (2, 2)]


def test_items_start_longest_first_and_results_keep_their_order():
    from d2slam.study.executors import dispatch_order, map_ordered

    assert dispatch_order([2.0, 5.0, 2.0, 9.0, 5.0]) == [3, 1, 4, 0, 2]  # ties keep their input order
    started = []

    def record(x):
        started.append(x)
        return -x

    out = map_ordered(record, [1, 4, 2, 8], progress=False, cost=float)
    assert started == [8, 4, 2, 1] and out == [-1, -4, -2, -8]
    assert map_ordered(abs, [-1, 4, -2, 8], jobs=2, progress=False, cost=abs) == [1, 4, 2, 8]


def test_the_study_orders_its_runs_by_estimated_cost():
    """ORB-SLAM3 (three repeats) first, then the costlier engine methods; more frames cost more."""
    from d2slam.study.core import run_cost, sequence_cost
    from d2slam.study.executors import dispatch_order
    from d2slam.study.grid import expand_grid
    from d2slam.study.runner import run_options

    specs = expand_grid(["walking_xyz"], ["none", "d2slam", "semantic", "d2slam-flow", "orbslam3"], [101], 300,
                        twin_methods=("none",), online_methods=())  # online runs: a phase of their own
    specs.append(RunSpec("walking_rpy", "none", 101, 900))
    options = run_options()
    order = [specs[i].run_id for i in dispatch_order([run_cost(s, options) for s in specs])]
    assert order == ["walking_xyz_s101_n300_orbslam3", "walking_rpy_s101_n900_none", "walking_xyz_s101_n300_d2slam-flow",
                     "walking_xyz_s101_n300_semantic", "walking_xyz_s101_n300_d2slam", "walking_xyz_s101_n300_none",
                     "walking_xyz_twin_s101_n300_none"]
    one = run_options(orbslam3_repeats=1)
    assert run_cost(specs[4], options) == 3 * run_cost(specs[4], one)
    assert sequence_cost(specs[-1].sequence_key) > sequence_cost(specs[0].sequence_key)


def test_code_text_ignores_comments_docstrings_and_layout_only():
    """The run keys hash ``code_text``: a comment, docstring or layout change keeps a study resumable; any change in
    what the code does (a constant, a name, a statement) changes the key."""
    from d2slam.digests import code_text

    base = 'x = 1\n\n\ndef f(a):\n    return a + x\n'
    doc = ('"""Module doc."""\n# a comment\nx = 1  # one\n\n\ndef f(a):\n    """Adds x."""\n'
           '    # the sum\n    return a + x\n')
    assert code_text(doc) == code_text(base)
    assert code_text('class C:\n    """Doc only."""\n') == code_text('class C:\n    pass\n')
    changed = ['x = 2\n\n\ndef f(a):\n    return a + x\n',  # a constant
               'x = 1\n\n\ndef f(a):\n    return a - x\n',  # an operator
               'x = 1\n\n\ndef g(a):\n    return a + x\n',  # a name
               'x = 1\n\n\ndef f(a):\n    y = "not a docstring"\n    return a + x\n']  # a statement
    for src in changed:
        assert code_text(src) != code_text(base)


def test_real_masks_are_segmented_once_per_sequence_before_the_runs(serial):
    from d2slam.config import DEFAULT
    from d2slam.data import open_sequence
    from d2slam.paths import cache_dir
    from d2slam.segmentation import get_segmenter
    from d2slam.segmentation.cache import STORE_NAME, read_store, segmenter_key, sequence_key
    from d2slam.study.runner import onnx_sequence_keys, run_options, segment_sequence

    dyn = RunSpec("sitting_static", "d2slam", 101, FRAMES)
    twin = RunSpec("sitting_static", "d2slam", 101, FRAMES, twin=True)
    specs = [RunSpec("sitting_static", "none", 101, FRAMES), dyn, twin,
             RunSpec("sitting_static", "oracle", 101, FRAMES, twin=True),
             RunSpec("walking_xyz", "d2slam-sim", 101, FRAMES), RunSpec("walking_xyz", "orbslam3-masked", 102, FRAMES)]
    # the real segmenter's masks by default; the oracle (truth) and d2slam-sim (simulated) read their own
    assert onnx_sequence_keys(specs, run_options()) == [dyn.sequence_key, twin.sequence_key,
                                                        ("synth", "walking_xyz", 102, FRAMES, False)]
    assert onnx_sequence_keys(specs, run_options(masks="sim")) == []
    # the study segmented its sequence before the runs (a phase of its own, timed; nothing to do when an earlier
    # test run left the masks in the shared mask cache): every frame is in the mask cache
    timing = json.loads((serial.out / "manifest.json").read_text())["timing"]
    assert timing["segmentation_s"] >= 0 and timing["segmentation_cpu_s"] >= 0 and timing["runs_cpu_s"] > 0
    seq = open_sequence(ensure_sequence("sitting_static", 101, FRAMES, False))
    folder = cache_dir("masks", sequence_key(seq), segmenter_key(get_segmenter("onnx", config=DEFAULT)))
    assert len(read_store(folder / STORE_NAME)[1]) == FRAMES
    assert segment_sequence(dyn.sequence_key, run_options())["error"] is None
    bad = segment_sequence(("synth", "no_such_scenario", 101, FRAMES, False), run_options())
    assert "no_such_scenario" in bad["error"]


# ------------------------------------------------------------------------------------- worker pools, interrupts
_HELD = []


def _hold_memory(nbytes: int) -> int:
    """A task of over a second (loky checks a worker's memory at most once a second) that keeps ``nbytes`` in its
    worker (as a loaded model or a cache does); returns the worker's pid."""
    import os
    import time

    if nbytes:
        _HELD.append(np.ones(nbytes, np.uint8))
    time.sleep(1.1)
    return os.getpid()


def test_pool_workers_keep_what_a_phase_loads_without_being_recycled(recwarn):
    """loky recycles a worker (warning "A worker stopped while some jobs were given to the executor ... memory
    leak") once it holds 300 MB more than after its first task. A study's workers run a light phase, then load the
    segmenter and their runs' memory: each call has its own pool, so that the first task of the phase sets the
    reference and no worker is recycled."""
    from d2slam.study.executors import map_ordered

    map_ordered(_hold_memory, [0, 0], jobs=2, progress=False)  # the light phase
    pids = map_ordered(_hold_memory, [320_000_000, 320_000_000, 0, 0, 0, 0], jobs=2, progress=False)
    assert len(set(pids)) <= 2  # no worker replaced
    assert not [w for w in recwarn if "worker stopped" in str(w.message)]


def _study_cli(out) -> list[str]:
    import sys

    return [sys.executable, "-m", "d2slam.cli", "study", "--out", str(out), "--scenarios", "sitting_static",
            "--methods", "none", "d2slam", "--seeds", "101", "--frames", str(FRAMES), "--twin-methods", "--jobs", "2",
            "--no-plots", "--quiet"]


@pytest.fixture
def ctrl_c_handled():
    """SIGINT handled as in an interactive session (KeyboardInterrupt) for the test and the processes it starts: a
    suite started in the background by a non-interactive shell inherits SIGINT ignored, which a study respects."""
    import signal

    prev = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, prev)


def test_ctrl_c_while_workers_start_is_kept_and_they_inherit_the_block(ctrl_c_handled):
    """While the pool's workers start, a Ctrl-C that reaches this thread waits (it is not lost: it arrives when they
    have started) and the processes started meanwhile have it blocked until their initializer ignores it."""
    import signal
    import subprocess
    import sys
    import threading

    from d2slam.study.executors import _sigint_deferred

    probe = "import signal; print(signal.SIGINT in signal.pthread_sigmask(signal.SIG_BLOCK, []))"
    with pytest.raises(KeyboardInterrupt):
        with _sigint_deferred():
            signal.pthread_kill(threading.get_ident(), signal.SIGINT)
            child = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True)
            reached_the_end = True
    assert reached_the_end and child.stdout.strip() == "True"
    assert signal.SIGINT not in signal.pthread_sigmask(signal.SIG_BLOCK, [])


def test_parallel_study_ctrl_c_is_one_line_and_leaves_nothing(serial, tmp_path, ctrl_c_handled):
    """Ctrl-C (SIGINT to the whole process group, as a terminal sends it) while two workers run: exit status 130,
    "d2slam: interrupted" and nothing else on stderr (no worker traceback, no leaked semaphores, no loky warning), no
    temporary file or folder of the study's processes left anywhere; on start, the study removed a killed process's
    leftover but not a running one's. A normal run prints no warning either."""
    import os
    import signal
    import subprocess
    import time
    import uuid

    import psutil

    from d2slam.outputs import temp_tag
    from d2slam.paths import cache_dir
    from d2slam.study.runner import features_dir, run_options

    done = subprocess.run(_study_cli(tmp_path / "normal"), capture_output=True, text=True, timeout=600)
    assert done.returncode == 0 and done.stderr == "", done.stderr

    gone = subprocess.Popen(["true"])
    gone.wait()
    seqs = cache_dir("study", "sequences")
    name = f"zz-test-{uuid.uuid4().hex[:8]}"
    dead, alive = seqs / f"{name}.tmp-{gone.pid}", seqs / f"{name}{temp_tag()}"
    dead.mkdir()
    alive.mkdir()
    out = tmp_path / "interrupted"
    try:
        p = subprocess.Popen(_study_cli(out), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                             start_new_session=True)
        pids, t0 = {p.pid}, time.monotonic()
        while not (out / "runs").is_dir() and p.poll() is None and time.monotonic() - t0 < 300:
            try:
                pids.update(c.pid for c in psutil.Process(p.pid).children(recursive=True))
            except psutil.Error:
                pass
            time.sleep(0.05)
        assert p.poll() is None, "the study ended before it could be interrupted"
        time.sleep(0.5)  # the runs' workers are starting or running
        pids.update(c.pid for c in psutil.Process(p.pid).children(recursive=True))
        os.killpg(p.pid, signal.SIGINT)
        stdout, stderr = p.communicate(timeout=120)
        assert not dead.exists() and alive.is_dir()
    finally:
        for d in (dead, alive):
            if d.exists():
                d.rmdir()
    assert p.returncode == 130 and stderr == "d2slam: interrupted\n", stderr
    assert not (out / "runs.csv").exists()
    places = [seqs, features_dir(run_options()), out / "runs"] + list(cache_dir("masks").glob("*/*"))
    left = [q for d in places for q in d.glob("*.tmp-*") if any(f".tmp-{pid}" in q.name for pid in pids)]
    assert left == []
    left_running = [q for q in psutil.process_iter() if q.pid in pids - {p.pid}]
    assert psutil.wait_procs(left_running, timeout=10)[1] == []  # every process of the study ended
