"""The mask cache (hit, miss, invalidation, corrupt files, the one-file format, writes merged across processes,
the earlier per-frame layout converted), the sim/gt label segmenters and the factory."""

from __future__ import annotations

import json
import shutil
import warnings
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np
import pytest

from d2slam.assets import asset_path, tum_frames
from d2slam.cli import main
from d2slam.config import Config, SegmentationConfig
from d2slam.errors import D2SlamError
from d2slam.segmentation import CachedSegmenter, get_segmenter, masks_for
from d2slam.segmentation.base import PersonInstance
from d2slam.segmentation.cache import (STORE_NAME, FrameRecord, MaskStore, RgbListSequence, read_store,
                                      segmenter_key, sequence_key, timestamp_stem)
from d2slam.segmentation.sim import LabelSegmenter, instances_from_labels

H, W = 24, 32


@pytest.fixture(scope="module")
def real_assets():
    """The models and frames, found before each test moves the cache (module scope: set up before the autouse one)."""
    return {"m384": asset_path("models/yolov8n-seg_deq_384x512.onnx"),
            "m256": asset_path("models/yolov8n-seg_deq_256x320.onnx"), "frames": tum_frames()}


@pytest.fixture(autouse=True)
def _cache_in_tmp(tmp_path, monkeypatch):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))


def _write_sequence(root: Path, n: int = 4, seed: int = 0) -> Path:
    """A tiny TUM-like folder (rgb/ + rgb.txt) with random images, plus mask_sim/, mask_gt/, scene.json."""
    rng = np.random.default_rng(seed)
    for sub in ("rgb", "mask_sim", "mask_gt"):
        (root / sub).mkdir(parents=True, exist_ok=True)
    lines = ["# timestamp filename"]
    for i in range(n):
        stem = f"{1305031102.175304 + i / 30:.6f}"
        cv2.imwrite(str(root / "rgb" / f"{stem}.png"), rng.integers(0, 256, (H, W, 3), dtype=np.uint8))
        sim = np.zeros((H, W), np.uint8)
        sim[2:10, 3:9] = 1
        if i % 2 == 0:
            sim[12:20, 20:30] = 2
        gt = np.zeros((H, W), np.uint8)
        gt[2:11, 3:10] = 5  # person id 5
        gt[15:22, 18:31] = 7  # person id 7
        gt[0:2, 25:32] = 9  # a moved object: not a person
        cv2.imwrite(str(root / "mask_sim" / f"{stem}.png"), sim)
        cv2.imwrite(str(root / "mask_gt" / f"{stem}.png"), gt)
        lines.append(f"{stem} rgb/{stem}.png")
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    (root / "scene.json").write_text(json.dumps({"format": "d2slam-synth/2", "person_ids": [5, 7],
                                                 "moved_object_ids": [9]}))
    return root


@dataclass
class CountingSegmenter:
    """A stand-in for the model: one box-shaped person whose position depends on the frame; counts calls."""

    model_sha256: str = "a" * 64
    threshold: float = 0.5
    name: str = "onnx"
    calls: int = 0

    def identity(self):
        return {"kind": self.name, "model_sha256": self.model_sha256, "config": {"score": self.threshold}}

    def __call__(self, frame):
        self.calls += 1
        mask = np.zeros(frame.rgb.shape[:2], bool)
        x = frame.index % 5
        mask[3:15, x:x + 9] = True
        return [PersonInstance(mask=mask, score=0.75 + 0.01 * frame.index, box=(x, 3.0, x + 9.0, 15.0))]


@pytest.fixture
def seq(tmp_path):
    return RgbListSequence(_write_sequence(tmp_path / "seq"))


def test_miss_then_hit_without_reading_images(seq):
    seg = CountingSegmenter()
    cached = CachedSegmenter(seg, seq)
    first = [cached.instances(i) for i in range(len(seq))]
    assert seg.calls == 4 and cached.misses == 4 and cached.hits == 0
    # one file for the sequence, written once every frame was there
    assert [p.name for p in cached.dir.glob("*.npz")] == [STORE_NAME] and (cached.dir / "meta.json").is_file()
    assert len(read_store(cached.dir / STORE_NAME)[1]) == 4
    again = CachedSegmenter(seg, seq)  # a new run, same key
    for p in seq.rgb_paths:  # hits must not touch the images
        p.unlink()
    second = [again.instances(i) for i in range(len(seq))]
    assert seg.calls == 4 and again.hits == 4 and again.misses == 0
    for a, b in zip(first, second):
        assert np.array_equal(a[0].mask, b[0].mask) and a[0].box == b[0].box
        assert a[0].score == pytest.approx(b[0].score)


def test_call_with_frame_uses_the_cache(seq):
    seg = CountingSegmenter()
    cached = CachedSegmenter(seg, seq)
    frame = seq[1]
    cached(frame)
    cached(frame)
    assert seg.calls == 1 and cached.hits == 1


def test_model_or_config_change_invalidates(seq):
    base = CountingSegmenter()
    CachedSegmenter(base, seq).fill(progress=False)
    other_model = CountingSegmenter(model_sha256="b" * 64)
    c2 = CachedSegmenter(other_model, seq)
    assert c2.fill(progress=False) == (0, 4) and other_model.calls == 4
    other_cfg = CountingSegmenter(threshold=0.3)
    c3 = CachedSegmenter(other_cfg, seq)
    assert c3.fill(progress=False) == (0, 4)
    assert len({CachedSegmenter(s, seq).dir for s in (base, other_model, other_cfg)}) == 3
    same = CountingSegmenter()
    assert CachedSegmenter(same, seq).fill(progress=False) == (4, 0) and same.calls == 0


def test_sequence_identity(tmp_path, seq):
    key = sequence_key(seq)
    assert key.startswith("seq-") and key == sequence_key(RgbListSequence(seq.root))
    other = RgbListSequence(_write_sequence(tmp_path / "seq2", n=3))
    assert sequence_key(other) != key
    txt = seq.root / "rgb.txt"  # an edited rgb.txt is another sequence
    txt.write_text(txt.read_text() + "# edited\n")
    assert sequence_key(RgbListSequence(seq.root)) != key


def _backdate(root: Path, seconds: float = 10.0) -> None:
    """Every file of ``root`` modified ``seconds`` ago (past the memo's mtime window)."""
    import os
    import time

    t = time.time_ns() - int(seconds * 1e9)
    for p in root.rglob("*"):
        os.utime(p, ns=(t, t))


def test_replaced_images_get_a_new_key_touched_ones_keep_it(seq, monkeypatch):
    """The key covers the images' bytes: replacing an image (same rgb.txt, same size even) is another sequence, its
    masks segmented again; touching or copying them back (same bytes, new times) keeps the key and the masks. The
    cheap digest (names, sizes, times) spares the hashing when nothing changed."""
    import d2slam.segmentation.cache as SC

    _backdate(seq.root)
    key = sequence_key(seq)
    hashed = []
    real = SC.sha256_file
    monkeypatch.setattr(SC, "sha256_file", lambda p: hashed.append(p) or real(p))
    assert sequence_key(seq) == key and hashed == []  # the memo: nothing read
    img = sorted((seq.root / "rgb").iterdir())[1]
    before = img.read_bytes()
    fresh = np.random.default_rng(9).integers(0, 256, (H, W, 3), dtype=np.uint8)
    cv2.imwrite(str(img), fresh)
    assert sequence_key(seq) != key and len(hashed) == 4  # replaced: hashed in full, another key
    seg = CountingSegmenter()
    CachedSegmenter(seg, seq).fill(progress=False)
    assert seg.calls == 4  # not the old masks
    img.write_bytes(before)  # the old bytes back, with a new time
    assert sequence_key(seq) == key


def test_a_memo_written_within_the_mtime_window_is_not_trusted(seq, monkeypatch):
    """Images modified just before the memo was written are hashed again next time (a coarse file system could
    hide a change within that window); past the window the memo is trusted."""
    import d2slam.segmentation.cache as SC

    key = sequence_key(seq)  # the images were written just now
    hashed = []
    real = SC.sha256_file
    monkeypatch.setattr(SC, "sha256_file", lambda p: hashed.append(p) or real(p))
    assert sequence_key(seq) == key and len(hashed) == 4
    _backdate(seq.root)
    hashed.clear()
    assert sequence_key(seq) == key and len(hashed) == 4  # new times: hashed, same content, memo rewritten
    hashed.clear()
    assert sequence_key(seq) == key and hashed == []


def test_a_damaged_memo_is_said_and_remade(seq, capsys):
    from d2slam.paths import cache_dir

    _backdate(seq.root)
    key = sequence_key(seq)
    (memo,) = cache_dir("masks", "stamps").glob("*.json")
    memo.write_bytes(memo.read_bytes()[:20])
    assert sequence_key(seq) == key
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"d2slam: damaged mask cache memo {memo} (")
    assert sequence_key(seq) == key and capsys.readouterr().err == ""


def test_real_segmenter_key_has_model_hash_and_mask_config(real_assets):
    m384, m256 = real_assets["m384"], real_assets["m256"]
    a = get_segmenter("onnx", model=m384)
    b = get_segmenter("onnx", model=m256)
    c = get_segmenter("onnx", model=m384, config=SegmentationConfig(nms_iou=0.5))
    d = get_segmenter("onnx", model=m384,
                      config=SegmentationConfig(intra_op_threads=1))
    assert a.identity()["model_sha256"] == a.sha256
    assert len({segmenter_key(s) for s in (a, b, c)}) == 3
    assert segmenter_key(d) == segmenter_key(a)  # thread count does not change masks
    e = get_segmenter("onnx", model=m384, config=SegmentationConfig(cache_flush_frames=7))
    assert segmenter_key(e) == segmenter_key(a)  # nor how often the cache file is written


@pytest.mark.parametrize("damage", ["garbage", "truncate", "empty", "wrong_arrays", "bitflip"])
def test_damaged_cache_file_is_recomputed_with_one_line(seq, damage, capsys):
    seg = CountingSegmenter()
    cached = CachedSegmenter(seg, seq)
    cached.fill(progress=False)
    good = cached.instances(2)
    path = cached.dir / STORE_NAME
    if damage == "garbage":
        path.write_bytes(b"not an npz at all")
    elif damage == "truncate":
        path.write_bytes(path.read_bytes()[:40])
    elif damage == "empty":
        path.write_bytes(b"")
    elif damage == "bitflip":
        blob = bytearray(path.read_bytes())
        blob[len(blob) // 2] ^= 0x10
        path.write_bytes(bytes(blob))
    else:  # a readable file whose arrays disagree: two frames, one instance range
        shape, frames = read_store(path)
        with np.load(path) as z:
            arrays = dict(z)
        arrays["first"] = arrays["first"][:2]
        np.savez(path, **arrays)
    capsys.readouterr()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no raw Python warning
        fresh = CachedSegmenter(seg, seq)
    err = capsys.readouterr().err
    assert err.startswith(f"d2slam: damaged mask cache file {path} (") and err.count("\n") == 1
    assert err.endswith("): segmenting its frames again\n")
    assert fresh.recovered == 1
    got = fresh.instances(2)
    assert seg.calls == 5 and fresh.misses == 1
    assert np.array_equal(got[0].mask, good[0].mask)
    fresh.fill(progress=False)  # the other frames too; the file is rewritten, valid
    assert len(read_store(path)[1]) == 4
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert CachedSegmenter(seg, seq).instances(2)[0].box == good[0].box


def _random_instances(rng, shape, k):
    out = []
    for j in range(k):
        mask = rng.random(shape) < 0.3
        if j == 0:
            mask[:] = False  # an empty mask (a person whose mask fell below the threshold)
        elif j == 1:
            mask[0, :] = mask[:, -1] = True  # touching the frame's borders
        out.append(PersonInstance(mask=mask, score=float(rng.random()), box=tuple(rng.random(4).tolist())))
    return out


def test_store_roundtrip_is_exact(tmp_path):
    """Masks (empty, at the borders, overlapping), scores and boxes come back exactly, in order, from the file."""
    rng = np.random.default_rng(3)
    shape = (13, 21)
    frames = {t: _random_instances(rng, shape, k) for t, k in ((10.5, 3), (10.0, 0), (11.25, 4))}
    store = MaskStore(tmp_path / STORE_NAME)
    for t, persons in frames.items():
        store.put(t, persons, shape)
    store.flush()
    again = MaskStore(tmp_path / STORE_NAME)
    assert len(again) == 3 and again.shape == shape and 10.0 in again and 9.0 not in again
    assert again.get(9.0) is None
    for t, persons in frames.items():
        got = again.get(t)
        assert len(got) == len(persons)
        for a, b in zip(got, persons):
            assert a.mask.dtype == bool and a.mask.shape == shape and np.array_equal(a.mask, b.mask)
            assert a.score == pytest.approx(b.score, rel=1e-6) and a.box == pytest.approx(b.box, rel=1e-6)
    record = FrameRecord.from_instances(1.0, frames[11.25])
    assert record.rects[0] == (0, 0, 0, 0) and len(record.bits[0]) == 0  # nothing stored for an empty mask


def test_the_file_is_written_every_few_frames_and_when_complete(seq):
    seg = CountingSegmenter()
    cached = CachedSegmenter(seg, seq, flush_frames=3)
    path = cached.dir / STORE_NAME
    cached.instances(0), cached.instances(1)
    assert not path.exists()  # two new frames: not yet written
    cached.instances(2)
    assert len(read_store(path)[1]) == 3  # three: written
    assert CachedSegmenter(seg, seq).instances(1)[0].box == (1.0, 3.0, 10.0, 15.0)  # another process reads them
    cached.instances(3)
    assert len(read_store(path)[1]) == 4  # the last missing frame: written at once
    assert not list(cached.dir.glob(".tmp-*"))


def test_flush_masks_writes_what_masks_for_segmented(seq, monkeypatch):
    """Part of a sequence segmented through ``masks_for`` reaches the file with ``flush_masks``, not before."""
    import d2slam.segmentation as S

    seg = CountingSegmenter()
    monkeypatch.setattr(S, "get_segmenter", lambda kind, sequence=None, config=None, model=None: seg)
    monkeypatch.setattr(S, "_SESSIONS", {})
    monkeypatch.setattr(S, "_CACHED", {})
    S.masks_for(seq, 0, "onnx", model="m.onnx")
    path = CachedSegmenter(seg, seq).dir / STORE_NAME
    assert not path.exists()
    S.flush_masks()
    assert list(read_store(path)[1]) == [timestamp_stem(seq.timestamps[0])]


def test_writes_of_two_processes_are_merged(seq):
    """Two readers of one sequence that segment different frames: the file ends up with both."""
    a, b = CachedSegmenter(CountingSegmenter(), seq), CachedSegmenter(CountingSegmenter(), seq)
    a.instances(0), b.instances(3)
    a.flush()
    b.flush()
    assert sorted(read_store(a.dir / STORE_NAME)[1]) == [timestamp_stem(seq.timestamps[i]) for i in (0, 3)]
    seg = CountingSegmenter()
    c = CachedSegmenter(seg, seq)
    c.instances(0), c.instances(3)
    assert seg.calls == 0 and c.hits == 2


def _write_frame_file(path: Path, persons, shape, timestamp):
    """One file of the earlier per-frame layout."""
    masks = np.stack([p.mask for p in persons]) if persons else np.zeros((0, *shape), bool)
    np.savez_compressed(path, bits=np.packbits(masks, axis=None), shape=np.asarray(masks.shape, np.int64),
                        scores=np.asarray([p.score for p in persons], np.float32),
                        boxes=np.asarray([p.box for p in persons], np.float32).reshape(-1, 4),
                        timestamp=np.float64(timestamp))


def test_a_folder_of_the_earlier_layout_is_converted(seq):
    """Per-frame files of the earlier layout become hits (a corrupt one is recomputed); they are left in place."""
    seg = CountingSegmenter()
    folder = CachedSegmenter(seg, seq).dir  # the same key: same sequence, same segmenter
    (folder / STORE_NAME).unlink(missing_ok=True)
    legacy = {}
    for i in range(3):
        persons = seg(seq[i]) if i else []
        legacy[i] = persons
        _write_frame_file(folder / f"{timestamp_stem(seq.timestamps[i])}.npz", persons, (H, W), seq.timestamps[i])
    (folder / f"{timestamp_stem(seq.timestamps[2])}.npz").write_bytes(b"junk")
    seg.calls = 0
    cached = CachedSegmenter(seg, seq)
    assert len(read_store(folder / STORE_NAME)[1]) == 2
    assert cached.instances(0) == [] and np.array_equal(cached.instances(1)[0].mask, legacy[1][0].mask)
    assert seg.calls == 0 and cached.hits == 2
    cached.instances(2)
    assert seg.calls == 1  # the corrupt file's frame
    assert len(list(folder.glob("1*.npz"))) == 3


def test_empty_frames_roundtrip(seq):
    class Nobody(CountingSegmenter):
        def __call__(self, frame):
            self.calls += 1
            return []

    seg = Nobody()
    c = CachedSegmenter(seg, seq)
    assert c.instances(0) == []
    c.flush()
    assert CachedSegmenter(seg, seq).instances(0) == [] and seg.calls == 1


def test_sim_and_gt_label_segmenters(seq):
    sim = get_segmenter("sim", seq)
    frame0, frame1 = seq[0], seq[1]
    p0 = sim(frame0)
    assert len(p0) == 2 and len(sim(frame1)) == 1
    assert p0[0].box == (3.0, 2.0, 9.0, 10.0) and p0[0].area == 48 and p0[0].score == 1.0
    assert p0[1].box == (20.0, 12.0, 30.0, 20.0)
    gt = get_segmenter("gt", seq)
    g = gt(frame0)
    assert len(g) == 2  # ids 5 and 7 are persons, 9 is an object
    assert [x.area for x in g] == [63, 91]
    # Through the pipeline's entry point (no cache needed for label images).
    assert [x.area for x in masks_for(seq, 0, "sim")] == [48, 80]
    assert len(masks_for(seq, 3, "gt", Config())) == 2
    assert not any((Path(seq.root).parent / "cache").rglob("*.npz"))


def test_label_instances_helper():
    labels = np.zeros((5, 6), np.uint8)
    labels[1:3, 1:4] = 3
    labels[4, 5] = 1
    inst = instances_from_labels(labels)
    assert [p.box for p in inst] == [(5.0, 4.0, 6.0, 5.0), (1.0, 1.0, 4.0, 3.0)]
    assert instances_from_labels(labels, ids=[2]) == []
    assert instances_from_labels(np.zeros((5, 6), np.uint8)) == []


def test_label_segmenter_bad_input(seq, tmp_path):
    with pytest.raises(D2SlamError, match="mask_sim"):
        get_segmenter("sim", RgbListSequence(_write_real_only(tmp_path / "real")))
    with pytest.raises(D2SlamError, match="needs a synthetic sequence"):
        get_segmenter("gt", None)
    stem = seq.rgb_paths[1].stem
    (seq.root / "mask_sim" / f"{stem}.png").unlink()
    with pytest.raises(D2SlamError, match=f"{stem}.png.*not found"):
        get_segmenter("sim", seq)(seq[1])
    (seq.root / "mask_sim" / f"{stem}.png").write_bytes(b"junk")
    with pytest.raises(D2SlamError, match="corrupt"):
        get_segmenter("sim", seq)(seq[1])
    cv2.imwrite(str(seq.root / "mask_sim" / f"{stem}.png"), np.zeros((5, 5), np.uint8))
    with pytest.raises(D2SlamError, match="differs"):
        get_segmenter("sim", seq)(seq[1])
    (seq.root / "scene.json").write_text("{}")
    with pytest.raises(D2SlamError, match="person_ids"):
        get_segmenter("gt", seq)
    with pytest.raises(D2SlamError, match="unknown segmenter kind"):
        get_segmenter("yolact", seq)


def _write_real_only(root: Path) -> Path:
    _write_sequence(root, n=2)
    shutil.rmtree(root / "mask_sim")
    return root


def test_reader_methods_are_used_when_present(seq):
    class WithReader:
        root, timestamps, name = seq.root, seq.timestamps, "x"

        def person_masks_sim(self, i):
            m = np.zeros((2, H, W), bool)
            m[0, 1:3, 1:3] = True
            return m

    seg = LabelSegmenter(WithReader(), "sim")
    got = seg.instances(0)
    assert len(got) == 1 and got[0].area == 4  # the empty second mask is dropped


def test_rgb_list_bad_input(tmp_path):
    root = tmp_path / "bad"
    root.mkdir()
    with pytest.raises(D2SlamError, match="rgb.txt not found"):
        RgbListSequence(root)
    (root / "rgb.txt").write_text("# c\n1.0 rgb/a.png\nabc rgb/b.png\n")
    with pytest.raises(D2SlamError, match=r"rgb.txt:3:"):
        RgbListSequence(root)
    (root / "rgb.txt").write_text("2.0 rgb/a.png\n1.0 rgb/b.png\n")
    with pytest.raises(D2SlamError, match=r"rgb.txt:2: .*strictly increasing"):
        RgbListSequence(root)
    (root / "rgb.txt").write_text("# nothing\n")
    with pytest.raises(D2SlamError, match="no images"):
        RgbListSequence(root)


def test_segment_command_fills_the_cache_once(tmp_path, capsys, real_assets, monkeypatch):
    """`d2slam segment SEQUENCE_DIR` with the real model on two real frames; the second run segments nothing."""
    root = tmp_path / "real_seq"
    (root / "rgb").mkdir(parents=True)
    frames = real_assets["frames"][:2]
    monkeypatch.setenv("D2SLAM_SEG_MODEL", str(real_assets["m384"]))  # the default model, wherever it was found
    lines = []
    for i, src in enumerate(frames):
        shutil.copyfile(src, root / "rgb" / f"{100 + i}.000000.png")
        lines.append(f"{100 + i}.000000 rgb/{100 + i}.000000.png")
    (root / "rgb.txt").write_text("\n".join(lines) + "\n")
    assert main(["segment", str(root), "--json"]) == 0
    first = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (first["frames"], first["segmented"], first["cached_before"]) == (2, 2, 0)
    assert main(["segment", str(root), "--json"]) == 0
    second = json.loads(capsys.readouterr().out.strip().splitlines()[-1])
    assert (second["segmented"], second["cached_before"]) == (0, 2)
    seq = RgbListSequence(root)
    # from now on only the cache can answer: reading a frame fails (the images stay: they are the cache's key)
    monkeypatch.setattr(RgbListSequence, "__getitem__", lambda self, i: pytest.fail("read a frame"))
    assert [len(masks_for(seq, i, "onnx")) for i in range(2)] == [2, 1]
    direct = get_segmenter("onnx")(cv2.cvtColor(cv2.imread(str(frames[0])), cv2.COLOR_BGR2RGB))
    cached = masks_for(seq, 0, "onnx")
    assert all(np.array_equal(a.mask, b.mask) for a, b in zip(direct, cached))
    assert main(["segment", str(root), str(frames[0])]) == 2  # a folder and images mixed


def _synthetic_fixture(root: Path) -> Path:
    """A TUM fixture folder (d2slam.data.fixtures) turned into a synthetic one: masks + scene.json."""
    from d2slam.data.fixtures import write_tum_folder

    write_tum_folder(root, n_frames=3, width=W, height=H)
    stems = [Path(line.split()[1]).stem for line in (root / "rgb.txt").read_text().splitlines()
             if line.strip() and not line.startswith("#")]
    for sub in ("mask_sim", "mask_gt"):
        (root / sub).mkdir()
    for stem in stems:
        gt = np.zeros((H, W), np.uint8)
        gt[2:11, 3:10] = 5
        gt[0:2, 25:32] = 9
        sim = (gt == 5).astype(np.uint8)
        cv2.imwrite(str(root / "mask_gt" / f"{stem}.png"), gt)
        cv2.imwrite(str(root / "mask_sim" / f"{stem}.png"), sim)
    scene = {"format": "d2slam-synth/2", "camera": {"fx": 30.0, "fy": 30.0, "cx": W / 2, "cy": H / 2, "width": W,
                                                    "height": H, "depth_factor": 5000.0},
             "objects": [{"id": 5, "kind": "person", "name": "p", "moved": True, "moving_intervals": []},
                         {"id": 9, "kind": "object", "name": "box", "moved": True, "moving_intervals": []}],
             "person_ids": [5], "moved_object_ids": [9]}
    (root / "scene.json").write_text(json.dumps(scene))
    return root


def test_with_the_project_readers(tmp_path):
    """sim/gt through SyntheticSequence.person_masks_*; a cache filled via `d2slam segment`'s reader is hit by
    the TUM/synthetic readers (same key: folder, rgb.txt, timestamps)."""
    from d2slam.data.synthetic import SyntheticSequence
    from d2slam.data.tum import TumSequence

    root = _synthetic_fixture(tmp_path / "synth")
    syn = SyntheticSequence(root)
    sim, gt = LabelSegmenter(syn, "sim"), LabelSegmenter(syn, "gt")
    assert [p.area for p in sim.instances(1)] == [63] and [p.area for p in gt.instances(1)] == [63]
    assert [p.box for p in gt.instances(0)] == [p.box for p in gt(syn[0])] == [(3.0, 2.0, 10.0, 11.0)]
    seg = CountingSegmenter()
    assert CachedSegmenter(seg, RgbListSequence(root)).fill(progress=False) == (0, 3)
    for reader in (TumSequence(root, camera="fr3"), syn):
        c = CachedSegmenter(seg, reader)
        assert [len(c.instances(i)) for i in range(len(reader))] == [1, 1, 1] and c.hits == 3
    assert seg.calls == 3


def test_unwritable_cache_is_a_clear_error(seq, capsys):
    cached = CachedSegmenter(CountingSegmenter(), seq, flush_frames=1)
    (cached.dir / STORE_NAME).mkdir()  # a folder where the file should go: unreadable, and the write fails
    with pytest.raises(D2SlamError, match="cannot write the mask cache.*D2SLAM_CACHE"):
        cached.instances(0)
    assert "damaged mask cache file" in capsys.readouterr().err
    assert not list(cached.dir.glob(".tmp-*"))  # no temporary file left behind
    (cached.dir / STORE_NAME).rmdir()
