"""TUM fr1/rpy fetched from a local mirror of its pinned public copy (never the network): the head of
``d2slam assets fetch`` (the whole lists cut, every sha256 checked, same bytes as ../shared's head), the whole sequence
of ``d2slam assets fetch --full-real`` (lists checked, every image decoded), lookups, refusals and resuming."""

from __future__ import annotations

import hashlib
import os

import pytest
from local_http import Server, head_as_whole, real_files, real_url_path

from d2slam import assets as A
from d2slam.cli import main
from d2slam.data import TumSequence
from d2slam.errors import D2SlamError

PINS = A.real_pins()
HEAD = PINS["head"]
N_FILES = len(HEAD["files"])
FIRST_DEPTH = next(rel for rel in HEAD["files"] if rel.startswith("depth/"))


def quiet(*_):
    pass


@pytest.fixture(scope="module")
def head_files():
    """The head's files at their mirror paths, its cut lists standing for the whole sequence's (read before the
    tests hide the shared folder)."""
    return real_files("head")


@pytest.fixture(scope="module")
def shared_head():
    return A.real_head()


@pytest.fixture
def mirror(head_files):
    srv = Server(seconds=300)
    srv.files.update(head_files)
    yield srv
    srv.close()


@pytest.fixture
def fresh(tmp_path, monkeypatch, mirror, shared_head):
    """A user's machine: no shared folder, an empty cache, the mirror in place of GitHub, and the whole sequence's
    lists pinned to the head's (the mirror serves the head as a whole sequence)."""
    monkeypatch.setenv("D2SLAM_SHARED", str(tmp_path / "no_shared"))
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(A.MIRROR_ENV, mirror.url)
    monkeypatch.setattr(A, "real_pins", lambda: head_as_whole(PINS))
    return tmp_path


def same_tree(a, b) -> bool:
    files = sorted(p.relative_to(a) for p in a.rglob("*") if p.is_file())
    return files == sorted(p.relative_to(b) for p in b.rglob("*") if p.is_file()) and all(
        (a / f).read_bytes() == (b / f).read_bytes() for f in files)


def test_the_head_is_fetched_cut_checked_and_found(fresh, mirror, shared_head):
    with pytest.raises(D2SlamError, match="fr1/rpy .* in neither .*d2slam assets fetch"):
        A.real_head()
    folder = A.fetch_real_head(echo=quiet)
    assert folder == fresh / "cache" / "assets" / A.real_head_rel() == A.real_head()
    assert same_tree(folder, shared_head)  # the cut lists and every image: the bytes of ../shared's head
    assert len(TumSequence(folder)) == HEAD["frames"]
    assert len(mirror.requests) == len(A.LISTS) + N_FILES
    assert sorted(p.name for p in folder.parent.iterdir()) == [folder.name]  # no temporary folder left
    assert A.fetch_real_head(echo=quiet) is None and len(mirror.requests) == len(A.LISTS) + N_FILES


def test_the_head_is_cut_from_the_real_whole_lists(tmp_path, monkeypatch, shared_head):
    """The pins as they are: the whole sequence's lists (sha256 pinned) cut to the head's (sha256 pinned)."""
    if A.real_full() is None:
        pytest.skip("the whole fr1/rpy sequence is not on this machine (d2slam assets fetch --full-real)")
    srv = Server(seconds=300)
    srv.files.update(real_files("real"))
    try:
        monkeypatch.setenv("D2SLAM_SHARED", str(tmp_path / "no_shared"))
        monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
        monkeypatch.setenv(A.MIRROR_ENV, srv.url)
        assert same_tree(A.fetch_real_head(echo=quiet), shared_head)
    finally:
        srv.close()


def test_the_shared_head_comes_first(tmp_path, monkeypatch, shared_head, mirror):
    monkeypatch.setenv("D2SLAM_SHARED", str(tmp_path / "shared"))
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(A.MIRROR_ENV, mirror.url)
    link = tmp_path / "shared" / A.real_head_rel()
    link.parent.mkdir(parents=True)
    link.symlink_to(shared_head)
    assert A.real_head() == link and A.fetch_real_head(echo=quiet) is None and not mirror.requests
    cached = tmp_path / "cache" / "assets" / A.real_head_rel()
    cached.parent.mkdir(parents=True)
    cached.symlink_to(shared_head)
    (tmp_path / "shared" / "real").rename(tmp_path / "shared" / "elsewhere")
    assert A.real_head() == cached  # not in the shared folder: the cache


def test_a_head_missing_a_file_is_not_found(tmp_path, monkeypatch, shared_head):
    import shutil

    copy = tmp_path / "shared" / A.real_head_rel()
    shutil.copytree(shared_head, copy)
    monkeypatch.setenv("D2SLAM_SHARED", str(tmp_path / "shared"))
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    assert A.find_real_head() == copy
    (copy / FIRST_DEPTH).write_bytes((copy / FIRST_DEPTH).read_bytes()[:-1])  # wrong size
    assert A.find_real_head() is None
    (copy / FIRST_DEPTH).unlink()
    assert A.find_real_head() is None


def test_an_interrupted_fetch_resumes_with_the_files_it_checked(fresh, mirror, head_files):
    missing = real_url_path(FIRST_DEPTH)
    data = mirror.files.pop(missing)
    with pytest.raises(D2SlamError, match=f"{FIRST_DEPTH}.*HTTP 404.*next fetch resumes"):
        A.fetch_real_head(echo=quiet)
    dest = fresh / "cache" / "assets" / A.real_head_rel()
    assert not dest.exists() and A.find_real_head() is None
    (work,) = dest.parent.iterdir()  # this process's temporary folder, kept for the next fetch
    assert work.name.startswith(dest.name + ".tmp-")
    done = len(mirror.requests)
    # the next fetch comes from another process: it takes the folder over from the one that is gone
    os.replace(work, dest.parent / f"{dest.name}.tmp-999999999")
    mirror.files[missing] = data
    assert A.fetch_real_head(echo=quiet) == dest and A.real_head() == dest
    later = [path for path, _ in mirror.requests[done:]]
    assert later[0] == missing and len(later) == N_FILES - list(HEAD["files"]).index(FIRST_DEPTH)
    assert sorted(p.name for p in dest.parent.iterdir()) == [dest.name]


@pytest.mark.parametrize("what", ["image", "list"])
def test_wrong_bytes_are_refused(fresh, mirror, what):
    rel = FIRST_DEPTH if what == "image" else "groundtruth.txt"
    mirror.files[real_url_path(rel)] = b"not the file"
    with pytest.raises(D2SlamError, match=f"sha256 .* of .*{rel} differs from the pinned"):
        A.fetch_real_head(echo=quiet)
    assert A.find_real_head() is None
    assert not list((fresh / "cache").rglob(rel.split("/")[-1] + "*"))  # the bad file was deleted


def test_a_file_mirror_works_too(tmp_path, monkeypatch, head_files, shared_head):
    root = tmp_path / "mirror"
    for path, data in head_files.items():
        (root / path.lstrip("/")).parent.mkdir(parents=True, exist_ok=True)
        (root / path.lstrip("/")).write_bytes(data)
    monkeypatch.setenv("D2SLAM_SHARED", str(tmp_path / "no_shared"))
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(A.MIRROR_ENV, root.as_uri())
    monkeypatch.setattr(A, "real_pins", lambda: head_as_whole(PINS))
    assert same_tree(A.fetch_real_head(echo=quiet), shared_head)


@pytest.fixture(scope="module")
def found_assets(shared_head):
    """Where the models, the five TUM frames and the head are on this machine (the shared folder or the cache), read
    before the tests hide them."""
    return {**{rel: A.asset_path(rel) for rel in A.ALL_ASSETS}, A.real_head_rel(): shared_head}


@pytest.fixture
def whole(tmp_path, monkeypatch, mirror, found_assets):
    """``--full-real`` on a machine with the shared folder (the head and the models found there, linked into one
    whatever held them: ../shared or, in a clone without it, the cache) and an empty cache: the mirror's head stands
    for the whole sequence."""
    shared = tmp_path / "shared"
    for rel, path in found_assets.items():
        (shared / rel).parent.mkdir(parents=True, exist_ok=True)
        (shared / rel).symlink_to(path)
    monkeypatch.setenv("D2SLAM_SHARED", str(shared))
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path / "cache"))
    monkeypatch.setenv(A.MIRROR_ENV, mirror.url)
    monkeypatch.setattr(A, "real_pins", lambda: head_as_whole(PINS))
    return tmp_path / "cache" / "real" / PINS["sequence"]


def test_full_real_fetches_checks_and_finds_the_whole_sequence(whole, mirror, shared_head, capsys):
    assert A.real_full() is None
    assert main(["assets", "list"]) == 0
    assert f"real/{PINS['sequence']}/" in capsys.readouterr().out
    assert main(["assets", "fetch", "--full-real"]) == 0
    out = capsys.readouterr().out
    assert f"{N_FILES} images ({N_FILES // 2} RGB, {N_FILES // 2} depth) to fetch and decode" in out
    assert f"the whole TUM fr1/rpy sequence fetched into {whole}" in out
    assert A.real_full() == whole and A.real_full_dir() == whole
    assert same_tree(whole, shared_head)
    assert len(TumSequence(whole)) == HEAD["frames"] and TumSequence(whole).camera.name == "freiburg1"
    n = len(mirror.requests)
    assert main(["assets", "fetch", "--full-real"]) == 0 and len(mirror.requests) == n
    assert f"sequence is in {whole}, nothing to fetch" in capsys.readouterr().out
    assert main(["assets", "list"]) == 0
    assert f"{whole}" in capsys.readouterr().out


def test_full_real_refuses_an_image_that_does_not_decode(whole, mirror, capsys):
    good = mirror.files[real_url_path(FIRST_DEPTH)]
    mirror.files[real_url_path(FIRST_DEPTH)] = hashlib.sha256(b"x").digest()
    assert main(["assets", "fetch", "--full-real"]) == 2
    err = capsys.readouterr().err
    assert f"{FIRST_DEPTH} arrived but is not a usable image" in err and "it was deleted" in err
    assert len(err.strip().splitlines()) == 1
    assert not whole.exists() and A.real_full() is None
    mirror.files[real_url_path(FIRST_DEPTH)] = good
    n = len(mirror.requests)
    assert main(["assets", "fetch", "--full-real"]) == 0 and A.real_full() == whole
    assert mirror.requests[n][0] == real_url_path(FIRST_DEPTH)  # resumed at the refused image


def test_full_real_refuses_lists_that_are_not_the_pinned_ones(whole, mirror, monkeypatch):
    monkeypatch.setattr(A, "real_pins", lambda: PINS)  # the real whole lists are pinned; the mirror has the head's
    with pytest.raises(D2SlamError, match="sha256 .* of .*rgb.txt differs from the pinned"):
        A.fetch_real_full(echo=quiet)
    assert not whole.exists()


def test_the_cut_keeps_comments_entries_and_the_ground_truth_span():
    lists = {"rgb.txt": b"# colour\n# t f\n1.00 rgb/1.png\n2.00 rgb/2.png\n3.00 rgb/3.png\n",
             "depth.txt": b"# depth\n1.01 depth/1.png\n2.01 depth/2.png\n\n3.01 depth/3.png\n",
             "groundtruth.txt": b"# gt\n0.50 0 0 0 0 0 0 1\n0.99 0 0 0 0 0 0 1\n2.51 0 0 0 0 0 0 1\n"
                                b"2.52 0 0 0 0 0 0 1\n"}
    cut = A.cut_head(lists, 2, 0.5)
    assert cut == {"rgb.txt": b"# colour\n# t f\n1.00 rgb/1.png\n2.00 rgb/2.png\n",
                   "depth.txt": b"# depth\n1.01 depth/1.png\n2.01 depth/2.png\n",
                   "groundtruth.txt": b"# gt\n0.50 0 0 0 0 0 0 1\n0.99 0 0 0 0 0 0 1\n2.51 0 0 0 0 0 0 1\n"}


def test_the_pins_are_checksums_and_urls_only(monkeypatch):
    assert PINS["lists"].keys() == HEAD["lists"].keys() == set(A.LISTS)
    assert N_FILES == 2 * HEAD["frames"]
    assert all(len(sha) == 64 and size > 0 for sha, size in HEAD["files"].values())
    monkeypatch.delenv(A.MIRROR_ENV, raising=False)
    assert A.real_url("rgb/1.png") == ("https://raw.githubusercontent.com/jmstark/gpu_odometry/"
                                       "aec7c853676c7d809d9fd89e728c3f54b725a63e/data/rgb/1.png")
