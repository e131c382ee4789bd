"""Trajectory plot against ground truth (a matplotlib Figure outside pyplot, PNG by Agg: no display needed, and
the caller's backend, e.g. a notebook's inline plots, is left untouched)."""

from __future__ import annotations

from pathlib import Path

from d2slam.data.base import Trajectory
from d2slam.errors import D2SlamError


def plot_trajectory(groundtruth: Trajectory, estimate: Trajectory, out: str | Path, title: str = "",
                    metrics: dict | None = None) -> Path:
    """Top (x-y) and side (x-z) views of the SE(3)-aligned estimate over ground truth, saved as PNG."""
    from matplotlib.figure import Figure  # outside pyplot: PNG by Agg, the caller's backend untouched

    from d2slam.eval.trajectory import aligned_estimate

    out = Path(out)
    if not out.parent.is_dir():
        raise D2SlamError("output folder does not exist", path=out.parent)
    gt, est, _ = aligned_estimate(groundtruth, estimate)
    fig = Figure(figsize=(10, 4.5))
    axes = fig.subplots(1, 2)
    for ax, (i, j, name) in zip(axes, [(0, 1, "x-y"), (0, 2, "x-z")]):
        ax.plot(groundtruth.poses[:, i, 3], groundtruth.poses[:, j, 3], color="0.6", lw=1, label="ground truth")
        ax.plot(est[:, i], est[:, j], color="tab:red", lw=1.2, label="estimate (SE(3)-aligned)")
        ax.set_xlabel(f"{'xyz'[i]} (m)")
        ax.set_ylabel(f"{'xyz'[j]} (m)")
        ax.set_title(name)
        ax.axis("equal")
        ax.grid(alpha=0.3)
    axes[0].legend(loc="best", fontsize=8)
    if metrics:
        title = (title + "  " if title else "") + "ATE {:.2f} cm, RPE {:.2f} cm / {:.2f} deg".format(
            100 * metrics["ate_rmse_m"], 100 * metrics["rpe_trans_m"], metrics["rpe_rot_deg"])
    if title:
        fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    return out
