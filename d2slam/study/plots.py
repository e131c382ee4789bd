"""The study's figures (PNG by Agg, drawn on matplotlib figures outside pyplot): trajectories, ATE bars with spread,
keypoint F1 per module, runtime breakdown. Each method has its colour in every figure and the ground truth is drawn
above the estimates (:mod:`d2slam.eval.plots`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from d2slam.eval.plots import GROUND_TRUTH, legend, method_colour
from d2slam.outputs import save_figure
from d2slam.run.sequence import STAGES
from d2slam.study.grid import LABELS, SCENARIOS


def _subplots(*grid, **kw):
    """A figure outside pyplot (``matplotlib.figure.Figure``): saved as PNG by Agg without switching the caller's
    backend (a notebook's inline plots keep working after the study's plots)."""
    from matplotlib.figure import Figure

    fig = Figure(figsize=kw.pop("figsize", None))
    return fig, fig.subplots(*grid, **kw)


def _scen(df) -> list[str]:
    present = set(df["scenario"])
    return [s for s in SCENARIOS if s in present] + sorted(present - set(SCENARIOS))


def plot_trajectories(aligned: dict, out: Path, seed: int) -> Path | None:
    """One panel per sequence (x-y, top view): each method's SE(3)-aligned estimate in its colour and the ground truth
    above them, one seed. ``aligned``: {(scenario, twin, method): (gt_xyz, est_xyz)}."""
    keys = sorted({(s, t) for (s, t, _m) in aligned},
                  key=lambda k: (SCENARIOS.index(k[0]) if k[0] in SCENARIOS else 99, k[1]))
    if not keys:
        return None
    n = len(keys)
    cols = min(3, n)
    rows = (n + cols - 1) // cols
    fig, axes = _subplots(rows, cols, figsize=(5 * cols, 4.3 * rows), squeeze=False)
    for ax, (s, t) in zip(axes.flat, keys):
        runs = [(m, gt, est) for (s2, t2, m), (gt, est) in aligned.items() if (s2, t2) == (s, t)]
        gt = max((g for _, g, _ in runs), key=len)  # the ground truth matched by the longest tracked run
        for m, _, est in runs:
            ax.plot(est[:, 0], est[:, 1], lw=1, color=method_colour(m), label=m)
        ax.plot(gt[:, 0], gt[:, 1], **GROUND_TRUTH)
        ax.set_title(f"{LABELS.get(s, s)}{' twin' if t else ''} (seed {seed})")
        ax.set_xlabel("x (m)")
        ax.set_ylabel("y (m)")
        ax.axis("equal")
        ax.grid(alpha=0.3)
        legend(ax, fontsize=7)
    for ax in list(axes.flat)[n:]:
        ax.axis("off")
    fig.tight_layout()
    save_figure(fig, out, dpi=90)
    return out


def plot_ate_bars(summary: pd.DataFrame, out: Path, methods: list[str]) -> Path | None:
    """Median ATE per sequence and method (dynamic sequences), error bars min-max over seeds, log scale."""
    return plot_summary_bars(summary, out, methods, "ate_rmse_m",
                             "ATE RMSE (m), median over seeds, bars min-max", log=True)


def plot_summary_bars(summary: pd.DataFrame, out: Path, methods: list[str], metric: str, ylabel: str,
                      log: bool = False, ylim: tuple | None = None) -> Path | None:
    """Bars of ``<metric>_median`` per sequence (dynamic sequences) and method from a ``summary.csv`` frame, error
    bars ``<metric>_min`` - ``<metric>_max`` (over seeds); None when no finite median. Missing cells stay empty."""
    d = summary[summary["twin"] == 0]
    col = f"{metric}_median"
    if d.empty or col not in d or not np.isfinite(d[col].to_numpy(np.float64)).any():
        return None
    scen = _scen(d)
    ms = [m for m in methods if m in set(d["method"])]
    width = 0.8 / max(len(ms), 1)
    fig, ax = _subplots(figsize=(max(6, 1.6 * len(scen) * max(1, len(ms) / 3)), 4.5))
    x = np.arange(len(scen))
    for k, m in enumerate(ms):
        med, lo, hi = [], [], []
        for s in scen:
            r = d[(d["scenario"] == s) & (d["method"] == m)]
            med.append(float(r[col].iloc[0]) if len(r) else np.nan)
            lo.append(float(r[f"{metric}_min"].iloc[0]) if len(r) else np.nan)
            hi.append(float(r[f"{metric}_max"].iloc[0]) if len(r) else np.nan)
        med, lo, hi = map(np.asarray, (med, lo, hi))
        yerr = np.nan_to_num(np.stack([med - lo, hi - med]))
        ax.bar(x + (k - (len(ms) - 1) / 2) * width, med, width, yerr=yerr, capsize=2, label=m,
               color=method_colour(m))
    ax.set_xticks(x, [LABELS.get(s, s) for s in scen])
    ax.set_ylabel(ylabel)
    if log:
        ax.set_yscale("log")
    if ylim is not None:
        ax.set_ylim(*ylim)
    ax.grid(axis="y", alpha=0.3)
    legend(ax, fontsize=7, ncol=min(4, len(ms)))
    fig.tight_layout()
    save_figure(fig, out, dpi=90)
    return out


def plot_keypoint_f1(module_f1: pd.DataFrame, out: Path) -> Path | None:
    """F1 of "dynamic" per module of the classifier (rows: method, module, f1 = median over runs)."""
    if module_f1.empty:
        return None
    methods = list(dict.fromkeys(module_f1["method"]))
    modules = list(dict.fromkeys(module_f1["module"]))
    width = 0.8 / max(len(modules), 1)
    fig, ax = _subplots(figsize=(max(6, 1.4 * len(methods)), 4.2))
    x = np.arange(len(methods))
    for k, mod in enumerate(modules):
        vals = [module_f1[(module_f1["method"] == m) & (module_f1["module"] == mod)]["f1"] for m in methods]
        vals = [float(v.iloc[0]) if len(v) else np.nan for v in vals]
        ax.bar(x + (k - (len(modules) - 1) / 2) * width, vals, width, label=mod)
    ax.set_xticks(x, methods)
    ax.set_ylim(0, 1)
    ax.set_ylabel("F1 of 'dynamic' (median over runs)")
    ax.grid(axis="y", alpha=0.3)
    legend(ax, fontsize=7, ncol=3)
    fig.tight_layout()
    save_figure(fig, out, dpi=90)
    return out


def plot_runtime(df: pd.DataFrame, out: Path, methods: list[str]) -> Path | None:
    """Stacked mean milliseconds per frame and stage, per method (median over runs)."""
    stages = [c for c in (f"ms_{s}" for s in STAGES) if c in df]
    d = df[np.isfinite(df["ms_per_frame"].astype(float))]
    ms = [m for m in methods if m in set(d["method"])]
    if d.empty or not ms:
        return None
    fig, ax = _subplots(figsize=(max(6, 1.2 * len(ms)), 4.2))
    bottom = np.zeros(len(ms))
    for st in stages:
        v = np.array([np.nan_to_num(np.nanmedian(d[d["method"] == m][st].to_numpy(float)))
                      if np.isfinite(d[d["method"] == m][st].to_numpy(float)).any() else 0.0 for m in ms])
        ax.bar(ms, v, bottom=bottom, label=st[3:])
        bottom += v
    other = np.array([np.nanmedian(d[d["method"] == m]["ms_per_frame"].to_numpy(float)) for m in ms]) - bottom
    ax.bar(ms, np.clip(other, 0, None), bottom=bottom, label="other / ORB-SLAM3 total", color="0.7")
    ax.set_ylabel("ms per frame (median over runs)")
    ax.grid(axis="y", alpha=0.3)
    legend(ax, fontsize=7)
    fig.tight_layout()
    save_figure(fig, out, dpi=90)
    return out
