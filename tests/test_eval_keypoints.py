"""Keypoint truth lookup and precision / recall / F1 accumulation."""

import math

import numpy as np
import pytest

from d2slam.errors import D2SlamError
from d2slam.eval.keypoints import KeypointMetrics, ModuleMetrics, keypoint_truth


def test_keypoint_truth_rounding_bounds_nan():
    m = np.zeros((4, 5), np.uint8)
    m[1, 2] = 7  # any non-zero id is dynamic
    kps = np.array([[2.4, 0.6], [1.6, 1.4], [2.6, 1.0], [-0.4, 0.0], [-0.6, 0.0], [4.6, 1.0], [np.nan, 1.0],
                    [2.0, 1.49]])
    assert keypoint_truth(kps, m).tolist() == [True, True, False, False, False, False, False, True]
    assert keypoint_truth(np.zeros((0, 2)), m).shape == (0,)
    with pytest.raises(D2SlamError):
        keypoint_truth(kps, np.zeros((2, 4, 5)))


def test_metrics_by_hand_and_accumulation():
    pred = np.array([1, 1, 0, 0, 1, 0], bool)
    truth = np.array([1, 0, 1, 0, 1, 0], bool)
    m = KeypointMetrics().update(pred, truth)
    assert (m.tp, m.fp, m.fn, m.tn) == (2, 1, 1, 2)
    assert m.precision == pytest.approx(2 / 3) and m.recall == pytest.approx(2 / 3)
    assert m.f1 == pytest.approx(2 / 3) and m.static_precision == pytest.approx(2 / 3)
    # accumulating two frames equals one frame of the concatenation
    m2 = KeypointMetrics().update(pred[:3], truth[:3]).update(pred[3:], truth[3:])
    assert m2 == m
    assert (KeypointMetrics().update(pred[:3], truth[:3]) + KeypointMetrics().update(pred[3:], truth[3:])) == m
    d = m.as_dict()
    assert d["tp"] == 2 and d["f1"] == pytest.approx(2 / 3)


def test_undefined_ratios_are_nan_and_zero_f1():
    m = KeypointMetrics().update(np.zeros(3, bool), np.zeros(3, bool))
    assert math.isnan(m.precision) and math.isnan(m.recall) and math.isnan(m.f1)
    assert m.static_precision == 1.0
    m = KeypointMetrics().update(np.array([True, False]), np.array([False, True]))
    assert m.precision == 0.0 and m.recall == 0.0 and m.f1 == 0.0
    with pytest.raises(D2SlamError):
        KeypointMetrics().update(np.zeros(2, bool), np.zeros(3, bool))


def test_module_metrics():
    mm = ModuleMetrics().update({"semantic": np.array([True, False]), "final": np.array([True, True])},
                                np.array([True, False]))
    d = mm.as_dict()
    assert d["semantic"]["f1"] == 1.0 and d["final"]["precision"] == 0.5


# ------------------------------------------------------------------------------------------ pipeline recorder
class _ToySequence:
    """Frames of ``toy.two_view_scene``; the truth mask is the union of the true person masks."""

    def __init__(self, seeds):
        from d2slam.dynamics.toy import two_view_scene

        self.frames = [two_view_scene(s, n_kps=300, n_matches=250, frame_index=i)[0] for i, s in enumerate(seeds)]

    def dynamic_mask(self, i):
        return self.frames[i].masks.any(axis=0)

    def dynamic_labels(self, i):  # people only (1): no moved objects
        return self.dynamic_mask(i).astype(np.uint8)


def test_recorder_matches_direct_module_metrics_and_is_strict_json():
    import json

    from d2slam.run.methods import get_filter
    from d2slam.eval.keypoints import KeypointRecorder

    seq = _ToySequence([0, 1, 2])
    f = get_filter("d2slam")
    rec = KeypointRecorder(seq)
    direct = ModuleMetrics()
    for i, inp in enumerate(seq.frames):
        bel = f(inp)
        rec(i, inp.kps, bel, f.last)
        direct.update(f.last.predictions(), keypoint_truth(inp.kps, seq.dynamic_mask(i)))
    res = rec.result()
    assert list(res["modules"]) == ["semantic", "geometric", "pose", "fusion", "bayes", "oim", "final"]
    assert res["frames"] == res["frames_with_diagnostics"] == 3 and res["keypoints"] == 900
    for name, m in direct.as_dict().items():
        assert res["modules"][name] == m  # no NaN here: identical numbers
    final = res["modules"]["final"]
    assert final["recall"] >= 0.95 and final["static_precision"] >= 0.95
    assert res["moved_objects"] == {"keypoints": 0, "recall": None}  # people only here
    json.dumps(res, allow_nan=False)


def test_recorder_stale_diagnostics_none_method_and_nan_to_null():
    import json

    from d2slam.run.methods import get_filter
    from d2slam.eval.keypoints import KeypointRecorder

    seq = _ToySequence([3, 4])
    f = get_filter("semantic")
    f(seq.frames[0])
    rec = KeypointRecorder(seq)
    inp = seq.frames[1]
    bel = np.zeros(len(inp.kps))
    bel[:10] = 0.9
    rec(1, inp.kps, bel, f.last)  # diagnostics of frame 0: not used, final from the beliefs
    res = rec.result()
    assert list(res["modules"]) == ["final"] and res["frames_with_diagnostics"] == 0
    truth = keypoint_truth(inp.kps, seq.dynamic_mask(1))
    assert res["modules"]["final"]["tp"] == int(truth[:10].sum())
    none = KeypointRecorder(seq)
    none(0, seq.frames[0].kps, None, None)  # method none: every keypoint static
    m = none.result()["modules"]["final"]
    assert m["tp"] == m["fp"] == 0 and m["precision"] is None and m["recall"] == 0.0
    json.dumps(none.result(), allow_nan=False)
    with pytest.raises(D2SlamError, match="beliefs"):
        none(0, seq.frames[0].kps, np.zeros(3), None)


def test_recorder_needs_truth():
    from d2slam.eval.keypoints import KeypointRecorder, keypoint_recorder

    with pytest.raises(D2SlamError, match="synthetic"):
        KeypointRecorder(object())
    assert keypoint_recorder(object()) is None


def _textured_synthetic(root, n=5, w=160, h=120):
    """A small synthetic sequence whose frames give ORB keypoints: seeded block texture drifting 1 px per frame, a
    "person" (id 1, mask_gt and mask_sim) on the left third."""
    import json

    import cv2
    from test_data_synthetic import scene

    from d2slam.data.fixtures import write_tum_folder

    info = write_tum_folder(root, n_frames=n, width=w, height=h)
    rng = np.random.default_rng(0)
    tex = cv2.resize(rng.integers(0, 256, (h // 4, (w + 2 * n) // 4, 3), dtype=np.uint8), ((w + 2 * n), h),
                     interpolation=cv2.INTER_NEAREST)
    (root / "mask_gt").mkdir()
    (root / "mask_sim").mkdir()
    gt = np.zeros((h, w), np.uint8)
    gt[20:110, 10:50] = 1
    for i, t in enumerate(info["rgb_ts"]):
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), np.ascontiguousarray(tex[:, i:i + w, ::-1]))
        cv2.imwrite(str(root / "mask_gt" / f"{t:.6f}.png"), gt)
        cv2.imwrite(str(root / "mask_sim" / f"{t:.6f}.png"), gt)
    sc = scene(info["rgb_ts"])
    sc["camera"].update(width=w, height=h, cx=w / 2, cy=h / 2, fx=150.0, fy=150.0)
    (root / "scene.json").write_text(json.dumps(sc))
    return info, gt


def test_recorder_in_the_pipeline_on_a_synthetic_sequence(tmp_path):
    import json

    from d2slam.config import DEFAULT
    from d2slam.data import open_sequence
    from d2slam.eval.keypoints import keypoint_recorder
    from d2slam.run.methods import get_filter, get_method
    from d2slam.run.sequence import run_sequence

    info, gt = _textured_synthetic(tmp_path / "walking_xyz_seed7")
    seq = open_sequence(info["root"])
    assert get_method("d2slam").needs_masks and not get_method("geometric").needs_masks
    kfilter = get_filter("d2slam", DEFAULT)
    seen = []

    def recorder(i, kps, beliefs, diag):
        seen.append((len(kps), int(keypoint_truth(kps, gt).sum())))
        rec(i, kps, beliefs, diag)

    rec = keypoint_recorder(seq)
    result = run_sequence(seq, DEFAULT, keypoint_filter=kfilter, mask_provider=seq.person_masks_gt,
                          recorder=recorder, progress=False)
    res = rec.result()
    assert res["frames"] == result.frames == 5 and res["frames_with_diagnostics"] == 5
    assert res["keypoints"] == sum(n for n, _ in seen) > 50
    assert res["dynamic_keypoints"] == sum(d for _, d in seen) > 5
    assert set(res["modules"]) == {"semantic", "geometric", "pose", "fusion", "bayes", "oim", "final"}
    # the semantic module sees the true masks: every keypoint inside the person (rounded pixel) is predicted dynamic
    assert res["modules"]["semantic"]["recall"] == 1.0
    json.dumps(res, allow_nan=False)
