"""`d2slam eval GROUNDTRUTH TRAJ` refuses a trajectory that does not belong to the ground truth (another synthetic
sequence named in its header, timestamps that are not the folder's frame times, another sequence's ground truth given
as a bare file, or a compact trajectory far from a bare ground truth) unless --force; arguments of the wrong kind or
in the wrong order are said so. Sequence folders are written as text files only: eval reads no image."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from d2slam.cli import main
from d2slam.data import Trajectory
from d2slam.data.tum import write_tum_trajectory

T0 = 1341846313.592026  # the synthetic clock


def path_poses(t: np.ndarray, kind: str) -> np.ndarray:
    """(N, 4, 4) camera poses: 'circle' (0.3 m radius, 6 s period, bobbing) or 'line' (along x at 0.2 m/s,
    bending and bobbing: no straight line, which no SE(3) alignment can use)."""
    poses = np.tile(np.eye(4), (len(t), 1, 1))
    s = t - T0
    if kind == "circle":
        poses[:, 0, 3], poses[:, 1, 3] = 0.3 * np.sin(2 * np.pi * s / 6), 0.3 * np.cos(2 * np.pi * s / 6)
        poses[:, 2, 3] = 0.05 * np.sin(2 * np.pi * s / 2)
    else:
        poses[:, 0, 3], poses[:, 1, 3], poses[:, 2, 3] = 0.2 * s, 0.02 * s ** 2, 0.03 * np.sin(2 * np.pi * s)
    return poses


def write_sequence(root, scenario: str, seed: int, kind: str, frames: int = 60):
    """A synthetic-like folder: scene.json, rgb.txt / depth.txt at 30 Hz with the seed's jitter, 100 Hz ground truth
    with d2slam synth's `# file:` line. Returns the frame times."""
    root.mkdir(parents=True)
    jitter = np.random.default_rng(seed).uniform(-0.0015, 0.0015, frames)
    ts = np.round(T0 + np.arange(frames) / 30.0 + jitter, 6)
    head = f"# file: 'd2slam-synth {scenario} seed {seed}'\n"
    (root / "rgb.txt").write_text("# color images\n" + head + "".join(f"{t:.6f} rgb/{t:.6f}.png\n" for t in ts))
    (root / "depth.txt").write_text("# depth maps\n" + head + "".join(f"{t + 0.005:.6f} depth/{t + 0.005:.6f}.png\n"
                                                                      for t in ts))
    gt_t = np.round(np.arange(np.ceil((ts[0] - 0.5) * 100), np.floor((ts[-1] + 0.5) * 100) + 1) / 100, 2)
    write_tum_trajectory(root / "groundtruth.txt", Trajectory(gt_t, path_poses(gt_t, kind)),
                         header=f"ground truth trajectory\nfile: 'd2slam-synth {scenario} seed {seed}'")
    (root / "scene.json").write_text(json.dumps({"format": "d2slam-synth/2", "scenario": scenario, "seed": seed}))
    return ts


def write_run(path, root, ts, kind: str, header: bool = True):
    """What `d2slam run` writes: the poses at the frame times, its header naming the sequence."""
    write_tum_trajectory(path, Trajectory(ts, path_poses(ts, kind)),
                         header=f"d2slam run --method none {root}" if header else None)
    return path


@pytest.fixture
def seqs(tmp_path):
    a, b = tmp_path / "a", tmp_path / "b"
    ta = write_sequence(a, "walking_xyz", 1, "circle")
    write_sequence(b, "walking_xyz", 2, "line")
    return a, b, write_run(tmp_path / "a.txt", a, ta, "circle"), ta


def one_line_error(capsys, argv) -> str:
    assert main(argv) == 2
    captured = capsys.readouterr()
    assert captured.out == "" and "Traceback" not in captured.err
    assert len(captured.err.strip().splitlines()) == 1
    return captured.err


def test_a_run_belongs_to_its_own_sequence(seqs, capsys):
    a, _, traj, _ = seqs
    for gt in (a, a / "groundtruth.txt"):
        assert main(["eval", str(gt), str(traj), "--json"]) == 0
        assert json.loads(capsys.readouterr().out)["ate_rmse_m"] < 0.005  # evo: nearest 100 Hz pose


def test_another_synthetic_sequence_is_refused_unless_forced(seqs, tmp_path, capsys):
    a, b, traj, _ = seqs
    plot = tmp_path / "p.png"
    for gt in (b, b / "groundtruth.txt"):
        err = one_line_error(capsys, ["eval", str(gt), str(traj), "--plot", str(plot)])
        assert f"the trajectory was run on {a} (walking_xyz seed 1), the ground truth is of walking_xyz seed 2" in err
        assert "--force" in err and not plot.exists()
    assert main(["eval", str(b), str(traj), "--force"]) == 0 and "ate_rmse_m" in capsys.readouterr().out


def test_timestamps_that_are_not_the_folders_frames_are_refused(seqs, tmp_path, capsys):
    a, b, _, ta = seqs
    bare = write_run(tmp_path / "nohead.txt", a, ta, "circle", header=False)  # another tool's output
    assert main(["eval", str(a), str(bare)]) == 0
    capsys.readouterr()
    (b / "scene.json").unlink()  # no identity: the frame times decide
    err = one_line_error(capsys, ["eval", str(b), str(bare)])
    assert "of the trajectory's 60 timestamps are frame times of" in err and "not run on this sequence" in err


def test_a_bare_ground_truth_file_is_checked_against_the_runs_sequence(seqs, tmp_path, capsys):
    a, b, traj, ta = seqs
    for src, ok in ((a, True), (b, False)):
        bare = tmp_path / "elsewhere" / f"{src.name}_gt.txt"
        bare.parent.mkdir(exist_ok=True)
        lines = (src / "groundtruth.txt").read_text().splitlines()
        bare.write_text("\n".join(x for x in lines if "d2slam-synth" not in x) + "\n")  # no identity line
        if ok:
            assert main(["eval", str(bare), str(traj)]) == 0
            capsys.readouterr()
        else:
            err = one_line_error(capsys, ["eval", str(bare), str(traj)])
            assert f"the trajectory was run on {a}, whose groundtruth.txt is not this ground truth" in err
    # nothing names the sequence: a compact trajectory far from the ground truth is refused, its own is not
    nohead = write_run(tmp_path / "nohead.txt", a, ta, "circle", header=False)
    err = one_line_error(capsys, ["eval", str(tmp_path / "elsewhere" / "b_gt.txt"), str(nohead)])
    assert "times the ground truth's extent" in err and "it looks like another trajectory" in err
    assert main(["eval", str(tmp_path / "elsewhere" / "a_gt.txt"), str(nohead)]) == 0


def test_arguments_of_the_wrong_kind_or_order_are_said(seqs, tmp_path, capsys):
    a, _, traj, _ = seqs
    err = one_line_error(capsys, ["eval", str(traj), str(a)])
    assert "TRAJ.txt is a folder, not a trajectory file: the arguments look swapped" in err
    err = one_line_error(capsys, ["eval", str(traj), str(a / "groundtruth.txt")])
    assert "the arguments look swapped" in err and "d2slam eval GROUNDTRUTH TRAJ.txt" in err
    empty = tmp_path / "empty"
    empty.mkdir()
    assert "no groundtruth.txt in this folder" in one_line_error(capsys, ["eval", str(empty), str(traj)])
    noseq = shutil.copytree(a, tmp_path / "nogt")
    (noseq / "groundtruth.txt").unlink()
    assert "the sequence has no ground truth" in one_line_error(capsys, ["eval", str(noseq), str(traj)])
    assert "trajectory file not found" in one_line_error(capsys, ["eval", str(a), str(tmp_path / "x.txt")])
    assert "ground truth not found" in one_line_error(capsys, ["eval", str(tmp_path / "x"), str(traj)])


def test_a_degenerate_alignment_is_a_one_line_error(tmp_path, capsys):
    t = T0 + np.arange(100) / 30.0
    line = np.tile(np.eye(4), (100, 1, 1))
    line[:, 0, 3] = 0.1 * (t - T0)  # a straight line: Umeyama has no rotation to fit
    write_tum_trajectory(tmp_path / "gt.txt", Trajectory(t, line))
    write_tum_trajectory(tmp_path / "est.txt", Trajectory(t, line))
    err = one_line_error(capsys, ["eval", str(tmp_path / "gt.txt"), str(tmp_path / "est.txt")])
    assert "cannot align the trajectories" in err and "straight line" in err
