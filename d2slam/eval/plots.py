"""Trajectory plot against ground truth (a matplotlib Figure outside pyplot, PNG by Agg: no display needed, and
the caller's backend, e.g. a notebook's inline plots, is left untouched), and the styles every figure of the
library and the notebooks shares:

* :data:`METHOD_COLOURS` / :func:`method_colour`: one fixed colour per method (Okabe-Ito's and Paul Tol's
  colour-blind-safe colours), the same in every figure; other names get a fixed colour derived from the name;
* :data:`GROUND_TRUTH`: ground truth as a thin black dashed line drawn above the estimates;
* :func:`legend`: a legend without entries for what drew nothing (a class with no points).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from d2slam.data.base import Trajectory
from d2slam.errors import D2SlamError
from d2slam.eval.trajectory import aligned_estimate
from d2slam.outputs import save_figure

# Every method of d2slam.run.methods and the real ORB-SLAM3 runs; related methods in related hues (ORB-SLAM3 oranges,
# the D2SLAM variants blues, its ablations purples / greens / yellows). Pairwise CIELAB distance >= 20
# (tests/test_plots.py).
METHOD_COLOURS = {
    "none": "#7F7F7F",
    "orbslam3": "#E69F00",
    "orbslam3-masked": "#D55E00",
    "oracle": "#009E73",
    "d2slam": "#0072B2",
    "d2slam-flow": "#56B4E9",
    "d2slam-sim": "#332288",
    "no-depth": "#CC79A7",
    "no-oim": "#882255",
    "no-bayes": "#999933",
    "semantic": "#DDCC77",
    "geometric": "#117733",
}
# Names outside the map: one of these, picked by a digest of the name (the same on every run and machine).
OTHER_COLOURS = ("#1F77B4", "#FF7F0E", "#2CA02C", "#D62728", "#9467BD", "#8C564B", "#E377C2", "#BCBD22",
                 "#17BECF", "#AEC7E8", "#FFBB78", "#98DF8A", "#FF9896", "#C5B0D5", "#C49C94", "#F7B6D2")
# Ground truth: thin, black, dashed, above every estimate (zorder).
GROUND_TRUTH = {"color": "k", "lw": 0.9, "ls": "--", "zorder": 10, "label": "ground truth"}


def method_colour(name: str) -> str:
    """The colour of method ``name`` in every figure (:data:`METHOD_COLOURS`, else a fixed one from the name)."""
    if name in METHOD_COLOURS:
        return METHOD_COLOURS[name]
    return OTHER_COLOURS[int(hashlib.sha256(str(name).encode()).hexdigest(), 16) % len(OTHER_COLOURS)]


def _drew_something(handle) -> bool:
    if hasattr(handle, "get_xydata"):  # a line
        return len(handle.get_xydata()) > 0
    if hasattr(handle, "get_offsets"):  # a scatter
        return len(handle.get_offsets()) > 0
    if hasattr(handle, "patches"):  # bars
        return any(np.isfinite(p.get_height()) and np.isfinite(p.get_width()) for p in handle.patches)
    return True


def legend(ax, **kwargs):
    """``ax.legend(**kwargs)`` without the entries of artists that drew nothing (an empty class, an all-NaN bar
    series); None (and no legend) when nothing is left."""
    handles, labels = ax.get_legend_handles_labels()
    kept = [(h, lab) for h, lab in zip(handles, labels) if _drew_something(h)]
    if not kept:
        return None
    return ax.legend([h for h, _ in kept], [lab for _, lab in kept], **kwargs)


def plot_trajectory(groundtruth: Trajectory, estimate: Trajectory, out: str | Path, title: str = "",
                    metrics: dict | None = None) -> Path:
    """Top (x-y) and side (x-z) views of the SE(3)-aligned estimate and the ground truth (drawn above it), saved
    as PNG."""
    from matplotlib.figure import Figure  # outside pyplot: PNG by Agg, the caller's backend untouched

    out = Path(out)
    if not out.parent.is_dir():
        raise D2SlamError("output folder does not exist", path=out.parent)
    gt, est, _ = aligned_estimate(groundtruth, estimate)
    fig = Figure(figsize=(10, 4.5))
    axes = fig.subplots(1, 2)
    for ax, (i, j, name) in zip(axes, [(0, 1, "x-y"), (0, 2, "x-z")]):
        ax.plot(est[:, i], est[:, j], color="tab:red", lw=1.2, label="estimate (SE(3)-aligned)")
        ax.plot(groundtruth.poses[:, i, 3], groundtruth.poses[:, j, 3], **GROUND_TRUTH)
        ax.set_xlabel(f"{'xyz'[i]} (m)")
        ax.set_ylabel(f"{'xyz'[j]} (m)")
        ax.set_title(name)
        ax.axis("equal")
        ax.grid(alpha=0.3)
    legend(axes[0], loc="best", fontsize=8)
    if metrics:
        title = (title + "  " if title else "") + "ATE {:.2f} cm, RPE {:.2f} cm / {:.2f} deg".format(
            100 * metrics["ate_rmse_m"], 100 * metrics["rpe_trans_m"], metrics["rpe_rot_deg"])
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    save_figure(fig, out, dpi=100)
    return out
