"""``d2slam download`` against a local HTTP server on 127.0.0.1 (threaded, in-process, with Range support)."""

from __future__ import annotations

import io
import json
import socket
import tarfile
import time
from pathlib import Path

import numpy as np
import pytest
from local_http import Server

from d2slam.cli import main
from d2slam.data import TumSequence
from d2slam.data import download as dl
from d2slam.data.fixtures import depth_pattern, write_tum_folder
from d2slam.errors import D2SlamError

NAME = "fr3_walking_xyz"
ARCHIVE = "rgbd_dataset_freiburg3_walking_xyz.tgz"
FOLDER = "rgbd_dataset_freiburg3_walking_xyz"
URL_PATH = f"/freiburg3/{ARCHIVE}"


def make_tgz(src_root: Path, arcname: str, extra: dict[str, bytes] | None = None,
             skip: tuple[str, ...] = ()) -> bytes:
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as tar:
        for path in sorted(src_root.rglob("*")):
            rel = path.relative_to(src_root).as_posix()
            if any(rel == s or rel.startswith(s + "/") for s in skip):
                continue
            tar.add(path, arcname=f"{arcname}/{rel}", recursive=False)
        for name, data in (extra or {}).items():
            info = tarfile.TarInfo(name)
            info.size = len(data)
            tar.addfile(info, io.BytesIO(data))
    return buf.getvalue()


@pytest.fixture(scope="module")
def tum_tgz(tmp_path_factory) -> bytes:
    """A TUM-layout archive: 4 frames at the fr3 camera's 640x480 (so TumSequence reads it with its camera)."""
    root = tmp_path_factory.mktemp("src") / FOLDER
    write_tum_folder(root, n_frames=4, width=640, height=480)
    (root / "accelerometer.txt").write_text("# accelerometer data\n")
    return make_tgz(root, FOLDER)


@pytest.fixture
def server(tum_tgz):
    srv = Server()
    srv.files[URL_PATH] = tum_tgz
    yield srv
    srv.close()


@pytest.fixture(autouse=True)
def isolated_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.delenv(dl.MIRROR_ENV, raising=False)


def quiet(*_):
    pass


def records() -> dict:
    return json.loads(dl.record_path().read_text())


def test_full_download_extracts_a_readable_sequence_and_records_sha256(server, tum_tgz, tmp_path):
    folder = dl.download_sequence(NAME, tmp_path / "data", base_url=server.url, log=quiet)
    assert folder == tmp_path / "data" / FOLDER
    seq = TumSequence(folder)
    assert len(seq) == 4 and seq.camera.name == "freiburg3"
    np.testing.assert_array_equal(seq[2].depth, depth_pattern(2, 480, 640).astype(np.float32) / np.float32(5000))
    assert (folder / "accelerometer.txt").is_file()
    # archive and .part removed, no temporary folder left
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == [FOLDER]
    import hashlib

    rec = records()[ARCHIVE]
    assert rec["sha256"] == hashlib.sha256(tum_tgz).hexdigest() and rec["size"] == len(tum_tgz)
    assert rec["url"] == server.url + URL_PATH
    assert server.requests == [(URL_PATH, None)]
    # a second call sees the folder and does nothing
    dl.download_sequence(NAME, tmp_path / "data", base_url=server.url, log=quiet)
    assert len(server.requests) == 1


def test_later_download_checked_against_record(server, tum_tgz, tmp_path):
    dl.download_sequence(NAME, tmp_path / "a", base_url=server.url, log=quiet)
    msgs = []
    dl.download_sequence(NAME, tmp_path / "b", base_url=server.url, log=msgs.append)
    assert any("matches the record" in m for m in msgs)
    # the server now serves a different (valid) archive under the same name: refused, nothing extracted
    tampered = tarfile.open(fileobj=io.BytesIO(tum_tgz), mode="r:gz")
    buf = io.BytesIO()
    with tarfile.open(fileobj=buf, mode="w:gz") as out:
        for m in tampered.getmembers():
            out.addfile(m, tampered.extractfile(m) if m.isfile() else None)
        info = tarfile.TarInfo(f"{FOLDER}/extra.txt")
        info.size = 1
        out.addfile(info, io.BytesIO(b"x"))
    server.files[URL_PATH] = buf.getvalue()
    assert server.files[URL_PATH] != tum_tgz
    with pytest.raises(D2SlamError, match="checksum mismatch") as err:
        dl.download_sequence(NAME, tmp_path / "c", base_url=server.url, log=quiet)
    assert str(dl.record_path()) in str(err.value)
    assert not (tmp_path / "c" / FOLDER).exists() and (tmp_path / "c" / ARCHIVE).is_file()


def test_resume_after_truncated_part(server, tum_tgz, tmp_path):
    dest = tmp_path / "data"
    dest.mkdir()
    half = len(tum_tgz) // 2
    (dest / (ARCHIVE + ".part")).write_bytes(tum_tgz[:half])
    dl.download_sequence(NAME, dest, base_url=server.url, log=quiet)
    assert server.requests == [(URL_PATH, f"bytes={half}-")]
    assert len(TumSequence(dest / FOLDER)) == 4


def test_restart_cleanly_when_server_ignores_range(server, tum_tgz, tmp_path):
    dest = tmp_path / "data"
    dest.mkdir()
    (dest / (ARCHIVE + ".part")).write_bytes(b"\x00" * 1000)  # garbage that a resume would keep
    server.ignore_range = True
    dl.download_sequence(NAME, dest, base_url=server.url, log=quiet)
    assert server.requests == [(URL_PATH, "bytes=1000-")]
    assert records()[ARCHIVE]["size"] == len(tum_tgz)
    assert len(TumSequence(dest / FOLDER)) == 4


def test_transfer_cut_midway_is_resumed(server, tum_tgz, tmp_path):
    server.cut_first = 3000
    msgs = []
    dl.download_sequence(NAME, tmp_path / "data", base_url=server.url, log=msgs.append)
    assert server.requests == [(URL_PATH, None), (URL_PATH, "bytes=3000-")]
    assert any("resuming" in m for m in msgs)
    assert len(TumSequence(tmp_path / "data" / FOLDER)) == 4


def test_part_longer_than_archive_restarts(server, tum_tgz, tmp_path):
    dest = tmp_path / "data"
    dest.mkdir()
    (dest / (ARCHIVE + ".part")).write_bytes(b"\x00" * (len(tum_tgz) + 10))
    dl.download_sequence(NAME, dest, base_url=server.url, log=quiet)
    assert server.requests == [(URL_PATH, f"bytes={len(tum_tgz) + 10}-"), (URL_PATH, None)]


@pytest.mark.parametrize("kind", ["garbage", "truncated", "not_tum", "traversal", "symlink"])
def test_corrupt_or_unsafe_archive_rejected(server, tum_tgz, tmp_path, kind):
    src = tmp_path / "src" / FOLDER
    write_tum_folder(src, n_frames=2, width=640, height=480)
    if kind == "garbage":
        data = b"this is not a gzip file" * 100
    elif kind == "truncated":
        data = tum_tgz[: len(tum_tgz) - 200]  # the server announces this length: only gzip can tell
    elif kind == "not_tum":
        data = make_tgz(src, FOLDER, skip=("groundtruth.txt",))
    elif kind == "traversal":
        data = make_tgz(src, FOLDER, extra={"../../evil.txt": b"owned"})
    else:
        buf = io.BytesIO()
        with tarfile.open(fileobj=buf, mode="w:gz") as tar:
            link = tarfile.TarInfo(f"{FOLDER}/rgb.txt")
            link.type, link.linkname = tarfile.SYMTYPE, "/etc/passwd"
            tar.addfile(link)
        data = buf.getvalue()
    server.files[URL_PATH] = data
    dest = tmp_path / "data"
    match = {"garbage": "corrupt", "truncated": "corrupt or truncated", "not_tum": "lacks groundtruth.txt",
             "traversal": "unsafe member", "symlink": "link or special file"}[kind]
    with pytest.raises(D2SlamError, match=match) as err:
        dl.download_sequence(NAME, dest, base_url=server.url, log=quiet)
    assert ARCHIVE in str(err.value)
    assert not (tmp_path / "evil.txt").exists() and not (dest.parent.parent / "evil.txt").exists()
    # nothing extracted, nothing recorded, the bad file moved aside so that a rerun starts afresh
    assert sorted(p.name for p in dest.iterdir()) == [ARCHIVE + ".corrupt"]
    assert not dl.record_path().exists()


def test_http_404_names_the_url(server, tmp_path):
    with pytest.raises(D2SlamError, match="HTTP 404") as err:
        dl.download_sequence("fr1_xyz", tmp_path / "data", base_url=server.url, log=quiet)
    assert f"{server.url}/freiburg1/rgbd_dataset_freiburg1_xyz.tgz" in str(err.value)
    assert "--archive" in str(err.value)


def test_unreachable_host_fails_fast_with_manual_instructions(tmp_path):
    with socket.socket() as s:  # an unused local port: connection refused at once
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    t = time.perf_counter()
    with pytest.raises(D2SlamError, match="cannot reach the server of the TUM archive") as err:
        dl.download_sequence(NAME, tmp_path / "data", base_url=f"http://127.0.0.1:{port}", log=quiet)
    assert time.perf_counter() - t < 5
    text = str(err.value)
    assert "download manually" in text and f"--archive PATH/{ARCHIVE}" in text
    assert not (tmp_path / "data").exists()  # nothing arrived: no empty --to folder left behind


def test_offline_download_leaves_no_folder_it_made(tmp_path, capsys):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    kept = tmp_path / "kept"
    kept.mkdir()
    for to in (tmp_path / "new" / "deeper", kept):
        assert main(["download", NAME, "--to", str(to), "--base-url", f"http://127.0.0.1:{port}"]) == 2
        assert "cannot reach the server" in capsys.readouterr().err
    assert not (tmp_path / "new").exists() and kept.is_dir() and not any(kept.iterdir())


def test_mirror_env_and_url_order(server, tmp_path, monkeypatch):
    info = dl.resolve(NAME)
    official = dl.archive_urls(info)
    assert official == [f"https://cvg.cit.tum.de/rgbd/dataset/freiburg3/{ARCHIVE}",
                        f"https://vision.in.tum.de/rgbd/dataset/freiburg3/{ARCHIVE}"]
    monkeypatch.setenv(dl.MIRROR_ENV, server.url + "/")
    assert dl.archive_urls(info) == [server.url + URL_PATH]
    assert dl.archive_urls(info, "http://x/y") == [f"http://x/y/freiburg3/{ARCHIVE}"]
    assert len(TumSequence(dl.download_sequence(NAME, tmp_path / "d", log=quiet))) == 4


def test_registry_has_required_sequences_and_no_invented_checksums():
    reg = dl.registry()
    for name in ["fr3_walking_xyz", "fr3_walking_halfsphere", "fr3_walking_static", "fr3_walking_rpy",
                 "fr3_sitting_static", "fr3_sitting_xyz", "fr3_sitting_halfsphere", "fr3_sitting_rpy",
                 "fr1_xyz", "fr1_desk", "fr2_xyz", "fr3_long_office_household", "fr3_nostructure_texture_far"]:
        info = reg[name]
        group, rest = name.split("_", 1)
        assert info.archive == f"rgbd_dataset_freiburg{group[2]}_{rest}.tgz" and info.group == f"freiburg{group[2]}"
    assert all(s.size is None and s.sha256 is None for s in reg.values())
    assert dl.resolve("rgbd_dataset_freiburg3_walking_xyz.tgz") == dl.resolve("freiburg3/walking_xyz") == reg[NAME]
    with pytest.raises(D2SlamError, match="did you mean fr3_walking_xyz"):
        dl.resolve("walking_xyz")


def test_manual_archive_and_cli(server, tum_tgz, tmp_path, capsys):
    manual = tmp_path / ARCHIVE
    manual.write_bytes(tum_tgz)
    assert main(["download", NAME, "--to", str(tmp_path / "m"), "--archive", str(manual)]) == 0
    assert manual.is_file() and len(TumSequence(tmp_path / "m" / FOLDER)) == 4  # a user's file is never deleted
    assert ARCHIVE in records()
    assert main(["download", "--list"]) == 0
    out = capsys.readouterr().out
    assert "fr3_sitting_rpy" in out and "https://cvg.cit.tum.de/rgbd/dataset/freiburg3/" in out
    assert main(["download", NAME, "--to", str(tmp_path / "k"), "--base-url", server.url, "--keep-archive"]) == 0
    assert (tmp_path / "k" / ARCHIVE).is_file()
    assert main(["download", "fr9_nothing", "--to", str(tmp_path / "x")]) == 2
    assert "unknown TUM sequence" in capsys.readouterr().err
    assert main(["download", NAME]) == 2


def test_corrupt_manual_archive_is_left_alone(tmp_path):
    manual = tmp_path / ARCHIVE
    manual.write_bytes(b"\x1f\x8b\x08" + b"\x00" * 50)  # gzip magic, then nonsense
    with pytest.raises(D2SlamError, match="corrupt or truncated") as err:
        dl.download_sequence(NAME, tmp_path / "m", archive=manual, log=quiet)
    assert err.value.path == manual and manual.is_file()  # the user's file is not moved or deleted
    assert not (tmp_path / "m").exists() and not dl.record_path().exists()  # no folder left behind either


def test_registry_checksum_is_enforced_when_present(server, tum_tgz, tmp_path, monkeypatch):
    import dataclasses

    real = dl.registry()
    fake = {k: dataclasses.replace(v, sha256="0" * 64) for k, v in real.items()}
    monkeypatch.setattr(dl, "registry", lambda: fake)
    with pytest.raises(D2SlamError, match="differs from the registry"):
        dl.download_sequence(NAME, tmp_path / "d", base_url=server.url, log=quiet)
    fake = {k: dataclasses.replace(v, size=len(tum_tgz) + 1) for k, v in real.items()}
    monkeypatch.setattr(dl, "registry", lambda: fake)
    with pytest.raises(D2SlamError, match="size .* differs from the registry"):
        dl.download_sequence(NAME, tmp_path / "e", base_url=server.url, log=quiet)


def test_silent_server_times_out_quickly(tmp_path):
    with socket.socket() as s:  # accepts connections (kernel backlog) but never answers
        s.bind(("127.0.0.1", 0))
        s.listen(4)
        url = f"http://127.0.0.1:{s.getsockname()[1]}"
        t = time.perf_counter()
        with pytest.raises(D2SlamError, match="cannot reach the server of the TUM archive .*timed out"):
            dl.download_sequence(NAME, tmp_path / "data", base_url=url, timeout=0.3, log=quiet)
        assert time.perf_counter() - t < 3


@pytest.fixture(scope="module")
def real_head_dir():
    from d2slam.assets import real_head

    return real_head()  # found before the tests move $D2SLAM_CACHE


def test_fr1_rpy_archive_of_real_frames_downloads_and_runs_end_to_end(real_head_dir, tmp_path, monkeypatch, capsys):
    """`d2slam download fr1_rpy` on a TUM-layout archive of real fr1/rpy frames (the first 40 of the head, laid out
    as the official archive: one top folder with the lists, rgb/, depth/ and accelerometer.txt), from a mirror
    ($D2SLAM_TUM_MIRROR) with the archive's checksum in the registry, then `d2slam run` on the folder it made."""
    import dataclasses
    import hashlib

    from d2slam.assets import LISTS, cut_head

    frames = 40
    root = tmp_path / "src" / "rgbd_dataset_freiburg1_rpy"
    cut = cut_head({name: (real_head_dir / name).read_bytes() for name in LISTS}, frames, 1.0)
    for name, data in cut.items():
        root.mkdir(parents=True, exist_ok=True)
        (root / name).write_bytes(data)
    for name in LISTS[:2]:
        for line in cut[name].decode().splitlines():
            if not line.startswith("#"):
                rel = line.split()[1]
                (root / rel).parent.mkdir(exist_ok=True)
                (root / rel).write_bytes((real_head_dir / rel).read_bytes())
    (root / "accelerometer.txt").write_text("# accelerometer data\n")
    tgz = make_tgz(root, root.name)
    srv = Server()
    srv.files["/freiburg1/rgbd_dataset_freiburg1_rpy.tgz"] = tgz
    real = dl.registry()
    pinned = {**real, "fr1_rpy": dataclasses.replace(real["fr1_rpy"], size=len(tgz),
                                                     sha256=hashlib.sha256(tgz).hexdigest())}
    monkeypatch.setattr(dl, "registry", lambda: pinned)
    monkeypatch.setenv(dl.MIRROR_ENV, srv.url)
    try:
        assert main(["download", "fr1_rpy", "--to", str(tmp_path / "data")]) == 0
    finally:
        srv.close()
    folder = tmp_path / "data" / "rgbd_dataset_freiburg1_rpy"
    out = capsys.readouterr().out
    assert f"fr1_rpy: {frames} RGB-D frames, camera freiburg1, in {folder}" in out
    assert sorted(p.name for p in (tmp_path / "data").iterdir()) == [folder.name]  # archive removed
    assert records()["rgbd_dataset_freiburg1_rpy.tgz"]["sha256"] == hashlib.sha256(tgz).hexdigest()
    traj, js = tmp_path / "t.txt", tmp_path / "r.json"
    assert main(["run", str(folder), "--method", "none", "--no-loop-closing", "--out", str(traj),
                 "--metrics-json", str(js)]) == 0
    rec = json.loads(js.read_text())
    assert rec["tracked"] == rec["frames"] == frames and rec["camera"]["name"] == "freiburg1"
    assert rec["camera"]["source"] == "folder name" and 0 < rec["metrics"]["ate_rmse_m"] < 0.05
    line = capsys.readouterr().out.strip().splitlines()[-1]
    assert line.startswith(f"d2slam run: method none; masks none; camera freiburg1 (folder name); tracked "
                           f"{frames}/{frames} frames; ATE ")
