"""The pipeline and `d2slam run` on a small TUM folder written from the analytic room."""

import json

import numpy as np
import pytest

import d2slam.run.methods as M
from d2slam.cli import main
from d2slam.data import open_sequence, read_tum_trajectory
from d2slam.errors import D2SlamError
from d2slam.run.methods import get_filter, get_method, methods, register
from d2slam.run.sequence import run_sequence
from d2slam.slam.fixture import write_room_sequence


@pytest.fixture(scope="module")
def room_dir(tmp_path_factory):
    return write_room_sequence(tmp_path_factory.mktemp("room") / "room", n=20, seed=1, fps=10.0)


def test_run_sequence_result_and_recorder(room_dir):
    seq = open_sequence(room_dir, camera="fr3")
    calls = []
    res = run_sequence(seq, recorder=lambda i, kps, bel, diag: calls.append((i, kps.shape, bel, diag)),
                       progress=False)
    assert res.frames == 20 and res.tracked == 20 and res.lost == 0
    assert set(res.stage_ms) == {"load", "extract", "filter", "track", "local_ba", "loop"}
    assert len(res.trajectory) == 20 and res.fps > 0
    assert [c[0] for c in calls] == list(range(20)) and calls[3][1][1] == 2 and calls[3][2] is None


def test_run_command_writes_trajectory_and_json(room_dir, tmp_path, capsys):
    out, js = tmp_path / "traj.txt", tmp_path / "run.json"
    assert main(["run", str(room_dir), "--camera", "fr3", "--method", "none", "--out", str(out), "--metrics-json",
                 str(js), "--quiet"]) == 0
    rec = json.loads(js.read_text())
    for key in ("frames", "tracked", "lost", "fps", "load_ms", "extract_ms", "track_ms", "local_ba_ms", "filter_ms",
                "method", "config_hash", "sequence"):
        assert key in rec
    assert rec["tracked"] == 20 and rec["method"] == "none"
    assert rec["metrics"]["ate_rmse_m"] < 0.02 and rec["metrics"]["rpe_rot_deg"] < 1.0
    # from this (test) process's start to the end of the first frame: positive, within the process's lifetime
    import psutil
    import time

    assert 0 < rec["startup_s"] < time.time() - psutil.Process().create_time()
    traj = read_tum_trajectory(out)
    assert len(traj) == 20
    # eval on the written files gives the same ATE as the run's JSON
    assert main(["eval", str(room_dir / "groundtruth.txt"), str(out), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert ev["ate_rmse_m"] == pytest.approx(rec["metrics"]["ate_rmse_m"], abs=1e-6)


def test_single_frame_sequence(tmp_path, capsys):
    d = write_room_sequence(tmp_path / "one", n=1)
    out, js = tmp_path / "t.txt", tmp_path / "r.json"
    assert main(["run", str(d), "--camera", "fr3", "--out", str(out), "--metrics-json", str(js), "--quiet"]) == 0
    rec = json.loads(js.read_text())
    assert rec["frames"] == 1 and rec["tracked"] == 1 and "metrics" not in rec  # too short to evaluate
    assert main(["eval", str(d / "groundtruth.txt"), str(out)]) == 2
    assert "need >= 3" in capsys.readouterr().err


def test_method_registry(monkeypatch):
    assert "none" in methods() and get_filter("none", None) is None
    with pytest.raises(D2SlamError, match="unknown method"):
        get_method("nope")
    monkeypatch.setattr(M, "_REGISTRY", dict(M._REGISTRY))  # the registration below ends with this test
    register("_test_all_static", lambda cfg: None)
    assert "_test_all_static" in methods()


def test_run_command_clear_errors(tmp_path, capsys):
    assert main(["run", str(tmp_path / "missing"), "--camera", "fr3", "--out", str(tmp_path / "t.txt")]) == 2
    assert main(["run", str(tmp_path), "--camera", "fr3", "--out", str(tmp_path / "no" / "t.txt")]) == 2
    assert "does not exist" in capsys.readouterr().err


@pytest.fixture(scope="module")
def synth_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("synth") / "wx"
    assert main(["synth", "walking_xyz", "--out", str(d), "--frames", "6", "--seed", "0", "--workers", "1"]) == 0
    return d


def test_run_command_records_keypoint_truth_on_synthetic(synth_dir, tmp_path):
    out, js = tmp_path / "traj.txt", tmp_path / "run.json"
    assert main(["run", str(synth_dir), "--method", "semantic", "--masks", "gt", "--out", str(out),
                 "--metrics-json", str(js), "--quiet"]) == 0
    kp = json.loads(js.read_text())["keypoints"]
    assert kp["frames"] == 6 and kp["keypoints"] > 0 and kp["dynamic_keypoints"] > 0
    assert kp["frames_with_diagnostics"] == 6


def test_d2slam_flow_runs_the_flow_through_the_engine(synth_dir, tmp_path):
    """--method d2slam-flow: the engine hands the previous grey image to the hook, the flow runs on every frame after
    the first, and two runs give the same trajectory."""
    from d2slam.config import DEFAULT
    from d2slam.run.methods import get_filter as dyn_filter
    from d2slam.segmentation import masks_for, stack_masks

    seq = open_sequence(synth_dir)
    shape = (seq.camera.height, seq.camera.width)
    flows = []

    def record(i, kps, bel, diag):
        flows.append(diag.timings_ms.get("flow"))

    res = run_sequence(seq, DEFAULT, keypoint_filter=dyn_filter("d2slam-flow", DEFAULT), recorder=record,
                       progress=False, mask_provider=lambda i: stack_masks(masks_for(seq, i, "sim", DEFAULT), shape))
    assert res.tracked == 6 and flows[0] is None and all(f is not None and f > 0 for f in flows[1:])
    trajs = []
    for k in range(2):
        out, js = tmp_path / f"t{k}.txt", tmp_path / f"r{k}.json"
        assert main(["run", str(synth_dir), "--method", "d2slam-flow", "--out", str(out), "--metrics-json", str(js),
                     "--quiet"]) == 0
        trajs.append(out.read_text())
    assert trajs[0] == trajs[1] and json.loads(js.read_text())["method"] == "d2slam-flow"


def test_oracle_is_the_keypoint_truth(synth_dir, tmp_path, capsys):
    """--method oracle runs on the truth masks (persons, moved objects while they move) and its labels are the
    keypoint truth: F1 1 by construction; it refuses other masks and real data."""
    out, js = tmp_path / "traj.txt", tmp_path / "run.json"
    assert main(["run", str(synth_dir), "--method", "oracle", "--out", str(out), "--metrics-json", str(js),
                 "--quiet"]) == 0
    rec = json.loads(js.read_text())
    final = rec["keypoints"]["modules"]["final"]
    assert rec["masks"] == "truth" and rec["keypoints"]["dynamic_keypoints"] > 0
    assert final["fp"] == 0 and final["fn"] == 0 and final["f1"] == 1.0
    assert main(["run", str(synth_dir), "--method", "oracle", "--masks", "sim", "--out", str(out)]) == 2
    assert "always uses the 'truth' masks" in capsys.readouterr().err


@pytest.fixture(scope="module")
def synth_twin_dir(tmp_path_factory):
    d = tmp_path_factory.mktemp("synth") / "wx_twin"
    assert main(["synth", "walking_xyz", "--out", str(d), "--frames", "6", "--seed", "0", "--workers", "1",
                 "--static-twin"]) == 0
    return d


def test_masks_from_another_sequence_the_occluded_twin(synth_dir, synth_twin_dir, tmp_path, capsys):
    """--masks-from: the oracle on the static twin with its dynamic sequence's truth (the occluded twin) flags the
    keypoints inside the silhouettes, which are static in the twin (its own truth is empty); the masks' sequence must
    be at the run's frames; a method without masks refuses the option."""
    from d2slam.segmentation import mask_source

    out, js = tmp_path / "traj.txt", tmp_path / "run.json"
    assert main(["run", str(synth_twin_dir), "--method", "oracle", "--out", str(out), "--metrics-json", str(js),
                 "--quiet"]) == 0
    alone = json.loads(js.read_text())["keypoints"]["modules"]["final"]
    assert alone["tp"] == alone["fp"] == 0  # the twin's own truth: nothing moves, nothing flagged
    assert main(["run", str(synth_twin_dir), "--method", "oracle", "--masks-from", str(synth_dir), "--out", str(out),
                 "--metrics-json", str(js), "--quiet"]) == 0
    rec = json.loads(js.read_text())
    assert rec["masks_from"] == str(synth_dir) and rec["tracked"] == 6
    assert rec["keypoints"]["modules"]["final"]["fp"] > 0  # the silhouettes' keypoints are flagged
    assert main(["run", str(synth_twin_dir), "--method", "none", "--masks-from", str(synth_dir), "--out",
                 str(out)]) == 2
    assert "reads no masks" in capsys.readouterr().err
    twin, dyn = open_sequence(synth_twin_dir), open_sequence(synth_dir)
    assert mask_source(twin, None) is twin and mask_source(twin, dyn) is dyn

    class Shifted:  # the same sequence with one timestamp moved, or one frame short
        def __init__(self, ts, root):
            self.timestamps, self.root = ts, root

        def __len__(self):
            return len(self.timestamps)

    ts = np.array(dyn.timestamps, dtype=np.float64)
    ts[3] += 0.01
    with pytest.raises(D2SlamError, match="frame 3 is at"):
        mask_source(twin, Shifted(ts, synth_dir))
    with pytest.raises(D2SlamError, match="has 5 frames, the run's 6"):
        mask_source(twin, Shifted(ts[:5], synth_dir))


def test_truth_masks_are_the_dynamic_truth(synth_dir):
    from d2slam.data import open_sequence
    from d2slam.eval.keypoints import OracleFilter
    from d2slam.segmentation import masks_for, stack_masks

    seq = open_sequence(synth_dir)
    for i in range(len(seq)):
        m = stack_masks(masks_for(seq, i, "truth"), (seq.camera.height, seq.camera.width))
        np.testing.assert_array_equal(m.any(axis=0), seq.dynamic_mask(i))
    kps = np.array([[0.0, 0.0], [10.4, 3.6], [np.nan, 1.0]])
    masks = np.zeros((2, 8, 12), bool)
    masks[1, 4, 10] = True
    inp = type("Inp", (), {"kps": kps, "masks": masks})()
    np.testing.assert_array_equal(OracleFilter()(inp), [0.0, 1.0, 0.0])
    inp.masks = None
    np.testing.assert_array_equal(OracleFilter()(inp), [0.0, 0.0, 0.0])


def test_oracle_needs_synthetic_truth(room_dir, tmp_path, capsys):
    from d2slam.study.grid import default_methods, expand_grid

    assert main(["run", str(room_dir), "--camera", "fr3", "--method", "oracle", "--out",
                 str(tmp_path / "t.txt")]) == 2
    assert "real data has no such truth" in capsys.readouterr().err
    assert "oracle" in default_methods() and "oracle" not in default_methods("tum")
    with pytest.raises(D2SlamError, match="synthetic truth"):
        expand_grid(["walking_xyz"], ["none", "oracle"], [1], 0, source="tum")


def test_run_command_no_keypoint_truth_on_tum(room_dir, tmp_path):
    js = tmp_path / "run.json"
    assert main(["run", str(room_dir), "--camera", "fr3", "--out", str(tmp_path / "t.txt"), "--metrics-json",
                 str(js), "--quiet"]) == 0
    assert "keypoints" not in json.loads(js.read_text())


def test_run_command_onnx_masks_go_through_masks_for(room_dir, tmp_path, monkeypatch):
    import d2slam.run.runner as seg  # masks_for as the run path calls it

    kinds = []

    def fake_masks_for(sequence, index, kind="onnx", config=None, model=None):
        kinds.append((index, kind))
        return []

    monkeypatch.setattr(seg, "masks_for", fake_masks_for)
    assert main(["run", str(room_dir), "--camera", "fr3", "--method", "semantic", "--out", str(tmp_path / "t.txt"),
                 "--quiet"]) == 0  # a TUM folder defaults to onnx masks
    assert kinds == [(i, "onnx") for i in range(20)]


def test_run_command_dispatches_orbslam3(room_dir, tmp_path, monkeypatch):
    import d2slam.run.methods as orb  # run_orbslam3 as the registry's runner calls it
    import d2slam.commands.run as run_command

    seen = []
    monkeypatch.setattr(orb, "run_orbslam3", lambda *a, **k: seen.append((a, k)) or "record")
    monkeypatch.setattr(run_command, "print_orbslam3", lambda record, args: 0 if record == "record" else 2)
    out = tmp_path / "t.txt"
    assert "orbslam3" in methods() and get_method("orbslam3").runner is not None
    assert main(["run", str(room_dir), "--camera", "fr3", "--method", "orbslam3", "--out", str(out),
                 "--repeats", "2", "--quiet"]) == 0
    ((a, k),) = seen
    assert a == (str(room_dir), str(out), None) and k["repeats"] == 2 and k["camera"] == "fr3" and k["masks"] is None
    assert main(["run", str(room_dir), "--method", "orbslam3", "--masks", "gt", "--out", str(out)]) == 2


def test_masks_are_read_ahead_with_the_frames(room_dir):
    """With prefetching, the mask provider runs in the reader thread (off the tracking thread), each frame's masks
    reach the engine with that frame, and the segment stage is the provider's own time; without, in this thread."""
    import threading
    import time

    seq = open_sequence(room_dir, camera="fr3")
    shape = (seq.camera.height, seq.camera.width)
    for prefetch in (True, False):
        threads, seen = set(), []

        def provider(i):
            threads.add(threading.current_thread())
            time.sleep(0.002)
            m = np.zeros((1, *shape), bool)
            m[0, :i + 1, :] = True  # frame i's mask: i + 1 rows
            return m

        class Spy:
            def __call__(self, inp):
                seen.append((inp.frame_index, int(inp.masks[0].any(axis=1).sum())))
                return np.zeros(len(inp.kps))

            def reset(self):
                pass

        res = run_sequence(seq, keypoint_filter=Spy(), mask_provider=provider, prefetch=prefetch, progress=False)
        assert (threading.main_thread() in threads) != prefetch
        assert seen == [(i, i + 1) for i in range(len(seq))]
        assert res.stage_ms["segment"] >= 2.0


def test_pipelined_extraction_gives_the_same_bytes(synth_dir):
    """The engine extracts frame i+1 in its worker thread while it tracks frame i, with the budget frame i's filter
    output sets (refill): same trajectory and beliefs, byte for byte, as a run that does everything in order, and
    as a second pipelined run."""
    from d2slam.config import DEFAULT
    from d2slam.run.methods import get_filter as dyn_filter

    seq = open_sequence(synth_dir)
    runs = []
    for prefetch in (True, False, True):
        beliefs = []
        res = run_sequence(seq, DEFAULT, keypoint_filter=dyn_filter("d2slam", DEFAULT),
                           mask_provider=lambda i: seq.person_masks_sim(i), prefetch=prefetch, progress=False,
                           recorder=lambda i, kps, bel, diag: beliefs.append((kps.copy(), bel.copy())))
        runs.append((res.trajectory.poses.tobytes(), beliefs))
    assert len(runs[0][1]) == len(seq) and runs[0][1][1][1].shape[0] > 1000  # refilled budget: more than n_features
    for other in runs[1:]:
        assert other[0] == runs[0][0]
        for (k0, b0), (k1, b1) in zip(runs[0][1], other[1]):
            np.testing.assert_array_equal(k0, k1)
            np.testing.assert_array_equal(b0, b1)
