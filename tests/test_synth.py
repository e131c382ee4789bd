"""The synthetic benchmark generator: determinism, TUM layout round trip, people and objects really moving, masks,
static twin, coverage, bad input."""

from __future__ import annotations

import importlib
import json
from pathlib import Path

import cv2
import numpy as np
import pytest

from d2slam.config import SYNTH_CAMERA, SynthConfig
from d2slam.errors import D2SlamError
from d2slam.synth import SCENARIOS, Scene, generate
from d2slam.synth.scene import DESK_CHAIR_IDS
from d2slam.synth.world import WorldRenderer

FRAMES = 16


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def seqs(tmp_path_factory):
    root = tmp_path_factory.mktemp("synth")
    out = {}
    out["a"] = generate("walking_xyz", root / "a", frames=FRAMES, seed=0, workers=2, progress=False)
    out["b"] = generate("walking_xyz", root / "b", frames=FRAMES, seed=0, workers=1, progress=False)
    out["twin"] = generate("walking_xyz", root / "twin", frames=FRAMES, seed=0, static_twin=True, workers=1,
                           progress=False)
    out["seed1"] = generate("walking_xyz", root / "seed1", frames=4, seed=1, workers=1, progress=False)
    return out


def _read_list(path: Path):
    rows = [ln.split() for ln in path.read_text().splitlines() if ln.strip() and not ln.startswith("#")]
    return rows


def _sorted_stems(root: Path, sub: str) -> list[str]:
    return [row[1] for row in _read_list(root / f"{sub}.txt")]


# ---------------------------------------------------------------------------------------------- determinism
def test_same_seed_gives_byte_identical_files_whatever_the_workers(seqs):
    a, b = _files(seqs["a"]["out"]), _files(seqs["b"]["out"])
    assert seqs["a"]["workers"] == 2 and seqs["b"]["workers"] == 1
    assert len(a) == 4 * FRAMES + 4 and a.keys() == b.keys()
    diff = [k for k in a if a[k] != b[k]]
    assert diff == []


def test_other_seed_gives_other_people_and_textures(seqs):
    a, c = seqs["a"]["out"], seqs["seed1"]["out"]
    ra = cv2.imread(str(a / _sorted_stems(a, "rgb")[0]))
    rc = cv2.imread(str(c / _sorted_stems(c, "rgb")[0]))
    assert np.abs(ra.astype(int) - rc.astype(int)).mean() > 10
    s0, s1 = Scene("walking_xyz", 0, FRAMES), Scene("walking_xyz", 1, FRAMES)
    p0 = np.array([p.root(0.5)[:3, 3] for p in s0.people])
    p1 = np.array([p.root(0.5)[:3, 3] for p in s1.people])
    assert np.abs(p0 - p1).max() > 0.1


# ---------------------------------------------------------------------------------------------- TUM layout
def test_tum_layout_round_trip_with_opencv(seqs):
    root = seqs["a"]["out"]
    for name in ("rgb.txt", "depth.txt", "groundtruth.txt"):
        head = (root / name).read_text().splitlines()[:3]
        assert all(line.startswith("# ") for line in head)
    rgb_rows, depth_rows = _read_list(root / "rgb.txt"), _read_list(root / "depth.txt")
    assert len(rgb_rows) == len(depth_rows) == FRAMES
    t_rgb = np.array([float(r[0]) for r in rgb_rows])
    t_depth = np.array([float(r[0]) for r in depth_rows])
    assert np.all(np.diff(t_rgb) > 0) and np.all(np.diff(t_depth) > 0)
    dt = np.diff(t_rgb)
    assert abs(dt.mean() - 1 / 30) < 0.002 and dt.std() > 0  # 30 Hz with jitter
    off = t_depth - t_rgb
    assert off.min() >= 0.002 - 1e-6 and off.max() <= 0.012 + 1e-6  # depth a few ms after RGB
    for (t, name), (td, dname) in zip(rgb_rows[:3], depth_rows[:3]):
        assert name == f"rgb/{t}.png" and len(t.split(".")[1]) == 6 and t.startswith("1341846")
        rgb = cv2.imread(str(root / name), cv2.IMREAD_UNCHANGED)
        assert rgb.dtype == np.uint8 and rgb.shape == (480, 640, 3)
        depth = cv2.imread(str(root / dname), cv2.IMREAD_UNCHANGED)
        assert depth.dtype == np.uint16 and depth.shape == (480, 640)
        metres = depth[depth > 0] / 5000.0
        assert 0.3 < metres.min() and metres.max() < 4.5 + 0.05
        for sub in ("mask_gt", "mask_sim"):
            m = cv2.imread(str(root / sub / f"{t}.png"), cv2.IMREAD_UNCHANGED)
            assert m.dtype == np.uint8 and m.shape == (480, 640)
    gt = np.array([[float(v) for v in r] for r in _read_list(root / "groundtruth.txt")])
    assert gt.shape[1] == 8
    rate = 1 / np.diff(gt[:, 0]).mean()
    assert abs(rate - 100) < 0.5 and np.all(np.diff(gt[:, 0]) > 0)
    assert gt[0, 0] < t_rgb[0] and gt[-1, 0] > t_rgb[-1]  # covers all frames
    np.testing.assert_allclose(np.linalg.norm(gt[:, 4:], axis=1), 1, atol=1e-6)
    # the 100 Hz ground truth samples the same path as the frames: compare at the nearest gt sample
    scene = Scene("walking_xyz", 0, FRAMES)
    k = np.searchsorted(gt[:, 0], t_rgb[5])
    T = scene.camera.poses([gt[k, 0] - scene.t0])[0]
    np.testing.assert_allclose(gt[k, 1:4], T[:3, 3], atol=2e-6)
    from scipy.spatial.transform import Rotation

    R = Rotation.from_quat(gt[k, 4:]).as_matrix()
    np.testing.assert_allclose(R, T[:3, :3], atol=1e-6)
    # optical frame: z forward looks into the room (+Y world), y down points to the floor (-Z world)
    assert T[1, 2] > 0.8 and T[2, 1] < -0.8


def test_scene_json(seqs):
    root = seqs["a"]["out"]
    scene = json.loads((root / "scene.json").read_text())
    assert scene["format"] == "d2slam-synth/2" and scene["scenario"] == "walking_xyz" and scene["seed"] == 0
    assert scene["frames"] == FRAMES and scene["static_twin"] is False
    assert scene["camera"] == {"fx": 535.4, "fy": 539.2, "cx": 320.1, "cy": 247.6, "width": 640, "height": 480,
                               "depth_factor": 5000.0}
    # two people and the two desk chairs (moved when somebody sits down or gets up during the sequence)
    assert scene["person_ids"] == [1, 2] and set(scene["moved_object_ids"]) <= set(DESK_CHAIR_IDS)
    kinds = {o["id"]: o for o in scene["objects"]}
    assert {oid for oid, o in kinds.items() if o["kind"] == "object"} == set(DESK_CHAIR_IDS)
    assert [kinds[p]["role"] for p in scene["person_ids"]] == ["walk", "walk"]
    for oid in DESK_CHAIR_IDS:
        o = kinds[oid]
        assert o["object"] == "chair" and o["moved"] == bool(o["moving_intervals"]) and isinstance(o["moved_by"], list)
        for a, b in o["moving_intervals"]:
            assert scene["generator"]["start_time"] <= a < b
    assert scene["generator"]["depth_rendered_at"] == "rgb_timestamp"
    assert scene["generator"]["depth_noise"]["b"] == 0.0019 and "depth_noise_corr_px" in scene["generator"]["config"]


def test_reads_back_through_the_library_reader(seqs):
    from d2slam.data.synthetic import SyntheticSequence

    seq = SyntheticSequence(seqs["a"]["out"])
    assert len(seq) == FRAMES
    f = seq[3]
    assert f.depth.dtype == np.float32 and 0.3 < f.depth[f.depth > 0].min()
    assert seq.dynamic_mask(3).any()
    gt = seq.frame_gt_poses()
    scene = Scene("walking_xyz", 0, FRAMES)
    np.testing.assert_allclose(gt[:, :3, 3], scene.camera.poses(scene.t_rel)[:, :3, 3], atol=2e-3)


# ---------------------------------------------------------------------------------------------- dynamics
def _render_ids(scene: Scene, times) -> list[np.ndarray]:
    r = WorldRenderer(scene)
    T = scene.camera.poses(times)
    try:
        return [r.render(t, T[k])[2] for k, t in enumerate(times)]
    finally:
        r.close()


def _centroid(mask):
    ys, xs = np.nonzero(mask)
    return np.array([xs.mean(), ys.mean()]) if len(xs) else None


@pytest.mark.parametrize("scenario", [s for s in SCENARIOS if s.startswith("walking")])
def test_walking_people_move_and_cover_much_of_the_image(scenario):
    scene = Scene(scenario, 0, 300)
    times = np.arange(0.0, 9.01, 0.5)
    ids = _render_ids(scene, times)
    person = [np.isin(m, scene.person_ids) for m in ids]
    coverage = np.array([m.mean() for m in person])
    assert coverage.max() >= 0.2 and np.mean(coverage > 0.02) > 0.6  # in view most of the time, near at times
    # their masks change between frames 0.5 s apart (someone is walking most of the time)
    changes = [(a ^ b).sum() / max((a | b).sum(), 1) for a, b in zip(person[:-1], person[1:])]
    assert np.median(changes) > 0.1


def test_sitting_people_move_a_little():
    scene = Scene("sitting_static", 0, 300)
    ids = _render_ids(scene, [0.0, 0.5, 1.0])
    for pid in scene.person_ids:
        masks = [m == pid for m in ids]
        assert all(m.sum() > 5000 for m in masks)  # both sitters are in view
        change = (masks[0] ^ masks[2]).sum() / (masks[0] | masks[2]).sum()
        assert 0.005 < change < 0.35
        shift = np.linalg.norm(_centroid(masks[0]) - _centroid(masks[2]))
        assert shift < 30  # they stay in place
    for p in scene.people:  # roots fixed, limbs move
        np.testing.assert_allclose(p.root(0.0), p.root(2.0))
        moves = np.linalg.norm(p.mesh(0.0)[0] - p.mesh(1.0)[0], axis=1)
        assert 0.005 < moves.max() < 0.5


@pytest.mark.parametrize("scenario", ["walking_carry", "walking_push"])
def test_the_moved_object_is_seen_moving(scenario):
    from d2slam.synth.actors import HeldObject

    scene = Scene(scenario, 0, 300)  # 10 s
    obj = next(o for o in scene.objects if isinstance(o, HeldObject))
    a, b = obj.intervals[0]
    times = np.linspace(a, b, 8)
    seen = [_centroid(m == obj.oid) for m in _render_ids(scene, times)]
    seen = [c for c in seen if c is not None]
    assert len(seen) >= 4
    assert max(np.linalg.norm(c - seen[0]) for c in seen) > 30  # pixels


def test_masks_consistent_with_rendered_people(seqs):
    root = seqs["a"]["out"]
    scene = json.loads((root / "scene.json").read_text())
    pids, oids = scene["person_ids"], [o["id"] for o in scene["objects"] if o["kind"] == "object"]
    ious, moved_labelled, moved_total = [], 0, 0
    for t, name in _read_list(root / "rgb.txt"):
        gt = cv2.imread(str(root / "mask_gt" / f"{t}.png"), cv2.IMREAD_UNCHANGED)
        sim = cv2.imread(str(root / "mask_sim" / f"{t}.png"), cv2.IMREAD_UNCHANGED)
        assert set(np.unique(gt)) <= {0, *pids, *oids}
        n = int(sim.max())
        assert set(np.unique(sim)) == set(range(n + 1))
        person = np.isin(gt, pids)
        if person.sum() > 2000:
            ious.append(((sim > 0) & person).sum() / ((sim > 0) | person).sum())
        moved = np.isin(gt, oids)
        # the segmenter labels objects only by bleeding over a person's contour
        far_from_people = moved & (cv2.dilate(person.astype(np.uint8), np.ones((31, 31), np.uint8)) == 0)
        moved_labelled += int((far_from_people & (sim > 0)).sum())
        moved_total += int(far_from_people.sum())
    assert np.median(ious) > 0.65  # simulated errors scale with the bounding box, large for thin limbs
    assert moved_total == 0 or moved_labelled / moved_total < 0.02


def test_walking_frames_show_people(seqs):
    frac = np.array([s["person_fraction"] for s in seqs["a"]["stats"]])
    assert frac.max() >= 0.05  # half a second of walking_xyz seed 0
    assert (frac > 0).all()


def test_static_twin_has_no_dynamic_pixels_and_same_room_and_path(seqs):
    twin, dyn = seqs["twin"]["out"], seqs["a"]["out"]
    scene = json.loads((twin / "scene.json").read_text())
    assert scene["static_twin"] is True and scene["person_ids"] == [] and scene["objects"] == []
    assert (twin / "groundtruth.txt").read_bytes().splitlines()[3:] == \
        (dyn / "groundtruth.txt").read_bytes().splitlines()[3:]
    assert _read_list(twin / "rgb.txt") == _read_list(dyn / "rgb.txt")
    same = []
    for (t, _), (td, dname) in zip(_read_list(twin / "rgb.txt"), _read_list(twin / "depth.txt")):
        for sub in ("mask_gt", "mask_sim"):
            assert not cv2.imread(str(twin / sub / f"{t}.png"), cv2.IMREAD_UNCHANGED).any()
        gt = cv2.imread(str(dyn / "mask_gt" / f"{t}.png"), cv2.IMREAD_UNCHANGED)
        away = cv2.dilate((gt > 0).astype(np.uint8), np.ones((9, 9), np.uint8)) == 0
        d0 = cv2.imread(str(twin / dname), cv2.IMREAD_UNCHANGED)
        d1 = cv2.imread(str(dyn / dname), cv2.IMREAD_UNCHANGED)
        same.append((d0[away] == d1[away]).mean())
    assert min(same) > 0.99  # the same room, path and noise away from the people


# ---------------------------------------------------------------------------------------------- bad input, CLI
def test_bad_input_is_a_clear_error(tmp_path):
    with pytest.raises(D2SlamError, match="unknown scenario"):
        Scene("walking_sideways", 0, 10)
    with pytest.raises(D2SlamError, match="frames"):
        Scene("walking_xyz", 0, 0)
    with pytest.raises(D2SlamError, match="seed"):
        Scene("walking_xyz", -1, 10)
    (tmp_path / "notes.txt").write_text("mine")
    with pytest.raises(D2SlamError, match="refusing"):
        generate("walking_xyz", tmp_path, frames=2, workers=1, progress=False)
    assert (tmp_path / "notes.txt").read_text() == "mine"


def test_cli_synth_and_rerun_replaces(tmp_path, capsys):
    from d2slam.cli import main

    out = tmp_path / "seq"
    assert main(["synth", "sitting_static", "--out", str(out), "--frames", "5", "--seed", "2"]) == 0
    text = capsys.readouterr().out
    assert "wrote 5 frames of sitting_static" in text and "person pixels" in text
    assert main(["synth", "sitting_static", "--out", str(out), "--frames", "3", "--seed", "2"]) == 0
    assert len(list((out / "rgb").iterdir())) == 3  # the longer previous run is gone
    with pytest.raises(SystemExit) as exc:
        main(["synth", "nope", "--out", str(out)])
    assert exc.value.code == 2


def test_bench_synth_reports_cpu_per_frame_and_in_all(capsys):
    """`d2slam bench synth` reports the CPU time of a frame in the steady state (median), by stage, and of the whole
    generation (this process and its workers, start-up included), which a loaded machine does not inflate as it
    does wall time."""
    import re

    from d2slam.cli import main

    assert main(["bench", "synth", "--scenario", "sitting_static", "--frames", "3", "--workers", "1"]) == 0
    out = capsys.readouterr().out
    median, mean = map(float, re.search(r"inside the workers: median ([\d.]+) ms, mean ([\d.]+) ms", out).groups())
    total, per = map(float, re.search(r"start-up included\): ([\d.]+) s = ([\d.]+) ms per frame", out).groups())
    assert 0 < median <= mean and abs(per - 1e3 * total / 3) <= 1e3 * 0.05 / 3 + 0.1  # total printed to 0.1 s
    assert 1e3 * total >= 3 * median
    split = dict(re.findall(r"(\w+) ([\d.]+) ms", out.split("by stage (median): ")[1].splitlines()[0]))
    assert list(split) == ["bodies", "gl", "sensor", "segmenter", "write"] and float(split["gl"]) > 0


def test_png_writer_round_trips_through_opencv(tmp_path):
    """The generator's own PNG writer (zlib-ng, SUB filter) for RGB, 16-bit depth and 8-bit grey, odd sizes too:
    OpenCV reads back exactly the pixels (RGB in OpenCV's BGR order)."""
    G = importlib.import_module("d2slam.synth.generate")
    rng = np.random.default_rng(0)
    images = [rng.integers(0, 256, (7, 5, 3), dtype=np.uint8), rng.integers(0, 65536, (9, 13), dtype=np.uint16),
              rng.integers(0, 256, (4, 3), dtype=np.uint8), rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)]
    for k, img in enumerate(images):
        path = tmp_path / f"{k}.png"
        G.write_image(path, img, SynthConfig().png_compression)
        back = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
        assert back.dtype == img.dtype and np.array_equal(back, img if img.ndim == 2 else img[:, :, ::-1])
        assert path.read_bytes() == G.png_bytes(img, SynthConfig().png_compression)  # deterministic


def test_config_constants_drive_the_noise():
    cfg, noise = SynthConfig(), SYNTH_CAMERA.depth_noise
    assert (noise.a, noise.b, noise.c) == (0.0012, 0.0019, 0.4)
    assert SYNTH_CAMERA.depth_factor == 5000.0 and cfg.fps == 30.0 and cfg.gt_rate == 100.0


def test_cli_synth_refuses_other_folders_before_any_work(tmp_path, monkeypatch, capsys):
    from d2slam.cli import main

    G = importlib.import_module("d2slam.synth.generate")  # the module (the package exports its function)

    monkeypatch.setattr(G, "render_frame", lambda *a: pytest.fail("rendered before the output was checked"))
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "mine.txt").write_text("mine")
    (tmp_path / "file").write_text("x")
    for out in ("notes", "file"):
        assert main(["synth", "sitting_static", "--out", str(tmp_path / out), "--frames", "3"]) == 2
        err = capsys.readouterr().err
        assert err.startswith(f"d2slam: error: {tmp_path / out}: --out: ") and err.count("\n") == 1
    assert (tmp_path / "notes" / "mine.txt").read_text() == "mine"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["file", "notes"]


def test_cli_synth_interrupted_leaves_nothing_half_made(tmp_path, monkeypatch, capsys):
    """Ctrl-C after a few frames: no DIR (or the previous sequence in it, untouched) and no temporary folder."""
    from d2slam.cli import main

    G = importlib.import_module("d2slam.synth.generate")  # the module (the package exports its function)

    real = G.render_frame
    rendered = []

    def interrupted(*args):
        if len(rendered) == 3:
            raise KeyboardInterrupt
        rendered.append(1)
        return real(*args)

    monkeypatch.setattr(G, "render_frame", interrupted)
    out = tmp_path / "seq"
    assert main(["synth", "sitting_static", "--out", str(out), "--frames", "8", "--workers", "1"]) == 130
    err = capsys.readouterr().err
    assert err.endswith("\nd2slam: interrupted\n") and "Traceback" not in err  # after the announcement
    assert len(rendered) == 3 and list(tmp_path.iterdir()) == []

    monkeypatch.setattr(G, "render_frame", real)
    assert main(["synth", "sitting_static", "--out", str(out), "--frames", "2", "--workers", "1"]) == 0
    before = _files(out)
    rendered.clear()
    monkeypatch.setattr(G, "render_frame", interrupted)
    assert main(["synth", "sitting_static", "--out", str(out), "--frames", "8", "--workers", "1"]) == 130
    assert _files(out) == before and [p.name for p in tmp_path.iterdir()] == ["seq"]
