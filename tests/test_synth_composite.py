"""People composited into a real recording (``d2slam synth real_walking --on TUM_DIR``, ``d2slam.synth.composite``,
``compositing``): a short composite of the real head's frames 30-59 (``d2slam.assets.real_head``, fr1/rpy), its
truth checked against its depth: every pixel where the depth image shows a person is nearer than the real depth
where that is valid, and the rest of the depth image is the real one (or a hole the people's edges and shadows
made); the colour image is the real one wherever nobody is; the recording's times, camera and ground truth."""

from __future__ import annotations

import dataclasses
import json

import cv2
import numpy as np
import pytest

from d2slam.assets import real_head
from d2slam.config import SynthConfig
from d2slam.data import open_sequence
from d2slam.data.tum import TumSequence
from d2slam.errors import D2SlamError
from d2slam.synth import generate
from d2slam.synth.scene import Scene
from d2slam.synth.twin import read_recording

FIRST, FRAMES, SEED = 30, 30, 2  # seed 2: people in view in most of these frames


def _fast() -> SynthConfig:
    """The sensor as always; the people's colour from fewer sub-frames (the truth and the depth do not depend on
    them): keeps the test fast."""
    cfg = SynthConfig()
    return dataclasses.replace(cfg, composite=dataclasses.replace(cfg.composite, subframe_px=8.0, subframes_min=2))


@pytest.fixture(scope="module")
def composite(tmp_path_factory):
    root = tmp_path_factory.mktemp("composite")
    rec = read_recording(real_head()).part(FIRST, FRAMES)
    res = generate("real_walking", root / "c", frames=FRAMES, seed=SEED, workers=1, progress=False, recording=rec,
                   cfg=_fast())
    return rec, res


def test_composite_people_are_nearer_than_the_real_depth(composite):
    rec, res = composite
    out = res["out"]
    seq, real = open_sequence(out), TumSequence(real_head())
    assert len(seq) == FRAMES and list(seq.person_ids) == [1, 2]
    shown = 0
    for i in range(FRAMES):
        k = int(rec.frame_index[i])
        d, r = seq.depth_image(i), real.depth_image(k)
        ids = cv2.imread(str(out / "mask_depth" / seq.depth_files[i].name), cv2.IMREAD_UNCHANGED)
        person = ids > 0
        valid = person & (r > 0)
        assert np.all(d[valid] < r[valid]), f"frame {i}: a person pixel is not nearer than the real depth"
        assert np.all(d[person] > 0)
        # elsewhere the real depth, or a hole made by the people (their edges, their projector shadow)
        rest = ~person
        assert np.all((d[rest] == r[rest]) | (d[rest] == 0))
        shown += int(person.sum())
        # the colour image: the real one where nobody covers a pixel's centre at any instant of the exposure
        rgb, real_rgb = seq.rgb_frame(i).rgb, real.rgb_frame(k).rgb
        gt = seq.mask_gt(i)
        assert set(np.unique(gt)) <= {0, 1, 2}
        if not gt.any() and not person.any():
            assert np.array_equal(rgb, real_rgb)
    assert shown > 0.02 * FRAMES * 640 * 480  # people are in view


def test_composite_follows_the_recording(composite):
    rec, res = composite
    out = res["out"]
    seq = open_sequence(out)
    assert np.allclose(seq.timestamps, rec.rgb_times) and np.allclose(seq.depth_timestamps, rec.depth_times)
    assert seq.camera.dist == rec.camera.dist and seq.camera.fx == rec.camera.fx
    gt = seq.groundtruth
    own = np.isin(np.round(rec.gt_times, 4), np.round(gt.timestamps, 4))
    assert np.allclose(rec.gt_poses[own], gt.poses, atol=2e-6)  # the recording's own, in its world
    scene = json.loads((out / "scene.json").read_text())
    assert not scene["static_twin"] and scene["recording"]["name"] == rec.name
    assert scene["recording"]["room"]["area_m2"]["standable_known_free"] > 0


def test_composite_refuses_bad_input():
    rec = read_recording(real_head())
    with pytest.raises(D2SlamError, match="static twin of real_walking is its recording"):
        Scene("real_walking", 0, 10, True, None, rec)
    with pytest.raises(D2SlamError, match="--on-trajectory"):
        Scene("real_carry", 0, 10, False, None, None)


def test_holes_are_filled_for_the_z_test_by_what_surrounds_them():
    """A hole inside the registered depth (a black monitor the Kinect does not measure) takes the nearest depth on its
    outline, so that nobody shows through it; the border the depth never covers takes the nearest valid pixel's."""
    from d2slam.synth.compositing import filled_depth

    z = np.full((60, 80), 3.0, np.float32)  # a wall at 3 m
    z[20:40, 30:60] = 1.0  # a monitor at 1 m ...
    z[24:36, 34:56] = 0.0  # ... whose screen is a hole
    z[10:14, 5:9] = 0.0  # a hole in the wall
    z[:5] = 0.0  # the border
    z[30:50, 0:3] = 0.0
    f = filled_depth(z, (5, 0, 3, 0))
    assert np.all(f[24:36, 34:56] == 1.0) and np.all(f[10:14, 5:9] == 3.0)
    assert np.all(f[:5, 40] == 3.0) and np.all(f[40, 0:3] == 3.0)
    assert np.all(f > 0) and np.array_equal(f[z > 0], z[z > 0])
