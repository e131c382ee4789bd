"""The study's numbers: the CSV schema, medians and spreads over seeds, improvement over a baseline, and the
paper-format Markdown tables (Tables 1-3 of the paper: rows fr3 w/xyz, w/half, w/static, w/rpy, s/static; columns
methods).

Improvement over a baseline, as in the paper's tables: ``(1 - ours / baseline) x 100`` %
(docs/design.md#improvement-over-a-baseline).
In our tables both are medians over seeds (``improvement(median ours, median baseline)``); the bracket gives the
range of the per-seed (paired: same sequence) improvements. ORB-SLAM3's per-sequence figure is already the median
of its repeats.
"""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from d2slam.config import DEFAULT
from d2slam.eval.config import EvalConfig
from d2slam.eval.fragment import is_fragment
from d2slam.outputs import staged_file
from d2slam.study.grid import (BASELINE, COMPOSITE_SCENARIOS, FR3_SCENARIOS, FULL, INTERACTION_SCENARIOS, LABELS,
                               LOOP_SCENARIOS, ORACLE, REAL_SCENARIOS,
                               ORBSLAM3, ORBSLAM3_MASKED, REPEATED, SCENARIOS)
from d2slam.study.improvement import improvement, improvement_table, metric_matrix  # noqa: F401 - the tables' API
from d2slam.study.improvement import methods_of as _methods
from d2slam.study.improvement import nanmedian as _nanmedian
from d2slam.study.improvement import scenarios_of as _scenarios
import json
from d2slam.errors import D2SlamError
from d2slam.study.calibration import calibration_checks, calibration_markdown, calibration_table
from d2slam.study.grid import RunSpec
from d2slam.study.paper import published_real
from pathlib import Path

# runs.csv: identity, outcome, deterministic results, then the timing columns (never compared between runs).
KEY_COLUMNS = ["scenario", "sequence", "twin", "method", "seed", "frames", "source", "loop_closing", "online"]
OUTCOME_COLUMNS = ["status", "error", "deterministic", "repeats", "config_hash"]
METRIC_COLUMNS = ["ate_rmse_m", "rpe_trans_m", "rpe_rot_deg"]
RESULT_COLUMNS = METRIC_COLUMNS + ["ate_min_m", "ate_max_m", "kp_precision", "kp_recall", "kp_f1",
                                   "kp_static_precision", "kp_object_recall", "kp_object_keypoints", "frames_tracked",
                                   "frames_lost", "tracked_share", "fragment", "keyframes", "map_points", "loops",
                                   "loops_true", "loops_false", "loop_closest_ratio"]
# tracked_share: frames_tracked over the frames the run went through (``frames`` is the grid's, 0 = all); fragment: 1
# when that share is below EvalConfig.min_tracked_share (d2slam.run.record.is_fragment: its errors are over the tracked
# part only). loops: detected by the engine's loop closing, true / false against the ground truth; loop_closest_ratio:
# the score of the wrong place-recognition candidate that went furthest over its keyframe's minimum score
# (d2slam.eval.loops).
# An online run (online = 1: d2slam.study.online): the share of its frames processed, the frames dropped, the lag
# from a frame's arrival to its pose (median, 95th percentile, ms) and the segmenter's frames per second; its
# metrics are over the processed frames. They depend on the machine's load, as the timings do; empty offline.
ONLINE_COLUMNS = ["processed_share", "frames_dropped", "lag_ms_median", "lag_ms_p95", "segmenter_fps"]
OPTIONAL_COLUMNS = ["kp_object_recall", "kp_object_keypoints", "loop_closing", "loops", "loops_true", "loops_false",
                    "loop_closest_ratio", "tracked_share", "fragment", "online"] + ONLINE_COLUMNS
# features_cached = 1: the run read the sequence's features extracted by an earlier run (its ms_extract and fps count
# the extraction time stored with them, d2slam.slam.features).
TIMING_COLUMNS = ["fps", "ms_per_frame", "ms_load", "ms_segment", "ms_extract", "ms_filter", "ms_track",
                  "ms_local_ba", "wall_s", "features_cached"]
RUN_COLUMNS = KEY_COLUMNS + OUTCOME_COLUMNS + RESULT_COLUMNS + ONLINE_COLUMNS + TIMING_COLUMNS
SUMMARY_STATS = ("median", "min", "max")
SUMMARY_METRICS = METRIC_COLUMNS + ["kp_precision", "kp_recall", "kp_f1", "frames_tracked", "frames_lost"]
SUMMARY_TIMINGS = ["fps", "ms_per_frame"]
GROUP = ["source", "scenario", "sequence", "twin", "method", "frames", "loop_closing", "online"]
UNITS = {"ate_rmse_m": "m", "rpe_trans_m": "m", "rpe_rot_deg": "deg"}
TITLES = {"ate_rmse_m": "ATE", "rpe_trans_m": "translational RPE", "rpe_rot_deg": "rotational RPE"}
DECIMALS = {"ate_rmse_m": 4, "rpe_trans_m": 4, "rpe_rot_deg": 3}


def runs_frame(rows: list[dict]) -> pd.DataFrame:
    """The runs as a DataFrame with exactly :data:`RUN_COLUMNS` (missing values NaN / empty)."""
    df = pd.DataFrame(rows)
    for c in RUN_COLUMNS:
        if c not in df:
            df[c] = np.nan
    df = df[RUN_COLUMNS].copy()
    for c in RESULT_COLUMNS + ONLINE_COLUMNS + TIMING_COLUMNS:
        df[c] = pd.to_numeric(df[c], errors="coerce").astype(np.float64)
    # an absent loop_closing or online (a study made before the column): 0
    for c in ("twin", "seed", "frames", "deterministic", "repeats", "loop_closing", "online"):
        df[c] = pd.to_numeric(df[c], errors="coerce").fillna(0).astype(np.int64)
    for c in ("error", "config_hash"):
        df[c] = ["" if (isinstance(v, float) and math.isnan(v)) or v is None else str(v) for v in df[c]]
    return df


def sort_runs(df: pd.DataFrame, methods: list[str] | None = None) -> pd.DataFrame:
    """Grid order (see :mod:`d2slam.study.grid`): scenario (paper order), dynamic before twin, then the online runs,
    seed, method."""
    methods = list(methods) if methods is not None else list(dict.fromkeys(df["method"]))
    key = pd.DataFrame({
        "s": df["scenario"].map(lambda s: SCENARIOS.index(s) if s in SCENARIOS else len(SCENARIOS)),
        "t": df["twin"], "on": df["online"], "seed": df["seed"], "lc": -df["loop_closing"],
        "m": df["method"].map(lambda m: methods.index(m) if m in methods else len(methods)),
        "src": df["source"]})
    order = key.sort_values(["src", "s", "on", "t", "seed", "lc", "m"], kind="mergesort").index
    return df.loc[order].reset_index(drop=True)


def write_runs_csv(df: pd.DataFrame, path) -> None:
    with staged_file(path) as tmp:  # whole or not at all
        df[RUN_COLUMNS].to_csv(tmp, index=False)  # repr: exact round trip


def read_runs_csv(path, online: bool = False) -> pd.DataFrame:
    """A study's ``runs.csv``: its offline runs, which every table but the online one is made of, or (``online``)
    every run, the online ones too (``online`` = 1)."""
    text = {c: str for c in ("scenario", "sequence", "method", "source", "status", "error", "config_hash")}
    df = pd.read_csv(path, keep_default_na=True, dtype=text)
    for c in OPTIONAL_COLUMNS:  # metrics a study made before they existed did not record: missing values
        if c not in df.columns:
            df[c] = np.nan
    missing = [c for c in RUN_COLUMNS if c not in df.columns]
    if missing:
        raise D2SlamError(f"not a study runs.csv: missing columns {', '.join(missing)}", path=path)
    df = runs_frame(df.to_dict("records"))
    return df if online else offline_runs(df)


def offline_runs(df: pd.DataFrame) -> pd.DataFrame:
    """The offline runs of ``df`` (the paper's protocol: every frame segmented first, nothing dropped)."""
    return df[df["online"] == 0].reset_index(drop=True)


def summarise(df: pd.DataFrame) -> pd.DataFrame:
    """One row per (source, scenario, twin, method, frames) in grid order: number of runs and of runs with
    metrics, then median / min / max over seeds of each metric (runs without the metric are left out), then the
    timing medians (separate, last)."""
    rows = []
    for key, g in df.groupby(GROUP, sort=False, dropna=False):
        row = dict(zip(GROUP, key))
        row["n_runs"] = int(len(g))
        row["n_ok"] = int(np.isfinite(g["ate_rmse_m"]).sum())
        row["seeds"] = " ".join(str(s) for s in sorted(g["seed"]))
        for c in SUMMARY_METRICS:
            v = g[c].to_numpy(np.float64)
            v = v[np.isfinite(v)]
            for stat, f in zip(SUMMARY_STATS, (np.median, np.min, np.max)):
                row[f"{c}_{stat}"] = float(f(v)) if len(v) else np.nan
        for c in SUMMARY_TIMINGS:
            v = g[c].to_numpy(np.float64)
            v = v[np.isfinite(v)]
            row[f"{c}_median"] = float(np.median(v)) if len(v) else np.nan
        rows.append(row)
    return pd.DataFrame(rows)


def write_summary_csv(summary: pd.DataFrame, path) -> None:
    with staged_file(path) as tmp:  # whole or not at all
        summary.to_csv(tmp, index=False)  # repr: exact round trip


# ------------------------------------------------------------------------------------------------------------
# Paper-format tables
# ------------------------------------------------------------------------------------------------------------
# Cells whose runs tracked less than this share of their frames (median over seeds; d2slam.run.record.is_fragment) get a
# dagger: EvalConfig.min_tracked_share, the rule `d2slam run` applies to one run.
TRACKED_FLAG = DEFAULT.evaluation.min_tracked_share
DAGGER = " †"
DAGGER_NOTE = (f"† the method tracked fewer than {100 * TRACKED_FLAG:g} % of the frames (median over seeds): its "
               "errors are over a shorter trajectory (see the tracking table).")


def tracked_shares(g: pd.DataFrame) -> np.ndarray:
    """Each run's share of its frames tracked: its ``tracked_share``, else (a study made before that column)
    frames_tracked / frames when the grid gave a frame count (NaN: unknown)."""
    share = g["tracked_share"].to_numpy(np.float64)
    frames = g["frames"].to_numpy(np.float64)
    old = g["frames_tracked"].to_numpy(np.float64) / np.where(frames > 0, frames, np.nan)
    return np.where(np.isfinite(share), share, old)


def tracked_fraction(df: pd.DataFrame, scenario: str, method: str, twin: int = 0) -> float:
    """Median over seeds of the share of frames tracked (:func:`tracked_shares`; NaN when no run recorded it)."""
    g = df[(df["scenario"] == scenario) & (df["method"] == method) & (df["twin"] == twin)]
    return _nanmedian(tracked_shares(g))


def _flag(df, scenario, method, twin=0) -> str:
    return DAGGER if is_fragment(tracked_fraction(df, scenario, method, twin), TRACKED_FLAG) else ""


def _fmt_imp(cell) -> str:
    if cell is None:
        return "n/a"
    imp, lo, hi, n = cell
    s = f"{imp:.1f} %"
    if n > 1:
        s += f" [{lo:.1f}, {hi:.1f}]"
    return s


def _rowhead(df: pd.DataFrame) -> str:
    """The row header: synthetic fr3-like scenes, real TUM fr3 sequences, or real sequences of other families."""
    if not (len(df) and (df["source"] == "tum").all()):
        return "fr3 (synthetic)"
    return "fr3 (real TUM)" if df["sequence"].astype(str).str.startswith("fr3").all() else "sequence (real TUM)"


def _md(header: list[str], rows: list[list[str]]) -> str:
    lines = ["| " + " | ".join(header) + " |", "|" + "|".join(["---"] * len(header)) + "|"]
    lines += ["| " + " | ".join(r) + " |" for r in rows]
    return "\n".join(lines)


def improvement_markdown(df: pd.DataFrame, metric: str, baseline: str = BASELINE,
                         methods: list[str] | None = None) -> str:
    scen, ms, cells = improvement_table(df, metric, baseline, methods)
    rows = [[LABELS.get(s, s)] + [_fmt_imp(cells[(s, m)]) + (_flag(df, s, m) if cells[(s, m)] else "")
                                  for m in ms] for s in scen]
    return _md([_rowhead(df)] + [f"`{m}`" for m in ms], rows)


def _orb_runs(df: pd.DataFrame) -> str:
    """How ORB-SLAM3 was run per sequence, from the runs' ``repeats`` column."""
    reps = sorted(set(int(r) for r in df[df["method"].isin(REPEATED)]["repeats"] if r > 0))
    if not reps or reps == [1]:
        return "one run per sequence: the spread over seeds includes its run-to-run variation"
    return f"median of its {'/'.join(map(str, reps))} repeats per sequence"


def absolute_markdown(df: pd.DataFrame, metric: str, twin: int = 0, methods: list[str] | None = None) -> str:
    """Median [min, max] over seeds (ORB-SLAM3: of the per-sequence medians over its repeats; for the ATE also
    ``{repeats lo-hi}``, the lowest and highest ATE of any single repeat)."""
    d = df[df["twin"] == twin]
    ms = [m for m in (methods or _methods(df)) if m in set(d["method"])]
    nd = DECIMALS.get(metric, 4)
    rows = []
    for s in _scenarios(d):
        r = [LABELS.get(s, s)]
        for m in ms:
            g = d[(d["scenario"] == s) & (d["method"] == m)]
            v = g[metric].to_numpy(np.float64)
            n_all = len(v)
            v = v[np.isfinite(v)]
            if not len(v):
                r.append("failed" if n_all else "")
                continue
            cell = f"{np.median(v):.{nd}f}"
            if len(v) > 1:
                cell += f" [{v.min():.{nd}f}, {v.max():.{nd}f}]"
            if len(v) < n_all:
                cell += f" ({n_all - len(v)} failed)"
            if m in REPEATED and metric == "ate_rmse_m" and (g["repeats"] > 1).any():  # the spread of its own repeats
                lo, hi = g["ate_min_m"].to_numpy(np.float64), g["ate_max_m"].to_numpy(np.float64)
                if np.isfinite(lo).any() and np.isfinite(hi).any():
                    cell += f" {{repeats {np.nanmin(lo):.{nd}f}-{np.nanmax(hi):.{nd}f}}}"
            r.append(cell + _flag(df, s, m, twin))
        rows.append(r)
    return _md([_rowhead(df) + (" static twin" if twin else "")] + [f"`{m}`" for m in ms], rows)


# The study's targets, checked run by run in ``targets_markdown``: the full method's ATE at most TARGET_ATE_TWIN x the
# engine's ATE on the static twin; `none` at least TARGET_NONE_TWIN x on the walking scenarios; dynamic-keypoint recall
# at least TARGET_RECALL at a static precision of at least TARGET_STATIC_PRECISION.
TARGET_ATE_TWIN = 1.2
TARGET_ATE_TWIN_OURS = 1.5  # the interaction scenarios (objects moved by people: beyond what the paper evaluates)
TARGET_MASKS_OVER_D2SLAM = 3.0  # ... where the masks-only baselines are to be at least this many times d2slam's ATE
TARGET_NONE_TWIN = 5.0
TARGET_RECALL = 0.95
TARGET_STATIC_PRECISION = 0.98
TARGET_METHODS = (BASELINE, FULL, "d2slam-flow", ORACLE)


def twin_ratios(df: pd.DataFrame, methods: list[str] | None = None) -> pd.DataFrame:
    """ATE of each method on the dynamic sequence divided by the engine's (``none``) ATE on its static twin
    (medians over seeds), per scenario; NaN where either is missing. The targets: ``d2slam`` <= 1.2,
    ``none`` >= 5 on the walking scenarios. ``twin_oracle_ate_m`` is the occluded twin's ATE (``oracle`` on the
    twin: the dynamic sequence's silhouettes cut out, nothing moving) and ``occluded`` its ratio to the twin: what
    occlusion alone costs the engine."""
    ms = [m for m in (methods or _methods(df))]
    out = []
    for s in _scenarios(df):
        def twin_ate(m):
            return _nanmedian(df[(df["scenario"] == s) & (df["twin"] == 1) & (df["method"] == m)]["ate_rmse_m"])

        t = twin_ate(BASELINE)
        row = {"scenario": s, "sequence": LABELS.get(s, s), "twin_none_ate_m": t, "twin_d2slam_ate_m": twin_ate(FULL),
               "twin_oracle_ate_m": twin_ate(ORACLE)}
        row["occluded"] = _ratio(row["twin_oracle_ate_m"], t)
        for m in ms:
            row[m] = _ratio(_nanmedian(df[(df["scenario"] == s) & (df["twin"] == 0) & (df["method"] == m)]
                                       ["ate_rmse_m"]), t)
        out.append(row)
    return pd.DataFrame(out)


def _ratio(a: float, b: float) -> float:
    return a / b if math.isfinite(a) and math.isfinite(b) and b > 0 else np.nan


def _has_occluded(df: pd.DataFrame) -> bool:
    return bool(np.isfinite(df[(df["twin"] == 1) & (df["method"] == ORACLE)]["ate_rmse_m"].astype(np.float64)).any())


def twin_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    ms = [m for m in (methods or _methods(df))]
    tr = twin_ratios(df, ms)
    if tr.empty or not np.isfinite(tr["twin_none_ate_m"]).any():
        return "_No static-twin run with metrics (run the study with the `none` method on synthetic data)._"
    occ = _has_occluded(df)
    rows = []
    for _, r in tr.iterrows():
        cells = [r["sequence"], _num(r["twin_none_ate_m"], 4) + _flag(df, r["scenario"], BASELINE, 1),
                 _num(r["twin_d2slam_ate_m"], 4) + _flag(df, r["scenario"], FULL, 1)]
        if occ:
            cells.append(_num(r["occluded"], 2, "x") + _flag(df, r["scenario"], ORACLE, 1))
        cells += [_num(r[m], 2, "x") + (_flag(df, r["scenario"], m) if math.isfinite(r[m]) else "") for m in ms]
        walking = r["scenario"].startswith("walking")
        full = r.get(FULL, np.nan)
        none = r.get(BASELINE, np.nan)
        cells.append("n/a" if not math.isfinite(full) else ("yes" if full <= TARGET_ATE_TWIN else "no")
                     + _flag(df, r["scenario"], FULL))
        cells.append("n/a" if not walking or not math.isfinite(none) else ("yes" if none >= TARGET_NONE_TWIN else "no"))
        rows.append(cells)
    header = (["fr3 (synthetic)", "twin ATE `none` (m)", "twin ATE `d2slam` (m)"]
              + (["occluded twin / twin"] if occ else [])
              + [f"`{m}` / twin" for m in ms] + ["`d2slam` <= 1.2x twin", "`none` >= 5x twin (walking)"])
    return _md(header, rows)


def target_checks(df: pd.DataFrame, methods: list[str] | None = None) -> pd.DataFrame:
    """The targets run by run: one row per dynamic run (scenario, method, seed) with its ATE over the same seed's
    static twin (``none``) and over its occluded twin (``oracle`` on the twin, when run), recall, static precision, and
    whether each target holds: ``ate_ok`` (a filter's ATE <= TARGET_ATE_TWIN x its reference (TARGET_ATE_TWIN_OURS on
    the interaction scenarios), the occluded twin when
    there is one, else the static twin: what a keypoint filter can reach on this engine; for ``none`` on a walking
    scenario >= TARGET_NONE_TWIN x the static twin; NaN elsewhere) and ``kp_ok`` (recall and static precision both at
    their targets; NaN without keypoint metrics, and for ``none``, which classifies nothing). A missing value never
    counts as met."""
    ms = [m for m in (methods or TARGET_METHODS) if m in set(df["method"])]
    twin = df[(df["twin"] == 1) & (df["method"] == BASELINE)].set_index(["scenario", "seed"])["ate_rmse_m"]
    occluded = df[(df["twin"] == 1) & (df["method"] == ORACLE)].set_index(["scenario", "seed"])["ate_rmse_m"]
    out = []
    for s in _scenarios(df[df["twin"] == 0]):
        walking = s.startswith("walking")
        for m in ms:
            g = df[(df["twin"] == 0) & (df["scenario"] == s) & (df["method"] == m)].sort_values("seed")
            for _, r in g.iterrows():
                t = twin.get((s, r["seed"]), np.nan)
                ratio = _ratio(float(r["ate_rmse_m"]), float(t))
                over_occ = _ratio(float(r["ate_rmse_m"]), float(occluded.get((s, r["seed"]), np.nan)))
                # NaN compares False: a run without a ratio (failed, or no twin) misses its target
                if m == BASELINE:  # no filter: nothing classified (its keypoint columns count every keypoint static)
                    ate_ok = bool(ratio >= TARGET_NONE_TWIN) if walking else np.nan
                    rec = sp = np.nan
                else:
                    limit = TARGET_ATE_TWIN_OURS if s in INTERACTION_SCENARIOS else TARGET_ATE_TWIN
                    ate_ok = bool((over_occ if (s, r["seed"]) in occluded.index else ratio) <= limit)
                    rec, sp = float(r.get("kp_recall", np.nan)), float(r.get("kp_static_precision", np.nan))
                has_kp = math.isfinite(rec) or math.isfinite(sp)
                kp_ok = bool(rec >= TARGET_RECALL and sp >= TARGET_STATIC_PRECISION) if has_kp else np.nan
                out.append({"scenario": s, "sequence": LABELS.get(s, s), "method": m, "seed": int(r["seed"]),
                            "ate_over_twin": ratio, "ate_over_occluded": over_occ, "ate_ok": ate_ok, "recall": rec,
                            "static_precision": sp, "kp_ok": kp_ok})
    return pd.DataFrame(out, columns=["scenario", "sequence", "method", "seed", "ate_over_twin", "ate_over_occluded",
                                      "ate_ok", "recall", "static_precision", "kp_ok"])


def _met(flags: pd.Series) -> str:
    """'k of n' over the runs a target applies to (``target_checks``: True / False; NaN where it does not apply)."""
    v = flags.dropna()
    return f"{int(v.astype(bool).sum())} of {len(v)}" if len(v) else "n/a"


def _per_seed(values, nd: int, suffix: str = "") -> str:
    return " / ".join(_num(float(v), nd, suffix) for v in values) or "n/a"


def targets_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    """The targets per scenario and method: the per-seed values (seeds ascending) and on how many runs each
    target holds (``target_checks``)."""
    tc = target_checks(df, methods)
    if tc.empty or not np.isfinite(tc["ate_over_twin"].astype(np.float64)).any():
        return "_No dynamic run with a static twin (run the study on synthetic data with `none`)._"
    occ = _has_occluded(df)
    rows = []
    for (s, m), g in tc.groupby(["scenario", "method"], sort=False):
        walking = s.startswith("walking")
        if m == BASELINE:
            ate_target = f">= {TARGET_NONE_TWIN:g}x twin: " + _met(g["ate_ok"]) if walking else "n/a"
        else:
            limit = TARGET_ATE_TWIN_OURS if s in INTERACTION_SCENARIOS else TARGET_ATE_TWIN
            ate_target = f"<= {limit:g}x {'occluded twin' if occ else 'twin'}: " + _met(g["ate_ok"])
        kp = g[g["kp_ok"].notna()]
        rows.append([g["sequence"].iloc[0], f"`{m}`", _per_seed(g["ate_over_twin"], 2, "x")]
                    + ([_per_seed(g["ate_over_occluded"], 2, "x") if m != BASELINE else "n/a"] if occ else [])
                    + [ate_target, _per_seed(kp["recall"], 3) if len(kp) else "n/a",
                       _per_seed(kp["static_precision"], 3) if len(kp) else "n/a", _met(g["kp_ok"])])
    seeds = ", ".join(str(x) for x in sorted(set(tc["seed"])))
    header = (["fr3 (synthetic)", "method", f"ATE / twin (seeds {seeds})"]
              + ([f"ATE / occluded twin (seeds {seeds})"] if occ else [])
              + ["ATE target: runs met", "recall", "static precision",
                 f"recall >= {TARGET_RECALL:g} at static precision >= {TARGET_STATIC_PRECISION:g}: runs met"])
    return _md(header, rows)


OCCLUDED_NOTE = ("The occluded twin is `oracle` run on the static twin with the dynamic sequence's truth as its "
                 "masks: the keypoints inside the people's (and moving objects') silhouettes are dropped and the "
                 "extraction budget refilled as in any filtered run, but nothing moves. Its ATE over the twin's is "
                 "what occlusion alone costs the engine; a method's ATE over the occluded twin's is what the moving "
                 "people cost beyond that (classification, silhouette corners, keyframes).")


def occluded_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    """Per scenario: the occluded twin's ATE (median over seeds) and each method's ATE on the dynamic sequence
    divided by it, with each method's per-seed (paired, ``metric_matrix``) ratios in brackets."""
    ms = [m for m in (methods or _methods(df))]
    dyn, twin = metric_matrix(df, "ate_rmse_m", 0), metric_matrix(df, "ate_rmse_m", 1)
    rows = []
    for s in _scenarios(df):
        occ = twin.loc[s, ORACLE] if ORACLE in twin.columns and s in twin.index else pd.Series(dtype=np.float64)
        o = _nanmedian(occ)
        cells = [LABELS.get(s, s), _num(o, 4) + _flag(df, s, ORACLE, 1)]
        for m in ms:
            ours = dyn.loc[s, m] if m in dyn.columns and s in dyn.index else pd.Series(dtype=np.float64)
            cell = _num(_ratio(_nanmedian(ours), o), 2, "x")
            pairs = (ours / occ).to_numpy(np.float64)  # aligned on the seed
            pairs = pairs[np.isfinite(pairs)]
            if len(pairs) > 1:
                cell += f" [{pairs.min():.2f}, {pairs.max():.2f}]"
            cells.append(cell + (_flag(df, s, m) if cell != "n/a" else ""))
        rows.append(cells)
    return _md(["fr3 (synthetic)", "occluded twin ATE `oracle` (m)"] + [f"`{m}` / occluded twin" for m in ms], rows)


OIM_METHODS = (FULL, "no-oim")


def oim_table(df: pd.DataFrame) -> pd.DataFrame:
    """What the Object Interaction Module buys, and where: per dynamic scenario, the ATE of ``d2slam`` and
    ``no-oim`` (medians over seeds) and their ratio, and each one's recall on the keypoints of moved objects (the
    people's masks do not cover them) and on every dynamic keypoint."""
    d = df[(df["twin"] == 0) & df["method"].isin(OIM_METHODS)]
    out = []
    for s in _scenarios(d):
        g = {m: d[(d["scenario"] == s) & (d["method"] == m)] for m in OIM_METHODS}
        if any(x.empty for x in g.values()):
            continue
        row = {"scenario": s, "sequence": LABELS.get(s, s)}
        for m, x in g.items():
            row[f"ate_{m}"] = _nanmedian(x["ate_rmse_m"])
            row[f"object_recall_{m}"] = _nanmedian(x["kp_object_recall"]) if "kp_object_recall" in x else np.nan
            row[f"recall_{m}"] = _nanmedian(x["kp_recall"])
        row["ratio"] = _ratio(row["ate_no-oim"], row[f"ate_{FULL}"])
        out.append(row)
    return pd.DataFrame(out)


def oim_markdown(df: pd.DataFrame) -> str:
    t = oim_table(df)
    if t.empty:
        return "_`d2slam` and `no-oim` were not both run._"
    rows = [[r["sequence"], _num(r[f"ate_{FULL}"], 4), _num(r["ate_no-oim"], 4), _num(r["ratio"], 2, "x"),
             _num(r[f"object_recall_{FULL}"], 3), _num(r["object_recall_no-oim"], 3), _num(r[f"recall_{FULL}"], 3),
             _num(r["recall_no-oim"], 3)] for _, r in t.iterrows()]
    return _md([_rowhead(df), "ATE `d2slam` (m)", "ATE `no-oim` (m)", "`no-oim` / `d2slam`",
                "moved-object recall `d2slam`", "`no-oim`", "dynamic recall `d2slam`", "`no-oim`"], rows)


def interaction_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    """The scenarios of our own (people moving objects): absolute ATE, ATE over the occluded twin, and the
    targets (``d2slam`` within TARGET_ATE_TWIN_OURS x the occluded twin; the masks-only baselines at least
    TARGET_MASKS_OVER_D2SLAM x ``d2slam``'s ATE)."""
    ours = df[df["scenario"].isin(INTERACTION_SCENARIOS)]
    ms = [m for m in (methods or _methods(df)) if m in set(ours["method"])]
    out = ["### ATE (m), absolute: median [min, max] over seeds", "", absolute_markdown(ours, "ate_rmse_m", 0, ms)]
    if _has_occluded(ours):
        out += ["", "### ATE relative to the occluded twin", "", occluded_markdown(ours, ms)]
    lines = []
    for s in _scenarios(ours):
        g = ours[(ours["scenario"] == s) & (ours["twin"] == 0)]
        full = _nanmedian(g[g["method"] == FULL]["ate_rmse_m"])
        for m in (ORBSLAM3_MASKED, "semantic"):
            other = _nanmedian(g[g["method"] == m]["ate_rmse_m"])
            r = _ratio(other, full)
            if math.isfinite(r):
                lines.append(f"- {LABELS.get(s, s)}: `{m}` / `{FULL}` = {r:.1f}x (target >= "
                             f"{TARGET_MASKS_OVER_D2SLAM:g}x: {'met' if r >= TARGET_MASKS_OVER_D2SLAM else 'not met'})")
    if lines:
        out += ["", "### The masks-only baselines against `d2slam` (medians over seeds)", "", *lines]
    return "\n".join(out)


def _num(v, nd: int, suffix: str = "") -> str:
    return f"{v:.{nd}f}{suffix}" if isinstance(v, (int, float, np.floating)) and math.isfinite(v) else "n/a"


def keypoint_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    """F1 (precision / recall) of "dynamic" keypoints, medians over seeds, dynamic sequences."""
    d = df[(df["twin"] == 0) & np.isfinite(df["kp_f1"].astype(np.float64))]
    ms = [m for m in (methods or _methods(df)) if m in set(d["method"])]
    if d.empty:
        return "_No keypoint metrics (they need synthetic sequences and a dynamics method)._"
    rows = []
    for s in _scenarios(d):
        r = [LABELS.get(s, s)]
        for m in ms:
            g = d[(d["scenario"] == s) & (d["method"] == m)]
            if g.empty:
                r.append("")
                continue
            r.append(f"{_nanmedian(g['kp_f1']):.3f} ({_nanmedian(g['kp_precision']):.3f} / "
                     f"{_nanmedian(g['kp_recall']):.3f})")
        rows.append(r)
    return _md([_rowhead(df)] + [f"`{m}`" for m in ms], rows)


def tracking_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    """Per sequence (dynamic, then twin) and method: median over seeds of 100 x frames_tracked / frames."""
    ms = [m for m in (methods or _methods(df)) if m in set(df["method"])]
    rows = []
    for twin in (0, 1):
        d = df[df["twin"] == twin]
        for s in _scenarios(d):
            r = [LABELS.get(s, s) + (" twin" if twin else "")]
            for m in ms:
                g = d[(d["scenario"] == s) & (d["method"] == m)]
                v = 100.0 * tracked_shares(g)
                v = v[np.isfinite(v)]
                r.append(f"{np.median(v):.0f}" if len(v) else "")
            rows.append(r)
    return _md([_rowhead(df)] + [f"`{m}`" for m in ms], rows)


def failures_markdown(df: pd.DataFrame) -> str:
    bad = df[~np.isfinite(df["ate_rmse_m"].astype(np.float64)) | ~df["status"].isin(["ok"])]
    if bad.empty:
        return "Every run has metrics (status ok)."
    rows = [[r["sequence"] + (" (twin)" if r["twin"] else "") + (" (online)" if r.get("online", 0) else ""),
             f"`{r['method']}`", str(r["seed"]), r["status"],
             str(r["error"]).replace("|", "/")[:200]] for _, r in bad.iterrows()]
    return _md(["sequence", "method", "seed", "status", "error"], rows)


ORACLE_NOTE = ("`oracle` is not a method but a ceiling: our engine with the keypoint truth as its filter (every "
               "keypoint on a person, or on an object while it moves, is dynamic; its F1 is 1 by construction). What "
               "separates a method from `oracle` is its classification; what separates `oracle` from the static twin "
               "is the engine with people in view: occlusion (the occluded twin measures it alone) and the moving "
               "people's silhouettes.")


def _frames_label(frames: int) -> str:
    """``--frames`` as a table says it: 0 means every frame of the sequence."""
    return "all" if int(frames) == 0 else str(int(frames))


def tables_markdown(df: pd.DataFrame, methods: list[str] | None = None, manifest: dict | None = None) -> str:
    """The whole ``tables.md``: Tables 1-3 over ``none`` and (when run) over ORB-SLAM3, absolute values, static-twin
    ratios, keypoint classification, the online runs beside their offline figures (when run), runs without metrics.
    Deterministic for a given runs table; the online table shows the online runs' figures, which depend on the
    machine's load (every other table: no timings)."""
    n_runs = len(df)
    online, df = df[df["online"] == 1], df[df["online"] == 0]
    online_part = (["", "## Online beside offline", "", online_note(manifest), "", online_markdown(online, df, methods)]
                   if not online.empty else [])
    methods = [m for m in (methods or _methods(df)) if m in set(df["method"])]
    real = df[df["scenario"].isin(REAL_SCENARIOS)]
    comp = df[df["scenario"].isin(COMPOSITE_SCENARIOS)]
    df = df[~df["scenario"].isin(REAL_SCENARIOS + COMPOSITE_SCENARIOS)]
    seeds = sorted(set(int(s) for s in df["seed"]))
    frames = sorted(set(int(f) for f in df["frames"]))
    if df.empty:  # real recordings (and the composites into them) only
        return "\n".join(["# D2SLAM study: results"] + _recordings_markdown(real, comp, methods) + online_part
                         + ["", "## Runs without metrics", "", failures_markdown(pd.concat([real, comp, online])),
                            ""])
    out = _header_markdown(df, methods, seeds, frames, manifest, n_runs)
    loops = df[df["scenario"].isin(LOOP_SCENARIOS)]
    df = df[~(df["scenario"].isin(LOOP_SCENARIOS) & (df["loop_closing"] == 0))]  # the others: loop closing on
    have_orb = ORBSLAM3 in methods and np.isfinite(df[df["method"] == ORBSLAM3]["ate_rmse_m"]).any()
    ours = df[df["scenario"].isin(INTERACTION_SCENARIOS)]
    df_all, df = df, df[~df["scenario"].isin(INTERACTION_SCENARIOS + LOOP_SCENARIOS)]  # the paper's: fr3
    out += _metric_tables_markdown(df, methods, have_orb)
    out += _ours_markdown(ours, loops, df_all, methods)
    out += _twins_markdown(df_all, methods)
    out += ["", "## Frames tracked (%), median over seeds", "",
            "ATE and RPE are computed on the tracked frames only (the TUM convention); a method that loses track "
            "early can show a small error over a short trajectory: read the errors with this table.", "",
            tracking_markdown(df_all, methods)]
    out += ["", "## Dynamic-keypoint classification: F1 (precision / recall), medians over seeds", "",
            keypoint_markdown(df_all, methods)]
    out += _recordings_markdown(real, comp, methods)
    out += online_part
    out += ["", "## Runs without metrics", "", failures_markdown(pd.concat([df_all, real, comp, online])), ""]
    return "\n".join(out)


def online_note(manifest: dict | None) -> str:
    """What the online table is made of: the protocol, the rate and the machine's load when the online runs
    started (from the manifest, when there is one)."""
    grid, timing = (manifest or {}).get("grid", {}), (manifest or {}).get("timing", {})
    rate = grid.get("online_rate_hz")
    at = ("" if rate is None else f" at {rate:g} Hz" if rate > 0 else " at their own timestamps")
    load = timing.get("online_load_average")
    return ("Online runs (`d2slam run --online`, docs/online.md): the frames arrive" + at + ", the segmenter runs in "
            "its own thread and the tracker drops the frames that arrive while it is busy; the real ORB-SLAM3 under "
            "the same camera. Each run's offline figures beside it (the paper's protocol: every frame segmented "
            "first, nothing dropped). ATE (m): median over seeds, online over the processed frames; online / offline: "
            "the ratio of the two medians; processed (%) and lag (ms, a frame's arrival to its pose: median and 95th "
            "percentile) medians over seeds. Online figures depend on the machine and its load: the study ran its "
            "online runs one at a time after the others"
            + (f" (load average {', '.join(f'{x:.2f}' for x in load)} when they started)" if load else "")
            + "; `d2slam run --deterministic` replays an engine run's schedule (`trajectories/<run>.schedule.npz`).")


def online_table(online: pd.DataFrame, offline: pd.DataFrame, methods: list[str] | None = None) -> pd.DataFrame:
    """Per scenario and method run online: the offline and online ATE (medians over seeds; offline: the dynamic
    sequence, loop closing on), their ratio, and the medians of the share of frames processed and of the lag."""
    offline = offline[(offline["twin"] == 0) & (offline["loop_closing"] == 1)]
    ms = [m for m in (methods or _methods(online)) if m in set(online["method"])]
    rows = []
    for s in _scenarios(online):
        for m in ms:
            on = online[(online["scenario"] == s) & (online["method"] == m)]
            if on.empty:
                continue
            off = offline[(offline["scenario"] == s) & (offline["method"] == m)]
            a_on, a_off = _nanmedian(on["ate_rmse_m"]), _nanmedian(off["ate_rmse_m"])
            rows.append({"scenario": s, "sequence": LABELS.get(s, s), "method": m, "runs": len(on),
                         "offline_ate_m": a_off, "online_ate_m": a_on, "ratio": _ratio(a_on, a_off),
                         "processed_pct": 100.0 * _nanmedian(on["processed_share"]),
                         "lag_ms_median": _nanmedian(on["lag_ms_median"]), "lag_ms_p95": _nanmedian(on["lag_ms_p95"])})
    return pd.DataFrame(rows, columns=["scenario", "sequence", "method", "runs", "offline_ate_m", "online_ate_m",
                                       "ratio", "processed_pct", "lag_ms_median", "lag_ms_p95"])


def online_markdown(online: pd.DataFrame, offline: pd.DataFrame, methods: list[str] | None = None) -> str:
    """The online table (:func:`online_table`) in Markdown; a cell with no figure is n/a."""
    t = online_table(online, offline, methods)
    rows = [[r["sequence"], f"`{r['method']}`", str(r["runs"]), _num(r["offline_ate_m"], 4),
             _num(r["online_ate_m"], 4), _num(r["ratio"], 2, "x"), _num(r["processed_pct"], 1),
             f"{_num(r['lag_ms_median'], 1)} / {_num(r['lag_ms_p95'], 1)}"] for _, r in t.iterrows()]
    return _md(["sequence", "method", "online runs", "offline ATE (m)", "online ATE (m)", "online / offline",
                "processed (%)", "lag p50 / p95 (ms)"], rows)


def _recordings_markdown(real: pd.DataFrame, comp: pd.DataFrame, methods: list[str] | None) -> list[str]:
    """The sections of the real recordings (``real``) and of the people composited into them (``comp``), those that
    have runs."""
    out = []
    if not real.empty:
        out += ["", "## Real recordings", "", REAL_NOTE, "", real_markdown(real, methods)]
    if not comp.empty:
        out += ["", "## Real background: people composited into a real recording", "", COMPOSITE_NOTE, "",
                real_background_markdown(comp, methods)]
    return out


def _header_markdown(df: pd.DataFrame, methods: list[str], seeds: list[int], frames: list[int],
                     manifest: dict | None, n_runs: int) -> list[str]:
    """The title and what the tables are made of: the sequences (``df``: the synthetic or fr3 runs), the seeds and
    frames of every run, the runs (``n_runs``: every row of the runs table, the real recordings' and the online
    runs' among them), the conventions, the config and code."""
    src = "real TUM RGB-D" if (df["source"] == "tum").all() else "synthetic TUM-like"
    others = n_runs - len(df)
    out = ["# D2SLAM study: results", "",
           f"Sequences: {src}, {', '.join(_frames_label(f) for f in frames)} frames; seeds "
           f"{', '.join(map(str, seeds))}; {n_runs} runs"
           + (f" ({len(df)} offline on these sequences, {others} on the real recordings, the composites and online, "
              "in their own sections below)" if others else "")
           + ". Generated by `d2slam study` from `runs.csv` (medians over seeds).",
           "Improvement over a baseline = (1 - ours / baseline) x 100 % (the paper's convention), computed on the "
           "medians over seeds; in brackets the range of the per-seed (paired) improvements.",
           "`none` is our engine with the keypoint filter off (the in-engine stand-in for ORB-SLAM3); `orbslam3` "
           f"is the real ORB-SLAM3 ({_orb_runs(df)}; not deterministic)"
           + (f"; `{ORBSLAM3_MASKED}` is the real ORB-SLAM3 on frames whose person masks (the masks the other methods "
              "get) are removed, depth 0 and RGB filled (docs/masking.md)" if ORBSLAM3_MASKED in methods else "")
           + ".", DAGGER_NOTE]
    if ORACLE in methods:
        out.insert(-1, ORACLE_NOTE)
    if manifest:
        out.append(f"Config hash `{manifest.get('config_hash', '')}`, git `{manifest.get('git', {}).get('commit', '')}`"
                   f", generator `{manifest.get('generator_version', '')}`.")
    return out


def _metric_tables_markdown(df: pd.DataFrame, methods: list[str], have_orb: bool) -> list[str]:
    """Tables 1-3 (ATE, RPE translation and rotation) on the paper's fr3 scenarios: the improvement over ``none``
    and (when it ran) over ORB-SLAM3, the absolute values, and the benchmark against the published record."""
    out = []
    for n, metric in enumerate(METRIC_COLUMNS, start=1):
        title, unit = TITLES[metric], UNITS[metric]
        out += ["", f"## Table {n}: {title} ({unit}), improvement over `{BASELINE}`", ""]
        if BASELINE in methods:
            out.append(improvement_markdown(df, metric, BASELINE, [m for m in methods if m not in REPEATED]))
        else:
            out.append(f"_`{BASELINE}` was not run: no improvement over it._")
        if have_orb:
            out += ["", f"### Table {n}b: {title}, improvement over real ORB-SLAM3 (`orbslam3`)", "",
                    improvement_markdown(df, metric, ORBSLAM3, methods)]
        out += ["", f"### Table {n}c: {title} ({unit}), absolute: median [min, max] over seeds", "",
                absolute_markdown(df, metric, 0, methods)]
    if have_orb and df["scenario"].isin(FR3_SCENARIOS).any():
        cal = calibration_table(df)
        if not cal.empty:
            out += ["", "## The benchmark against the published record on the real fr3 sequences", "",
                    "ORB-SLAM3's ATE and each method's improvement over `orbslam3` (paired by seed: median [min, max] "
                    "over seeds) beside the published values on the real TUM sequences (`d2slam bench calibration`; "
                    "d2slam.study.calibration).", "", calibration_markdown(cal), ""]
            out += [f"- {label}: {what}: {'met' if ok else 'not met'}" for label, what, ok in calibration_checks(cal)]
    return out


def _ours_markdown(ours: pd.DataFrame, loops: pd.DataFrame, df_all: pd.DataFrame, methods: list[str]) -> list[str]:
    """The scenarios beyond the paper's (people moving objects, the loop) and what the OIM buys."""
    out = []
    if not ours.empty:
        out += ["", "## Interaction scenarios (ours): people moving objects", "",
                "A person carries a box (`walking_carry`) or pushes a chair (`walking_push`) across the view while "
                "another walks; the segmenter labels the people, not the objects. These scenarios go beyond the "
                "paper's evaluation (no TUM counterpart).", "", interaction_markdown(ours, methods)]
    if not loops.empty:
        out += ["", "## Loop closing: the scenario with a return (ours)", "", LOOP_NOTE, "", loop_markdown(loops)]
    if set(OIM_METHODS) <= set(df_all["method"]):
        out += ["", "## What the OIM buys, and where", "",
                "`d2slam` with and without the Object Interaction Module (eq 9-10): ATE (medians over seeds) and the "
                "recall of the final classification on the keypoints of moved objects while they move (which the "
                "masks do not cover) and on every dynamic keypoint.", "", oim_markdown(df_all)]
    return out


def _twins_markdown(df: pd.DataFrame, methods: list[str]) -> list[str]:
    """The static twins' ATE, each method's ATE over the twin's, the targets run by run, and the occluded twin."""
    occluded = _has_occluded(df)
    out = []
    if (df["twin"] == 1).any():
        out += ["", "## Static twins: ATE (m), absolute", ""]
        if occluded:
            out += ["`oracle` on a static twin is the occluded twin (see below).", ""]
        out.append(absolute_markdown(df, "ate_rmse_m", 1, methods))
    out += ["", "## ATE relative to the engine's ATE on the static twin", "",
            "Median ATE of each method on the dynamic sequence / median ATE of `none` on its static twin (same "
            "camera path, no people). Targets: `d2slam` <= 1.2x; `none` >= 5x on the walking scenarios.",
            "", twin_markdown(df, [m for m in methods])]
    out += ["", "## Targets, run by run", "",
            ("Each dynamic run's ATE over the ATE of `none` on the same seed's static twin and over the same seed's "
             "occluded twin, its dynamic-keypoint recall and static precision, and on how many runs each target holds "
             "(`target_checks`): a keypoint filter is held to 1.2x the occluded twin (what a filter can reach on this "
             "engine), `none` to at least 5x the static twin on the walking scenarios." if occluded else
             "Each dynamic run's ATE over the ATE of `none` on the same seed's static twin, its dynamic-keypoint "
             "recall and static precision, and on how many runs each target holds (`target_checks`)."), "",
            targets_markdown(df, [m for m in TARGET_METHODS if m in methods])]
    if occluded:
        out += ["", "## ATE relative to the occluded twin", "", OCCLUDED_NOTE, "",
                "Median ATE of each method on the dynamic sequence / median ATE of the occluded twin; in brackets "
                "the range of the per-seed ratios.", "", occluded_markdown(df, [m for m in methods])]
    return out


REAL_NOTE = ("The real TUM fr1/rpy (723 frames of a Kinect turning fast about its own axes, with blur and lens "
             "distortion; nobody in view): every method once over all its frames, `orbslam3` and `orbslam3-masked` "
             "repeated (median [min, max]). Nothing moves, so a keypoint filter should cost nothing: each method's "
             "ATE over `none`'s beside it, and the published values of other systems below (different runs of "
             "other code: `data/published_real.csv`). Frames tracked counts the frames with a pose; a run below "
             f"{100 * TRACKED_FLAG:g} % of them is marked {DAGGER.strip()}.")


def real_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    """The real recordings: per method, frames tracked, ATE (m; ORB-SLAM3: median [min, max] of its repeats), ATE
    over `none`'s, RPE and ms per frame; then the published ATE of other systems on the same recordings."""
    rows = []
    for scenario in [s for s in REAL_SCENARIOS if s in set(df["scenario"])]:
        d = df[df["scenario"] == scenario]
        base = _nanmedian(d[d["method"] == BASELINE]["ate_rmse_m"].to_numpy(np.float64))
        for m in [m for m in (methods or _methods(d)) if m in set(d["method"])]:
            g = d[d["method"] == m]
            r = g.iloc[0]
            ate = float(r["ate_rmse_m"])
            cell = (f"{ate:.4f} [{float(r['ate_min_m']):.4f}, {float(r['ate_max_m']):.4f}]"
                    if m in REPEATED and np.isfinite(r.get("ate_min_m", np.nan)) else _num(ate, 4))
            rows.append([LABELS.get(scenario, scenario), f"`{m}`",
                         f"{int(r['frames_tracked'])} / {int(r['frames_tracked']) + int(r['frames_lost'])}"
                         + _flag(df, scenario, m), cell, f"{ate / base:.2f}x" if np.isfinite(base) and base > 0
                         and np.isfinite(ate) else "n/a", _num(float(r["rpe_trans_m"]), 4),
                         _num(float(r["ms_per_frame"]), 1)])
        for _, p in published_real()[lambda x: x["sequence"] == scenario].iterrows():
            rows.append([LABELS.get(scenario, scenario), f"{p['method']} (published: {p['source']})", "",
                         _num(float(p["ate_rmse_m"]), 3), "", "", ""])
    return _md(["sequence", "method", "frames tracked", "ATE (m)", "ATE / `none`", "RPE (m)", "ms / frame"], rows)


COMPOSITE_NOTE = ("The benchmark's people composited into the whole real fr1/rpy (`d2slam synth real_walking --on`; "
                  "docs/real_people.md): the background, the sensor and the camera motion are real, the people and "
                  "their per-pixel truth ours; one composite per seed. Its twins are the real recording itself: "
                  "`none` and `d2slam` on it, and the occluded twin, `oracle` on it with the composite's truth as its "
                  "masks (the people's silhouettes cut out of the real frames: what occlusion alone costs). ATE (m): "
                  "median [min, max] over seeds (`orbslam3`, `orbslam3-masked`: each seed's the median of its "
                  "repeats); ATE / occluded twin: the per-seed ratios, median [min, max]. Target: `d2slam` within "
                  f"{TARGET_ATE_TWIN:g}x the occluded twin on every run; `none` and the real ORB-SLAM3 beside it "
                  "measure what handling the dynamics is worth on a real background.")


def real_background_markdown(df: pd.DataFrame, methods: list[str] | None = None) -> str:
    """The composites (``COMPOSITE_SCENARIOS``): per sequence, the twins on the real recording (``none``,
    ``d2slam``, the occluded twin), then every method on the composite: frames tracked (median share), ATE (median
    [min, max] over seeds), ATE over the same seed's occluded twin; then the target line of ``d2slam``."""
    rows, lines = [], []
    for scenario in [s for s in COMPOSITE_SCENARIOS if s in set(df["scenario"])]:
        d = df[df["scenario"] == scenario]
        occ = d[(d["twin"] == 1) & (d["method"] == ORACLE)].set_index("seed")["ate_rmse_m"]
        label = LABELS.get(scenario, scenario)
        for twin in (1, 0):
            dt = d[d["twin"] == twin]
            for m in [m for m in (methods or _methods(dt)) if m in set(dt["method"])]:
                g = dt[dt["method"] == m]
                ate = g["ate_rmse_m"].to_numpy(np.float64)
                ratios = [float(a) / float(occ[sd]) if sd in occ.index and float(occ[sd]) > 0 else np.nan
                          for sd, a in zip(g["seed"], ate)]
                what = (f"real recording: `{m}`" + (" (occluded twin)" if m == ORACLE else "")) if twin else f"`{m}`"
                share = tracked_fraction(d, scenario, m, twin)
                rows.append([label, what, _num(100 * share, 1) + _flag(d, scenario, m, twin),
                             spread_cell(ate, 4), spread_cell(ratios, 2)])
        g = d[(d["twin"] == 0) & (d["method"] == FULL)]
        if len(g) and len(occ):
            r = np.array([float(a) / float(occ[sd]) if sd in occ.index else np.nan
                          for sd, a in zip(g["seed"], g["ate_rmse_m"])])
            ok = int((r <= TARGET_ATE_TWIN).sum())
            lines.append(f"- {label}: `{FULL}` within {TARGET_ATE_TWIN:g}x the occluded twin on {ok} of {len(r)} runs"
                         f" ({', '.join(_num(v, 2, 'x') for v in r)}): {'met' if ok == len(r) else 'not met'}")
    table = _md(["sequence", "method", "frames tracked (%)", "ATE (m)", "ATE / occluded twin"], rows)
    return table + ("\n\n" + "\n".join(lines) if lines else "")


LOOP_NOTE = ("`office_loop`: the camera walks one loop round the office, returns to where it started and goes on "
             "round part of the loop; people walk, stand and sit in view, also at the place of return. Each method "
             "with the engine's loop closing on and off: ATE (m) median [min, max] over seeds, the paired ratio on / "
             "off (median [min, max] of the per-seed ratios), loops detected, true and false (summed over seeds; "
             f"false: the loop's relative pose is more than {100 * EvalConfig.loop_true_max_m:g} cm or "
             f"{EvalConfig.loop_true_max_deg:g} deg off the truth), and the closest call: the highest score a wrong "
             "place-recognition candidate reached over its keyframe's minimum score (max over seeds; none: no "
             "wrong candidate).")


def loop_markdown(df: pd.DataFrame) -> str:
    """The scenario with a return: per (sequence, method), loop closing on and off (see ``LOOP_NOTE``)."""
    rows = []
    for s in _scenarios(df):
        for twin in (0, 1):
            d = df[(df["scenario"] == s) & (df["twin"] == twin)]
            for m in _methods(d):
                on = d[(d["method"] == m) & (d["loop_closing"] == 1)]
                off = d[(d["method"] == m) & (d["loop_closing"] == 0)]
                pair = on.set_index("seed")["ate_rmse_m"] / off.set_index("seed")["ate_rmse_m"] \
                    if not on.empty and not off.empty else pd.Series(dtype=np.float64)
                label = LABELS.get(s, s) + (" twin" if twin else "")

                def count(c):
                    v = on[c].to_numpy(np.float64)
                    return str(int(np.nansum(v))) if np.isfinite(v).any() else "n/a"

                ratio = on["loop_closest_ratio"].to_numpy(np.float64)
                rows.append([label, f"`{m}`", spread_cell(on["ate_rmse_m"], 4, missing="failed") if len(on) else "",
                             spread_cell(off["ate_rmse_m"], 4, missing="failed") if len(off) else "",
                             spread_cell(pair.to_numpy(np.float64), 2) if len(pair) else "",
                             count("loops"), count("loops_true"), count("loops_false"),
                             f"{np.nanmax(ratio):.2f}" if np.isfinite(ratio).any() else "none"])
    return _md(["sequence", "method", "ATE on (m)", "ATE off (m)", "on / off", "loops", "true", "false",
                "closest call"], rows)


BASELINE_METHODS = (ORBSLAM3, ORBSLAM3_MASKED, BASELINE, FULL, ORACLE)


def baseline_comparison(df: pd.DataFrame, methods: tuple = BASELINE_METHODS) -> pd.DataFrame:
    """The practitioner's baselines beside ours on the dynamic sequences: per scenario and method, the median
    [min, max] over seeds of ATE (m) and translational RPE (m), the median share of frames tracked (%) and the median
    ms per frame (a timing: it depends on the machine and its load, so it stays out of ``tables.md``)."""
    d = df[df["twin"] == 0]
    rows = []
    for s in _scenarios(d):
        for m in methods:
            g = d[(d["scenario"] == s) & (d["method"] == m)]
            if g.empty:
                continue
            tracked = 100.0 * tracked_shares(g)
            rows.append({"scenario": LABELS.get(s, s), "method": m,
                         "ATE m": spread_cell(g["ate_rmse_m"].to_numpy(np.float64), 4),
                         "RPE m": spread_cell(g["rpe_trans_m"].to_numpy(np.float64), 4),
                         "tracked %": f"{_nanmedian(tracked):.0f}",
                         "ms/frame": f"{_nanmedian(g['ms_per_frame'].to_numpy(np.float64)):.1f}"})
    return pd.DataFrame(rows)


# ------------------------------------------------------------------------------------------------------------
# Ablation tables (notebooks/07_ablations.ipynb): one row per sequence and method, spreads over seeds
# ------------------------------------------------------------------------------------------------------------
MODULE_METRICS = ("f1", "recall", "precision", "static_precision")


def spread_cell(values, nd: int = 4, missing: str = "n/a") -> str:
    """``median [min, max]`` of the finite values (just the median for one value); ``missing`` when none is
    finite, and ``(k failed)`` appended when ``k`` of them are not finite but some are."""
    v = np.asarray(values, dtype=np.float64).reshape(-1)
    ok = v[np.isfinite(v)]
    if not len(ok):
        return missing if len(v) else ""
    cell = f"{np.median(ok):.{nd}f}"
    if len(ok) > 1:
        cell += f" [{ok.min():.{nd}f}, {ok.max():.{nd}f}]"
    if len(ok) < len(v):
        cell += f" ({len(v) - len(ok)} n/a)"
    return cell


def ablation_table(df: pd.DataFrame, methods: list[str] | None = None, twin: int = 0) -> pd.DataFrame:
    """Rows (sequence, method) in grid order; columns as ``median [min, max]`` over seeds: ATE (m, † when the
    method tracked < 90 % of the frames), keypoint F1, recall and static precision of "dynamic", frames tracked
    (of the sequence's frames) and runs with an ATE / runs. ``none`` has no keypoint F1 (it predicts nothing
    dynamic: precision undefined), shown ``n/a``."""
    d = df[df["twin"] == twin]
    ms = [m for m in (methods or _methods(d)) if m in set(d["method"])]
    rows, index = [], []
    for s in _scenarios(d):
        for m in ms:
            g = d[(d["scenario"] == s) & (d["method"] == m)]
            if g.empty:
                continue
            ate = spread_cell(g["ate_rmse_m"], 4, missing="failed")
            if np.isfinite(g["ate_rmse_m"].to_numpy(np.float64)).any():
                ate += _flag(df, s, m, twin)
            frames = sorted(set(int(f) for f in g["frames"]))
            rows.append({"ATE (m)": ate,
                         "kp F1": spread_cell(g["kp_f1"], 3),
                         "kp recall": spread_cell(g["kp_recall"], 3),
                         "static precision": spread_cell(g["kp_static_precision"], 3),
                         "frames tracked": spread_cell(g["frames_tracked"], 0) + " / "
                                           + "/".join(_frames_label(f) for f in frames),
                         "runs ok": f"{int(np.isfinite(g['ate_rmse_m'].to_numpy(np.float64)).sum())}/{len(g)}"})
            index.append((LABELS.get(s, s) + (" twin" if twin else ""), m))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["sequence", "method"])
                        if index else None)


def read_run_records(out) -> list[dict]:
    """The per-run JSON records of a finished study (``out/runs/<run_id>.json``: run, row, keypoints, stage_ms), in
    the order of ``out/runs.csv``. A run whose record is missing is skipped; an unreadable one is a D2SlamError
    naming the file."""
    out = Path(out)
    df = read_runs_csv(out / "runs.csv")
    records = []
    for r in df.itertuples(index=False):
        spec = RunSpec(r.scenario, r.method, int(r.seed), int(r.frames), bool(r.twin), r.source, bool(r.loop_closing),
                       bool(r.online))
        path = out / "runs" / f"{spec.run_id}.json"
        if not path.is_file():
            continue
        try:
            records.append(json.loads(path.read_text()))
        except (OSError, json.JSONDecodeError) as exc:
            raise D2SlamError(f"unreadable run record: {exc}", path=path) from exc
    return records


def module_metrics(records: list[dict]) -> pd.DataFrame:
    """Long table of the classifier's per-module keypoint metrics: one row per (run, module) with the run's
    scenario, sequence, twin, method, seed, frames and the module's tp/fp/fn/tn, precision, recall, f1,
    static_precision (NaN where undefined). Modules in the pipeline's order (semantic, geometric, pose, fusion,
    bayes, oim, final); a method runs only some of them (``none``: only ``final``)."""
    cols = ["scenario", "sequence", "twin", "method", "seed", "frames", "module", "tp", "fp", "fn", "tn",
            *MODULE_METRICS]
    rows = []
    for rec in records:
        run = rec.get("run") or {}
        mods = (rec.get("keypoints") or {}).get("modules") or {}
        for name, m in mods.items():
            row = {"scenario": run.get("scenario"), "sequence": LABELS.get(run.get("scenario"), run.get("scenario")),
                   "twin": int(bool(run.get("twin"))), "method": run.get("method"), "seed": run.get("seed"),
                   "frames": run.get("frames"), "module": name}
            for k in ("tp", "fp", "fn", "tn", *MODULE_METRICS):
                v = m.get(k)
                row[k] = np.nan if v is None else float(v)
            rows.append(row)
    return pd.DataFrame(rows, columns=cols)


def module_table(mod: pd.DataFrame, method: str = FULL, twin: int = 0) -> pd.DataFrame:
    """One method's per-module keypoint metrics: rows (sequence, module), columns F1, recall, precision and static
    precision as ``median [min, max]`` over seeds (from :func:`module_metrics`)."""
    d = mod[(mod["method"] == method) & (mod["twin"] == twin)]
    rows, index = [], []
    for s in _scenarios(d):
        g = d[d["scenario"] == s]
        for name in dict.fromkeys(g["module"]):
            h = g[g["module"] == name]
            rows.append({k.replace("_", " "): spread_cell(h[k], 3) for k in MODULE_METRICS})
            index.append((LABELS.get(s, s) + (" twin" if twin else ""), name))
    return pd.DataFrame(rows, index=pd.MultiIndex.from_tuples(index, names=["sequence", "module"])
                        if index else None)
