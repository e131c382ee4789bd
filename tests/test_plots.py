"""Figures a reader can read: one fixed colour per method in every figure, ground truth drawn above the estimates, no
legend entry for what drew nothing."""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd
import pytest
from matplotlib.colors import to_rgb, to_rgba
from matplotlib.figure import Figure

from d2slam.eval.plots import GROUND_TRUTH, METHOD_COLOURS, OTHER_COLOURS, legend, method_colour


def _lab(colour) -> np.ndarray:
    """CIELAB (D65) of a matplotlib colour."""
    c = np.asarray(to_rgb(colour))
    c = np.where(c > 0.04045, ((c + 0.055) / 1.055) ** 2.4, c / 12.92)
    xyz = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]]) @ c
    f = np.cbrt(xyz / np.array([0.95047, 1.0, 1.08883]))
    f = np.where(xyz / np.array([0.95047, 1.0, 1.08883]) > 0.008856, f,
                 7.787 * xyz / np.array([0.95047, 1.0, 1.08883]) + 16 / 116)
    return np.array([116 * f[1] - 16, 500 * (f[0] - f[1]), 200 * (f[1] - f[2])])


@pytest.fixture
def saved(monkeypatch):
    """The figures the plotting functions save (drawn outside pyplot)."""
    figs = []
    real = Figure.savefig
    monkeypatch.setattr(Figure, "savefig", lambda self, *a, **k: figs.append(self) or real(self, *a, **k))
    return figs


def test_every_method_has_its_own_colour():
    from d2slam.run.methods import methods
    from d2slam.study.grid import ORBSLAM3, ORBSLAM3_MASKED

    names = list(dict.fromkeys(methods() + [ORBSLAM3, ORBSLAM3_MASKED]))
    assert set(names) <= set(METHOD_COLOURS)
    colours = [method_colour(m) for m in names]
    assert len(set(colours)) == len(names)
    for a, b in itertools.combinations(names, 2):  # told apart at a glance, not merely different
        assert np.linalg.norm(_lab(method_colour(a)) - _lab(method_colour(b))) >= 20, (a, b)
    # a name outside the map: a fixed colour, the same in every process and on every machine
    assert method_colour("my-filter") == method_colour("my-filter") == "#FFBB78" and "#FFBB78" in OTHER_COLOURS


def test_study_plots_use_the_method_colours_and_draw_ground_truth_on_top(tmp_path, saved):
    from d2slam.study.plots import plot_ate_bars, plot_trajectories

    t = np.linspace(0, 1, 30)
    gt = np.c_[t, np.sin(t), 0 * t]
    methods = ["none", "orbslam3", "d2slam", "geometric"]
    aligned = {("walking_xyz", 0, m): (gt, gt + 0.01 * k) for k, m in enumerate(methods)}
    assert plot_trajectories(aligned, tmp_path / "t.png", 101) == tmp_path / "t.png"
    ax = saved[-1].axes[0]
    lines = {ln.get_label(): ln for ln in ax.get_lines()}
    for m in methods:
        assert to_rgba(lines[m].get_color()) == to_rgba(method_colour(m))
    truth = lines["ground truth"]
    assert truth.get_linestyle() == "--" and to_rgba(truth.get_color()) == to_rgba("k")
    assert truth.get_zorder() == GROUND_TRUTH["zorder"] > max(lines[m].get_zorder() for m in methods)

    summary = pd.DataFrame({"scenario": "walking_xyz", "twin": 0, "method": methods,
                            "ate_rmse_m_median": [0.5, 0.4, 0.01, np.nan], "ate_rmse_m_min": [0.4, 0.3, 0.009, np.nan],
                            "ate_rmse_m_max": [0.6, 0.5, 0.011, np.nan]})
    assert plot_ate_bars(summary, tmp_path / "a.png", methods) is not None
    ax = saved[-1].axes[0]
    bars = {c.get_label(): c for c in ax.containers if hasattr(c, "patches")}
    for m in methods:
        assert bars[m].patches[0].get_facecolor() == to_rgba(method_colour(m))
    # geometric has no value: no legend entry for it
    assert [t.get_text() for t in ax.get_legend().get_texts()] == ["none", "orbslam3", "d2slam"]


def test_eval_plot_draws_ground_truth_on_top(tmp_path, saved):
    from d2slam.data import Trajectory
    from d2slam.eval.plots import plot_trajectory

    t = np.arange(40) / 30.0
    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, 0, 3], poses[:, 1, 3] = t, np.sin(t)
    est = poses.copy()
    est[:, 2, 3] = 0.01 * np.cos(7 * t)
    plot_trajectory(Trajectory(t, poses), Trajectory(t, est), tmp_path / "p.png")
    for ax in saved[-1].axes:
        truth = [ln for ln in ax.get_lines() if ln.get_label() == "ground truth"]
        others = [ln for ln in ax.get_lines() if ln.get_label() != "ground truth"]
        assert len(truth) == 1 and others and truth[0].get_zorder() > max(ln.get_zorder() for ln in others)


def test_legend_leaves_out_empty_classes():
    ax = Figure().subplots()
    xy = np.random.default_rng(0).random((5, 2))
    ax.scatter(xy[:, 0], xy[:, 1], label="close")
    ax.scatter(xy[:0, 0], xy[:0, 1], label="far or no depth")  # a class with no points
    ax.plot([], [], label="empty line")
    ax.bar([0, 1], [np.nan, np.nan], label="no value")
    ax.bar([0, 1], [1.0, 2.0], label="values")
    assert [t.get_text() for t in legend(ax, fontsize=8).get_texts()] == ["close", "values"]
    empty = Figure().subplots()
    empty.scatter([], [], label="nothing")
    assert legend(empty) is None and empty.get_legend() is None
