"""The real ORB-SLAM3 baseline (pyorbslam3): the project-built vocabulary loads and tracks, settings, run JSON,
repeats, and every failure recorded as a status while the caller survives."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from d2slam.assets import tum_frames
from d2slam.baselines import orbslam3 as O
from d2slam.baselines import vocab as V
from d2slam.cachefiles import sha256_file
from d2slam.config import DEFAULT
from d2slam.data import open_sequence, read_tum_trajectory
from d2slam.data.intrinsics import FREIBURG3
from d2slam.errors import D2SlamError
from d2slam.run.orbslam3_runs import run_orbslam3

pytest.importorskip("pyorbslam3")

T0 = 1305031102.0
SHIFT_PX = 1.0  # image shift per frame
DEPTH_M = 2.0  # a fronto-parallel plane: shifting the image by s px = moving the camera by -s z / fx


def _shift_px(i):
    """Image shift (x, y) of frame i: a curved path, so that the SE(3) alignment of the evaluation is defined."""
    return SHIFT_PX * i, 0.02 * i * i


def write_shift_sequence(root: Path, n: int = 36) -> Path:
    """A TUM fr3-named folder: a real fr3 frame shifted by _shift_px(i) over a fronto-parallel plane at DEPTH_M, i.e.
    a camera translating by (-sx z / fx, -sy z / fy, 0); ground truth to match (36 frames: RPE has 1 s pairs)."""
    root.mkdir(parents=True)
    (root / "rgb").mkdir()
    (root / "depth").mkdir()
    img = cv2.imread(str(tum_frames()[0]))
    depth = np.full(img.shape[:2], int(DEPTH_M * 5000), np.uint16)
    rl, dl = [], []
    for i in range(n):
        t = T0 + i / 30
        sx, sy = _shift_px(i)
        shifted = cv2.warpAffine(img, np.float32([[1, 0, sx], [0, 1, sy]]), (640, 480),
                                 borderMode=cv2.BORDER_REFLECT)
        cv2.imwrite(str(root / f"rgb/{t:.6f}.png"), shifted)
        cv2.imwrite(str(root / f"depth/{t + 0.004:.6f}.png"), depth)
        rl.append(f"{t:.6f} rgb/{t:.6f}.png")
        dl.append(f"{t + 0.004:.6f} depth/{t + 0.004:.6f}.png")
    (root / "rgb.txt").write_text("\n".join(rl) + "\n")
    (root / "depth.txt").write_text("\n".join(dl) + "\n")
    gt = []
    for t in np.arange(T0 - 0.1, T0 + n / 30 + 0.1, 0.01):
        sx, sy = _shift_px((t - T0) * 30)
        gt.append(f"{t:.4f} {-sx * DEPTH_M / 535.4:.6f} {-sy * DEPTH_M / 539.2:.6f} 0 0 0 0 1")
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return root


@pytest.fixture(scope="module")
def built_vocab(tmp_path_factory):
    out = tmp_path_factory.mktemp("vocab") / "voc.txt"
    m = V.build_vocabulary(out, synthetic=False, real=True, progress=False)
    return Path(m["path"])


@pytest.fixture(scope="module")
def seq_dir(tmp_path_factory):
    return write_shift_sequence(tmp_path_factory.mktemp("seq") / "rgbd_dataset_freiburg3_shift")


def test_settings_yaml_fr3_values_and_check(tmp_path, seq_dir):
    cam = open_sequence(seq_dir).camera
    text = O.settings_yaml(cam)
    for line in ['File.version: "1.0"', "Camera1.fx: 535.400000", "Camera1.fy: 539.200000",
                 "Camera1.cx: 320.100000", "Camera1.cy: 247.600000", "Stereo.b: 0.074710", "Stereo.ThDepth: 40.0",
                 "RGBD.DepthMapFactor: 5000.0", "ORBextractor.nFeatures: 1000", "ORBextractor.scaleFactor: 1.2",
                 "ORBextractor.nLevels: 8", "ORBextractor.iniThFAST: 20", "ORBextractor.minThFAST: 7"]:
        assert line in text
    p = tmp_path / "s.yaml"
    p.write_text(text)
    O.check_settings(p)
    p.write_text(text.replace("Stereo.b: 0.074710\n", ""))
    with pytest.raises(D2SlamError, match="Stereo.b"):
        O.check_settings(p)
    p.write_text("Camera1.fx: 1\n")
    with pytest.raises(D2SlamError, match="%YAML"):
        O.check_settings(p)


def test_map_segments_from_states():
    # NOT_INIT, OK, OK, RECENTLY_LOST, OK (reloc, same map), LOST, NO_IMAGES_YET, OK (new map)
    seg = O._map_segments(np.array([1, 2, 2, 3, 2, 4, 0, 2]))
    assert seg.tolist() == [-1, 0, 0, 0, 0, 0, 0, 1]


def test_built_vocabulary_loads_in_orbslam3_and_tracks(tmp_path, seq_dir, built_vocab):
    out = tmp_path / "traj.txt"
    record = run_orbslam3(seq_dir, out, tmp_path / "run.json", vocab=built_vocab, progress=False)
    run = record.orbslam3
    assert run["status"] == "ok", run["message"]
    # the record every method returns: ORB-SLAM3's outcome and figures, its trajectory, evaluated
    assert (record.method, record.status, record.error, record.tracked, record.repeats) == ("orbslam3", "ok", "", 36, 1)
    assert len(record.trajectory) == 36 and record.stage_ms == {} and record.loops is None
    assert record.evaluation.metrics.ate_rmse_m == run["metrics"]["ate_rmse_m"] == record.ate_range[0]
    assert record.evaluation.aligned[0].shape == (36, 3)
    assert run["frames"] == 36 and run["tracked"] == 36 and run["lost"] == 0 and run["resets"] == 0
    assert run["vocabulary"]["kind"] == "built" and run["vocabulary"]["path"] == str(built_vocab.resolve())
    assert run["ms_per_frame"] > 0 and run["fps"] > 0 and run["method"] == "orbslam3"
    saved = json.loads((tmp_path / "run.json").read_text())
    assert saved["status"] == "ok" and saved["vocabulary"]["sha256"] == sha256_file(built_vocab)
    traj = read_tum_trajectory(out)
    assert len(traj) == 36 and run["trajectory_source"] == "SaveTrajectoryTUM"
    # T_world_camera from the identity: the camera moves by -shift * z / f
    sx, sy = _shift_px(np.arange(36))
    assert np.allclose(traj.poses[:, 0, 3], -sx * DEPTH_M / 535.4, atol=0.01)
    assert np.allclose(traj.poses[:, 1, 3], -sy * DEPTH_M / 539.2, atol=0.01)
    assert np.abs(traj.poses[:, 2, 3]).max() < 0.01
    assert np.allclose(traj.poses[:, :3, :3], np.eye(3), atol=0.01)
    # evaluated with evo against the ground truth, as the engine's run JSON
    assert saved["metrics"]["ate_rmse_m"] < 0.01 and saved["metrics"]["n_matched"] == 36


def _stores() -> set:
    return set(Path(DEFAULT.baseline.orbslam3_frame_store_dir).glob("d2slam_orbslam3_frames_*"))


def test_repeats_report_median_and_spread(tmp_path, seq_dir, built_vocab):
    before = _stores()
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", repeats=2, vocab=built_vocab, max_frames=6, progress=False,
                         evaluate=False).orbslam3
    assert len(run["runs"]) == 2 and run["statuses"] == ["ok", "ok"]
    assert run["tracked"] == 6 and run["tracked_spread"]["values"] == [6, 6]
    lo, hi = run["ms_per_frame_spread"]["min"], run["ms_per_frame_spread"]["max"]
    assert lo <= run["ms_per_frame"] <= hi
    assert (tmp_path / "t.txt").is_file() and (tmp_path / "t.rep1.txt").is_file()
    # the repeats read the frames decoded once; the store is gone afterwards
    assert run["frame_store"]["frames"] == 6 and run["frame_store"]["error"] is None
    assert run["frame_store"]["bytes"] >= 6 * 640 * 480 * 7 and _stores() == before
    assert all(r["stage_ms"]["load"] > 0 for r in run["runs"])  # the decoding time per frame, measured once


def test_run_seconds_say_where_the_time_went(tmp_path, seq_dir, built_vocab):
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", vocab=built_vocab, progress=False).orbslam3
    sec = run["seconds"]
    assert set(sec) == {"track", "load", "decode", "loop", "save", "process", "evaluate"}
    assert sec["load"] > 0 and sec["decode"] > 0 and sec["evaluate"] > 0
    assert sec["track"] + sec["decode"] <= sec["loop"] <= run["wall_s"]
    assert abs(sec["process"] + sec["load"] + sec["loop"] + sec["save"] - run["wall_s"]) < 0.01
    assert run["cpu_s"] > 0 and "frame_store" not in run  # a single run decodes in its worker
    from d2slam.bench.orbslam3_vs_engine import overhead

    o = overhead(run)
    assert o["overhead"] == pytest.approx(sum(o[k] for k in ("process", "load", "decode", "save", "evaluate")))


def test_frame_store_holds_what_the_worker_would_decode(tmp_path, seq_dir):
    """The frames repeats share are the arrays the worker gives ORB-SLAM3 when it decodes them itself; an unreadable
    frame ends the store, and the worker meets its error after the frames before it."""
    import shutil

    from d2slam.baselines import _orbslam3_worker as W

    seq = open_sequence(seq_dir)
    meta = W.write_frame_store(seq, 4, tmp_path / "store")
    assert meta["frames"] == 4 and meta["error"] is None and meta["io_s"] > 0
    for i, got in enumerate(W.store_frames(tmp_path / "store")):  # (timestamp, rgb, depth, io_s, seg_s, mask_s)
        want = W.sequence_frame(seq, i)
        assert got[0] == want[0] and np.array_equal(got[1], want[1]) and np.array_equal(got[2], want[2])
        assert got[2].dtype == np.float32 and got[2].max() == pytest.approx(DEPTH_M * 5000)
    broken = tmp_path / "rgbd_dataset_freiburg3_broken"
    shutil.copytree(seq_dir, broken)
    bad = open_sequence(broken)
    bad.rgb_files[2].write_bytes(b"not a png")
    meta = W.write_frame_store(bad, 4, tmp_path / "bad")
    assert meta["frames"] == 2 and bad.rgb_files[2].name in meta["error"]
    frames = W.store_frames(tmp_path / "bad")
    assert len([next(frames), next(frames)]) == 2
    with pytest.raises(D2SlamError, match=bad.rgb_files[2].name):
        next(frames)


def test_corrupt_frame_with_repeats_is_recorded_as_without(tmp_path, seq_dir, built_vocab):
    import shutil

    broken = tmp_path / "rgbd_dataset_freiburg3_broken"
    shutil.copytree(seq_dir, broken)
    seq = open_sequence(broken)
    seq.rgb_files[5].write_bytes(b"not a png")
    run = run_orbslam3(broken, tmp_path / "t.txt", vocab=built_vocab, progress=False, repeats=2,
                         evaluate=False).orbslam3
    assert run["statuses"] == ["failed", "failed"] and seq.rgb_files[5].name in run["message"]
    assert run["frames"] == 5 and run["tracked"] == 5


def test_corrupt_vocabulary_is_a_failed_run_not_a_crash(tmp_path, seq_dir):
    bad = tmp_path / "ORBvoc.txt"
    bad.write_text("10 6 0 0\n0 1 1 2 3")  # ORB-SLAM3's own loader would accept this and crash later
    (tmp_path / "t.txt").write_text("stale\n")
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", tmp_path / "r.json", vocab=bad, progress=False).orbslam3
    assert run["status"] == "failed" and "vocabulary" in run["message"] and str(bad) in run["message"]
    assert json.loads((tmp_path / "r.json").read_text())["status"] == "failed"
    assert not (tmp_path / "t.txt").exists()
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", vocab=tmp_path / "missing.txt", progress=False).orbslam3
    assert run["status"] == "failed" and "not found" in run["message"]


def test_settings_orbslam3_rejects_is_a_failed_run(tmp_path, seq_dir, built_vocab):
    # passes our check, but ORB-SLAM3 calls exit(-1): the child dies, the caller records it
    cam = open_sequence(seq_dir).camera
    p = tmp_path / "kb.yaml"
    p.write_text(O.settings_yaml(cam).replace('"PinHole"', '"KannalaBrandt8"'))
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", vocab=built_vocab, settings=p, progress=False).orbslam3
    assert run["status"] == "failed" and "aborting" in run["message"]
    assert Path(run["log"]).is_file()
    p.write_text(O.settings_yaml(cam).replace("ORBextractor.nFeatures: 1000\n", ""))
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", vocab=built_vocab, settings=p, progress=False).orbslam3
    assert run["status"] == "failed" and "nFeatures" in run["message"]


def test_timeout_kills_the_child(tmp_path, seq_dir, built_vocab):
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", vocab=built_vocab, timeout=0.2, progress=False).orbslam3
    assert run["status"] == "timeout" and "limit" in run["message"]
    assert run["frames"] < 36


def test_corrupt_frame_mid_sequence_is_recorded(tmp_path, seq_dir, built_vocab):
    import shutil

    broken = tmp_path / "rgbd_dataset_freiburg3_broken"
    shutil.copytree(seq_dir, broken)
    seq = open_sequence(broken)
    seq.rgb_files[5].write_bytes(b"not a png")
    run = run_orbslam3(broken, tmp_path / "t.txt", vocab=built_vocab, progress=False).orbslam3
    assert run["status"] == "failed" and seq.rgb_files[5].name in run["message"]
    assert run["frames"] == 5 and run["tracked"] == 5  # what ran before it is kept
    assert len(read_tum_trajectory(tmp_path / "t.txt")) == 5


def test_bad_arguments_raise(tmp_path, seq_dir):
    with pytest.raises(D2SlamError, match="repeats"):
        run_orbslam3(seq_dir, tmp_path / "t.txt", repeats=0)
    with pytest.raises(D2SlamError, match="not found"):
        run_orbslam3(tmp_path / "nope", tmp_path / "t.txt")


def test_config_section_defaults():
    assert DEFAULT.baseline.vocab_k == 10 and DEFAULT.baseline.vocab_levels == 6
    assert all(900 <= s <= 999 for s in DEFAULT.baseline.vocab_train_seeds)


def test_bench_helpers_and_topic_registered(capsys):
    from d2slam import bench
    from d2slam.bench import orbslam3_vs_engine as B

    assert "orbslam3_vs_engine" in bench.topics()
    assert B._ms_per_frame({"fps": 20.0}) == 50.0 and B._ms_per_frame({"ms_per_frame": 7}) == 7.0
    assert B._ms_per_frame({}) is None
    assert B._ms_per_frame({"method": "none", "fps": 5.0, "stage_ms": {"load": 30.0, "extract": 20.0,
                                                                       "track": 40.0}}) == 60.0
    row = {"sequence": "walking_xyz s101", "variant": "dynamic", "method": "orbslam3", "status": "lost",
           "frames": 300, "tracked": 280, "ms_per_frame": 20.0, "ms_per_frame_spread": {"min": 18.0, "max": 25.0},
           "metrics": {"ate_rmse_m": 0.25, "rpe_trans_m": 0.3, "rpe_rot_deg": 5.0},
           "metrics_spread": {"ate_rmse_m": {"min": 0.2, "max": 0.4}}}
    ours = dict(row, method="none", status="ok", tracked=300, ms_per_frame=50.0, ms_per_frame_spread=None,
                metrics_spread=None)

    class Args:
        frames, repeats = 300, 3

    B._print_table([row, ours], Args)
    out = capsys.readouterr().out
    assert "0.2500 [0.2000, 0.4000]" in out and "280/300" in out and "20.0 [18.0, 25.0]" in out
    assert "= 2.5x" in out


def test_run_command_entry_prints_the_outcome(tmp_path, seq_dir, built_vocab, capsys):
    from argparse import Namespace

    from d2slam.commands.run import print_orbslam3
    from d2slam.run.methods import get_method

    args = Namespace(sequence=str(seq_dir), out=str(tmp_path / "t.txt"), metrics_json=str(tmp_path / "r.json"),
                     camera=None, quiet=True, vocab=str(built_vocab))
    runner = get_method("orbslam3").runner
    assert print_orbslam3(runner(args), args) == 0
    out = capsys.readouterr().out
    assert "orbslam3 rgbd_dataset_freiburg3_shift: ok" in out and "vocabulary: built" in out
    args.vocab = str(tmp_path / "missing.txt")
    record = runner(args)
    assert print_orbslam3(record, args) == 2 and (record.status, record.trajectory) == ("failed", None)
    assert "failed" in capsys.readouterr().err


def test_a_camera_file_gives_orbslam3_its_th_depth(tmp_path, seq_dir, built_vocab):
    """``--camera FILE.yaml``: ORB-SLAM3's settings take the file's camera and its Stereo.ThDepth, not the TUM 40."""
    from d2slam.data.intrinsics import read_camera_file

    cam = tmp_path / "cam.yaml"
    cam.write_text(O.settings_yaml(FREIBURG3).replace(f"Stereo.ThDepth: {DEFAULT.engine.th_depth:.6f}",
                                                      "Stereo.ThDepth: 35.000000"))
    assert read_camera_file(cam).th_depth == 35.0
    out = tmp_path / "traj.txt"
    run = run_orbslam3(seq_dir, out, vocab=built_vocab, camera=str(cam), max_frames=5, progress=False).orbslam3
    assert run["status"] in ("ok", "lost"), run["message"]
    written = read_camera_file(run["settings"])
    assert written.th_depth == 35.0 and written.camera.fx == FREIBURG3.fx


def test_the_worker_imports_this_d2slam_from_any_folder(tmp_path, seq_dir, built_vocab, monkeypatch):
    """``python -m`` puts the working folder first on sys.path: another d2slam checkout there must not be run."""
    fake = tmp_path / "elsewhere" / "d2slam"
    fake.mkdir(parents=True)
    (fake / "__init__.py").write_text("raise ImportError('the d2slam of the working folder')\n")
    monkeypatch.chdir(fake.parent)
    run = run_orbslam3(seq_dir, tmp_path / "t.txt", vocab=built_vocab, max_frames=3, progress=False,
                         evaluate=False).orbslam3
    assert run["status"] == "ok", run["message"]


def test_bench_prints_the_per_run_split_and_takes_a_config(tmp_path, built_vocab, capsys):
    """`d2slam bench orbslam3_vs_engine` prints where each run's seconds went; `--config` reaches ORB-SLAM3's runs
    (here: no frame store, every repeat decodes its frames)."""
    from d2slam.cli import main
    from d2slam.study.sequences import ensure_sequence

    ensure_sequence("sitting_static", 101, 40, False)  # the study's cached test sequence
    (tmp_path / "c.yaml").write_text("baseline: {orbslam3_frame_store_mb: 0}\n")
    argv = ["bench", "orbslam3_vs_engine", "--scenarios", "sitting_static", "--seeds", "101", "--frames", "40", "--variants",
            "dynamic", "--methods", "orbslam3", "--repeats", "2", "--vocab", str(built_vocab)]
    assert main(argv + ["--out", str(tmp_path / "a")]) == 0
    out = capsys.readouterr().out
    assert "per-run seconds" in out and "overhead" in out and "decode" in out
    rows = json.loads((tmp_path / "a" / "bench_orbslam3.json").read_text())["rows"]
    assert rows[0]["frame_store"]["frames"] == 40
    assert main(argv + ["--out", str(tmp_path / "b"), "--config", str(tmp_path / "c.yaml")]) == 0
    rows = json.loads((tmp_path / "b" / "bench_orbslam3.json").read_text())["rows"]
    assert "frame_store" not in rows[0] and rows[0]["status"] in ("ok", "lost", "reset")


def test_run_command_marks_an_orbslam3_fragment(tmp_path, built_vocab, monkeypatch, capsys):
    """`d2slam run --method orbslam3` on frames that turn black after the 12th of 36 (ORB-SLAM3 cannot track them):
    the run JSON and the line say it is a fragment and the command exits with 3 (the same rule as the engine's)."""
    from d2slam.cli import main

    seq = write_shift_sequence(tmp_path / "rgbd_dataset_freiburg3_shift")
    for path in sorted((seq / "rgb").iterdir())[12:]:
        cv2.imwrite(str(path), np.zeros((480, 640, 3), np.uint8))
    monkeypatch.setenv("PYORBSLAM3_VOCAB", str(built_vocab))
    js = tmp_path / "r.json"
    assert main(["run", str(seq), "--method", "orbslam3", "--out", str(tmp_path / "t.txt"), "--metrics-json",
                 str(js)]) == 3
    rec = json.loads(js.read_text())
    assert rec["fragment"] is True and rec["tracked"] <= 12 and rec["frames"] == 36
    assert rec["tracked_share"] == round(rec["tracked"] / 36, 4) and "fragment_note" in rec
    captured = capsys.readouterr()
    (line,) = [x for x in (captured.out + captured.err).splitlines() if x.startswith("d2slam run:")]
    assert f"tracked {rec['tracked']}/36 frames (" in line and "): a fragment, below 90 %;" in line
