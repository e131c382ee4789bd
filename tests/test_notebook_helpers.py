"""d2slam.notebook: the notebooks' set-up runs what the library runs (same trajectory as ``run_method``), records
every frame's hook input, diagnostics and keypoint truth, and reads sequences from the study cache."""

from __future__ import annotations

import shutil

import numpy as np
from test_eval_keypoints import _textured_synthetic

from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.eval.keypoints import KeypointRecorder, keypoint_truth
from d2slam.methods import run_method
from d2slam.notebook import development_sequence, mask_provider, recorded_run
from d2slam.study.sequences import MARKER, sequence_dir


def test_recorded_run_is_the_library_run(tmp_path):
    info, gt = _textured_synthetic(tmp_path / "walking_xyz_seed7", n=6)
    seq = open_sequence(info["root"])
    seen = []
    run = recorded_run(seq, "d2slam", also=lambda i, kps, beliefs, diag: seen.append(i))
    ref = run_method(seq, "d2slam", DEFAULT, masks="sim", synthetic=True, progress=False)
    assert np.array_equal(run.result.trajectory.poses, ref.result.trajectory.poses)
    assert [f.index for f in run.frames] == seen == list(range(len(seq)))
    for f in run.frames:
        assert f.inp.frame_index == f.diag.frame_index == f.index
        assert np.array_equal(f.kps, f.inp.kps) and np.array_equal(f.truth, keypoint_truth(f.kps, gt))
        assert np.array_equal(f.inp.masks, mask_provider(seq)(f.index)) and f.inp.masks.any()
    n = sum(len(f.kps) for f in run.frames)
    assert run.cat("belief").shape == run.cat("truth").shape == (n,) and run.cat("truth").any()
    rec = KeypointRecorder(seq)
    recorded_run(seq, "d2slam", also=rec)
    assert rec.result()["modules"]["final"] == ref.keypoints["modules"]["final"]


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
