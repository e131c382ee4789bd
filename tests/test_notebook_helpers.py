"""d2slam.notebook: the notebooks' set-up runs what the library runs (same trajectory as ``run_method``), records
every frame's hook input, diagnostics and keypoint truth, and reads sequences from the study cache."""

from __future__ import annotations

import shutil
from types import SimpleNamespace

import numpy as np
import pytest
from test_eval_keypoints import _textured_synthetic

from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.eval.keypoints import KeypointRecorder, keypoint_truth
from d2slam.notebook import (config_values, development_sequence, mask_provider, recorded_run,
                             seed_showing)
from d2slam.run.runner import run_method
from d2slam.study.sequences import MARKER, sequence_dir


def test_recorded_run_is_the_library_run(tmp_path):
    info, gt = _textured_synthetic(tmp_path / "walking_xyz_seed7", n=6)
    seq = open_sequence(info["root"])
    seen = []
    run = recorded_run(seq, "d2slam", also=lambda i, kps, beliefs, diag: seen.append(i))
    ref = run_method(seq, "d2slam", DEFAULT, masks="sim", synthetic=True, progress=False)
    assert np.array_equal(run.result.trajectory.poses, ref.trajectory.poses)
    assert [f.index for f in run.frames] == seen == list(range(len(seq)))
    for f in run.frames:
        assert f.inp.frame_index == f.diag.frame_index == f.index
        assert np.array_equal(f.kps, f.inp.kps) and np.array_equal(f.truth, keypoint_truth(f.kps, gt))
        assert np.array_equal(f.inp.masks, mask_provider(seq)(f.index)) and f.inp.masks.any()
    n = sum(len(f.kps) for f in run.frames)
    assert run.cat("belief").shape == run.cat("truth").shape == (n,) and run.cat("truth").any()
    rec = KeypointRecorder(seq)
    light = recorded_run(seq, "d2slam", also=rec, inputs=False)
    assert rec.result()["modules"]["final"] == ref.keypoints["modules"]["final"]
    assert all(f.inp is None for f in light.frames) and np.array_equal(light.cat("belief"), run.cat("belief"))


def test_recorded_run_without_filter_or_masks(tmp_path):
    info, _ = _textured_synthetic(tmp_path / "walking_xyz_seed7", n=5)
    seq = open_sequence(info["root"])
    run = recorded_run(seq, "none", masks=None)
    assert len(run.frames) == 5 and all(f.diag is None and f.inp is None for f in run.frames)
    assert run.result.tracked == 5


def test_development_sequence_reads_the_cache(tmp_path):
    info, _ = _textured_synthetic(tmp_path / "src", n=5)
    path = sequence_dir("walking_xyz", 7, 5, False, root=tmp_path / "cache")
    shutil.copytree(info["root"], path)
    (path / MARKER).write_text("{}\n")  # complete: nothing is generated
    seq = development_sequence("walking_xyz", 7, 5, root=tmp_path / "cache")
    assert len(seq) == 5 and seq.root == path


def test_config_values():
    assert config_values(DEFAULT.dynamics, "beta_min", "z_far") == \
        f"`beta_min` = {DEFAULT.dynamics.beta_min}, `z_far` = {DEFAULT.dynamics.z_far}"


class _Plan:
    """A scene plan (a stand-in for ``d2slam.synth.Scene``): a camera at the origin looking along +z, one frame per
    second; per seed, where a person stands and when and where an object moves."""

    intrinsics = SimpleNamespace(fx=100.0, fy=100.0, cx=50.0, cy=50.0, width=100, height=100)
    IN, OUT = np.array([0.0, 0.0, 2.0]), np.array([0.0, 0.0, -2.0])  # in front of the camera, behind it
    PEOPLE = {0: [], 1: [(0, 9)], 2: [(0, 2), (1, 9)], 3: [(5, 9)], 4: [(0, 9)]}  # frames [a, b) in view
    OBJECTS = {0: [], 1: [(0, 9, 0, 1)], 2: [(0, 9, 0, 9)], 3: [(0, 2, 0, 9)], 4: [(0, 9, 3, 9)]}  # view, moving

    def __init__(self, scenario, seed, frames, cfg=None):
        self.t_rel = np.arange(frames, dtype=float)
        self.camera = SimpleNamespace(poses=lambda t: np.repeat(np.eye(4)[None], len(t), axis=0))
        self.people = [self._track(a, b) for a, b in self.PEOPLE[seed]]
        self.objects = []
        for a, b, m0, m1 in self.OBJECTS[seed]:
            o = self._track(a, b)
            o.moving = lambda t, m0=m0, m1=m1: m0 <= t < m1
            self.objects.append(o)

    def _track(self, a, b):
        def pose(t):
            T = np.eye(4)
            T[:3, 3] = self.IN if a <= t < b else self.OUT
            return T
        return SimpleNamespace(root=pose, pose=pose)


def test_seed_showing(monkeypatch):
    monkeypatch.setattr("d2slam.notebook.Scene", _Plan)
    assert seed_showing("walking_xyz", 9, "people", seeds=[0, 1, 2, 3]) == 2  # 2 + 8 frames x people in view
    assert seed_showing("walking_xyz", 9, "people", seeds=[4, 1]) == 1  # a tie: the lowest seed
    assert seed_showing("walking_carry", 9, "moving objects", seeds=[1, 2, 3, 4]) == 2  # moving while in view
    with pytest.raises(D2SlamError, match="no seed"):
        seed_showing("walking_carry", 9, "moving objects", seeds=[0])
    with pytest.raises(D2SlamError, match="what must be"):
        seed_showing("walking_carry", 9, "boxes")
