"""The study's online runs (``RunSpec.online``, ``d2slam.study.online``): where the grid has them, their keys (and
the offline runs' keys left as they are), the phase that runs them after every other run, one at a time in the
study's process, their rows and replayable schedules, --resume, and the online-beside-offline table. Nothing here is
timed: a stand-in segmenter (one box) keeps the tiny study fast."""

from __future__ import annotations

import dataclasses

import numpy as np
import pandas as pd
import pytest

import d2slam.run.online as online_path
from d2slam.config import DEFAULT, with_overrides
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.run.online import Schedule, replay
from d2slam.segmentation.base import PersonInstance
from d2slam.study import core, run_study
from d2slam.study import grid as G
from d2slam.study import tables as T
from d2slam.study.grid import RunSpec, expand_grid
from d2slam.study.keys import run_ident, run_key
from d2slam.study.online import online_config, schedule_path
from d2slam.study.runner import base_row, run_options
from d2slam.study.sequences import ensure_sequence

FRAMES = 40
OFFLINE_FIELDS = {"scenario", "method", "seed", "frames", "twin", "source", "loop_closing"}
WALKING = ("walking_xyz", "walking_halfsphere", "walking_static", "walking_rpy")


# ---------------------------------------------------------------------------------------------- grid and keys
def test_the_default_grid_runs_online_where_it_belongs_and_nowhere_else():
    specs = expand_grid(G.SCENARIOS, frames=300)
    online = [s for s in specs if s.online]
    want = {(s, m, seed) for s in WALKING for m in G.ONLINE_METHODS for seed in G.DEFAULT_SEEDS}
    want |= {("fr1_rpy", m, min(G.DEFAULT_SEEDS)) for m in G.ONLINE_METHODS}
    assert {(s.scenario, s.method, s.seed) for s in online} == want and len(online) == len(want)
    assert all(not s.twin and s.loop_closing for s in online)
    assert all(s.frames == 300 for s in online if s.scenario != "fr1_rpy")
    assert all(s.source == "real" and s.frames == 0 for s in online if s.scenario == "fr1_rpy")
    assert all(s.run_id.endswith("_online") for s in online)
    # without them: the offline grid, in its order, every spec naming the offline fields only
    offline = expand_grid(G.SCENARIOS, frames=300, online_methods=())
    assert offline == [s for s in specs if not s.online]
    assert all(set(s.to_dict()) == OFFLINE_FIELDS and not s.run_id.endswith("_online") for s in offline)
    options = run_options()
    assert all(set(run_ident(s, options)["spec"]) == OFFLINE_FIELDS for s in offline)
    # only the methods asked for; those that cannot run online are refused in one line
    assert {s.method for s in expand_grid(["walking_rpy"], ["none", "semantic"], [1], 40,
                                          online_methods=G.ONLINE_METHODS) if s.online} == {"none"}
    assert not any(s.online for s in expand_grid(["walking_rpy"], ["none", "semantic"], [1], 40))  # methods chosen
    with pytest.raises(D2SlamError, match="oracle cannot run online"):
        expand_grid(["walking_rpy"], ["none", "oracle"], [1], 40, online_methods=("oracle",))


def test_an_online_key_reads_the_online_section_its_offline_key_does_not():
    options, rate = run_options(), run_options(with_overrides(DEFAULT, {"online": {"rate_hz": 30.0}}))
    age = run_options(with_overrides(DEFAULT, {"online": {"mask_max_age_s": 0.1}}))
    for m in ("none", "d2slam", "orbslam3"):
        off, on = RunSpec("walking_xyz", m, 1, 40), RunSpec("walking_xyz", m, 1, 40, online=True)
        assert run_key(off, options) != run_key(on, options)
        assert run_key(off, rate) == run_key(off, options) and run_key(on, rate) != run_key(on, options)
        # ORB-SLAM3 online reads the rate alone: its threads and masks are its own
        assert (run_key(on, age) == run_key(on, options)) == (m == "orbslam3")


# ---------------------------------------------------------------------------------------------- the online phase
def test_online_runs_come_after_every_other_run_one_at_a_time_here(monkeypatch, tmp_path):
    """On two workers, and on a Dask cluster: the runs phase gets the offline runs, then the online phase the
    online runs, in grid order, serially in this process."""
    calls = []

    def fake_map(fn, items, args=(), jobs=1, scheduler=None, desc="", on_result=None, **kw):
        calls.append((desc, jobs, scheduler, list(items)))
        out = []
        for i, it in enumerate(items):
            r = ({"key": it, "path": None, "error": None} if desc in ("sequences", "segmentation") else
                 {"row": {**base_row(it), "status": "ok", "online": int(it.online)}, "trajectory": None,
                  "aligned": None, "keypoints": None, "stage_ms": {}, "loops": None})
            out.append(r)
            if on_result is not None:
                on_result(i, r)
        return out

    monkeypatch.setattr(core, "map_ordered", fake_map)
    monkeypatch.setattr(core, "check_dask_workers", lambda scheduler, expected: 2)
    monkeypatch.setattr(core, "_prepare_kernels", lambda: None)
    monkeypatch.setattr(core, "_prepare_vocabulary", lambda progress: None)
    grid = dict(scenarios=["walking_xyz", "sitting_static"], methods=["none", "d2slam"], seeds=[101, 102],
                frames=FRAMES, twin_methods=(), plots=False, progress=False, online_methods=G.ONLINE_METHODS)
    for where, kw in (("joblib", {"jobs": 2}), ("dask", {"scheduler": "tcp://127.0.0.1:1"})):
        calls.clear()
        res = run_study(tmp_path / where, **grid, **kw)
        assert [c[0] for c in calls] == ["sequences", "segmentation", "runs", "online"]
        runs, online = calls[2], calls[3]
        assert not any(s.online for s in runs[3]) and len(runs[3]) == 8
        assert online[1:3] == (1, None)  # serial, in this process, whatever the study's executor
        assert [s.run_id for s in online[3]] == [f"walking_xyz_s{seed}_n{FRAMES}_{m}_online" for seed in (101, 102)
                                                 for m in ("none", "d2slam")]
        assert "online_s" in res.manifest["timing"] and res.manifest["grid"]["online_runs"] == 4
    # --no-online's grid: no online phase at all
    calls.clear()
    run_study(tmp_path / "none", **{**grid, "online_methods": ()})
    assert [c[0] for c in calls if c[3]] == ["sequences", "segmentation", "runs"]


# ---------------------------------------------------------------------------------------------- a tiny study
class _BoxSegmenter:
    """A fast stand-in for the real segmenter: one person-sized box, the same on every frame."""

    def __call__(self, rgb):
        mask = np.zeros(rgb.shape[:2], bool)
        mask[120:400, 200:320] = True
        return [PersonInstance(mask, 0.9, (200.0, 120.0, 320.0, 400.0))]


GRID = dict(scenarios=["walking_xyz"], methods=["none", "d2slam"], seeds=[101], frames=FRAMES, twin_methods=(),
            online_methods=G.ONLINE_METHODS,
            plots=False, progress=False)


@pytest.fixture(scope="module")
def tiny(tmp_path_factory):
    ensure_sequence("walking_xyz", 101, FRAMES, False)
    mp = pytest.MonkeyPatch()
    mp.setattr(online_path, "online_segmenter", lambda config: _BoxSegmenter())
    try:
        yield run_study(tmp_path_factory.mktemp("online"), **GRID), mp
    finally:
        mp.undo()


def test_a_tiny_study_writes_online_rows_and_replayable_schedules(tiny):
    res, _ = tiny
    df = T.read_runs_csv(res.out / "runs.csv", online=True)
    assert df["method"].tolist() == ["none", "d2slam", "none", "d2slam"] and df["online"].tolist() == [0, 0, 1, 1]
    off, on = df[df["online"] == 0], df[df["online"] == 1]
    assert (on["deterministic"] == 0).all() and (off["deterministic"] == 1).all()
    assert (on["status"] == "ok").all() and np.isfinite(on["ate_rmse_m"]).all()
    for c in T.ONLINE_COLUMNS:
        assert off[c].isna().all(), c  # an offline row has no online figure
    assert ((on["processed_share"] > 0) & (on["processed_share"] <= 1)).all()
    assert (on["frames_dropped"] == FRAMES - np.round(on["processed_share"] * FRAMES)).all()
    assert (on["lag_ms_p95"] >= on["lag_ms_median"]).all()
    assert np.isnan(on["segmenter_fps"].iloc[0]) and on["segmenter_fps"].iloc[1] > 0  # none runs no segmenter
    assert T.read_runs_csv(res.out / "runs.csv")["online"].tolist() == [0, 0]  # the offline tables' rows
    # the schedule beside the trajectory replays the online run byte for byte
    spec = RunSpec("walking_xyz", "d2slam", 101, FRAMES, online=True)
    path = schedule_path(res.out, spec)
    assert path.parent == res.out / "trajectories" and (res.out / "trajectories" / f"{spec.run_id}.txt").is_file()
    seq = open_sequence(ensure_sequence("walking_xyz", 101, FRAMES, False))
    again = replay(seq, Schedule.load(path), "d2slam", online_config(spec, run_options()), progress=False)
    with np.load(res.out / "runs" / f"{spec.run_id}.npz") as z:
        assert np.array_equal(again.trajectory.poses, z["poses"])
    md = (res.out / "tables.md").read_text()
    assert "## Online beside offline" in md and "| w/xyz | `d2slam` | 1 |" in md


def test_resume_reuses_the_online_runs_and_redoes_one_whose_schedule_is_gone(tiny, tmp_path, capsys):
    res, _ = tiny
    again = run_study(res.out, resume=True, **GRID)
    assert len(again.manifest["grid"]["reused_runs"]) == 4
    cols = ["method", "online", "ate_rmse_m", "processed_share", "lag_ms_median"]
    assert again.runs[cols].equals(res.runs[cols])  # the rows read back, not run again
    schedule_path(res.out, RunSpec("walking_xyz", "none", 101, FRAMES, online=True)).unlink()
    third = run_study(res.out, resume=True, **GRID)
    assert sorted(third.manifest["grid"]["reused_runs"]) == ["walking_xyz_s101_n40_d2slam",
                                                             "walking_xyz_s101_n40_d2slam_online",
                                                             "walking_xyz_s101_n40_none"]
    assert "damaged online run's schedule" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------- the table
def test_the_online_table_sets_each_online_run_beside_its_offline_figures():
    rows = []
    for seed, (off, on, share, lag) in zip((1, 2, 3), ((0.010, 0.011, 0.9, 20.0), (0.020, 0.030, 1.0, 30.0),
                                                       (0.030, 0.033, 0.8, 40.0))):
        spec = RunSpec("walking_xyz", "d2slam", seed, 300)
        rows.append({**base_row(spec), "status": "ok", "ate_rmse_m": off})
        rows.append({**base_row(dataclasses.replace(spec, online=True)), "status": "ok", "online": 1,
                     "deterministic": 0, "ate_rmse_m": on, "processed_share": share, "lag_ms_median": lag,
                     "lag_ms_p95": 2 * lag})
    df = T.runs_frame(rows)
    t = T.online_table(df[df["online"] == 1], df[df["online"] == 0])
    r = t.iloc[0]
    assert (r["method"], r["runs"]) == ("d2slam", 3)
    assert r["offline_ate_m"] == pytest.approx(0.020) and r["online_ate_m"] == pytest.approx(0.030)
    assert r["ratio"] == pytest.approx(1.5) and r["processed_pct"] == pytest.approx(90.0)
    assert (r["lag_ms_median"], r["lag_ms_p95"]) == (30.0, 60.0)
    md = T.tables_markdown(df, ["d2slam"], {"grid": {"online_rate_hz": 30.0}, "timing": {"online_load_average":
                                                                                           [1.0, 0.5, 0.25]}})
    assert "| w/xyz | `d2slam` | 3 | 0.0200 | 0.0300 | 1.50x | 90.0 | 30.0 / 60.0 |" in md
    assert "at 30 Hz" in md and "load average 1.00, 0.50, 0.25" in md
    # every other table is made of the offline runs alone
    assert "0.0300 [" not in md.split("## Online beside offline")[0]
    summary = T.summarise(df)
    assert sorted(summary["online"].tolist()) == [0, 1] and (summary["n_runs"] == 3).all()
    assert pd.Series(T.sort_runs(df)["online"]).tolist() == [0, 0, 0, 1, 1, 1]
