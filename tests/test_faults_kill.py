"""Kill -9 and Ctrl-C at several points of ``synth``, segmentation, the vocabulary build, ``run`` and ``study``: the
killed command leaves no half-written output (at most a temporary file named after its process, which the next run
removes), and a re-run gives the same bytes as an uninterrupted run.

Each fault is injected by ``tests/fault_hook.py`` in a child process: at the N-th call of a function (or of
``os.replace`` for a given file: between a staged file's writing and its rename) the process sends itself SIGKILL (it
dies on the spot, cleaning nothing) or SIGINT (Ctrl-C). The hook says when it acts, so a command that ended before
the point fails the test instead of passing it.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import pandas as pd


def _tree(folder: Path, skip: tuple[str, ...] = ()) -> dict[str, str]:
    """sha256 of every file under ``folder`` (relative paths; names in ``skip`` left out)."""
    return {p.relative_to(folder).as_posix(): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(folder.rglob("*")) if p.is_file() and p.name not in skip}


def _temps(*folders: Path) -> list[Path]:
    return [p for f in folders if f.exists() for p in f.rglob("*") if ".tmp-" in p.name]


def _faulted(proc, action: str) -> None:
    """The fault was reached, and the command ended as that fault ends it."""
    assert "fault-hook: reached" in proc.stderr, proc.stderr[-2000:]
    if action == "SIGKILL":
        assert proc.returncode == -9, proc.stderr[-2000:]
    else:
        tail = proc.stderr[proc.stderr.index("fault-hook: reached"):]
        assert proc.returncode == 130 and tail.strip().splitlines()[1:] == ["d2slam: interrupted"], proc.stderr


def test_synth_killed_or_interrupted_then_rerun(fault_world, tmp_path):
    """Killed while rendering (its temporary folder stays, named after it) and interrupted just before the rename
    (nothing left; on start it removed the dead process's folder): DIR never appears half-made, and the re-run writes
    the bytes of an uninterrupted run (the study cache's copy of the same sequence)."""
    w = fault_world
    out = tmp_path / "seq"
    args = ["synth", w.SCENARIO, "--out", out, "--frames", w.FRAMES, "--seed", w.SEED, "--workers", 1]
    killed = w.run(*args, hook=("d2slam.synth.generate:write_image", 7, "SIGKILL"))
    _faulted(killed, "SIGKILL")
    assert not out.exists() and len(_temps(tmp_path)) == 1 and _temps(tmp_path)[0].name.startswith("seq.tmp-")
    interrupted = w.run(*args, hook=("d2slam.outputs:replace_dir", 1, "SIGINT"))
    _faulted(interrupted, "SIGINT")
    assert not out.exists() and _temps(tmp_path) == []
    done = w.run(*args)
    assert done.returncode == 0, done.stderr
    assert _temps(tmp_path) == []
    assert _tree(out, skip=(".d2slam-synth",)) == _tree(w.seq, skip=(".complete",))


def _masks(cache: Path) -> dict:
    """The decoded content of every mask file of ``cache`` (the zip's own bytes carry its write time)."""
    from d2slam.segmentation.cache import read_store

    out = {}
    for path in sorted(cache.glob("masks/*/*/masks.npz")):
        shape, frames = read_store(path)
        out[path.parent.relative_to(cache).as_posix()] = (shape, {
            k: (r.scores.tobytes(), r.boxes.tobytes(), r.rects, [b.tobytes() for b in r.bits])
            for k, r in frames.items()})
    return out


def test_segmentation_killed_or_interrupted_then_rerun(fault_world, tmp_path):
    """`d2slam segment SEQ` killed after two frames, then killed between writing the mask file and renaming it (its
    temporary file stays), then interrupted there (the frames it segmented are written at exit): the re-run removes
    the dead process's file and ends with the masks of an uninterrupted run."""
    w = fault_world
    ref = tmp_path / "ref"
    uninterrupted = w.start("segment", w.seq, cache=ref)  # beside the first fault, on the other core
    cache = tmp_path / "cache"
    _faulted(w.run("segment", w.seq, cache=cache,
                   hook=("d2slam.segmentation.onnx:OnnxSegmenter.__call__", 3, "SIGKILL")), "SIGKILL")
    assert w.wait(uninterrupted).returncode == 0
    assert list(cache.glob("masks/*/*/masks.npz")) == []
    _faulted(w.run("segment", w.seq, cache=cache, hook=("os:replace", 1, "SIGKILL", "masks.npz")), "SIGKILL")
    assert list(cache.glob("masks/*/*/masks.npz")) == [] and len(_temps(cache / "masks")) == 1
    interrupted = w.run("segment", w.seq, cache=cache, hook=("os:replace", 1, "SIGINT", "masks.npz"))
    _faulted(interrupted, "SIGINT")
    done = w.run("segment", w.seq, cache=cache)
    assert done.returncode == 0 and _temps(cache / "masks") == []
    assert _masks(cache) == _masks(ref) and len(_masks(ref)) == 1


def test_vocabulary_build_killed_or_interrupted_then_rerun(fault_world, tmp_path):
    """`d2slam vocab build --out V` killed before its tree, killed between writing V and renaming it, interrupted
    before its manifest: V is whole or absent each time, and the re-run writes the bytes of an uninterrupted build."""
    w = fault_world
    ref = tmp_path / "ref" / "v.txt"
    ref.parent.mkdir()
    uninterrupted = w.start("vocab", "build", "--out", ref, "--no-synthetic")
    out = tmp_path / "mine" / "v.txt"
    out.parent.mkdir()
    args = ["vocab", "build", "--out", out, "--no-synthetic"]
    _faulted(w.run(*args, hook=("d2slam.baselines.vocab:build_tree", 1, "SIGKILL")), "SIGKILL")
    assert w.wait(uninterrupted).returncode == 0
    assert sorted(p.name for p in out.parent.iterdir()) == ["v.txt.lock"]
    _faulted(w.run(*args, hook=("os:replace", 1, "SIGKILL", "v.txt'")), "SIGKILL")
    assert not out.exists() and len(_temps(out.parent)) == 1
    _faulted(w.run(*args, hook=("os:replace", 1, "SIGINT", "v.txt.json")), "SIGINT")
    assert out.read_bytes() == ref.read_bytes()  # the text was whole before the manifest
    done = w.run(*args)
    assert done.returncode == 0 and "built in" in done.stderr, done.stderr
    assert out.read_bytes() == ref.read_bytes() and _temps(out.parent) == []
    mine, theirs = (json.loads(Path(f"{p}.json").read_text()) for p in (out, ref))
    assert (mine["sha256"], mine["key"]) == (theirs["sha256"], theirs["key"])


def test_vocabulary_training_render_killed_then_rerun(fault_world, tmp_path):
    """The default vocabulary's training frames are rendered by a child process: killing the build (kill -9 of the
    parent) stops the child too, before it finishes its folder; the re-run renders the frames again and builds the
    vocabulary of an uninterrupted build."""
    import psutil

    w = fault_world
    code = ("from d2slam.baselines.vocab import build_vocabulary\nfrom d2slam.config import BaselineConfig\n"
            "cfg = BaselineConfig(vocab_train_seeds=(900,), vocab_train_scenarios=('walking_xyz',), "
            "vocab_train_frames=12, vocab_train_stride=3)\n"
            "m = build_vocabulary(cfg=cfg, real=True, progress=True)\nprint(m['sha256'])\n")
    uninterrupted = w.start("--python", code, cache=tmp_path / "ref")
    cache = tmp_path / "cache"
    killed = w.run("--python", code, cache=cache, hook=("d2slam.progress:Progress.update", 2, "SIGKILL"))
    _faulted(killed, "SIGKILL")
    ref = w.wait(uninterrupted)
    assert ref.returncode == 0, ref.stderr
    children = [p for p in psutil.process_iter(["cmdline"]) if str(cache) in " ".join(p.info["cmdline"] or [])]
    assert psutil.wait_procs(children, timeout=60)[1] == []  # the render child noticed and stopped
    train = cache / "vocab" / "train"
    assert [p for p in train.rglob(".complete")] == []  # its folder never completed
    done = w.run("--python", code, cache=cache)
    assert done.returncode == 0, done.stderr
    assert done.stdout == ref.stdout and _temps(train) == []
    assert (cache / "vocab" / "d2slam_orbvoc.txt").read_bytes() == \
        (tmp_path / "ref" / "vocab" / "d2slam_orbvoc.txt").read_bytes()


def test_run_killed_or_interrupted_then_rerun(fault_world, tmp_path):
    """`d2slam run` killed mid-sequence (nothing written), interrupted between writing the trajectory and renaming
    it (nothing written), killed between writing the metrics JSON and renaming it (the trajectory is whole, the
    JSON's temporary file stays): the re-run removes it and writes the bytes of an uninterrupted run."""
    w = fault_world
    ref = tmp_path / "ref.txt"
    base = ["run", w.seq, "--method", "d2slam", "--no-loop-closing", "--quiet"]
    uninterrupted = w.start(*base, "--out", ref, "--metrics-json", tmp_path / "ref.json")
    out, js = tmp_path / "t.txt", tmp_path / "t.json"
    args = base + ["--out", out, "--metrics-json", js]
    _faulted(w.run(*args, hook=("d2slam.slam.engine:Engine.process", 4, "SIGKILL")), "SIGKILL")
    first = w.wait(uninterrupted)
    assert first.returncode == 0, first.stderr
    assert not out.exists() and not js.exists() and _temps(tmp_path) == []
    _faulted(w.run(*args, hook=("os:replace", 1, "SIGINT", "t.txt")), "SIGINT")
    assert not out.exists() and _temps(tmp_path) == []
    _faulted(w.run(*args, hook=("os:replace", 1, "SIGKILL", "t.json")), "SIGKILL")
    assert out.read_bytes() == ref.read_bytes() and not js.exists() and len(_temps(tmp_path)) == 1
    done = w.run(*args)
    assert done.returncode == 0 and _temps(tmp_path) == [], done.stderr
    assert out.read_bytes() == ref.read_bytes()
    same = ("frames", "tracked", "lost", "keyframes", "map_points", "keypoints", "config_hash", "metrics_error")
    mine, theirs = (json.loads(p.read_text()) for p in (js, tmp_path / "ref.json"))
    assert {k: mine.get(k) for k in same} == {k: theirs.get(k) for k in same} and mine["tracked"] == w.FRAMES


STUDY = ("from d2slam.study import run_study\n"
         "run_study({out!r}, scenarios=['sitting_static'], methods=['none', 'd2slam'], seeds=[3], frames=6, "
         "twin_methods=(), progress=False, plots=False, resume=True)\n")


def _study(out: Path) -> tuple:
    """What must not depend on interruptions: the deterministic columns of runs.csv and the trajectory files."""
    from d2slam.study import tables as T

    df = pd.read_csv(out / "runs.csv")
    cols = [c for c in T.RUN_COLUMNS if c not in T.TIMING_COLUMNS and c in df.columns]
    return df[cols].to_csv(index=False), _tree(out / "trajectories")


def test_study_killed_or_interrupted_then_resumed(fault_world, tmp_path):
    """A study killed during its second run (the first is saved), killed between writing a run's arrays and its
    record, then interrupted while writing runs.csv: the resumed study gives the runs.csv and trajectories of an
    uninterrupted one, and no temporary file is left."""
    w = fault_world
    ref = tmp_path / "ref"
    uninterrupted = w.start("--python", STUDY.format(out=str(ref)))
    out = tmp_path / "out"
    code = STUDY.format(out=str(out))
    _faulted(w.run("--python", code, hook=("d2slam.study.core:execute_run", 2, "SIGKILL")), "SIGKILL")
    assert w.wait(uninterrupted).returncode == 0
    assert len(list((out / "runs").glob("*.json"))) == 1 and not (out / "runs.csv").exists()
    (out / "runs" / next((out / "runs").glob("*.json")).name).unlink()  # the next kill then meets the same run
    _faulted(w.run("--python", code, hook=("os:replace", 1, "SIGKILL", "/runs/")), "SIGKILL")
    assert list((out / "runs").glob("*.json")) == [] and len(_temps(out)) == 1
    _faulted(w.run("--python", code, hook=("os:replace", 1, "SIGINT", "runs.csv")), "SIGINT")
    assert not (out / "runs.csv").exists() and len(list((out / "runs").glob("*.json"))) == 2
    done = w.run("--python", code)
    assert done.returncode == 0, done.stderr
    assert _study(out) == _study(ref) and _temps(out) == []
