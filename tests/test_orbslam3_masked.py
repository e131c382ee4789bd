"""``orbslam3-masked``: the real ORB-SLAM3 on frames with the person masks removed. Registered with the same default
masks as the other mask-using methods, runnable end to end by ``d2slam run`` and the study (repeats, median and
spread), the masks really reach ORB-SLAM3, and missing masks are a one-line error before ORB-SLAM3 starts."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import pytest

from d2slam.baselines import vocab as V
from d2slam.cli import main
from d2slam.config import DEFAULT
from d2slam.run.methods import get_method, mask_kind, methods
from d2slam.study.sequences import ensure_sequence

pytest.importorskip("pyorbslam3")

FRAMES = 40  # the sequence tests/test_study_run.py uses (generated once into the study cache)


@pytest.fixture(scope="module")
def vocab(tmp_path_factory):
    """A small vocabulary built from the shared real frames (as in tests/test_orbslam3.py), given to every
    ORB-SLAM3 run through $PYORBSLAM3_VOCAB."""
    out = tmp_path_factory.mktemp("vocab") / "voc.txt"
    return Path(V.build_vocabulary(out, synthetic=False, real=True, progress=False)["path"])


@pytest.fixture(scope="module")
def seq():
    return ensure_sequence("sitting_static", 101, FRAMES, False)


@pytest.fixture
def tum_dir(tmp_path):
    from test_orbslam3 import write_shift_sequence  # a real fr3 frame shifted: a TUM folder without masks

    return write_shift_sequence(tmp_path / "rgbd_dataset_freiburg3_shift", n=4)


def test_registered_beside_orbslam3_with_the_default_masks_of_the_other_methods():
    from d2slam.study.grid import default_methods

    m = get_method("orbslam3-masked")
    assert m.needs_masks and m.runner is not None and m.masks is None
    assert mask_kind(m, None, synthetic=True) == mask_kind(get_method("d2slam"), None, synthetic=True) == "onnx"
    assert mask_kind(m, None, synthetic=False) == "onnx" and mask_kind(m, "gt", synthetic=True) == "gt"
    names = default_methods()
    assert names.index("orbslam3-masked") == names.index("orbslam3") + 1 and "orbslam3-masked" in methods()


def test_run_command_end_to_end(tmp_path, seq, vocab, monkeypatch, capsys):
    monkeypatch.setenv("PYORBSLAM3_VOCAB", str(vocab))
    traj, run_json = tmp_path / "t.txt", tmp_path / "r.json"
    code = main(["run", str(seq), "--method", "orbslam3-masked", "--masks", "gt", "--out", str(traj),
                 "--metrics-json", str(run_json), "--quiet"])
    run = json.loads(run_json.read_text())
    assert code in (0, 1), run.get("message")
    assert run["method"] == "orbslam3-masked" and run["masks"] == "gt" and run["frames"] == FRAMES
    assert run["masking"] == dataclasses.asdict(DEFAULT.masking) and run["tracked"] > FRAMES // 2
    assert {"segment", "mask", "track"} <= set(run["stage_ms"]) and run["stage_ms"]["mask"] > 0
    assert run["ms_per_frame"] >= run["stage_ms"]["mask"] and traj.is_file()
    assert "orbslam3-masked sitting_static" in capsys.readouterr().out
    # no --masks: the real segmenter's, like the other mask-using methods; one summary line like `d2slam run`'s
    assert main(["run", str(seq), "--method", "orbslam3-masked", "--out", str(traj), "--metrics-json",
                 str(run_json)]) in (0, 1)
    run = json.loads(run_json.read_text())
    assert run["masks"] == "onnx" and "cached in" in run["masks_origin"] and run["camera_source"] == "scene.json"
    summary = [x for x in capsys.readouterr().out.splitlines() if x.startswith("d2slam run:")]
    assert len(summary) == 1 and summary[0].startswith(
        "d2slam run: method orbslam3-masked; masks onnx (yolov8n-seg_deq_384x512.onnx, cached in ")
    assert f"camera synthetic (scene.json); tracked {run['tracked']:.0f}/{FRAMES} frames; ATE " in summary[0]
    assert summary[0].endswith(f"; wrote {traj}, {run_json}")


def test_the_worker_gives_orbslam3_the_frames_without_the_people(seq):
    """What the ORB-SLAM3 child process tracks with --masks: depth 0 and RGB filled on the (dilated) masks."""
    import numpy as np

    from d2slam.baselines._orbslam3_worker import remove_people
    from d2slam.baselines.masking import dilate
    from d2slam.data import open_sequence
    from d2slam.segmentation import masks_for, stack_masks

    s = open_sequence(seq)
    i = next(k for k in range(FRAMES) if masks_for(s, k, "gt"))
    frame = s[i]
    rgb, depth, seg_s, mask_s = remove_people(s, i, frame.rgb, frame.depth * 5000, "gt", DEFAULT)
    region = dilate(stack_masks(masks_for(s, i, "gt"), depth.shape).any(axis=0), DEFAULT.masking.dilate_px)
    assert region.any() and (depth[region] == 0).all() and (depth[~region] == frame.depth[~region] * 5000).all()
    assert (rgb[region] != frame.rgb[region]).any() and np.array_equal(rgb[~region], frame.rgb[~region])
    assert seg_s >= 0 and mask_s > 0


def test_repeats_share_frames_masked_once(seq, vocab, tmp_path):
    """Repeated runs read the frames with the people removed once (the frame store): the same arrays as the worker's
    own masking, and each frame's masking time still counts in its milliseconds."""
    import numpy as np

    from d2slam.baselines import _orbslam3_worker as W
    from d2slam.run.orbslam3_runs import run_orbslam3
    from d2slam.data import open_sequence
    from d2slam.segmentation import masks_for

    s = open_sequence(seq)
    i = next(k for k in range(FRAMES) if masks_for(s, k, "gt"))
    W.write_frame_store(s, i + 1, tmp_path / "store", "gt", DEFAULT)
    got = list(W.store_frames(tmp_path / "store"))[i]
    want = W.sequence_frame(s, i, "gt", DEFAULT)
    assert np.array_equal(got[1], want[1]) and np.array_equal(got[2], want[2]) and (got[2] == 0).any()
    run = run_orbslam3(seq, tmp_path / "t.txt", repeats=2, vocab=vocab, masks="gt", max_frames=12, progress=False,
                       evaluate=False).orbslam3
    assert run["frame_store"]["mask_s"] > 0 and run["frame_store"]["frames"] == 12
    for r in run["runs"]:
        assert r["status"] in ("ok", "lost") and r["stage_ms"]["mask"] > 0
        assert r["ms_per_frame"] == pytest.approx(r["stage_ms"]["mask"] + r["stage_ms"]["track"], abs=1e-2)


def test_study_runs_it_with_repeats(seq, vocab, monkeypatch):
    from d2slam.study.grid import RunSpec
    from d2slam.study.keys import run_key
    from d2slam.study.runner import execute_run, run_options

    monkeypatch.setenv("PYORBSLAM3_VOCAB", str(vocab))
    spec = RunSpec("sitting_static", "orbslam3-masked", 101, FRAMES)
    out = execute_run(spec, run_options(orbslam3_repeats=2, masks="gt"))
    row = out["row"]
    assert row["status"] in ("ok", "lost"), row["error"]
    assert row["deterministic"] == 0 and row["repeats"] == 2 and row["frames_tracked"] > FRAMES // 2
    assert row["ate_min_m"] <= row["ate_rmse_m"] <= row["ate_max_m"] and out["trajectory"] is not None
    # its runs are keyed by the masks and repeats; the plain orbslam3 run keeps a key of its own
    keys = {run_key(spec, run_options(orbslam3_repeats=2, masks="gt")),
            run_key(spec, run_options(orbslam3_repeats=3, masks="gt")),
            run_key(spec, run_options(orbslam3_repeats=2, masks="sim")),
            run_key(dataclasses.replace(spec, method="orbslam3"), run_options(orbslam3_repeats=2, masks="gt"))}
    assert len(keys) == 4


def _one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("d2slam: error:") and len(err.splitlines()) == 1, err
    return err


def test_missing_masks_are_a_one_line_error(tmp_path, tum_dir, seq, monkeypatch, capsys):
    out = ["--out", str(tmp_path / "t.txt")]
    run = ["run", str(tum_dir), "--method", "orbslam3-masked", *out]
    assert "mask_sim" in _one_line_error(capsys, run + ["--masks", "sim"])
    assert "mask_gt" in _one_line_error(capsys, run + ["--masks", "truth"])
    monkeypatch.setenv("D2SLAM_SEG_MODEL", str(tmp_path / "missing.onnx"))
    assert "model not found" in _one_line_error(capsys, run)  # real data: onnx masks by default
    assert "--masks-from" in _one_line_error(capsys, run + ["--masks-from", str(seq)])
    assert "--masks does not apply" in _one_line_error(
        capsys, ["run", str(seq), "--method", "orbslam3", "--masks", "sim", *out])
    assert not (tmp_path / "t.txt").exists()
