"""What `d2slam run` says: one summary line (method, masks and where they came from, camera and where it came from,
frames tracked, ATE, files written), the real segmenter's masks by default, their first segmentation announced with
an estimate before it starts, and a missing model named with what works (no flag `run` lacks)."""

from __future__ import annotations

import json
import shutil

import pytest

from d2slam.assets import asset_path
from d2slam.cli import main
from d2slam.methods import get_method, mask_kind
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
