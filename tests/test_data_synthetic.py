"""SyntheticSequence: scene.json, masks, person masks, dynamic-pixel truth, open_sequence, bad inputs."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest

from d2slam.data import SyntheticSequence, TumSequence, open_sequence
from d2slam.data.fixtures import write_tum_folder
from d2slam.errors import D2SlamError

H, W = 48, 64
PERSON_A, PERSON_B, BOX, DESK = 1, 2, 5, 7


def gt_mask(i: int) -> np.ndarray:
    """Person A in the left columns; person B only in frames >= 2; the box (moved) at the bottom; a never-moved
    desk object at the top right."""
    m = np.zeros((H, W), np.uint8)
    m[10:40, 0:10] = PERSON_A
    if i >= 2:
        m[5:20, 30:40] = PERSON_B
    m[40:48, 20:30] = BOX
    m[0:5, 50:64] = DESK
    return m


def sim_mask(i: int) -> np.ndarray:
    m = np.zeros((H, W), np.uint8)
    m[11:39, 0:9] = 1
    if i >= 2:
        m[6:21, 31:41] = 3  # a gap in labels: label 2 absent
    return m


def scene(rgb_ts: np.ndarray) -> dict:
    return {
        "format": "d2slam-synth/2", "scenario": "walking_xyz", "seed": 7, "frames": len(rgb_ts),
        "static_twin": False,
        "camera": {"fx": 50.0, "fy": 51.0, "cx": 32.0, "cy": 24.0, "width": W, "height": H, "depth_factor": 5000},
        "objects": [
            {"id": PERSON_A, "kind": "person", "name": "a", "moved": True,
             "moving_intervals": [[rgb_ts[0], rgb_ts[-1]]]},
            {"id": PERSON_B, "kind": "person", "name": "b", "moved": True, "moving_intervals": []},
            # the box moves exactly from frame 1's to frame 2's timestamp (ends included) and again at frame 4
            {"id": BOX, "kind": "object", "name": "box", "moved": True,
             "moving_intervals": [[rgb_ts[1], rgb_ts[2]], [rgb_ts[4] - 0.001, rgb_ts[4] + 0.001]]},
            {"id": DESK, "kind": "object", "name": "desk", "moved": False, "moving_intervals": []},
        ],
        "person_ids": [PERSON_A, PERSON_B], "moved_object_ids": [BOX], "generator": {"name": "test"},
    }


def write_synthetic(root: Path, n: int = 5) -> dict:
    info = write_tum_folder(root, n_frames=n, width=W, height=H)
    (root / "mask_gt").mkdir()
    (root / "mask_sim").mkdir()
    for i, t in enumerate(info["rgb_ts"]):
        cv2.imwrite(str(root / "mask_gt" / f"{t:.6f}.png"), gt_mask(i))
        cv2.imwrite(str(root / "mask_sim" / f"{t:.6f}.png"), sim_mask(i))
    (root / "scene.json").write_text(json.dumps(scene(info["rgb_ts"]), indent=1))
    return info


@pytest.fixture
def synth(tmp_path) -> dict:
    return write_synthetic(tmp_path / "walking_xyz_seed7")


def test_reads_scene_camera_masks_and_truth(synth):
    seq = open_sequence(synth["root"])
    assert type(seq) is SyntheticSequence and len(seq) == 5
    assert (seq.camera.fx, seq.camera.fy, seq.camera.width, seq.camera.height) == (50.0, 51.0, W, H)
    assert seq.scenario == "walking_xyz" and seq.seed == 7 and not seq.static_twin
    assert seq.person_ids.tolist() == [1, 2] and seq.moved_object_ids.tolist() == [BOX]
    assert seq[0].rgb.shape == (H, W, 3) and seq.groundtruth is not None
    for i in range(5):
        np.testing.assert_array_equal(seq.mask_gt(i), gt_mask(i))
        np.testing.assert_array_equal(seq.mask_sim(i), sim_mask(i))
        assert seq.mask_gt(i).dtype == np.uint8

    masks, ids = seq.person_masks_gt(0, return_ids=True)
    assert masks.dtype == bool and masks.shape == (1, H, W) and ids.tolist() == [PERSON_A]
    masks, ids = seq.person_masks_gt(3, return_ids=True)
    assert ids.tolist() == [PERSON_A, PERSON_B]
    np.testing.assert_array_equal(masks[1], gt_mask(3) == PERSON_B)
    sim, labels = seq.person_masks_sim(3, return_labels=True)
    assert sim.shape == (2, H, W) and labels.tolist() == [1, 3]
    np.testing.assert_array_equal(sim[1], sim_mask(3) == 3)
    assert seq.person_masks_sim(0).shape == (1, H, W)


@pytest.mark.parametrize("i, box_moving", [(0, False), (1, True), (2, True), (3, False), (4, True)])
def test_dynamic_mask_follows_moving_intervals(synth, i, box_moving):
    seq = SyntheticSequence(synth["root"])
    m = gt_mask(i)
    want = np.isin(m, [PERSON_A, PERSON_B] + ([BOX] if box_moving else []))
    got = seq.dynamic_mask(i)
    assert got.dtype == bool
    np.testing.assert_array_equal(got, want)
    assert not got[m == DESK].any()  # a never-moved object is static
    assert (BOX in seq.dynamic_ids(i).tolist()) == box_moving


def test_open_sequence_without_scene_is_tum(synth):
    (synth["root"] / "scene.json").unlink()
    with pytest.raises(D2SlamError, match="scene.json not found"):
        SyntheticSequence(synth["root"])
    with pytest.raises(D2SlamError, match="--camera"):  # folder name names no freiburg camera
        open_sequence(synth["root"])
    assert type(open_sequence(synth["root"], camera="fr3")) is TumSequence


@pytest.mark.parametrize("edit, match", [
    (lambda s: s.update(format="other/1"), "format is 'other/1'"),
    (lambda s: s.update(format="d2slam-synth/1"), "old generator .*regenerate it with `d2slam synth"),
    (lambda s: s.pop("camera"), "missing key 'camera'"),
    (lambda s: s["camera"].pop("fx"), "camera lacks fx"),
    (lambda s: s["camera"].update(fx=-1), "positive"),
    (lambda s: s.update(person_ids=[1]), "person_ids .* disagree"),
    (lambda s: s.update(moved_object_ids=[5, 7]), "moved_object_ids .* disagree"),
    (lambda s: s["objects"][0].update(id=300), "1..255"),
    (lambda s: s["objects"][1].update(id=1), "listed twice"),
    (lambda s: s["objects"][2].update(moving_intervals=[[2.0, 1.0]]), "t0 <= t1"),
    (lambda s: s["objects"][2].update(kind="robot"), "kind 'robot'"),
])
def test_bad_scene_json(synth, edit, match):
    path = synth["root"] / "scene.json"
    data = json.loads(path.read_text())
    edit(data)
    path.write_text(json.dumps(data))
    with pytest.raises(D2SlamError, match=match) as err:
        SyntheticSequence(synth["root"])
    assert err.value.path == path


def test_scene_json_syntax_error_names_line(synth):
    path = synth["root"] / "scene.json"
    path.write_text('{\n "format": "d2slam-synth/2",\n "camera": }\n')
    with pytest.raises(D2SlamError, match="invalid JSON") as err:
        SyntheticSequence(synth["root"])
    assert err.value.path == path and err.value.line == 3


def test_bad_masks(synth):
    seq = SyntheticSequence(synth["root"])
    stem = seq.rgb_files[1].stem
    (synth["root"] / "mask_gt" / f"{stem}.png").unlink()
    with pytest.raises(D2SlamError, match="mask of frame 1 .* not found") as err:
        seq.mask_gt(1)
    assert err.value.path == synth["root"] / "mask_gt" / f"{stem}.png"
    bad = synth["root"] / "mask_sim" / f"{seq.rgb_files[2].stem}.png"
    bad.write_bytes(bad.read_bytes()[:40])
    with pytest.raises(D2SlamError, match="cannot be decoded") as err:
        seq.mask_sim(2)
    assert err.value.path == bad
    cv2.imwrite(str(synth["root"] / "mask_gt" / f"{seq.rgb_files[3].stem}.png"), np.zeros((H, W), np.uint16))
    with pytest.raises(D2SlamError, match="uint8 single-channel"):
        seq.mask_gt(3)
    m = gt_mask(4)
    m[0, 0] = 99  # an id scene.json does not know
    cv2.imwrite(str(synth["root"] / "mask_gt" / f"{seq.rgb_files[4].stem}.png"), m)
    with pytest.raises(D2SlamError, match=r"ids \[99\] are not objects"):
        seq.dynamic_mask(4)
    with pytest.raises(IndexError):
        seq.mask_gt(5)


def test_explicit_camera_must_agree_with_the_scene(synth, tmp_path):
    import dataclasses

    from d2slam.data.base import Camera

    cam = Camera(fx=1.0, fy=1.0, cx=32.0, cy=24.0, width=W, height=H)
    with pytest.raises(D2SlamError, match="conflicts with this synthetic sequence's own camera .* fx"):
        SyntheticSequence(synth["root"], camera=cam)
    with pytest.raises(D2SlamError, match="conflicts"):
        open_sequence(synth["root"], camera="fr1")
    own = SyntheticSequence(synth["root"]).camera
    same = dataclasses.replace(own, name="mine")
    assert SyntheticSequence(synth["root"], camera=same).camera == own
    copy = shutil.copytree(synth["root"], tmp_path / "copy")
    assert len(SyntheticSequence(copy)) == 5
