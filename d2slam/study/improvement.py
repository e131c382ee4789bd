"""Improvement over a baseline, as in the paper's tables: ``(1 - ours / baseline) x 100`` %
(docs/design.md#improvement-over-a-baseline), of the medians over seeds, with the range of the per-seed (paired:
same sequence) improvements. Shared by the study's tables (``tables``), the paper's figures beside ours (``paper``)
and the calibration against the published record (``calibration``)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd

from d2slam.study.grid import BASELINE, SCENARIOS


def improvement(ours, baseline):
    """``(1 - ours / baseline) x 100`` (%), elementwise; NaN where either is missing or the baseline is not > 0."""
    ours = np.asarray(ours, dtype=np.float64)
    base = np.asarray(baseline, dtype=np.float64)
    with np.errstate(divide="ignore", invalid="ignore"):
        out = (1.0 - ours / base) * 100.0
    out = np.where(np.isfinite(ours) & np.isfinite(base) & (base > 0), out, np.nan)
    return out if out.ndim else float(out)


def scenarios_of(df) -> list[str]:
    present = set(df["scenario"])
    return [s for s in SCENARIOS if s in present] + sorted(present - set(SCENARIOS))


def methods_of(df) -> list[str]:
    return list(dict.fromkeys(df["method"]))


def metric_matrix(df: pd.DataFrame, metric: str, twin: int = 0) -> pd.DataFrame:
    """Per-seed values: index (scenario, seed), columns methods (NaN where a run has no metric)."""
    d = df[df["twin"] == twin]
    if d.empty:
        return pd.DataFrame()
    return d.pivot_table(index=["scenario", "seed"], columns="method", values=metric, aggfunc="first",
                         dropna=False)


def improvement_table(df: pd.DataFrame, metric: str, baseline: str = BASELINE, methods: list[str] | None = None):
    """Rows scenarios, columns methods: ``(improvement of the medians, min, max of the per-seed improvements)``,
    or None where not computable. Returns (scenarios, methods, cells dict)."""
    scen = scenarios_of(df[df["twin"] == 0])
    methods = [m for m in (methods or methods_of(df)) if m != baseline]
    mat = metric_matrix(df, metric)
    cells = {}
    for s in scen:
        for m in methods:
            cells[(s, m)] = None
            if mat.empty or m not in mat.columns or baseline not in mat.columns or s not in mat.index:
                continue
            ours = mat.loc[s, m].to_numpy(np.float64)
            base = mat.loc[s, baseline].to_numpy(np.float64)
            med_o, med_b = nanmedian(ours), nanmedian(base)
            imp = improvement(med_o, med_b)
            if not math.isfinite(imp):
                continue
            per_seed = improvement(ours, base)
            per_seed = per_seed[np.isfinite(per_seed)]
            cells[(s, m)] = (imp, float(per_seed.min()) if len(per_seed) else np.nan,
                             float(per_seed.max()) if len(per_seed) else np.nan, len(per_seed))
    return scen, methods, cells


def nanmedian(v) -> float:
    v = np.asarray(v, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(np.median(v)) if len(v) else float("nan")
