"""TUM reader, associator, ground-truth interpolation, trajectory I/O, intrinsics and every bad input."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from d2slam.data import Sequence, Trajectory, TumSequence, open_sequence, read_tum_trajectory, write_tum_trajectory
from d2slam.data.base import Camera
from d2slam.data.fixtures import T0, analytic_pose, depth_pattern, rgb_pattern, write_tum_folder
from d2slam.data.intrinsics import FREIBURG1, FREIBURG2, FREIBURG3, camera_by_name, camera_from_folder
from d2slam.data.tum import associate, interpolate_poses
from d2slam.errors import D2SlamError

SMALL = Camera(fx=50.0, fy=50.0, cx=32.0, cy=24.0, width=64, height=48, name="small")


@pytest.fixture
def tum(tmp_path) -> dict:
    return write_tum_folder(tmp_path / "rgbd_dataset_freiburg3_fixture", n_frames=5)


def open_small(root, **kw) -> TumSequence:
    return TumSequence(root, camera=SMALL, **kw)


def edit_line(path: Path, lineno: int, new: str) -> None:
    lines = path.read_text().splitlines()
    lines[lineno - 1] = new
    path.write_text("\n".join(lines) + "\n")


def first_data_line(path: Path) -> int:
    return next(i for i, ln in enumerate(path.read_text().splitlines(), 1) if ln and not ln.startswith("#"))


# ------------------------------------------------------------------------------------------------------------------
# Reading a valid folder
# ------------------------------------------------------------------------------------------------------------------
def test_reads_frames_lazily_with_exact_content(tum):
    seq = open_small(tum["root"])
    assert isinstance(seq, Sequence)
    assert len(seq) == 5 and seq.name == "rgbd_dataset_freiburg3_fixture"
    np.testing.assert_array_equal(seq.timestamps, tum["rgb_ts"])
    np.testing.assert_array_equal(seq.depth_timestamps, tum["depth_ts"])
    np.testing.assert_allclose(seq.depth_timestamps - seq.timestamps, 0.004, atol=2e-6)
    for i, frame in enumerate(seq):
        assert frame.index == i and frame.timestamp == seq.timestamps[i]
        assert frame.rgb.dtype == np.uint8 and frame.rgb.shape == (48, 64, 3)
        np.testing.assert_array_equal(frame.rgb, rgb_pattern(i, 48, 64))  # RGB order, not BGR
        assert frame.depth.dtype == np.float32 and frame.depth.shape == (48, 64)
        np.testing.assert_array_equal(frame.depth, depth_pattern(i, 48, 64).astype(np.float32) / np.float32(5000))
        assert (frame.depth[0] == 0).all() and frame.depth[1, 0] == pytest.approx((5000 + 10 * i) / 5000)
        assert frame.rgb_path.name == f"{seq.timestamps[i]:.6f}.png"
    assert seq[-1].index == 4
    with pytest.raises(IndexError):
        seq[5]
    # lazy: an image deleted after construction is reported when the frame is read, naming list file and line
    seq[3].rgb_path.unlink()
    with pytest.raises(D2SlamError) as err:
        seq[3]
    assert err.value.path == tum["root"] / "rgb.txt" and err.value.line == 3 + 4


def test_camera_from_folder_name_and_explicit(tum, tmp_path):
    seq = TumSequence(tum["root"])  # folder name says freiburg3
    assert seq.camera == FREIBURG3
    assert TumSequence(tum["root"], camera="fr1").camera == FREIBURG1
    assert camera_from_folder("rgbd_dataset_freiburg2_xyz") == FREIBURG2
    assert camera_from_folder("/x/fr1_desk") == FREIBURG1 and camera_from_folder("FR3-walking") == FREIBURG3
    assert camera_by_name("freiburg2") == FREIBURG2 and camera_by_name("3") == FREIBURG3
    assert FREIBURG1.has_distortion and not FREIBURG3.has_distortion
    assert FREIBURG1.dist == (0.2624, -0.9531, -0.0054, 0.0026, 1.1633)
    assert (FREIBURG3.fx, FREIBURG3.fy, FREIBURG3.cx, FREIBURG3.cy) == (535.4, 539.2, 320.1, 247.6)
    assert all(c.depth_factor == 5000 and c.bf == 40 for c in (FREIBURG1, FREIBURG2, FREIBURG3))
    other = shutil.copytree(tum["root"], tmp_path / "my_sequence")
    with pytest.raises(D2SlamError, match="--camera"):
        TumSequence(other)
    with pytest.raises(D2SlamError, match="several cameras"):
        camera_from_folder("fr1_vs_fr2")
    with pytest.raises(D2SlamError, match="unknown camera"):
        camera_by_name("kinect")
    # the fr3 camera is 640x480: reading a 64x48 frame with it is an error naming the file, not a silent mismatch
    with pytest.raises(D2SlamError, match="64x48, the camera is 640x480"):
        seq[0]


def test_open_sequence_gives_tum_reader(tum):
    seq = open_sequence(tum["root"], camera=SMALL)
    assert type(seq) is TumSequence and len(seq) == 5


def test_parsing_tolerates_comments_whitespace_commas_blank_lines(tum):
    root = tum["root"]
    rows = [ln for ln in (root / "rgb.txt").read_text().splitlines() if not ln.startswith("#")]
    t, name = rows[1].split()
    rows[1] = f"  {t}\t\t{name}   "
    t, name = rows[2].split()
    rows[2] = f"{t},{name}"
    (root / "rgb.txt").write_text("\n  # indented comment\n\n" + "\r\n".join(rows) + "\n\n")
    seq = open_small(root)
    assert len(seq) == 5


def test_missing_groundtruth_is_none(tmp_path):
    info = write_tum_folder(tmp_path / "seq", n_frames=3, with_groundtruth=False)
    seq = open_small(info["root"])
    assert seq.groundtruth is None
    with pytest.raises(D2SlamError, match="no ground truth"):
        seq.gt_pose(T0 + 0.1)


# ------------------------------------------------------------------------------------------------------------------
# Association (TUM associate.py)
# ------------------------------------------------------------------------------------------------------------------
def associate_reference(first, second, offset, max_difference):
    """TUM's associate.py, verbatim logic (quadratic)."""
    first_keys, second_keys = list(first), list(second)
    potential = [(abs(a - (b + offset)), a, b) for a in first_keys for b in second_keys
                 if abs(a - (b + offset)) < max_difference]
    potential.sort()
    matches = []
    for _, a, b in potential:
        if a in first_keys and b in second_keys:
            first_keys.remove(a)
            second_keys.remove(b)
            matches.append((a, b))
    matches.sort()
    return matches


def pairs(a, b, max_dt=0.02, offset=0.0):
    i, j = associate(np.asarray(a, float), np.asarray(b, float), max_dt, offset)
    return [(a[x], b[y]) for x, y in zip(i, j)]


def test_association_edge_cases():
    # one-to-one: two RGB frames compete for one depth frame; the closer wins, the other stays unmatched
    assert pairs([1.000, 1.010], [1.012]) == [(1.010, 1.012)]
    # greedy by |dt|, not by time order: b=1.015 is closest to a=1.02 (0.005) though nearer a=1.00 in order
    assert pairs([1.00, 1.02], [1.015, 1.03]) == [(1.02, 1.015)]
    # tolerance is strict (< max_dt), as in associate.py
    assert pairs([1.0], [1.0 + 0.0199]) == [(1.0, 1.0199)]
    assert pairs([1.0], [1.0625], max_dt=0.0625) == []  # |dt| == max_dt exactly (binary-exact values)
    assert pairs([1.0], [1.0625], max_dt=0.0626) == [(1.0, 1.0625)]
    assert pairs([1.0], [1.03]) == []
    # offset is added to the second list
    assert pairs([1.0], [0.7], offset=0.3) == [(1.0, 0.7)]
    assert pairs([1.0], [1.0], offset=0.3) == []
    assert pairs([], [1.0]) == [] and pairs([1.0], []) == []


@settings(max_examples=150, deadline=None)
@given(st.lists(st.integers(0, 400), max_size=30, unique=True), st.lists(st.integers(0, 400), max_size=30,
                                                                         unique=True),
       st.sampled_from([0.0, 0.013, -0.02]), st.sampled_from([0.005, 0.02, 0.05]))
def test_association_equals_tum_associate_py(a_ms, b_ms, offset, max_dt):
    a = sorted(x / 400.0 for x in a_ms)
    b = sorted(x / 400.0 for x in b_ms)
    assert pairs(a, b, max_dt, offset) == associate_reference(a, b, offset, max_dt)


def test_association_long_sequence_is_vectorised():
    rng = np.random.default_rng(3)
    a = T0 + np.arange(20000) / 30.0
    b = np.sort(a + rng.uniform(-0.015, 0.015, len(a)))
    i, j = associate(a, b)
    assert len(i) == len(np.unique(i)) == len(np.unique(j)) and np.all(np.diff(i) > 0)
    assert np.all(np.abs(a[i] - b[j]) < 0.02) and len(i) > 19000
    k = slice(0, 300)  # the first 300 agree with the quadratic reference
    sub = associate(a[k], b[k])
    assert [(a[x], b[y]) for x, y in zip(*sub)] == associate_reference(list(a[k]), list(b[k]), 0.0, 0.02)


def test_sequence_uses_offset_and_tolerance(tmp_path):
    info = write_tum_folder(tmp_path / "seq", n_frames=4, depth_lag=0.015)
    assert len(open_small(info["root"])) == 4
    with pytest.raises(D2SlamError, match="no RGB/depth pair within 0.01 s") as err:
        open_small(info["root"], max_dt=0.01)
    assert err.value.path.name == "depth.txt"
    seq = open_small(info["root"], max_dt=0.01, offset=-0.015)
    assert len(seq) == 4


# ------------------------------------------------------------------------------------------------------------------
# Ground truth
# ------------------------------------------------------------------------------------------------------------------
def test_gt_interpolation_between_two_known_poses():
    a = np.eye(4)
    b = np.eye(4)
    b[:3, :3] = Rotation.from_euler("z", 90, degrees=True).as_matrix()
    b[:3, 3] = [1.0, 2.0, -4.0]
    ts = np.array([10.0, 10.04])
    out = interpolate_poses(ts, np.stack([a, b]), [10.0, 10.01, 10.02, 10.04], max_gap=None)
    np.testing.assert_array_equal(out[0], a)
    np.testing.assert_array_equal(out[3], b)  # a sample time returns the sample exactly
    want = np.eye(4)
    want[:3, :3] = Rotation.from_euler("z", 45, degrees=True).as_matrix()
    want[:3, 3] = [0.5, 1.0, -2.0]
    np.testing.assert_allclose(out[2], want, atol=1e-12)
    np.testing.assert_allclose(Rotation.from_matrix(out[1][:3, :3]).as_euler("xyz", degrees=True), [0, 0, 22.5],
                               atol=1e-9)
    np.testing.assert_allclose(out[1][:3, 3], [0.25, 0.5, -1.0], atol=1e-12)
    # outside the range, or across a gap longer than max_gap: NaN
    out = interpolate_poses(ts, np.stack([a, b]), [9.99, 10.05, 10.02], max_gap=0.01)
    assert np.isnan(out).all()


def test_sequence_gt_lookup_and_policy(tum):
    seq = open_small(tum["root"])
    gt = seq.groundtruth
    assert isinstance(gt, Trajectory) and len(gt) == len(tum["gt_ts"])
    np.testing.assert_allclose(gt.poses, analytic_pose(gt.timestamps), atol=1e-6)
    # frames fall between 100 Hz samples: interpolation reproduces the analytic motion
    np.testing.assert_allclose(seq.frame_gt_poses(), analytic_pose(seq.timestamps), atol=1e-6)
    np.testing.assert_allclose(seq.gt_pose(seq.timestamps[2]), analytic_pose(seq.timestamps[2])[0], atol=1e-6)
    before, after = gt.timestamps[0] - 0.5, gt.timestamps[-1] + 0.5
    assert np.isnan(seq.gt_poses([before, after])).all()
    with pytest.raises(D2SlamError, match="no ground truth at t=") as err:
        seq.gt_pose(after)
    assert err.value.path.name == "groundtruth.txt"


# ------------------------------------------------------------------------------------------------------------------
# Trajectory files
# ------------------------------------------------------------------------------------------------------------------
def test_trajectory_round_trip(tmp_path):
    rng = np.random.default_rng(0)
    n = 50
    poses = np.tile(np.eye(4), (n, 1, 1))
    poses[:, :3, :3] = Rotation.random(n, random_state=1).as_matrix()
    poses[:, :3, 3] = rng.normal(0, 3, (n, 3))
    ts = T0 + np.cumsum(rng.uniform(0.01, 0.05, n))
    ts = np.round(ts, 6)
    path = write_tum_trajectory(tmp_path / "traj.txt", Trajectory(ts, poses))
    text = path.read_text().splitlines()
    assert text[0].startswith("#") and len(text) == n + 1
    assert all(len(tok.split(".")[1]) >= 6 for tok in text[1].split())
    back = read_tum_trajectory(path)
    np.testing.assert_array_equal(back.timestamps, ts)
    np.testing.assert_allclose(back.poses, poses, atol=5e-9)
    # empty trajectories round-trip too
    write_tum_trajectory(tmp_path / "empty.txt", Trajectory(np.zeros(0), np.zeros((0, 4, 4))))
    assert len(read_tum_trajectory(tmp_path / "empty.txt")) == 0


@pytest.mark.parametrize("case, match", [
    ("nan", "non-finite"), ("unsorted", "strictly increasing"), ("duplicate", "strictly increasing"),
    ("scaled", "not a rigid"), ("reflection", "not a rigid"), ("shape", "expected timestamps"),
])
def test_trajectory_writer_rejects_bad_trajectories(tmp_path, case, match):
    ts = np.array([1.0, 2.0, 3.0])
    poses = np.tile(np.eye(4), (3, 1, 1))
    if case == "nan":
        poses[1, 0, 3] = np.nan
    elif case == "unsorted":
        ts = np.array([1.0, 3.0, 2.0])
    elif case == "duplicate":
        ts = np.array([1.0, 2.0, 2.0])
    elif case == "scaled":
        poses[2, :3, :3] *= 2
    elif case == "reflection":
        poses[2, 0, 0] = -1
    elif case == "shape":
        poses = poses[:2]
    with pytest.raises(D2SlamError, match=match):
        write_tum_trajectory(tmp_path / "t.txt", Trajectory(ts, poses))
    assert not (tmp_path / "t.txt").exists()


@pytest.mark.parametrize("line, match", [
    ("1.0 0 0 0 0 0 0", "expected 8 columns"),
    ("1.0 0 0 0 0 0 0 1 9", "expected 8 columns"),
    ("1.0 0 zero 0 0 0 0 1", "ty 'zero' is not a number"),
    ("nan 0 0 0 0 0 0 1", "not finite"),
    ("1.0 0 0 0 0 0 0 2", "norm 2"),
    ("0.5 0 0 0 0 0 0 1", "not after the previous"),
    ("0.9 0 0 0 0 0 0 1", "duplicated"),
])
def test_trajectory_reader_errors_name_file_and_line(tmp_path, line, match):
    path = tmp_path / "gt.txt"
    path.write_text("# header\n0.9 0 0 0 0 0 0 1\n\n" + line + "\n")
    with pytest.raises(D2SlamError, match=match) as err:
        read_tum_trajectory(path)
    assert err.value.path == path and err.value.line == 4
    assert str(err.value).startswith(f"{path}:4: ")


# ------------------------------------------------------------------------------------------------------------------
# Bad inputs of a sequence folder: each names the file (and line)
# ------------------------------------------------------------------------------------------------------------------
def test_missing_folder_and_list_files(tum, tmp_path):
    with pytest.raises(D2SlamError, match="sequence folder not found"):
        open_small(tmp_path / "nope")
    (tmp_path / "afile").write_text("x")
    with pytest.raises(D2SlamError, match="not a folder"):
        open_small(tmp_path / "afile")
    for name in ("rgb.txt", "depth.txt"):
        root = shutil.copytree(tum["root"], tmp_path / f"no_{name}")
        (root / name).unlink()
        with pytest.raises(D2SlamError, match="file not found") as err:
            open_small(root)
        assert err.value.path == root / name


@pytest.mark.parametrize("file, mutate, match", [
    ("rgb.txt", lambda t, n: f"{t}", "expected 2 columns"),
    ("depth.txt", lambda t, n: f"{t} {n} extra", "expected 2 columns"),
    ("rgb.txt", lambda t, n: f"12:00:01 {n}", "timestamp '12:00:01' is not a number"),
    ("depth.txt", lambda t, n: f"inf {n}", "not finite"),
])
def test_malformed_lines(tum, file, mutate, match):
    path = tum["root"] / file
    line = first_data_line(path) + 1
    t, n = path.read_text().splitlines()[line - 1].split()
    edit_line(path, line, mutate(t, n))
    with pytest.raises(D2SlamError, match=match) as err:
        open_small(tum["root"])
    assert err.value.path == path and err.value.line == line


@pytest.mark.parametrize("kind", ["unsorted", "duplicated"])
@pytest.mark.parametrize("file", ["rgb.txt", "depth.txt", "groundtruth.txt"])
def test_unsorted_or_duplicated_timestamps(tum, file, kind):
    path = tum["root"] / file
    lines = path.read_text().splitlines()
    k = first_data_line(path) + 1  # 1-based line of the second entry
    first, second = lines[k - 2].split(maxsplit=1), lines[k - 1].split(maxsplit=1)
    if kind == "unsorted":
        lines[k - 2], lines[k - 1] = " ".join([second[0], first[1]]), " ".join([first[0], second[1]])
    else:
        lines[k - 1] = " ".join([first[0], second[1]])
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(D2SlamError, match="duplicated" if kind == "duplicated" else "not after") as err:
        open_small(tum["root"])
    assert err.value.path == path and err.value.line == k


def test_referenced_image_missing(tum):
    seq = open_small(tum["root"])
    seq.depth_files[2].unlink()
    with pytest.raises(D2SlamError, match="not found") as err:
        open_small(tum["root"])
    assert err.value.path == tum["root"] / "depth.txt" and err.value.line == 4 + 2


@pytest.mark.parametrize("damage", ["truncated", "garbage", "empty"])
@pytest.mark.parametrize("which", ["rgb", "depth"])
def test_corrupt_or_truncated_png(tum, damage, which):
    seq = open_small(tum["root"])
    path = (seq.rgb_files if which == "rgb" else seq.depth_files)[1]
    data = path.read_bytes()
    path.write_bytes({"truncated": data[: len(data) // 2], "garbage": b"\x89PNG not really" * 20,
                      "empty": b""}[damage])
    with pytest.raises(D2SlamError, match="cannot be decoded") as err:
        seq[1]
    assert err.value.path == tum["root"] / f"{which}.txt" and err.value.line == 4 + 1


def test_8bit_depth_and_wrong_image_types(tum):
    seq = open_small(tum["root"])
    cv2.imwrite(str(seq.depth_files[0]), np.full((48, 64), 200, np.uint8))
    with pytest.raises(D2SlamError, match="is 8-bit") as err:
        seq[0]
    assert err.value.path.name == "depth.txt" and err.value.line == 4
    cv2.imwrite(str(seq.depth_files[1]), np.zeros((48, 64, 3), np.uint16))
    with pytest.raises(D2SlamError, match="16-bit single-channel"):
        seq[1]
    cv2.imwrite(str(seq.rgb_files[2]), np.zeros((48, 64), np.uint8))  # grey
    with pytest.raises(D2SlamError, match="not an 8-bit colour image") as err:
        seq[2]
    assert err.value.path.name == "rgb.txt"
    cv2.imwrite(str(seq.depth_files[3]), np.zeros((40, 64), np.uint16))
    with pytest.raises(D2SlamError, match="depth image .* is 64x40"):
        seq[3]


def test_no_association_and_no_frames(tum, tmp_path):
    path = tum["root"] / "depth.txt"
    lines = path.read_text().splitlines()
    shifted = [ln if ln.startswith("#") else f"{float(ln.split()[0]) + 100:.6f} {ln.split()[1]}" for ln in lines]
    path.write_text("\n".join(shifted) + "\n")
    with pytest.raises(D2SlamError, match="no RGB/depth pair within 0.02 s") as err:
        open_small(tum["root"])
    assert err.value.path == path
    (tum["root"] / "rgb.txt").write_text("# only comments\n\n")
    with pytest.raises(D2SlamError, match="no frames") as err:
        open_small(tum["root"])
    assert err.value.path == tum["root"] / "rgb.txt"


def test_bad_groundtruth_names_line(tum):
    path = tum["root"] / "groundtruth.txt"
    line = first_data_line(path) + 3
    edit_line(path, line, "1305031102.03 1 2 3")
    with pytest.raises(D2SlamError, match="expected 8 columns") as err:
        open_small(tum["root"])
    assert err.value.path == path and err.value.line == line
    path.write_text("# nothing\n")
    with pytest.raises(D2SlamError, match="no poses"):
        open_small(tum["root"])


def test_invalid_arguments(tum):
    with pytest.raises(D2SlamError, match="max_dt"):
        open_small(tum["root"], max_dt=0)
    with pytest.raises(D2SlamError, match="max_dt"):
        open_small(tum["root"], offset=math.nan)
