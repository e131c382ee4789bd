"""Run keys follow what a run reads (``d2slam.study.keys``, ``d2slam.run.methods.run_reads``): a change to a config
field or to a part of the code re-keys only the runs whose method reads it; ``--resume`` then runs only those, says
before it starts how many and why, and renders and segments nothing again when only the engine changed. A field a
method is said not to read leaves its trajectory byte-identical when it changes."""

from __future__ import annotations

import dataclasses
import gc
import sys
import threading

import numpy as np
import pytest

import d2slam.digests as digests
from d2slam.config import DEFAULT, with_overrides
from d2slam.data import open_sequence
from d2slam.dynamics.config import FLOW_FIELDS, OIM_FIELDS
from d2slam.run.methods import methods
from d2slam.run.runner import run_method
from d2slam.study import run_study
from d2slam.study.grid import RunSpec
from d2slam.study.keys import run_key
from d2slam.study.runner import run_options
from d2slam.study.sequences import ensure_sequence
from d2slam.synth.version import generator_version

FRAMES = 40
ALL = methods()
OIM_METHODS = {"d2slam", "no-depth", "no-bayes", "d2slam-flow", "d2slam-sim"}
FILTERS = OIM_METHODS | {"no-oim", "semantic", "geometric"}
ENGINE = FILTERS | {"none", "oracle"}
ONNX = FILTERS - {"geometric", "d2slam-sim"} | {"orbslam3-masked"}


def _keys(config=DEFAULT) -> dict:
    options = run_options(config)
    return {m: run_key(RunSpec("walking_xyz", m, 0, 120), options) for m in ALL}


def _changed(overrides: dict) -> set:
    before, after = _keys(), _keys(with_overrides(DEFAULT, overrides))
    return {m for m in ALL if before[m] != after[m]}


@pytest.mark.parametrize("overrides, expected", [
    ({"dynamics": {"delta_a": 40.0}}, OIM_METHODS),  # eq 9
    ({"dynamics": {"ours": {"oim_belief": 0.8}}}, OIM_METHODS),  # ours, inside the OIM
    ({"dynamics": {"flow": {"flow_window": 15}}}, {"d2slam-flow"}),
    ({"dynamics": {"flow": {"enabled": True}}}, FILTERS),  # read by every classifier
    ({"dynamics": {"beta_max": 0.3}}, FILTERS),  # eq 2: every classifier
    ({"dynamics": {"ours": {"silhouette_px": 3.0}}}, FILTERS),
    ({"dynamics": {"ours": {"silhouette_p": 0.8}}}, set()),  # the band's likelihood, without the band
    ({"orb": {"n_features": 900}}, ENGINE),  # the engine's, not ORB-SLAM3's
    ({"baseline": {"orbslam3_repeats": 5}}, {"orbslam3", "orbslam3-masked"}),
    ({"masking": {"fill": "black"}}, {"orbslam3-masked"}),
    ({"segmentation": {"score_threshold": 0.3}}, ONNX),  # the real segmenter's masks
    ({"segmentation": {"intra_op_threads": 1}}, set()),  # changes no mask
    ({"online": {"rate_hz": 15.0}}, set()),  # offline runs read none of it
    ({"study": {"run_cost_default_ms": 60.0}}, set()),
])
def test_a_config_change_rekeys_the_runs_that_read_it(overrides, expected):
    assert _changed(overrides) == expected


def test_an_engine_code_change_rekeys_engine_runs_only(monkeypatch):
    """The engine's source re-keys every engine run, but not ORB-SLAM3's, not the synthetic sequences (generator
    version) and not the mask cache (segmenter key: the model, the decoder and the segmenter's config)."""
    before, gen = _keys(), generator_version()
    real = digests.code_text
    monkeypatch.setattr(digests, "code_text", lambda src: real(src) + ("#" if "class Tracker" in src else ""))
    digests.source_digest.cache_clear()
    try:
        after = _keys()
        assert generator_version.__wrapped__() == gen
    finally:
        monkeypatch.undo()
        digests.source_digest.cache_clear()
    assert {m for m in ALL if before[m] != after[m]} == ENGINE


def _perturbed(fields) -> dict:
    """Each dotted field of ``fields`` moved to another valid value."""
    out: dict = {}
    cfg = DEFAULT.dynamics
    for name in fields:
        *path, leaf = name.split(".")
        sec = cfg
        for p in path:
            sec = getattr(sec, p)
        v = getattr(sec, leaf)
        new = (not v) if isinstance(v, bool) else (v + 1 if isinstance(v, int) else
                                                  (v * 0.9 if isinstance(v, float) else v))
        d = out
        for p in path:
            d = d.setdefault(p, {})
        d[leaf] = new
    return {"dynamics": out}


@pytest.fixture(scope="module")
def sequence():
    return open_sequence(ensure_sequence("sitting_static", 101, FRAMES, False))


@pytest.mark.parametrize("method, fields", [("no-oim", OIM_FIELDS), ("semantic", OIM_FIELDS + FLOW_FIELDS),
                                            ("geometric", OIM_FIELDS), ("d2slam", FLOW_FIELDS)])
def test_fields_a_method_does_not_read_leave_its_run_unchanged(sequence, method, fields):
    changes = _perturbed(fields)
    config = with_overrides(DEFAULT, changes)
    a = run_method(sequence, method, DEFAULT, masks="sim", synthetic=True, progress=False)
    b = run_method(sequence, method, config, masks="sim", synthetic=True, progress=False)
    assert np.array_equal(a.trajectory.poses, b.trajectory.poses)
    assert np.array_equal(a.trajectory.timestamps, b.trajectory.timestamps)


def test_resume_reruns_only_what_changed_and_says_why(tmp_path, monkeypatch, capsys):
    ensure_sequence("sitting_static", 101, FRAMES, False)
    grid = dict(scenarios=["sitting_static"], methods=["none", "no-oim", "d2slam"], seeds=[101], frames=FRAMES,
                twin_methods=(), plots=False)
    out = tmp_path / "study"
    first = run_study(out, progress=False, **grid)
    assert (first.runs["status"] == "ok").all()
    oim = with_overrides(DEFAULT, {"dynamics": {"delta_a": 40.0}})
    res = run_study(out, config=oim, resume=True, progress=None, **grid)
    assert res.manifest["grid"]["reused_runs"] == ["sitting_static_s101_n40_no-oim", "sitting_static_s101_n40_none"]
    assert res.manifest["grid"]["rerun_reasons"] == {"config: dynamics.delta_a": 1}
    assert "resume: 3 runs, 2 reused, 1 to run (1 config: dynamics.delta_a)" in capsys.readouterr().err

    # the engine's code changes: every run again, but no sequence is rendered and no frame segmented
    import d2slam.segmentation.onnx as onnx
    import d2slam.study.sequences as sequences

    def refused(*a, **k):
        raise AssertionError("rendered or segmented again")

    monkeypatch.setattr(sequences, "generate", refused)
    monkeypatch.setattr(onnx.OnnxSegmenter, "segment", refused)
    real = digests.code_text
    monkeypatch.setattr(digests, "code_text", lambda src: real(src) + ("#" if "class Tracker" in src else ""))
    digests.source_digest.cache_clear()
    try:
        again = run_study(out, config=oim, resume=True, progress=False, **grid)
    finally:
        monkeypatch.undo()
        digests.source_digest.cache_clear()
    assert (again.runs["status"] == "ok").all() and again.manifest["grid"]["reused_runs"] == []
    assert again.manifest["grid"]["rerun_reasons"] == {"code": 3}
    cols = ["method", "ate_rmse_m", "frames_tracked", "kp_f1"]
    assert again.runs[cols].equals(res.runs[cols])  # the same code of the methods: the same numbers


def test_code_text_parses_safely_from_threads():
    """Run keys are computed in a dask worker's threads at once. Parsing from several threads, with a thread switch
    forced inside the AST's construction (a garbage collector callback that runs Python code, a tiny switch interval),
    gives every thread the same text; unserialised, CPython 3.11 fails with "AST constructor recursion depth
    mismatch"."""
    sources = [p.read_text(encoding="utf-8") for p in sorted((digests.PACKAGE / "slam").glob("*.py"))]
    want = [digests.code_text(s) for s in sources]
    got, errors = [], []

    def parse():
        try:
            got.append([digests.code_text(s) for s in sources])
        except Exception as e:  # noqa: BLE001 - the test reports what a thread raised
            errors.append(repr(e))

    def callback(*_):
        sum(range(50))

    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)
    gc.callbacks.append(callback)
    try:
        threads = [threading.Thread(target=parse) for _ in range(4)]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    finally:
        gc.callbacks.remove(callback)
        sys.setswitchinterval(interval)
    assert errors == [] and got == [want] * 4
