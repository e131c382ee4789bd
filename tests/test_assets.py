"""``d2slam assets fetch`` against a local mirror on 127.0.0.1: download, sha256, derived float models (same bytes
as the shared files, same person masks as the int8 model), the head of TUM fr1/rpy (tests/test_real_assets.py tests
it in detail), lookup order, and the messages when files are missing."""

from __future__ import annotations

import hashlib
import socket

import numpy as np
import onnx
import pytest
from local_http import Server, asset_mirror, head_as_whole

from d2slam import assets as A
from d2slam.cli import main
from d2slam.dequantize import dequantize_file
from d2slam.errors import D2SlamError
from d2slam.paths import shared_dir
from d2slam.segmentation import get_segmenter
from d2slam.segmentation.onnx import OnnxSegmenter, read_rgb

#: Mask agreement of the float conversion with the int8 model at the same input size (per frame, union of persons).
MIN_IOU = 0.98


def sha(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture(scope="module")
def mirror():
    # from this checkout's assets, found before the tests hide them; fr1/rpy's head stands for the whole sequence
    srv = asset_mirror(seconds=300, whole_lists="head")
    yield srv
    srv.close()


@pytest.fixture(scope="module")
def real_shared():
    return shared_dir()


@pytest.fixture
def fresh(tmp_path, monkeypatch, mirror, real_shared):
    """A user's machine: no shared folder, an empty cache, the mirror in place of GitHub (whose fr1/rpy lists are
    the head's)."""
    monkeypatch.setenv("D2SLAM_SHARED", str(tmp_path / "no_shared"))
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(A.MIRROR_ENV, mirror.url)
    monkeypatch.delenv("D2SLAM_SEG_MODEL", raising=False)
    monkeypatch.setattr(A, "real_pins", lambda pins=A.real_pins(): head_as_whole(pins))
    return tmp_path


def test_fetch_downloads_verifies_derives_and_is_idempotent(fresh, mirror, real_shared, capsys):
    assert len(A.missing()) == len(A.ALL_ASSETS) and A.find_real_head() is None
    n_requests = len(mirror.requests)
    assert main(["assets", "fetch"]) == 0
    assert A.missing() == []
    head = A.real_head()
    assert head == fresh / "cache" / "assets" / A.real_head_rel()
    assert sorted(p.name for p in head.iterdir()) == ["depth", "depth.txt", "groundtruth.txt", "rgb", "rgb.txt"]
    n_fetched = len(A.DOWNLOADS) + len(A.LISTS) + len(A.real_pins()["head"]["files"])
    cache = fresh / "cache" / "assets"
    for rel in A.ALL_ASSETS:
        path = A.find(rel)
        assert path == cache / rel
        if (real_shared / rel).is_file():  # same bytes as the shared folder's file (derived ones included)
            assert path.read_bytes() == (real_shared / rel).read_bytes()
    assert {sha(cache / d.path) for d in A.DERIVED} == {d.sha256 for d in A.DERIVED}
    assert len(mirror.requests) - n_requests == n_fetched
    assert not list(cache.rglob("*.part*")) and not list(cache.rglob("*.tmp-*"))
    capsys.readouterr()
    assert main(["assets", "fetch"]) == 0  # everything found: nothing downloaded
    assert "nothing to fetch" in capsys.readouterr().out
    assert len(mirror.requests) - n_requests == n_fetched
    seg = get_segmenter("onnx")  # the default model comes from the cache
    assert seg.model_path == cache / "models/yolov8n-seg_deq_384x512.onnx"


def test_shared_folder_comes_first_and_nothing_is_fetched(monkeypatch, tmp_path, mirror):
    shared = tmp_path / "shared"  # a shared folder holding every asset (links to wherever this checkout found them)
    for rel in A.ALL_ASSETS:
        (shared / rel).parent.mkdir(parents=True, exist_ok=True)
        (shared / rel).symlink_to(A.asset_path(rel))
    (shared / A.real_head_rel()).parent.mkdir(parents=True)
    (shared / A.real_head_rel()).symlink_to(A.real_head())
    cache = tmp_path / "cache"
    (cache / "assets" / "models").mkdir(parents=True)
    (cache / "assets" / A.INT8_MODEL).write_bytes(b"a stale copy the shared folder takes precedence over")
    monkeypatch.setenv("D2SLAM_SHARED", str(shared))
    monkeypatch.setenv("D2SLAM_CACHE", str(cache))
    monkeypatch.setenv(A.MIRROR_ENV, mirror.url)
    n_requests = len(mirror.requests)
    assert A.fetch_assets(echo=lambda *_: None) == []
    assert len(mirror.requests) == n_requests
    assert A.find(A.INT8_MODEL) == shared / A.INT8_MODEL
    assert [p.parent for p in A.tum_frames()] == [shared / A.TUM_FRAMES_DIR] * 5
    (shared / A.INT8_MODEL).unlink()  # not in the shared folder: the cache
    assert A.find(A.INT8_MODEL) == cache / "assets" / A.INT8_MODEL


def test_derived_float_model_masks_match_the_int8_model(tmp_path):
    """The conversion at the int8 file's own input size (320x320): same persons, masks IoU >= MIN_IOU per frame."""
    int8 = A.asset_path(A.INT8_MODEL)
    f320 = dequantize_file(int8, tmp_path / "f320.onnx", 320, 320)
    ops = {n.op_type for n in onnx.load(str(f320)).graph.node}
    assert "Conv" in ops and not ops & {"ConvInteger", "DynamicQuantizeLinear", "Cast"}
    q = OnnxSegmenter(int8)
    with pytest.warns(UserWarning, match="not a known"):
        f = OnnxSegmenter(f320, allow_unknown_model=True)
    assert f.input_hw == q.input_hw == (320, 320)
    for path in A.tum_frames():
        img = read_rgb(path)
        a, b = q(img), f(img)
        assert len(a) == len(b) > 0, path.name
        ua, ub = np.any([p.mask for p in a], axis=0), np.any([p.mask for p in b], axis=0)
        assert (ua & ub).sum() / (ua | ub).sum() >= MIN_IOU, path.name


def test_wrong_bytes_from_a_mirror_are_refused(fresh, monkeypatch):
    bad = Server(seconds=60)
    try:
        for a in A.DOWNLOADS:
            bad.files["/" + a.url_path] = b"not the file"
        monkeypatch.setenv(A.MIRROR_ENV, bad.url + "/")
        with pytest.raises(D2SlamError, match="sha256 .* differs from the pinned"):
            A.fetch_assets(echo=lambda *_: None)
    finally:
        bad.close()
    assert not [p for p in (fresh / "cache" / "assets").rglob("*") if p.is_file()]


def test_offline_and_nothing_found_says_what_to_fetch_and_how(fresh, monkeypatch):
    with socket.socket() as s:  # an unused local port: connection refused at once
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    monkeypatch.setenv(A.MIRROR_ENV, f"http://127.0.0.1:{port}")
    with pytest.raises(D2SlamError, match="cannot reach .* offline.*by hand") as err:
        A.fetch_assets(timeout=2, echo=lambda *_: None)
    assert A.INT8_MODEL in str(err.value)
    for call in (A.tum_frames, lambda: get_segmenter("onnx")):
        with pytest.raises(D2SlamError, match="d2slam assets fetch"):
            call()
