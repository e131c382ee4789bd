"""The paper's published numbers (``data/paper_tables.csv``: Tables 1-3 as improvement % over ORB-SLAM3;
``data/published_absolute.csv``: absolute ATE of ORB-SLAM3 and others, with sources) and what they imply.

The paper gives only improvements. Under a published ORB-SLAM3 ATE ``b``, an improvement ``p`` % implies an
absolute ATE ``b (1 - p / 100)``; conversely a method's published absolute ATE ``a`` and its improvement ``p``
imply the baseline the paper used, ``a / (1 - p / 100)``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from d2slam.errors import D2SlamError
from d2slam.paths import REPO_ROOT
from d2slam.study.grid import FR3_SCENARIOS, LABELS
from d2slam.study.improvement import improvement_table

SEQUENCES = [LABELS[s] for s in FR3_SCENARIOS]  # w/xyz, w/half, w/static, w/rpy, s/static
PAPER_METHODS = ["DynaSLAM", "DS-SLAM", "DP-SLAM", "D2SLAM"]
METRICS = {1: "ate", 2: "rpe_trans", 3: "rpe_rot"}
STUDY_METRIC = {"ate": "ate_rmse_m", "rpe_trans": "rpe_trans_m", "rpe_rot": "rpe_rot_deg"}


def data_dir() -> Path:
    return REPO_ROOT / "data"


def _read(name: str, columns: list[str]) -> pd.DataFrame:
    path = data_dir() / name
    if not path.is_file():
        raise D2SlamError("published-numbers file not found", path=path)
    df = pd.read_csv(path, comment="#")
    missing = [c for c in columns if c not in df.columns]
    if missing:
        raise D2SlamError(f"missing columns {', '.join(missing)}", path=path)
    return df


def paper_tables() -> pd.DataFrame:
    """Long form: table, metric, sequence, method, improvement_pct."""
    return _read("paper_tables.csv", ["table", "metric", "sequence", "method", "improvement_pct"])


def paper_table(table: int) -> pd.DataFrame:
    """Table 1, 2 or 3 in the paper's layout: rows sequences, columns methods (improvement %)."""
    df = paper_tables()
    d = df[df["table"] == table]
    if d.empty:
        raise D2SlamError(f"no table {table} in paper_tables.csv", path=data_dir() / "paper_tables.csv")
    return d.pivot(index="sequence", columns="method", values="improvement_pct").reindex(
        index=SEQUENCES, columns=PAPER_METHODS)


def published_absolute() -> pd.DataFrame:
    """Long form: method, source, sequence, ate_rmse_m (NaN = not reported)."""
    return _read("published_absolute.csv", ["method", "source", "sequence", "ate_rmse_m"])


def published_real() -> pd.DataFrame:
    """Long form (method, source, sequence, ate_rmse_m): published ATE on the study's real recordings
    (``data/published_real.csv``; ``sequence`` is the study's scenario name)."""
    return _read("published_real.csv", ["method", "source", "sequence", "ate_rmse_m"])


def orbslam3_baselines() -> pd.DataFrame:
    """Rows sequences, columns the published ORB-SLAM3 sources: absolute ATE (m)."""
    d = published_absolute()
    d = d[d["method"] == "ORB-SLAM3"]
    return d.pivot(index="sequence", columns="source", values="ate_rmse_m").reindex(index=SEQUENCES)


def implied_absolute(table: int = 1) -> pd.DataFrame:
    """The paper's table ``table`` turned into absolute errors under each published ORB-SLAM3 ATE: rows
    sequences, columns (source, method). Only Table 1 (ATE) has published baselines."""
    if table != 1:
        raise D2SlamError("only the ATE (Table 1) has published absolute ORB-SLAM3 values")
    imp = paper_table(1)
    base = orbslam3_baselines()
    parts = {src: base[src].to_numpy()[:, None] * (1.0 - imp.to_numpy() / 100.0) for src in base.columns}
    frames = {src: pd.DataFrame(v, index=imp.index, columns=imp.columns) for src, v in parts.items()}
    return pd.concat(frames, axis=1)


def implied_baseline() -> pd.DataFrame:
    """The ORB-SLAM3 ATE each method's own published absolute ATE implies through the paper's Table 1:
    ``a / (1 - p / 100)``; rows sequences, columns methods present in both files."""
    imp = paper_table(1)
    pub = published_absolute()
    out = {}
    for m in PAPER_METHODS:
        d = pub[pub["method"] == m]
        if d.empty:
            continue
        a = d.set_index("sequence")["ate_rmse_m"].reindex(SEQUENCES).to_numpy(np.float64)
        p = imp[m].to_numpy(np.float64)
        with np.errstate(divide="ignore", invalid="ignore"):
            out[m] = np.where(p < 100.0, a / (1.0 - p / 100.0), np.nan)
    return pd.DataFrame(out, index=SEQUENCES)


def side_by_side(runs: pd.DataFrame, table: int, ours: str = "d2slam", baseline: str = "none") -> pd.DataFrame:
    """The paper's D2SLAM improvement next to ours (median over seeds, over ``baseline``) for Table ``table``."""
    metric = STUDY_METRIC[METRICS[table]]
    scen, _, cells = improvement_table(runs, metric, baseline, [ours])
    paper = paper_table(table)["D2SLAM"]
    ours_col = {LABELS[s]: (cells[(s, ours)][0] if cells.get((s, ours)) else np.nan) for s in scen}
    return pd.DataFrame({"paper D2SLAM vs ORB-SLAM3 (%)": paper,
                         f"ours `{ours}` vs `{baseline}` (%)": pd.Series(ours_col).reindex(SEQUENCES)})
