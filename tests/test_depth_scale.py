"""The depth-scale check of `d2slam run` (d2slam.data.depth_scale): depth read with a factor 5 or 0.2 off is caught
both ways, against the ground truth's camera motion (a moving camera) or the depth seen indoors (a still camera, no
ground truth), and the right scale raises no alarm."""

from __future__ import annotations

import dataclasses

import cv2
import numpy as np
import pytest

from d2slam.cli import main
from d2slam.data.config import DepthCheckConfig

CHECK = DepthCheckConfig()
from d2slam.data import Trajectory
from d2slam.data.depth_scale import candidate_pairs, depth_scale_warning, rigid_ransac, translation_ratios
from d2slam.data.intrinsics import FREIBURG3
from d2slam.data.tum import TumSequence, write_tum_trajectory
from d2slam.slam.fixture import BoxRoom, write_room_sequence


@pytest.fixture(scope="module")
def moving(tmp_path_factory):
    """The box room seen from a camera on a 0.3 m circle (fr3, depth x5000, ground truth)."""
    return write_room_sequence(tmp_path_factory.mktemp("moving") / "room", n=12, seed=1, fps=10.0)


@pytest.fixture(scope="module")
def still(tmp_path_factory):
    """The box room from a camera that does not move, with ground truth and without."""
    root = tmp_path_factory.mktemp("still") / "still"
    (root / "rgb").mkdir(parents=True)
    (root / "depth").mkdir()
    pose = np.eye(4)
    pose[:3, 3] = (0.3, -0.1, -0.6)
    gray, depth = BoxRoom(2).render(pose)
    ts = 1000.0 + np.arange(6) / 10.0
    for t in ts:
        cv2.imwrite(str(root / "rgb" / f"{t:.6f}.png"), cv2.cvtColor(gray, cv2.COLOR_GRAY2BGR))
        cv2.imwrite(str(root / "depth" / f"{t:.6f}.png"), np.rint(depth * 5000.0).astype(np.uint16))
    (root / "rgb.txt").write_text("".join(f"{t:.6f} rgb/{t:.6f}.png\n" for t in ts))
    (root / "depth.txt").write_text("".join(f"{t:.6f} depth/{t:.6f}.png\n" for t in ts))
    write_tum_trajectory(root / "groundtruth.txt", Trajectory(ts, np.repeat(pose[None], len(ts), axis=0)))
    return root


def read_as(root, scale: float) -> TumSequence:
    """The sequence with its depth read ``scale`` times too large (depth factor 5000 / scale)."""
    return TumSequence(root, camera=dataclasses.replace(FREIBURG3, depth_factor=5000.0 / scale))


def test_a_moving_camera_measures_the_factor_against_the_ground_truth(moving):
    for scale in (1.0, 5.0, 0.2):
        ratios = translation_ratios(read_as(moving, scale))
        assert len(ratios) == CHECK.depth_pairs
        assert np.allclose(ratios, scale, rtol=0.1), (scale, ratios)
    assert depth_scale_warning(read_as(moving, 1.0)) is None
    five = depth_scale_warning(read_as(moving, 5.0))  # millimetres written, read with factor 1000
    fifth = depth_scale_warning(read_as(moving, 0.2))
    assert "ground truth's camera motion" in five and "depth factor 1000 the camera moves 5" in five
    assert "look like depth factor 5000" in five and "DepthMapFactor" in five
    assert "depth factor 25000 the camera moves 0.2" in fifth and "look like depth factor 5000" in fifth


def test_a_still_camera_falls_back_to_the_depth_seen_indoors(still, tmp_path):
    assert translation_ratios(read_as(still, 1.0)) == []  # no baseline: nothing to measure against
    assert depth_scale_warning(read_as(still, 1.0)) is None
    for scale, where in ((5.0, "at the median"), (0.2, "95th percentile")):
        msg = depth_scale_warning(read_as(still, scale))
        assert msg is not None and where in msg and "look like depth factor 5000" in msg
    (still / "groundtruth.txt").rename(tmp_path / "gt.txt")  # no ground truth at all: the same
    try:
        assert depth_scale_warning(read_as(still, 1.0)) is None
        assert depth_scale_warning(read_as(still, 0.2)) is not None
    finally:
        (tmp_path / "gt.txt").rename(still / "groundtruth.txt")


def test_pairs_need_motion_and_overlap():
    poses = np.tile(np.eye(4), (40, 1, 1))
    poses[:, 0, 3] = np.arange(40) * 0.02  # 2 cm per frame along x
    pairs = candidate_pairs(poses)
    assert pairs and all(CHECK.depth_min_baseline_m <= 0.02 * (j - i) <= CHECK.depth_max_baseline_m for i, j in pairs)
    assert all(j == min(i + 25, 39) for i, j in pairs)  # the largest baseline within depth_max_baseline_m
    assert pairs[0][0] == 0 and pairs[-1][0] > 30  # spread over the sequence
    assert candidate_pairs(np.tile(np.eye(4), (40, 1, 1))) == []  # a still camera
    turned = poses.copy()
    turned[1::2, :3, :3] = cv2.Rodrigues(np.array([0.0, np.radians(30.0), 0.0]))[0]  # odd frames turned 30 deg
    assert all((i - j) % 2 == 0 for i, j in candidate_pairs(turned))
    poses[:, 0, 0] = np.nan  # no ground truth at the frames
    assert candidate_pairs(poses) == []


def test_rigid_ransac_ignores_moving_points_and_is_scale_free():
    rng = np.random.default_rng(3)
    P = rng.uniform([-1, -1, 1], [1, 1, 4], size=(200, 3))
    R = cv2.Rodrigues(np.array([0.05, -0.1, 0.02]))[0]
    t = np.array([0.1, -0.05, 0.2])
    Q = P @ R.T + t + rng.normal(0, 0.002, P.shape)
    Q[:60] += rng.uniform(-0.5, 0.5, (60, 3))  # 30 % of the points move (people)
    for s in (1.0, 5.0, 0.2):
        est, inliers = rigid_ransac(s * P, s * Q)
        assert np.allclose(est, s * t, atol=0.01 * s) and inliers >= 130
    assert rigid_ransac(P[:10], Q[:10]) == (None, 0)  # too few matches


def test_run_warns_once_with_the_factor_and_runs(moving, tmp_path, capsys):
    """A TUM-layout folder read through an ORB-SLAM3 settings file with the wrong DepthMapFactor (1000: every depth
    5 times too large): one warning naming the factor to set, and the run goes on (it tracks nothing with depths past
    the engine's range: a fragment, exit status 3); the right one: no warning, every frame tracked."""
    yaml = ("%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\n"
            "Camera.width: 640\nCamera.height: 480\nCamera.bf: 40.0\nDepthMapFactor: {f}\n")
    for factor, warned in ((1000.0, True), (5000.0, False)):
        cam = tmp_path / f"cam{factor:.0f}.yaml"
        cam.write_text(yaml.format(f=factor))
        code = main(["run", str(moving), "--camera", str(cam), "--out", str(tmp_path / "t.txt"), "--quiet"])
        assert code == (3 if warned else 0)
        err = capsys.readouterr().err
        assert err.count("warning:") == int(warned)
        if warned:
            assert "depth factor 1000 the camera moves 5" in err and "look like depth factor 5000" in err


def test_orbslam3_runs_are_checked_too(moving, tmp_path, monkeypatch, capsys):
    """The real ORB-SLAM3 has its own runner; the depth is checked before it starts all the same."""
    import d2slam.commands.run as run_command
    from d2slam.run import methods

    ran = []
    for name in ("orbslam3", "orbslam3-masked"):
        monkeypatch.setitem(methods._REGISTRY, name, dataclasses.replace(
            methods.get_method(name), runner=lambda args: ran.append(args) or "record"))
    monkeypatch.setattr(run_command, "print_orbslam3", lambda record, args: 0 if record == "record" else 2)
    cam = tmp_path / "mm.yaml"
    cam.write_text("%YAML:1.0\nCamera.fx: 535.4\nCamera.fy: 539.2\nCamera.cx: 320.1\nCamera.cy: 247.6\n"
                   "Camera.width: 640\nCamera.height: 480\nCamera.bf: 40.0\nDepthMapFactor: 25000.0\n")
    for name in ("orbslam3", "orbslam3-masked"):
        assert main(["run", str(moving), "--method", name, "--camera", str(cam), "--out", str(tmp_path / "t.txt")]) == 0
        assert "depth factor 25000 the camera moves 0.2" in capsys.readouterr().err
    assert len(ran) == 2
