"""The methods on real frames: the first 120 frames of TUM fr1/rpy (a real Kinect: fast rotations, blur, lens
distortion, depth taken at its own instant; nobody in view), from ``d2slam.assets.real_head`` (the shared folder, or
``d2slam assets fetch``).

Nothing moves in these frames, so a keypoint filter must not break tracking nor cost accuracy: every method tracks
every frame, and each filter's ATE is within 1.1x the unfiltered engine's (``none``). The whole sequence is the
study's judge (docs/results.md, "Real recordings"); the head is what every clone can run."""

import math

import pytest

from d2slam.assets import real_head
from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.methods import get_method, methods, run_method

FILTERS = [m for m in methods() if m != "none" and get_method(m).runner is None and get_method(m).masks is None]
MAX_RATIO = 1.1


@pytest.fixture(scope="module")
def head():
    return open_sequence(real_head())


@pytest.fixture(scope="module")
def baseline(head):
    return run_method(head, "none", DEFAULT, progress=False)


def test_the_head_is_the_real_recording(head):
    assert len(head) == 120 and head.camera.name == "freiburg1" and head.camera.has_distortion


def test_the_filters_are_the_methods_a_user_runs_on_real_data():
    assert {"d2slam", "d2slam-flow", "geometric", "no-depth", "no-oim", "no-bayes", "semantic"} <= set(FILTERS)
    assert "oracle" not in FILTERS  # it needs the synthetic truth


def test_none_tracks_every_frame(baseline):
    assert baseline.tracked == baseline.frames == 120
    assert baseline.evaluation.metrics.ate_rmse_m < 0.05


@pytest.mark.parametrize("method", FILTERS)
def test_a_filter_tracks_every_frame_and_costs_nothing(head, baseline, method):
    run = run_method(head, method, DEFAULT, progress=False)
    assert run.tracked == run.frames == 120, f"{method} tracked {run.tracked} of 120 frames"
    ratio = run.evaluation.metrics.ate_rmse_m / baseline.evaluation.metrics.ate_rmse_m
    assert math.isfinite(ratio) and ratio <= MAX_RATIO, f"{method}: ATE {ratio:.2f}x none's"
