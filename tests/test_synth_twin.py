"""The synthetic twin of a real recording (``d2slam synth fr1_rpy_twin --on-trajectory``, ``d2slam.synth.twin``): its
camera, times and poses follow the recording; the lens distortion applied to the images is the inverse of the camera
model's undistortion; the other scenarios' files are what they were before the twin existed."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from d2slam.config import SynthConfig
from d2slam.data import open_sequence
from d2slam.data.fixtures import recording_folder
from d2slam.data.intrinsics import FREIBURG1
from d2slam.errors import D2SlamError
from d2slam.synth import generate
from d2slam.synth.scene import Scene
from d2slam.synth.sensor import correlated_noise
from d2slam.synth.twin import (LensMap, distort_normalised, placement, read_recording, row_weights,
                               undistort_normalised)

FRAMES = 3


@pytest.fixture(scope="module")
def twin(tmp_path_factory):
    root = tmp_path_factory.mktemp("twin")
    rec_dir = recording_folder(root)
    rec = read_recording(rec_dir)
    res = generate("fr1_rpy_twin", root / "twin", frames=FRAMES, workers=1, progress=False, recording=rec)
    return rec_dir, rec, res


def _rows(path: Path) -> list[list[str]]:
    return [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]


# ---------------------------------------------------------------------------------------------- the recording
def test_twin_camera_times_and_poses_follow_the_recording(twin):
    rec_dir, rec, res = twin
    out = res["out"]
    seq = open_sequence(out)
    # the camera: the recording's (freiburg1) with its lens distortion
    cam = seq.camera
    assert (cam.fx, cam.fy, cam.cx, cam.cy, cam.width, cam.height) == (FREIBURG1.fx, FREIBURG1.fy, FREIBURG1.cx,
                                                                       FREIBURG1.cy, 640, 480)
    assert cam.dist == FREIBURG1.dist
    # the times: the recording's first RGB and depth stamps, verbatim, associated as in the recording
    real = _rows(rec_dir / "rgb.txt")[:FRAMES], _rows(rec_dir / "depth.txt")[:FRAMES]
    assert [r[0] for r in _rows(out / "rgb.txt")] == [r[0] for r in real[0]]
    assert [r[0] for r in _rows(out / "depth.txt")] == [r[0] for r in real[1]]
    assert np.allclose(seq.depth_timestamps, [float(r[0]) for r in real[1]], atol=1e-6)
    # the poses: the recording's ground truth placed in the room by one rigid motion about the vertical
    scene = json.loads((out / "scene.json").read_text())
    A = np.array(scene["recording"]["placement"])
    tw = SynthConfig().twin
    first = open_sequence(rec_dir).gt_poses(np.asarray(seq.timestamps[:1]))[0]
    assert np.allclose(A, placement(first, tw.anchor_xy, tw.anchor_heading_deg), atol=1e-8)
    placed = A @ first
    assert np.allclose(placed[:2, 3], tw.anchor_xy) and np.isclose(placed[2, 3], first[2, 3])
    axis = placed[:3, 2]
    assert np.isclose(np.degrees(np.arctan2(axis[1], axis[0])), tw.anchor_heading_deg)
    assert np.allclose(A[2, :3], [0, 0, 1]) and np.allclose(A[:3, 2], [0, 0, 1])  # about the vertical only
    gt_real, gt_twin = open_sequence(rec_dir).groundtruth, seq.groundtruth
    sel = np.isin(np.round(gt_real.timestamps, 4), np.round(gt_twin.timestamps, 4))
    assert sel.sum() == len(gt_twin) > 100
    assert np.allclose(np.einsum("ij,njk->nik", A, gt_real.poses[sel]), gt_twin.poses, atol=2e-6)
    # a static twin: no people, no masks
    assert scene["static_twin"] and scene["person_ids"] == [] and scene["objects"] == []
    assert scene["generator"]["depth_rendered_at"] == "depth_timestamp"
    assert not any(seq.mask_gt(i).any() for i in range(FRAMES))


def test_twin_renders_at_the_recorded_instants(twin):
    """The frame's pose is the recording's ground truth at its timestamp, placed; sub-frames spread over the
    exposure (and the rolling shutter's rows), each row's weights summing to one."""
    rec_dir, rec, res = twin
    scene = Scene("fr1_rpy_twin", 0, FRAMES, cfg=SynthConfig(), recording=rec)
    A = scene.camera.A
    seq = open_sequence(rec_dir)
    real = seq.gt_poses(np.asarray(seq.timestamps[:FRAMES]))
    assert np.allclose(scene.camera.poses(scene.t_rel), np.einsum("ij,njk->nik", A, real), atol=1e-9)
    w = row_weights(0.0, 0.03, 7, np.array([[0.0, 0.01], [0.01, 0.03], [0.012, 0.012]]))
    assert np.allclose(w.sum(1), 1.0) and np.allclose(w[0], [3 / 7, 3 / 7, 1 / 7, 0, 0, 0, 0])
    assert np.allclose(w[1, :2], 0) and w[2, 2] == 1.0  # a window shorter than a slice takes the slice it is in
    assert res["frames"] == FRAMES and all(s["hole_fraction"] > 0.15 for s in res["stats"])  # the border at least


def test_twin_needs_its_recording_and_only_it_takes_one(tmp_path, capsys):
    from d2slam.cli import main

    with pytest.raises(D2SlamError, match="--on-trajectory"):
        Scene("fr1_rpy_twin", 0, 3)
    rec = read_recording(recording_folder(tmp_path))
    with pytest.raises(D2SlamError, match="own camera path"):
        Scene("walking_xyz", 0, 3, recording=rec)
    assert main(["synth", "fr1_rpy_twin", "--out", str(tmp_path / "o")]) == 2
    assert "--on-trajectory" in capsys.readouterr().err
    (tmp_path / "nogt").mkdir()
    for f in ("rgb.txt", "depth.txt"):
        (tmp_path / "nogt" / f).write_text((tmp_path / "rgbd_dataset_freiburg1_fake" / f).read_text())
    for d in ("rgb", "depth"):
        (tmp_path / "nogt" / d).symlink_to(tmp_path / "rgbd_dataset_freiburg1_fake" / d)
    with pytest.raises(D2SlamError):
        read_recording(tmp_path / "nogt")


# ---------------------------------------------------------------------------------------------- the lens
def test_undistortion_inverts_opencvs_lens_model():
    rng = np.random.default_rng(0)
    K = FREIBURG1.K
    px = rng.uniform([0, 0], [639, 479], size=(500, 2))
    xd = (px - K[[0, 1], [2, 2]]) / K[[0, 1], [0, 1]]
    x = undistort_normalised(xd, FREIBURG1.dist)
    assert np.abs(distort_normalised(x, FREIBURG1.dist) - xd).max() < 1e-12
    back, _ = cv2.projectPoints(np.concatenate([x, np.ones((len(x), 1))], 1).reshape(-1, 1, 3), np.zeros(3),
                                np.zeros(3), K, np.asarray(FREIBURG1.dist))
    assert np.abs(back.reshape(-1, 2) - px).max() < 1e-6


def test_a_rendered_point_lands_where_projectpoints_says():
    """Small white squares rendered by the pinhole canvas (OpenGL) and distorted by the lens map land, to within a
    pixel, where cv2.projectPoints with the camera's distortion puts their centres."""
    from d2slam.synth.gl import GLRenderer

    lens = LensMap(FREIBURG1)
    atlas = np.full((8, 8, 3), 255, np.uint8)
    centres = np.array([[x, y, 1.5] for x in (-0.7, -0.35, 0.0, 0.35, 0.7) for y in (-0.5, 0.0, 0.5)])
    h = 0.01
    P, tri = [], []
    for k, c in enumerate(centres):  # a square facing the camera (counter-clockwise seen from it: V x U towards it)
        P += [c + [-h, -h, 0], c + [h, -h, 0], c + [h, h, 0], c + [-h, h, 0]]
        tri += [[4 * k, 4 * k + 2, 4 * k + 1], [4 * k, 4 * k + 3, 4 * k + 2]]
    P, tri = np.array(P), np.array(tri)
    gl = GLRenderer(lens.K, lens.width, lens.height, atlas)
    try:
        gl.set_static(P, tri, np.ones((len(P), 3)), np.full((len(P), 2), 0.5))
        img = lens(gl.render_colour(np.eye(4))[..., 0].astype(np.float32))
    finally:
        gl.close()
    want, _ = cv2.projectPoints(centres.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), FREIBURG1.K,
                                np.asarray(FREIBURG1.dist))
    want = want.reshape(-1, 2)
    n, lab, _, cent = cv2.connectedComponentsWithStats((img > 60).astype(np.uint8))
    assert n - 1 == len(centres)
    got = np.array([(np.array(np.nonzero(lab == i))[::-1] * img[lab == i]).sum(1) / img[lab == i].sum()
                    for i in range(1, n)])
    d = np.hypot(*(got[:, None, :] - want[None]).transpose(2, 0, 1))
    assert d.min(axis=0).max() < 1.0
    # and without the lens, the same render would miss by several pixels at the image's edge
    assert np.hypot(*((FREIBURG1.K[:2, :2] @ (centres[:, :2] / 1.5).T).T + FREIBURG1.K[:2, 2] - want).T).max() > 3


# ---------------------------------------------------------------------------------------------- the others
# walking_xyz seed 0, 4 frames, and its static twin, as the generator wrote them before the twin scenario and its
# sensor existed. Made on this project's machine (Mesa llvmpipe, the pinned pyrender); another rasteriser may differ.
#
# Across CPUs only the depth PNGs differ: their noise is smoothed by OpenCV's float32 separable filter
# (d2slam.synth.sensor.correlated_noise), whose SIMD path (AVX2 with FMA, or SSE only) changes the field's last bits
# (2 in 3 of its values, by up to 1e-6); rounded to steps of 1/5000 m, 1 to 5 of a frame's ~295,000 valid pixels move
# by one step (x86-64-v2's paths forced: 12 pixels over the 4 frames, a frame's sums moving by at most 3 steps). The
# holes, the RGB, the masks and the texts are the same bytes on this machine, x86-64-v3 and x86-64-v2. So:
# - "others": sha256 over the files (path and content), scene.json (it lists the whole SynthConfig) and the depth
#   PNGs left out, on any CPU;
# - "depth": per depth PNG (in time order), its holes (value 0), the sum of its values and their sum under the
#   pseudo-random signs of _signs(); the holes exactly, the sums within DEPTH_TOL steps (a 5 % change of the
#   noise's correlation length moves the sums by 3,400 to 30,000 steps, the signed sums by 110 to 4,400);
# - "all": sha256 over the files but scene.json (the depth PNGs too) where the depth noise's filter gives this
#   machine's bits (FILTER_BITS); on any CPU, a second generation writes the same bytes.
WALKING_XYZ_4 = {
    "all": "06bafb9b6d749777645489d4349947d4ea249a03387bb77e11688444567e50fd",
    "others": "93b6eac51ea8750d973a4a4c5ba171ecb6552989f69b9bc5631444529fae10fc",
    "depth": [(12264, 5313008523, -5135695), (12236, 5292767038, -6017164), (12601, 5274671935, -7080721),
              (12407, 5267915081, -3874639)],
}
WALKING_XYZ_4_TWIN = {
    "all": "69d7d414392a9cff41ff49e053de1c7649bc44e927161fce2c0d1688dabb5cc4",
    "others": "6b60203ff34c96d13e9b7ae92ba8092d714325fb7b1a4c5e62c64f70c6ed3b3a",
    "depth": [(10431, 5580293862, -5342890), (10347, 5575630814, -6434724), (10493, 5566255171, -8237897),
              (10199, 5563413551, -6336409)],
}
DEPTH_TOL = 64  # steps of 1/5000 m, summed over a frame's pixels
# sha256 of correlated_noise over a 480 x 640 float32 field of default_rng(0)'s standard normals, on this machine
FILTER_BITS = "5718ae1d6a36575c3e2e1f6cbf73d5a47d3588d9f78177c2b5131a80b0b3d64c"


def _digest(out: Path, depth: bool = True) -> str:
    h = hashlib.sha256()
    for p in sorted(out.rglob("*")):
        if p.is_file() and p.name != "scene.json" and (depth or p.parent.name != "depth"):
            h.update(str(p.relative_to(out)).encode())
            h.update(hashlib.sha256(p.read_bytes()).digest())
    return h.hexdigest()


def _signs(shape: tuple[int, int]) -> np.ndarray:
    return np.random.default_rng(0).integers(0, 2, shape) * 2 - 1


def _depth_summary(path: Path) -> tuple[int, int, int]:
    d = cv2.imread(str(path), cv2.IMREAD_UNCHANGED).astype(np.int64)
    return int((d == 0).sum()), int(d.sum()), int((_signs(d.shape) * d).sum())


def _filter_has_this_machines_bits() -> bool:
    white = np.random.default_rng(0).standard_normal((480, 640), dtype=np.float32)
    field = correlated_noise(white, SynthConfig().depth_noise_corr_px)
    return hashlib.sha256(field.tobytes()).hexdigest() == FILTER_BITS


@pytest.mark.parametrize("static_twin,want", [(False, WALKING_XYZ_4), (True, WALKING_XYZ_4_TWIN)],
                         ids=["walking_xyz", "static_twin"])
def test_fr3_scenarios_write_the_same_bytes(tmp_path, static_twin, want):
    out, again = (generate("walking_xyz", tmp_path / name, frames=4, seed=0, static_twin=static_twin, workers=1,
                           progress=False)["out"] for name in ("s", "again"))
    assert _digest(again) == _digest(out)  # byte-identical on one machine
    assert _digest(out, depth=False) == want["others"]
    got = [_depth_summary(p) for p in sorted((out / "depth").glob("*.png"))]
    assert len(got) == len(want["depth"]), got
    for (holes, total, signed), (w_holes, w_total, w_signed) in zip(got, want["depth"]):
        assert holes == w_holes and abs(total - w_total) <= DEPTH_TOL and abs(signed - w_signed) <= DEPTH_TOL, got
    if _filter_has_this_machines_bits():
        assert _digest(out) == want["all"]
