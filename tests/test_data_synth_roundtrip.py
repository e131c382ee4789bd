"""A sequence written by ``d2slam.synth`` reads back through SyntheticSequence: frames, masks, truth, gt."""

from __future__ import annotations

import json

import numpy as np
import pytest

from d2slam.data import SyntheticSequence, open_sequence
from d2slam.synth import generate

FRAMES = 6


@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    generate("walking_xyz", root / "walking_xyz", frames=FRAMES, seed=3, workers=1, progress=False)
    generate("walking_xyz", root / "twin", frames=FRAMES, seed=3, static_twin=True, workers=1, progress=False)
    return root


def test_generated_sequence_reads_back(generated):
    seq = open_sequence(generated / "walking_xyz")
    assert isinstance(seq, SyntheticSequence) and len(seq) == FRAMES  # every RGB frame got its depth frame
    scene = json.loads((generated / "walking_xyz" / "scene.json").read_text())
    cam = scene["camera"]
    assert (seq.camera.fx, seq.camera.fy, seq.camera.cx, seq.camera.cy) == (cam["fx"], cam["fy"], cam["cx"],
                                                                            cam["cy"])
    assert seq.camera.depth_factor == cam["depth_factor"]
    assert np.all(np.diff(seq.timestamps) > 0)
    assert np.all(np.abs(seq.depth_timestamps - seq.timestamps) < 0.02)
    assert len(seq.person_ids) >= 1
    shape = (seq.camera.height, seq.camera.width)
    gt = seq.frame_gt_poses()
    assert not np.isnan(gt).any()  # ground truth covers every frame
    np.testing.assert_allclose(gt[:, 3], np.tile([0, 0, 0, 1.0], (FRAMES, 1)))
    for i in (0, FRAMES - 1):
        frame = seq[i]
        assert frame.rgb.shape == shape + (3,) and frame.rgb.dtype == np.uint8
        assert frame.depth.shape == shape and frame.depth.dtype == np.float32
        valid = frame.depth[frame.depth > 0]
        assert 0.5 < valid.mean() < 6.0 and (frame.depth > 0).mean() > 0.5  # metres, mostly valid
        gt_ids = seq.mask_gt(i)
        dyn = seq.dynamic_mask(i)
        assert dyn.shape == shape and dyn.dtype == bool
        np.testing.assert_array_equal(dyn, np.isin(gt_ids, seq.dynamic_ids(i)))
        persons, ids = seq.person_masks_gt(i, return_ids=True)
        assert persons.shape[1:] == shape and set(ids.tolist()) <= set(seq.person_ids.tolist())
        np.testing.assert_array_equal(persons.any(axis=0), np.isin(gt_ids, seq.person_ids))
        assert dyn[persons.any(axis=0)].all() and dyn.mean() > 0.01  # people are in view and dynamic
        sim = seq.person_masks_sim(i)
        assert sim.dtype == bool and sim.shape[1:] == shape and sim.any()
        # the simulated segmenter mostly overlaps the true people (it is realistic, not exact)
        overlap = (sim.any(axis=0) & persons.any(axis=0)).sum() / max(sim.any(axis=0).sum(), 1)
        assert overlap > 0.5


def test_static_twin_has_no_dynamic_pixels(generated):
    twin = open_sequence(generated / "twin")
    assert isinstance(twin, SyntheticSequence) and twin.static_twin and len(twin) == FRAMES
    assert twin.person_ids.size == 0
    for i in range(FRAMES):
        assert not twin.dynamic_mask(i).any() and twin.person_masks_gt(i).shape[0] == 0
    real = open_sequence(generated / "walking_xyz")
    np.testing.assert_allclose(twin.frame_gt_poses(), real.frame_gt_poses(), atol=1e-9)  # same camera path
