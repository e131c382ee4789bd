"""What a user brings: any RGB-D camera (ORB-SLAM3 settings YAML), a config file, output paths that cannot be
written, depth in another scale, a sequence with unpaired frames or no ground truth, and a study on a partial TUM
copy. Each bad case is a one-line error (exit 2) or a console message, before any long work."""

from __future__ import annotations

import json
import os
import re
import shutil
import tempfile
from pathlib import Path

import cv2
import numpy as np
import pytest

from d2slam.baselines.orbslam3 import settings_yaml
from d2slam.cli import main
from d2slam.config import DEFAULT, load_config_file
from d2slam.data import open_sequence
from d2slam.data.depth_scale import depth_scale_warning
from d2slam.data.intrinsics import FREIBURG1, FREIBURG3, read_camera_file
from d2slam.errors import D2SlamError
from d2slam.run.orbslam3_runs import run_orbslam3
from d2slam.slam.fixture import write_room_sequence

# ORB-SLAM2 / ORB-SLAM3 0.x style (TUM3.yaml), with OpenCV's first line that PyYAML rejects.
OLD_TUM3 = """%YAML:1.0

# Camera Parameters. Adjust them!
Camera.fx: 535.4
Camera.fy: 539.2
Camera.cx: 320.1
Camera.cy: 247.6

Camera.k1: 0.0
Camera.k2: 0.0
Camera.p1: 0.0
Camera.p2: 0.0

Camera.width: 640
Camera.height: 480
Camera.fps: 30.0
Camera.bf: 40.0
Camera.RGB: 1
ThDepth: 35.0
DepthMapFactor: 5000.0
ORBextractor.nFeatures: 1000
"""

INTRINSICS = ("fx", "fy", "cx", "cy", "width", "height", "dist", "depth_factor", "bf")


def same_camera(a, b, tol=1e-5):
    return all(np.allclose(getattr(a, f), getattr(b, f), atol=tol) for f in INTRINSICS)


@pytest.fixture(scope="module")
def room(tmp_path_factory):
    """A TUM-layout folder (fr3 intrinsics, depth x5000) whose name names no camera."""
    return write_room_sequence(tmp_path_factory.mktemp("room") / "room", n=12, seed=1, fps=10.0)


def run_cmd(room, tmp_path, *extra, name="t"):
    out, js = tmp_path / f"{name}.txt", tmp_path / f"{name}.json"
    code = main(["run", str(room), "--out", str(out), "--metrics-json", str(js), "--quiet", *extra])
    return code, out, js


# ------------------------------------------------------------------------------------------------------------------
# --camera FILE
# ------------------------------------------------------------------------------------------------------------------
def test_old_style_settings_file(tmp_path):
    path = tmp_path / "TUM3.yaml"
    path.write_text(OLD_TUM3)
    s = read_camera_file(path)
    assert same_camera(s.camera, FREIBURG3) and s.th_depth == 35.0 and s.camera.name == "TUM3"


def test_new_style_settings_file_round_trips(tmp_path):
    """ORB-SLAM3 1.0 keys (Camera1.*, Stereo.b, RGBD.DepthMapFactor, Stereo.ThDepth), as our baseline writes them."""
    path = tmp_path / "fr1.yaml"
    path.write_text(settings_yaml(FREIBURG1))
    s = read_camera_file(path)
    assert same_camera(s.camera, FREIBURG1, tol=1e-4) and s.th_depth == DEFAULT.engine.th_depth


@pytest.mark.parametrize("text, match", [
    (OLD_TUM3.replace("Camera.fy: 539.2\n", ""), "lack Camera.fy"),
    (OLD_TUM3.replace("DepthMapFactor: 5000.0\n", "").replace("Camera.bf: 40.0\n", ""), "DepthMapFactor, Camera.bf"),
    ('Camera.type: "KannalaBrandt8"\n' + OLD_TUM3.split("\n", 1)[1], "only PinHole"),
    (OLD_TUM3.replace("Camera.fx: 535.4", "Camera.fx: abc"), "Camera.fx must be a number"),
    ("Camera.fx: [1, 2\n", "not a YAML file"),
    ("- 1\n- 2\n", "must be a YAML mapping"),
])
def test_bad_settings_files(tmp_path, text, match):
    path = tmp_path / "cam.yaml"
    path.write_text(text)
    with pytest.raises(D2SlamError, match=match):
        read_camera_file(path)


def test_run_with_a_camera_file_records_it_and_its_th_depth(room, tmp_path):
    cam = tmp_path / "mycam.yaml"
    cam.write_text(OLD_TUM3)
    code, out, js = run_cmd(room, tmp_path, "--camera", str(cam))
    assert code == 0
    rec = json.loads(js.read_text())
    assert rec["camera"]["fx"] == 535.4 and rec["camera"]["depth_factor"] == 5000.0
    assert rec["camera"]["source"] == str(cam.resolve()) and rec["camera"]["name"] == "mycam"
    code, out3, js3 = run_cmd(room, tmp_path, "--camera", "fr3", name="fr3")
    rec3 = json.loads(js3.read_text())
    assert code == 0 and rec3["camera"]["source"] == "fr3" and rec3["camera"]["name"] == "freiburg3"
    assert rec["config_hash"] != rec3["config_hash"]  # ThDepth 35 of the file is in the run's config
    cam.write_text(OLD_TUM3.replace("ThDepth: 35.0", "ThDepth: 40.0"))
    code, out4, js4 = run_cmd(room, tmp_path, "--camera", str(cam), name="same")
    assert code == 0 and json.loads(js4.read_text())["config_hash"] == rec3["config_hash"]
    body = [ln for ln in out4.read_text().splitlines() if not ln.startswith("#")]
    assert body == [ln for ln in out3.read_text().splitlines() if not ln.startswith("#")]


def test_camera_that_conflicts_with_a_synthetic_sequence_is_an_error(tmp_path, capsys):
    d = tmp_path / "wx"
    assert main(["synth", "walking_xyz", "--out", str(d), "--frames", "3", "--seed", "0", "--workers", "1"]) == 0
    capsys.readouterr()
    assert main(["run", str(d), "--camera", "fr1", "--out", str(tmp_path / "t.txt"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "conflicts with this synthetic sequence's own camera" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "t.txt").exists()
    code, _, js = run_cmd(d, tmp_path, "--camera", "fr3")  # the same camera as its own: fine
    assert code == 0 and json.loads(js.read_text())["camera"]["source"] == "scene.json"


# ------------------------------------------------------------------------------------------------------------------
# --config FILE
# ------------------------------------------------------------------------------------------------------------------
def test_config_file_overrides_and_is_saved(room, tmp_path, capsys):
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("engine:\n  th_depth: 30.0\nsynth:\n  depth_time_offset: [0.001, 0.002]\n")
    config, overrides = load_config_file(cfg)
    assert config.engine.th_depth == 30.0 and config.synth.depth_time_offset == (0.001, 0.002)
    assert config.dynamics == DEFAULT.dynamics and overrides["engine"] == {"th_depth": 30.0}
    code, _, js = run_cmd(room, tmp_path, "--camera", "fr3", "--config", str(cfg))
    rec = json.loads(js.read_text())
    assert code == 0 and rec["config_overrides"] == overrides and rec["config"]["engine"]["th_depth"] == 30.0
    assert rec["config_file"] == str(cfg.resolve())
    for text, match in [("engine:\n  nope: 1\n", "unknown engine config field 'nope'"),
                        ("nope:\n  x: 1\n", "unknown config section 'nope'"), ("engine: 3\n", "expected sections")]:
        cfg.write_text(text)
        assert main(["run", str(room), "--camera", "fr3", "--config", str(cfg), "--out", str(tmp_path / "x.txt")]) == 2
        assert match in capsys.readouterr().err


def test_config_values_are_type_checked(room, tmp_path, capsys):
    """A value of the wrong type is a one-line error naming the field, the type expected and the value given, before
    anything runs; ints are taken for floats (as floats), lists for tuples, a bool is no number."""
    cfg = tmp_path / "cfg.yaml"
    out = tmp_path / "x.txt"
    for text, match in [("dynamics: {z_far: five}\n", "dynamics.z_far must be float, got 'five' (str)"),
                        ("dynamics: {z_far: true}\n", "dynamics.z_far must be float, got True (bool)"),
                        ("orb: {n_features: 1.5}\n", "orb.n_features must be int, got 1.5 (float)"),
                        ("orb: {n_features: yes}\n", "orb.n_features must be int, got True (bool)"),
                        ("dynamics: {flow: {enabled: 1}}\n", "dynamics.flow.enabled must be bool, got 1 (int)"),
                        ("dynamics: {f_ransac_method: 3}\n", "dynamics.f_ransac_method must be str, got 3 (int)"),
                        ("engine: {optimizer: gtsam}\n", "engine.optimizer must be one of 'lm', 'g2o', got 'gtsam'"),
                        ("synth: {depth_time_offset: [0.1, 0.2, 0.3]}\n",
                         "synth.depth_time_offset must be tuple[float, float], got [0.1, 0.2, 0.3] (list)"),
                        ("synth: {depth_time_offset: 0.1}\n", "synth.depth_time_offset must be tuple[float, float]"),
                        ("baseline: {vocab_train_seeds: [900, x]}\n",
                         "baseline.vocab_train_seeds[1] must be int, got 'x' (str)"),
                        ("synth: {body: 3}\n", "synth.body must be a section of fields (BodyConfig), got 3")]:
        cfg.write_text(text)
        with pytest.raises(D2SlamError, match=re.escape(match)):
            load_config_file(cfg)
        assert main(["run", str(room), "--camera", "fr3", "--config", str(cfg), "--out", str(out)]) == 2
        captured = capsys.readouterr()
        assert match in captured.err and len(captured.err.strip().splitlines()) == 1
        assert "Traceback" not in captured.err and captured.out == "" and not out.exists()
    cfg.write_text("dynamics: {z_far: 5}\nsynth: {depth_time_offset: [0, 0.01], body: {simplify: 3}}\n")
    config, _ = load_config_file(cfg)
    assert config.dynamics.z_far == 5.0 and isinstance(config.dynamics.z_far, float)
    assert config.synth.depth_time_offset == (0.0, 0.01) and config.synth.body.simplify == 3.0
    assert config.hash() == load_config_file(cfg)[0].hash()


# ------------------------------------------------------------------------------------------------------------------
# Output paths, checked before the run
# ------------------------------------------------------------------------------------------------------------------
@pytest.fixture
def readonly_dir(tmp_path):
    """A folder that refuses new files (chmod 555; as root, which ignores it, /sys, a read-only file system)."""
    d = tmp_path / "ro"
    d.mkdir()
    d.chmod(0o555)
    for candidate in (d, Path("/sys")):
        try:
            fd, name = tempfile.mkstemp(dir=candidate)
        except OSError:
            yield candidate
            break
        os.close(fd)
        os.unlink(name)
    else:
        pytest.fail("no folder on this machine refuses writes")
    d.chmod(0o755)


def bad_outputs(tmp_path, readonly_dir, name):
    folder = tmp_path / "a_folder"
    folder.mkdir(exist_ok=True)
    return [(tmp_path / "missing_dir" / name, "folder does not exist"), (folder, "is a folder"),
            (readonly_dir / name, "cannot write into the folder")]


def test_run_outputs_checked_before_the_run(room, tmp_path, readonly_dir, capsys):
    for path, match in bad_outputs(tmp_path, readonly_dir, "run.json"):
        out = tmp_path / "traj.txt"
        assert main(["run", str(room), "--camera", "fr3", "--out", str(out), "--metrics-json", str(path)]) == 2
        err = capsys.readouterr().err
        assert match in err and "--metrics-json" in err and len(err.strip().splitlines()) == 1
        assert not out.exists()  # nothing was run
        assert main(["run", str(room), "--camera", "fr3", "--out", str(path)]) == 2
        assert match in capsys.readouterr().err
        for method in ("orbslam3", "d2slam"):  # the real ORB-SLAM3 has the same rule
            assert main(["run", str(room), "--camera", "fr3", "--method", method, "--out", str(path)]) == 2
            assert match in capsys.readouterr().err
    with pytest.raises(D2SlamError, match="folder does not exist"):  # the library does not create the folder
        run_orbslam3(room, tmp_path / "nowhere" / "t.txt", camera="fr3", progress=False)
    assert not (tmp_path / "nowhere").exists()


def test_other_commands_check_their_outputs(room, tmp_path, readonly_dir, capsys):
    gt = room / "groundtruth.txt"
    for path, match in bad_outputs(tmp_path, readonly_dir, "plot.png"):
        assert main(["eval", str(gt), str(gt), "--plot", str(path)]) == 2
        assert match in capsys.readouterr().err
        assert main(["vocab", "build", "--out", str(path), "--no-synthetic"]) == 2
        assert match in capsys.readouterr().err
    blocker = tmp_path / "a_file"
    blocker.write_text("x")
    for args in (["synth", "walking_xyz", "--frames", "3", "--out"], ["study", "--frames", "40", "--out"]):
        for path, match in ((blocker, "exists and is not a folder"), (readonly_dir / "sub", "cannot write")):
            assert main([*args, str(path)]) == 2
            assert match in capsys.readouterr().err


# ------------------------------------------------------------------------------------------------------------------
# Depth scale, unpaired frames, no ground truth
# ------------------------------------------------------------------------------------------------------------------
def test_depth_in_millimetres_is_reported_with_the_factor_to_set(room, tmp_path, capsys):
    mm = shutil.copytree(room, tmp_path / "room_mm")
    for png in (mm / "depth").glob("*.png"):
        d = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), np.round(d.astype(np.float64) / 5.0).astype(np.uint16))  # metres x 1000
    assert depth_scale_warning(open_sequence(room, camera="fr3")) is None
    msg = depth_scale_warning(open_sequence(mm, camera="fr3"))
    assert "depth factor 5000" in msg and "look like depth factor 1000" in msg and "DepthMapFactor" in msg
    assert main(["run", str(mm), "--camera", "fr3", "--out", str(tmp_path / "t.txt"), "--quiet"]) == 0
    assert "warning: the depth does not match the ground truth's camera motion" in capsys.readouterr().err
    cam = tmp_path / "mm.yaml"
    cam.write_text(OLD_TUM3.replace("DepthMapFactor: 5000.0", "DepthMapFactor: 1000.0"))
    assert main(["run", str(mm), "--camera", str(cam), "--out", str(tmp_path / "t.txt"), "--quiet"]) == 0
    assert "warning" not in capsys.readouterr().err


def test_fewer_frames_and_no_ate_are_said_on_the_console(room, tmp_path, capsys):
    cut = shutil.copytree(room, tmp_path / "cut")
    lines = (cut / "depth.txt").read_text().splitlines()
    (cut / "depth.txt").write_text("\n".join(lines[:-3]) + "\n")  # the last 3 RGB frames lose their depth
    (cut / "groundtruth.txt").unlink()
    assert main(["run", str(cut), "--camera", "fr3", "--out", str(tmp_path / "t.txt")]) == 0
    out = capsys.readouterr().out
    assert "9 of the 12 frames of rgb.txt were run" in out and "no depth image within" in out
    assert "no ATE/RPE: the sequence has no groundtruth.txt" in out


# ------------------------------------------------------------------------------------------------------------------
# Study on a partial TUM copy
# ------------------------------------------------------------------------------------------------------------------
def test_study_tum_root_missing_partial_and_all_failed(tmp_path, capsys):
    assert main(["study", "--tum-root", str(tmp_path / "does_not_exist"), "--out", str(tmp_path / "o")]) == 2
    assert "--tum-root: folder not found" in capsys.readouterr().err
    root = tmp_path / "tum"
    write_room_sequence(root / "rgbd_dataset_freiburg3_walking_xyz", n=12, seed=1, fps=10.0)
    out = tmp_path / "res"
    code = main(["study", "--tum-root", str(root), "--out", str(out), "--methods", "none", "--seeds", "101",
                 "--frames", "0", "--jobs", "1", "--no-plots", "--quiet"])
    text = capsys.readouterr().out
    assert code == 0 and "skipped (not under" in text and "rgbd_dataset_freiburg3_sitting_static" in text
    assert "1 runs: 1 ok, 0 failed" in text
    tables = (out / "tables.md").read_text()
    assert "all frames" in tables and "0 frames" not in tables
    (root / "rgbd_dataset_freiburg3_walking_xyz" / "groundtruth.txt").write_text("# nothing\n")
    code = main(["study", "--tum-root", str(root), "--out", str(tmp_path / "res2"), "--methods", "none",
                 "--seeds", "101", "--frames", "0", "--jobs", "1", "--no-plots", "--quiet"])
    assert code == 1 and "no run succeeded" in capsys.readouterr().err


def test_input_files_that_are_missing_or_not_text_are_one_line_errors(tmp_path):
    from d2slam.baselines.vocab import Vocabulary
    from d2slam.errors import D2SlamError

    binary = tmp_path / "cam.yaml"
    binary.write_bytes(b"\xff\xfe\x00\x81")
    with pytest.raises(D2SlamError, match="camera settings file not found"):
        read_camera_file(tmp_path / "missing.yaml")
    with pytest.raises(D2SlamError, match="cannot read camera settings as text"):
        read_camera_file(binary)
    with pytest.raises(D2SlamError, match="cannot read vocabulary as text"):
        Vocabulary.load(binary)
