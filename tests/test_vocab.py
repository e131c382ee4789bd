"""The DBoW2 vocabulary builder: format facts ORB-SLAM3's loader relies on, k-majority, determinism, bad files."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from d2slam.baselines import vocab as V
from d2slam.cli import main
from d2slam.errors import D2SlamError


def _clustered_descriptors(n_centres=40, per=60, flip=12, seed=1):
    """Descriptors drawn around random centres (each bit flipped with probability flip/256)."""
    rng = np.random.default_rng(seed)
    centres = rng.integers(0, 256, (n_centres, 32), dtype=np.uint8)
    bits = np.unpackbits(np.repeat(centres, per, axis=0), axis=1)
    noise = rng.random(bits.shape) < flip / 256
    desc = np.packbits(bits ^ noise, axis=1)
    image_ids = np.tile(np.arange(per), n_centres)  # every centre appears in every "image"
    return desc, image_ids, centres


def test_hamming_matches_bit_count():
    rng = np.random.default_rng(0)
    a = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    b = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    ref = np.unpackbits(a ^ b, axis=1).sum(axis=1)
    assert np.array_equal(V.hamming(a, b), ref)
    assert np.array_equal(V.hamming(a[:, None], b[None]).diagonal(), ref)


def test_majority_is_dbow2_mean_value():
    # 3 descriptors: bit set in 2 of 3 -> set; 4 descriptors: set in exactly 2 -> set (count >= ceil(n/2))
    d = np.zeros((7, 32), np.uint8)
    d[0:2, 0] = 0b1000_0000
    d[3:5, 1] = 0b0000_0001
    keys = np.array([0, 0, 0, 1, 1, 1, 1])
    centres, counts = V._majority(d, keys, 3)
    assert counts.tolist() == [3, 4, 0]
    assert centres[0, 0] == 0b1000_0000 and centres[1, 1] == 0b0000_0001
    assert centres[0, 1] == 0 and not centres[2].any()


def test_kmajority_clusters_and_reaches_a_fixpoint():
    desc, _, _ = _clustered_descriptors(n_centres=10, per=50, flip=8)
    truth = np.repeat(np.arange(10), 50)
    labels = V._kmajority(desc, np.array([0]), np.array([len(desc)]), 10, np.random.default_rng(0), 20)
    # purity: each label is (mostly) one true cluster (k-means++ may still merge two of ten)
    purity = sum(np.bincount(truth[labels == j]).max() for j in np.unique(labels)) / len(desc)
    assert purity >= 0.9 and len(np.unique(labels)) >= 9
    # converged: every descriptor is nearest to the majority centre of its own cluster
    centres, _ = V._majority(desc, labels, 10)
    d = V.hamming(desc[:, None], centres[None])
    assert (d[np.arange(len(desc)), labels] == d.min(axis=1)).all()


def test_kmajority_runs_many_segments_at_once():
    desc, _, _ = _clustered_descriptors(n_centres=6, per=30, flip=8)
    sizes = np.array([60, 60, 60])  # three nodes of two true clusters each
    starts = np.array([0, 60, 120])
    labels = V._kmajority(desc, starts, sizes, 2, np.random.default_rng(0), 10)
    truth = np.repeat(np.arange(6), 30)
    for s in starts:  # each node's two clusters separated
        pairs = np.unique(np.stack([truth[s:s + 60], labels[s:s + 60]], 1), axis=0)
        assert len(pairs) == 2


@pytest.fixture(scope="module")
def small_vocab(tmp_path_factory):
    desc, ids, _ = _clustered_descriptors()
    vocab = V.build_tree(desc, ids, k=10, L=6, levelsup=4, seed=0)
    path = tmp_path_factory.mktemp("voc") / "voc.txt"
    sha = vocab.save(path)
    return vocab, path, sha, desc, ids


def test_text_format_header_nodes_and_no_trailing_newline(small_vocab):
    vocab, path, _, _, _ = small_vocab
    text = path.read_text()
    lines = text.split("\n")
    assert lines[0] == "10 6 0 0"
    assert not text.endswith("\n")
    assert len(lines) - 1 == vocab.n_nodes - 1  # one line per non-root node
    rows = [ln.split() for ln in lines[1:]]
    assert all(len(r) == 35 for r in rows)
    assert all(0 <= int(b) <= 255 for r in rows for b in r[2:34])


def test_breadth_first_parent_ids_and_leaves(small_vocab):
    vocab, path, _, _, _ = small_vocab
    rows = np.array([ln.split() for ln in path.read_text().split("\n")[1:]], float)
    parent = rows[:, 0].astype(int)
    node_id = np.arange(1, len(parent) + 1)
    assert (parent < node_id).all()
    assert (np.diff(parent) >= 0).all()  # breadth-first: children listed in their parents' order
    depth = vocab.depth()
    assert (np.diff(depth) >= 0).all() and depth.max() <= 6
    # leaf flags agree with the tree (ORB-SLAM3 decides leafness by "no children")
    has_child = np.zeros(vocab.n_nodes, bool)
    has_child[parent] = True
    assert np.array_equal(rows[:, 1] > 0, ~has_child[1:])
    # no word shallower than L - levelsup (ORB-SLAM3's FeatureVector level) and at most k children each
    assert depth[vocab.is_leaf].min() >= 2
    assert np.bincount(parent).max() <= 10


def test_leaf_weights_are_idf_and_inner_weights_zero(small_vocab):
    vocab, path, _, desc, ids = small_vocab
    rows = np.array([ln.split() for ln in path.read_text().split("\n")[1:]], float)
    leaf = rows[:, 1] > 0
    assert (rows[~leaf, -1] == 0).all()
    words = vocab.transform(desc)
    n_images = len(np.unique(ids))
    n_word = np.array([len(np.unique(ids[words == w])) for w in np.flatnonzero(vocab.is_leaf)])
    expected = np.log(n_images / np.maximum(n_word, 1))
    assert np.allclose(rows[leaf, -1], expected, atol=1e-5)
    assert (rows[leaf, -1] >= 0).all() and rows[leaf, -1].max() > 0


def test_roundtrip_and_determinism(small_vocab):
    vocab, path, sha, desc, ids = small_vocab
    back = V.Vocabulary.load(path)
    assert np.array_equal(back.parent, vocab.parent) and np.array_equal(back.descriptors, vocab.descriptors)
    again = V.build_tree(desc, ids, k=10, L=6, levelsup=4, seed=0)
    assert again.to_text() == vocab.to_text()
    assert V.build_tree(desc, ids, seed=1).to_text() != vocab.to_text()


def test_descriptors_descend_to_a_close_word(small_vocab):
    vocab, _, _, desc, _ = small_vocab
    words = vocab.transform(desc)
    assert vocab.is_leaf[words].all()
    assert V.hamming(desc, vocab.descriptors[words]).mean() < 20


@pytest.mark.parametrize("content, what", [
    ("hello world\n0 1" + " 0" * 33, "header"),
    ("10 6 0 0\n0 1 1 2 3", "35 numbers"),
    ("10 6 0 0\n0 1" + " 0" * 16 + " (0" + " 0" * 16, "35 numbers"),  # a flipped bit: a space became "("
    ("10 6 0 0\n0 1" + " 0" * 33 + "\n", "newline"),
    ("10 6 0 0\n0 0" + " 0" * 33, "inner node without children"),
    ("10 6 0 0\n5 1" + " 0" * 33, "parent"),
    ("10 6 0 0\n0 1" + " 300" * 32 + " 0", "0-255"),
    ("99 6 0 0\n0 1" + " 0" * 33, "range"),
])
def test_bad_vocabulary_files_are_named_with_line(tmp_path, content, what):
    p = tmp_path / "bad.txt"
    p.write_text(content)
    with pytest.raises(D2SlamError, match=what) as err:
        V.check_vocabulary_file(p)
    assert str(p) in str(err.value)


def test_missing_vocabulary(tmp_path):
    with pytest.raises(D2SlamError, match="not found"):
        V.check_vocabulary_file(tmp_path / "none.txt")


def test_resolve_kinds(small_vocab, tmp_path, monkeypatch):
    vocab, path, sha, _, _ = small_vocab
    info = V.resolve_vocabulary(path, build=False)
    assert info["kind"] == "external" and info["sha256"] == sha  # no manifest beside it
    official = tmp_path / "ORBvoc.txt"
    official.write_bytes(path.read_bytes())
    monkeypatch.setenv("PYORBSLAM3_VOCAB", str(official))
    info = V.resolve_vocabulary(None, build=False)
    assert info["kind"] == "official" and info["source"] == "PYORBSLAM3_VOCAB"
    monkeypatch.setenv("PYORBSLAM3_VOCAB", str(tmp_path / "missing.txt"))
    with pytest.raises(D2SlamError, match="PYORBSLAM3_VOCAB"):
        V.resolve_vocabulary(None, build=False)


def test_cli_build_real_frames_manifest_and_cache(tmp_path, capsys):
    out = tmp_path / "v.txt"
    assert main(["vocab", "build", "--no-synthetic", "--out", str(out)]) == 0
    m = json.loads((tmp_path / "v.txt.json").read_text())
    assert m["kind"] == "built" and m["n_images"] == 5 and m["sources"][0]["kind"] == "real"
    assert m["n_descriptors"] > 4000 and m["n_words"] > 1000
    assert m["params"]["k"] == 10 and m["params"]["L"] == 6
    first = out.read_bytes()
    assert main(["vocab", "build", "--no-synthetic", "--out", str(out)]) == 0
    assert "cached" in capsys.readouterr().out and out.read_bytes() == first
    assert V.resolve_vocabulary(out, build=False)["kind"] == "built"
    assert main(["vocab", "check", str(out)]) == 0


def test_cli_build_bad_images_dir(tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["vocab", "build", "--no-synthetic", "--no-real", "--images-dir", str(empty),
                 "--out", str(tmp_path / "v.txt")]) == 2
    assert "no images" in capsys.readouterr().err
    (empty / "x.png").write_bytes(b"not a png")
    assert main(["vocab", "build", "--no-synthetic", "--no-real", "--images-dir", str(empty),
                 "--out", str(tmp_path / "v.txt")]) == 2
    assert "x.png" in capsys.readouterr().err


def test_progress_logs_lines_without_a_terminal(capsys):
    bar = V.Progress("vocabulary: stage", 3, "step", enabled=True, interval=0.0)  # pytest's stderr: no terminal
    for _ in range(3):
        bar.update()
    bar.close()
    lines = capsys.readouterr().err.strip().splitlines()
    assert lines[0].startswith("d2slam: vocabulary: stage: 1/3 steps") and \
        lines[-1].startswith("d2slam: vocabulary: stage: 3/3 steps in")
    quiet = V.Progress("vocabulary: stage", 3, "step", enabled=False, interval=0.0)
    quiet.update()
    quiet.close()
    assert capsys.readouterr().err == ""


def test_a_build_is_announced_with_an_estimate_and_a_cached_one_is_silent(tmp_path, capsys):
    out = tmp_path / "v.txt"
    m = V.build_vocabulary(out, synthetic=False, real=True, progress=False)
    err = capsys.readouterr().err.splitlines()
    assert err[0].startswith("vocabulary: building the DBoW2 vocabulary") and "about" in err[0] and str(out) in err[0]
    assert err[-1].startswith("vocabulary: built in") and len(err) == 2  # progress off: no stage lines
    assert not m["cached"] and {"render", "descriptors", "tree", "write", "total"} <= set(m["seconds"])
    assert V.build_vocabulary(out, synthetic=False, real=True, progress=False)["cached"]
    assert capsys.readouterr().err == ""


def test_a_second_builder_waits_for_the_first(tmp_path, capsys):
    import threading

    out = tmp_path / "v.txt"
    entered = threading.Event()

    def lock():  # the build's lock (d2slam.outputs.file_lock)
        return V.file_lock(out.with_name(out.name + ".lock"),
                           waiting=f"vocabulary: another process is building {out}; waiting for it")

    def second():
        with lock():
            entered.set()

    with lock():
        t = threading.Thread(target=second)
        t.start()
        assert not entered.wait(0.5)  # blocked while the first holds the lock
    t.join(10)
    assert entered.is_set() and "waiting for it" in capsys.readouterr().err


def test_training_jobs_are_keyed_by_generator_and_need_training_seeds(tmp_path, monkeypatch):
    from dataclasses import replace

    from d2slam.config import DEFAULT
    from d2slam.synth.version import generator_version

    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path))
    cfg = replace(DEFAULT.baseline, vocab_train_seeds=(900,), vocab_train_scenarios=("walking_xyz",))
    (job,) = V.training_jobs(cfg)
    assert generator_version() in job["out"] and job["out"].endswith("walking_xyz_s900_n60_every6")
    assert not job["done"] and V._n_rendered([job]) == 10
    with pytest.raises(D2SlamError, match="900-999"):
        V.training_jobs(replace(cfg, vocab_train_seeds=(101,)))


def test_rendered_training_frames_are_the_sequence_files(tmp_path):
    """Only every stride-th frame is rendered, and each file is byte for byte the one `d2slam synth` writes."""
    from d2slam.data import open_sequence
    from d2slam.study.sequences import ensure_sequence

    seq = open_sequence(ensure_sequence("sitting_static", 101, 40, False))  # also used by the ORB-SLAM3 tests
    job = {"scenario": "sitting_static", "seed": 101, "frames": 40, "stride": 20, "out": str(tmp_path / "j")}
    V.render_training_frames([job], progress=False)
    files = V.images_of_dir(tmp_path / "j")
    assert [f.name for f in files] == [seq.rgb_files[0].name, seq.rgb_files[20].name]
    assert all(f.read_bytes() == seq.rgb_files[i].read_bytes() for f, i in zip(files, (0, 20)))
    assert (tmp_path / "j" / V.MARKER).is_file() and not (tmp_path / "j.part").exists()


def test_resolve_checks_a_file_once_and_trusts_its_own_build(small_vocab, tmp_path, monkeypatch):
    _, path, _, _, _ = small_vocab
    calls = []
    monkeypatch.setattr(V, "check_vocabulary_file", lambda p: calls.append(p))
    external = tmp_path / "other.txt"
    external.write_bytes(path.read_bytes())
    V.resolve_vocabulary(external, build=False)
    V.resolve_vocabulary(external, build=False)
    assert len(calls) == 1  # once per content and process
    built = tmp_path / "built.txt"
    V.build_vocabulary(built, synthetic=False, real=True, progress=False)
    assert V.resolve_vocabulary(built, build=False)["kind"] == "built" and len(calls) == 1


def test_the_cached_vocabulary_is_checked_for_staleness_once_per_process(tmp_path, monkeypatch):
    """A cached vocabulary built from other training frames (an older generator) or other parameters is rebuilt:
    resolving the cache's vocabulary asks build_vocabulary, which reuses a current file and rebuilds a stale one;
    once per process."""
    monkeypatch.delenv("PYORBSLAM3_VOCAB", raising=False)
    out = tmp_path / "voc.txt"
    desc = np.random.default_rng(0).integers(0, 256, (500, 32), dtype=np.uint8)
    V.build_tree(desc, np.arange(500) // 50, k=4, L=2).save(out)
    monkeypatch.setattr(V, "default_vocab_path", lambda: out)
    monkeypatch.setattr(V, "_CURRENT", set())
    calls = []
    monkeypatch.setattr(V, "build_vocabulary", lambda path, progress=True: calls.append(Path(path)))
    V.resolve_vocabulary(None, build=True)
    V.resolve_vocabulary(None, build=True)
    assert calls == [out]
    V.resolve_vocabulary(None, build=False)  # no build allowed: the file as it is
    assert calls == [out]
