"""Stored features (d2slam.slam.features): a run that reads a sequence's saved features gives exactly the run that
extracts them (trajectory, beliefs, keyframes), with and without the keypoint filter; the stored extraction time
is what the reading run reports; bad or mismatched files give clear errors, and the study replaces a corrupt one."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from d2slam.cachefiles import Damaged
from d2slam.config import DEFAULT
from d2slam.data import open_sequence
from d2slam.errors import D2SlamError
from d2slam.run.methods import get_method
from d2slam.run.sequence import run_sequence
from d2slam.segmentation import masks_for, stack_masks
from d2slam.slam.engine import Engine
from d2slam.slam.features import CachedFeatures, FeatureRecorder
from d2slam.study.sequences import ensure_sequence

FRAMES = 40
# Stored features have the fixed budget: the runs that read them with a filter turn the refill off.
FIXED = dataclasses.replace(DEFAULT, engine=dataclasses.replace(DEFAULT.engine, refill_filtered=False))


@pytest.fixture(scope="module")
def seq():
    return open_sequence(ensure_sequence("sitting_static", 101, FRAMES, False))


def _run(seq, method, features=None, config=FIXED):
    kfilter = get_method(method).factory(config)
    provider = None
    if kfilter is not None:
        shape = (seq.camera.height, seq.camera.width)

        def provider(i):
            return stack_masks(masks_for(seq, i, "sim", config), shape)

    beliefs = []

    def rec(i, kps, bel, diag):
        beliefs.append(None if bel is None else bel.copy())

    res = run_sequence(seq, config, keypoint_filter=kfilter, mask_provider=provider, recorder=rec,
                       progress=False, features=features)
    return res, beliefs


@pytest.fixture(scope="module")
def saved(seq, tmp_path_factory):
    rec = FeatureRecorder()
    res, beliefs = _run(seq, "d2slam", rec)
    path = rec.save(tmp_path_factory.mktemp("features") / "f.npz")
    return path, rec, res, beliefs


@pytest.mark.parametrize("method", ["none", "d2slam"])
def test_cached_run_equals_extracting_run(seq, saved, method):
    path, rec, res_d2, beliefs_d2 = saved
    ref, ref_bel = (res_d2, beliefs_d2) if method == "d2slam" else _run(seq, method)
    cached = CachedFeatures(path)
    res, bel = _run(seq, method, cached)
    assert res.tracked == ref.tracked and res.keyframes == ref.keyframes and res.map_points == ref.map_points
    np.testing.assert_array_equal(res.trajectory.timestamps, ref.trajectory.timestamps)
    np.testing.assert_array_equal(res.trajectory.poses, ref.trajectory.poses)
    for a, b in zip(bel, ref_bel):
        if a is None:
            assert b is None
        else:
            np.testing.assert_array_equal(a, b)
    # the reading run reports the extraction time stored with the features
    assert res.stage_ms["extract"] == pytest.approx(np.mean(rec.extract_ms))


def test_frames_rebuilt_bit_identical(seq, saved):
    path, *_ = saved
    cached = CachedFeatures(path)
    eng = Engine(seq.camera, DEFAULT)
    for i in (0, FRAMES // 2, FRAMES - 1):
        f = seq[i]
        fresh = eng.extractor(f.gray, f.depth, i, f.timestamp)
        got = cached.frame(i)
        for k in ("kps", "kps_raw", "octave", "angle", "desc", "depth", "ur", "inv_sigma2"):
            a, b = getattr(got, k), getattr(fresh, k)
            assert a.dtype == b.dtype
            np.testing.assert_array_equal(a, b)
        assert got.timestamp == f.timestamp and got.index == i
        got.mp[:] = 7  # a frame is the caller's: the next call gives fresh arrays
        assert (cached.frame(i).mp == -1).all()


def test_mismatched_and_corrupt_files(seq, saved, tmp_path):
    path, *_ = saved
    cached = CachedFeatures(path)
    with pytest.raises(D2SlamError, match="does not match"):
        cached.check(seq.timestamps[:FRAMES - 1])
    with pytest.raises(D2SlamError, match="does not match"):
        cached.check(seq.timestamps + 1.0)
    bad = tmp_path / "bad.npz"
    bad.write_bytes(b"not a zip")
    with pytest.raises(Damaged, match="ValueError"):  # not a zip: numpy takes it for a pickle, and refuses it
        CachedFeatures(bad)
    with pytest.raises(D2SlamError, match="features must be"):
        run_sequence(seq, DEFAULT, progress=False, features="cache.npz")
    with pytest.raises(D2SlamError, match="no features to save"):
        FeatureRecorder().save(tmp_path / "empty.npz")


def test_what_each_run_still_reads(seq, saved):
    path, *_ = saved
    frame0 = CachedFeatures(path).frame(0)
    eng = Engine(seq.camera, FIXED, get_method("d2slam").factory(FIXED))
    with pytest.raises(D2SlamError, match="needs the depth image"):
        eng.process(None, None, 0, float(seq.timestamps[0]), features=frame0)
    with pytest.raises(D2SlamError, match="images are needed"):
        Engine(seq.camera, DEFAULT).process(None, None, 0, float(seq.timestamps[0]))
    Engine(seq.camera, DEFAULT).process(None, None, 0, float(seq.timestamps[0]), features=frame0)  # no filter
    # the depth-only read equals the frame's depth (no RGB decoded)
    for i in (0, FRAMES - 1):
        np.testing.assert_array_equal(seq.depth_image(i), seq[i].depth)
    with pytest.raises(IndexError):
        seq.depth_image(FRAMES)


def test_sequence_without_depth_only_reader(seq, saved):
    """A sequence that has no ``depth_image`` gives its depth through whole frames: same run."""
    path, _, ref, ref_bel = saved

    class Plain:
        def __len__(self):
            return len(seq)

        def __getitem__(self, i):
            return seq[i]

        def __getattr__(self, name):  # camera, timestamps, root, masks ... but no depth_image
            if name == "depth_image":
                raise AttributeError(name)
            return getattr(seq, name)

    assert not hasattr(Plain(), "depth_image")
    res, bel = _run(Plain(), "d2slam", CachedFeatures(path))
    np.testing.assert_array_equal(res.trajectory.poses, ref.trajectory.poses)


def test_study_replaces_a_corrupt_cache_file(seq, tmp_path):
    from d2slam.slam.features import CachedFeatures as CF
    from d2slam.study.runner import _features, features_path, run_options

    options = run_options(cache_root=tmp_path)
    target = features_path(seq, seq.root, DEFAULT, options)
    features, save_to = _features(seq, seq.root, DEFAULT, options)
    assert isinstance(features, FeatureRecorder) and save_to == target
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(b"garbage")
    features, save_to = _features(seq, seq.root, DEFAULT, options)
    assert isinstance(features, FeatureRecorder) and save_to == target and not target.exists()
    _run(seq, "none", features)
    features.save(save_to)
    features, save_to = _features(seq, seq.root, DEFAULT, options)
    assert isinstance(features, CF) and save_to is None


def test_refilling_runs_take_no_stored_features(seq, saved):
    """With ``refill_filtered`` (the default) and a filter, each frame's budget follows the filter: stored or
    recorded features are refused with a clear error, by the pipeline and by the engine; without a filter they serve."""
    path, *_ = saved
    for features in (CachedFeatures(path), FeatureRecorder()):
        with pytest.raises(D2SlamError, match="fixed extraction budget"):
            _run(seq, "d2slam", features, config=DEFAULT)
    eng = Engine(seq.camera, DEFAULT, get_method("d2slam").factory(DEFAULT))
    with pytest.raises(D2SlamError, match="fixed budget"):
        eng.process(None, seq[0].depth, 0, float(seq.timestamps[0]), features=CachedFeatures(path).frame(0))
    res, _ = _run(seq, "none", CachedFeatures(path), config=DEFAULT)
    assert res.tracked == FRAMES


def test_refill_budget_follows_the_filter(seq):
    """``Engine.feature_budget``: n_features plus the keypoints the filter flagged in the last frame, capped at
    refill_max x n_features; n_features without a filter or with the refill off."""
    from d2slam.slam.frame import Frame

    class Flags:  # flags a fixed number of keypoints per frame
        def __init__(self, k):
            self.k = k

        def __call__(self, inp):
            b = np.zeros(len(inp.kps))
            b[:self.k] = 1.0
            return b

        def reset(self):
            pass

    n = DEFAULT.orb.n_features
    for k, want in ((0, n), (137, n + 137), (900, int(DEFAULT.engine.refill_max * n))):
        eng = Engine(seq.camera, DEFAULT, Flags(k))
        assert eng.feature_budget() == n  # before the first frame
        f = seq[0]
        eng.process(f.gray, f.depth, 0, f.timestamp)
        assert int(eng.last.dynamic.sum()) == min(k, eng.last.n)
        assert eng.feature_budget() == want
        f = seq[1]
        eng.process(f.gray, f.depth, 1, f.timestamp)
        assert eng.last.n > n if k else eng.last.n <= n  # the second frame extracted more
    assert Engine(seq.camera, FIXED, Flags(137)).refills is False
    eng = Engine(seq.camera, DEFAULT)
    assert not eng.refills and eng.feature_budget() == n
    assert isinstance(eng.extractor(seq[0].gray, seq[0].depth), Frame)
