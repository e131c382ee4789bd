"""What `d2slam run` says: one summary line (method, masks and where they came from, camera and where it came from,
frames tracked, ATE, files written), the real segmenter's masks by default, their first segmentation announced with
an estimate before it starts, and a missing model named with what works (no flag `run` lacks)."""

from __future__ import annotations

import json
import shutil

import pytest

from d2slam.assets import asset_path
from d2slam.cli import main
from d2slam.run.methods import get_method, mask_kind
from d2slam.slam.fixture import write_room_sequence

MODEL = "yolov8n-seg_deq_384x512.onnx"


@pytest.fixture(scope="module")
def model():
    return asset_path(f"models/{MODEL}")  # found before the cache moves


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    return write_room_sequence(tmp_path_factory.mktemp("room") / "room", n=12, seed=1, fps=10.0)


@pytest.fixture
def cache(tmp_path, monkeypatch, model, assets_kept):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("D2SLAM_SEG_MODEL", str(model))
    return tmp_path / "cache"


def summary_lines(out: str) -> list[str]:
    return [line for line in out.splitlines() if line.startswith("d2slam run:")]


def test_one_summary_line_says_what_was_used(room, tmp_path, cache, capsys):
    traj, js = tmp_path / "t.txt", tmp_path / "r.json"
    argv = ["run", str(room), "--method", "d2slam", "--camera", "fr3", "--out", str(traj), "--metrics-json", str(js)]
    assert main(argv) == 0
    captured = capsys.readouterr()
    # the first segmentation of the sequence is announced with an estimate before it starts
    assert f"d2slam: segmenting 12 frames of room with {MODEL} into the mask cache {cache}/masks/" in captured.err
    assert "(once per sequence) (about " in captured.err
    (line,) = summary_lines(captured.out)
    assert captured.out.rstrip().endswith(line)  # the last line
    rec = json.loads(js.read_text())
    assert rec["masks"] == "onnx" and rec["masks_origin"].startswith(f"{MODEL}, cached in {cache}/masks/")
    assert line == (f"d2slam run: method d2slam; masks onnx ({rec['masks_origin']}); camera freiburg3 (--camera fr3); "
                    f"tracked 12/12 frames; ATE {rec['metrics']['ate_rmse_m']:.4f} m; wrote {traj}, {js}")
    assert main([*argv[:-2]]) == 0  # cached now: nothing announced; no --metrics-json: one file written
    captured = capsys.readouterr()
    assert "segmenting" not in captured.err and summary_lines(captured.out)[0].endswith(f"; wrote {traj}")


def test_camera_origins_and_no_masks(room, tmp_path, capsys):
    cam = tmp_path / "mycam.yaml"
    cam.write_text("%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\n"
                   "Camera.width: 640\nCamera.height: 480\nCamera.bf: 40.0\nDepthMapFactor: 5000.0\n")
    fr3 = shutil.copytree(room, tmp_path / "rgbd_dataset_freiburg3_room")  # a TUM name: the camera from it
    for seq, extra, camera in ((room, ["--camera", str(cam)], f"mycam ({cam.resolve()})"),
                               (fr3, [], "freiburg3 (folder name)")):
        assert main(["run", str(seq), "--out", str(tmp_path / "t.txt"), *extra]) == 0
        (line,) = summary_lines(capsys.readouterr().out)
        assert line.startswith(f"d2slam run: method none; masks none; camera {camera}; tracked 12/12 frames; ATE ")
    assert main(["run", str(room), "--camera", "fr3", "--out", str(tmp_path / "t.txt"), "--quiet"]) == 0
    assert capsys.readouterr().out == ""
    short = write_room_sequence(tmp_path / "short", n=6, seed=1, fps=10.0)  # 0.5 s: no 1-second RPE pair
    assert main(["run", str(short), "--camera", "fr3", "--out", str(tmp_path / "t.txt")]) == 0
    out = capsys.readouterr().out
    assert "no RPE: cannot compute RPE over 1.0 s pairs" in out and "tracked 6/6 frames; ATE 0.0" in out
    assert " m (no RPE); wrote " in summary_lines(out)[0]
    assert main(["run", str(short), "--camera", "fr3", "--out", str(tmp_path / "t.txt"), "--metrics-json",
                 str(tmp_path / "short.json"), "--quiet"]) == 0
    rec = json.loads((tmp_path / "short.json").read_text())  # the ATE alone, as the line gives it
    assert list(rec["metrics"]) == ["ate_rmse_m"] and rec["metrics_error"].startswith("no RPE: cannot compute")
    assert f"ATE {rec['metrics']['ate_rmse_m']:.4f} m (no RPE)" in summary_lines(out)[0]


def test_the_real_segmenter_is_the_default_everywhere():
    for synthetic in (True, False):
        for name in ("d2slam", "d2slam-flow", "semantic", "no-oim", "orbslam3-masked"):
            assert mask_kind(get_method(name), None, synthetic=synthetic) == "onnx"
        assert mask_kind(get_method("d2slam"), "sim", synthetic=synthetic) == "sim"  # still an option
        assert mask_kind(get_method("none"), None, synthetic=synthetic) is None
    assert mask_kind(get_method("d2slam-sim"), None, synthetic=True) == "sim"
    assert mask_kind(get_method("oracle"), None, synthetic=True) == "truth"


def test_a_missing_model_names_what_works(room, tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv("D2SLAM_SEG_MODEL", str(tmp_path / "absent.onnx"))
    out = tmp_path / "t.txt"
    assert main(["run", str(room), "--method", "d2slam", "--camera", "fr3", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.startswith("d2slam: error:") and len(err.splitlines()) == 1 and captured.out == ""
    assert "segmentation model not found" in err and "$D2SLAM_SEG_MODEL" in err and "d2slam assets fetch" in err
    assert "pass --model" not in err and "--allow-unknown-model (or" not in err and not out.exists()


def test_a_run_over_a_fragment_says_so_and_exits_3(tmp_path, capsys):
    """A run that loses track for good (the frames after the 14th are black: no keypoint) tracks 14 of 24 frames:
    its line and run JSON mark it a fragment and its ATE as over the tracked part only, and it exits with 3."""
    import cv2
    import numpy as np

    seq = write_room_sequence(tmp_path / "room", n=24, seed=1, fps=10.0)
    for path in sorted((seq / "rgb").iterdir())[14:]:
        cv2.imwrite(str(path), np.zeros((480, 640, 3), np.uint8))
    traj, js = tmp_path / "t.txt", tmp_path / "r.json"
    argv = ["run", str(seq), "--camera", "fr3", "--out", str(traj), "--metrics-json", str(js)]
    assert main(argv) == 3
    (line,) = summary_lines(capsys.readouterr().out)
    rec = json.loads(js.read_text())
    assert (rec["tracked"], rec["frames"]) == (14, 24) and rec["fragment"] is True
    assert rec["tracked_share"] == round(14 / 24, 4) and rec["min_tracked_share"] == 0.9
    assert rec["fragment_note"].startswith("tracked 14 of 24 frames (58.3 %, below evaluation.min_tracked_share 0.9)")
    assert "over the tracked frames only" in rec["fragment_note"]
    assert line == (f"d2slam run: method none; masks none; camera freiburg3 (--camera fr3); tracked 14/24 frames "
                    f"(58.3 %): a fragment, below 90 %; ATE {rec['metrics']['ate_rmse_m']:.4f} m over the tracked "
                    f"fragment only; wrote {traj}, {js}")
    assert main([*argv, "--quiet"]) == 3 and capsys.readouterr().out == ""
    cfg = tmp_path / "half.yaml"  # the share is a config field: at 0.5 the same run is a result
    cfg.write_text("evaluation: {min_tracked_share: 0.5}\n")
    assert main([*argv, "--config", str(cfg)]) == 0
    (line,) = summary_lines(capsys.readouterr().out)
    assert "tracked 14/24 frames; ATE " in line and "a fragment" not in line and "fragment only" not in line
    rec = json.loads(js.read_text())
    assert rec["fragment"] is False and "fragment_note" not in rec and rec["min_tracked_share"] == 0.5


def test_the_fragment_rule():
    from d2slam.config import DEFAULT
    from d2slam.eval.fragment import fragment_fields, is_fragment, tracked_share

    assert DEFAULT.evaluation.min_tracked_share == 0.9
    assert is_fragment(tracked_share(3, 120)) and is_fragment(0.0) and is_fragment(tracked_share(107, 120))
    assert not is_fragment(tracked_share(108, 120)) and not is_fragment(1.0)  # 90 % exactly is a result
    assert not is_fragment(tracked_share(None, 120)) and not is_fragment(tracked_share(0, 0))  # unknown: not judged
    assert is_fragment(0.6, min_share=0.7) and not is_fragment(0.6, min_share=0.5)
    assert fragment_fields(120, 120, 0.9) == {"tracked_share": 1.0, "fragment": False, "min_tracked_share": 0.9}
    assert fragment_fields(None, None, 0.9) == {"tracked_share": None, "fragment": False, "min_tracked_share": 0.9}
    assert fragment_fields(3, 120, 0.9)["fragment_note"].startswith("tracked 3 of 120 frames (2.5 %, below ")


def test_orbslam3_runs_go_through_the_same_rule(capsys):
    """``d2slam run --method orbslam3``'s line and exit status from its record: a fragment exits 3 whatever ORB-SLAM3's
    own status, a failure before any frame stays 2 and is no fragment."""
    from argparse import Namespace

    from d2slam.commands.run import print_orbslam3
    from d2slam.run.record import Orbslam3Run, RunRecord

    def record(status, tracked, frames=120):
        report = {"method": "orbslam3", "name": "seq", "status": status, "message": "m", "camera": "freiburg1",
                  "camera_source": "folder name", "frames_expected": frames, "trajectory": "t.txt",
                  **({"frames": frames, "tracked": tracked} if tracked is not None else {})}
        run = Orbslam3Run(None, frames if tracked is not None else None, tracked, 0, None, None, report)
        return RunRecord(method="orbslam3", sequence="seq", run=run, config_hash="x", status=status, error="",
                         evaluation=None)

    args = Namespace(sequence="seq", camera=None, metrics_json=None, quiet=False)
    for status, tracked, code in (("ok", 120, 0), ("lost", 110, 1), ("lost", 3, 3), ("reset", 60, 3),
                                  ("failed", None, 2), ("crashed", None, 2)):
        assert print_orbslam3(record(status, tracked), args) == code, (status, tracked)
        captured = capsys.readouterr()
        (line,) = summary_lines(captured.out + captured.err)
        assert ("a fragment, below 90 %" in line) == (code == 3), line
