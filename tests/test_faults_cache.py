"""Every kind of cache file truncated and bit-flipped: the next command that reads it says so in one line (no
traceback, no raw Python warning), remakes it, and gives the bytes of a run on an intact cache; `d2slam cache check`
finds each beforehand and `--fix` removes it. Two runs segmenting one sequence at once segment it once.

The runs here are in this process (a run on 6 frames takes well under a second once the kernels are loaded); what a
process keeps in memory of a cache file is dropped between them (``fresh``), so that each run reads the files again
as a new process would."""

from __future__ import annotations

import importlib
import shutil
import sys
import warnings
from pathlib import Path

import pytest

from d2slam.cli import main


def _damage(path: Path, how: str) -> None:
    """Truncate ``path`` to a third, or flip one bit in its middle (its size kept)."""
    data = bytearray(path.read_bytes())
    if how == "truncate":
        path.write_bytes(bytes(data[: len(data) // 3]))
    else:
        data[len(data) // 2] ^= 0x08
        path.write_bytes(bytes(data))


def fresh() -> None:
    """Forget what this process keeps of the cache's files (a new process would read them again)."""
    import d2slam.baselines.vocab as V
    import d2slam.cachefiles as CF
    import d2slam.segmentation as S
    from d2slam.slam import orb_vocabulary as O

    S._CACHED.clear()
    O._load.cache_clear()
    O._sha256.cache_clear()
    V._CHECKED.clear()
    V._CURRENT.clear()
    CF._REPORTED.clear()


@pytest.fixture
def world(fault_world, monkeypatch):
    fault_world.env(monkeypatch)
    fresh()
    return fault_world


def _run(seq, out: Path, capsys, *extra) -> str:
    """``d2slam run SEQ --method d2slam`` (the real segmenter's masks) in this process: returns its stderr."""
    fresh()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no raw Python warning
        code = main(["run", str(seq), "--method", "d2slam", "--quiet", "--out", str(out), *extra])
    err = capsys.readouterr().err
    assert code == 0 and "Traceback" not in err, err
    return err


def _said(err: str, what: str, path: Path) -> None:
    """``err`` holds exactly one line saying ``path`` was damaged and is remade."""
    lines = [line for line in err.splitlines() if line.startswith("d2slam: damaged")]
    assert len(lines) == 1 and lines[0].startswith(f"d2slam: damaged {what} {path} ("), err


NO_LOOPS = ("--no-loop-closing",)


@pytest.fixture(scope="module")
def reference(fault_world, tmp_path_factory):
    """The trajectories of runs on an intact cache, with loop closing off and on."""
    root = tmp_path_factory.mktemp("ref")
    with pytest.MonkeyPatch.context() as mp:
        fault_world.env(mp)
        fresh()
        out = {}
        for name, extra in (("none", NO_LOOPS), ("loops", ())):
            assert main(["run", str(fault_world.seq), "--method", "d2slam", "--quiet", "--out",
                         str(root / f"{name}.txt"), *extra]) == 0
            out[name] = (root / f"{name}.txt").read_bytes()
    return out


@pytest.mark.parametrize("how", ["truncate", "bitflip"])
def test_mask_file(world, reference, tmp_path, capsys, how):
    (store,) = world.cache.glob("masks/*/*/masks.npz")
    _damage(store, how)
    err = _run(world.seq, tmp_path / "t.txt", capsys, *NO_LOOPS)
    _said(err, "mask cache file", store)
    assert (tmp_path / "t.txt").read_bytes() == reference["none"]
    _run(world.seq, tmp_path / "u.txt", capsys, *NO_LOOPS)  # the file was rewritten: read, not segmented
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("how", ["truncate", "bitflip"])
def test_mask_memo(world, reference, tmp_path, capsys, how):
    from d2slam.segmentation.cache import sequence_key

    memos = sorted(world.cache.glob("masks/stamps/*.json"))
    memo = next(m for m in memos if str(world.seq.resolve()) in m.read_text())
    seq = type("Seq", (), {"root": world.seq})()
    fresh()
    key = sequence_key(seq)
    _damage(memo, how)
    fresh()
    assert sequence_key(seq) == key  # the images hashed again: the same key, the same masks
    _said(capsys.readouterr().err, "mask cache memo", memo)
    err = _run(world.seq, tmp_path / "t.txt", capsys, *NO_LOOPS)
    assert "damaged" not in err and (tmp_path / "t.txt").read_bytes() == reference["none"]


@pytest.mark.parametrize("how", ["truncate", "bitflip"])
def test_bag_of_words_file(world, reference, tmp_path, capsys, how):
    (bow,) = world.cache.glob("vocab/bow/*.npz")
    _damage(bow, how)
    assert main(["vocab", "check"]) == 1  # what a run would trip on
    assert "damaged" in capsys.readouterr().out
    err = _run(world.seq, tmp_path / "t.txt", capsys)
    _said(err, "bag-of-words vocabulary", bow)
    assert (tmp_path / "t.txt").read_bytes() == reference["loops"]
    fresh()
    assert main(["vocab", "check"]) == 0


@pytest.mark.parametrize("how", ["truncate", "bitflip"])
def test_vocabulary_text(world, reference, tmp_path, capsys, how):
    text = world.cache / "vocab" / "d2slam_orbvoc.txt"
    before = text.read_bytes()
    _damage(text, how)
    code = main(["vocab", "check"])  # found beforehand: a malformed file (2) or one that is not its build's (1)
    cap = capsys.readouterr()
    assert code in (1, 2) and str(text) in cap.out + cap.err and "Traceback" not in cap.err
    err = _run(world.seq, tmp_path / "t.txt", capsys)
    _said(err, "vocabulary", text)
    assert text.read_bytes() == before and (tmp_path / "t.txt").read_bytes() == reference["loops"]


@pytest.mark.parametrize("how", ["truncate", "bitflip"])
def test_vocabulary_training_frames(world, capsys, how):
    from d2slam.baselines.vocab import training_jobs

    job = Path(training_jobs()[0]["out"])
    frame = sorted(job.glob("*.png"))[1]
    before, text = frame.read_bytes(), (world.cache / "vocab" / "d2slam_orbvoc.txt").read_bytes()
    _damage(frame, how)
    assert main(["vocab", "build"]) == 0
    cap = capsys.readouterr()
    _said(cap.err, "vocabulary training frames", job)
    assert "cached (identical build)" in cap.out  # the same frames again: the same vocabulary, not rebuilt
    assert frame.read_bytes() == before and (world.cache / "vocab" / "d2slam_orbvoc.txt").read_bytes() == text


STUDY = dict(scenarios=["sitting_static"], methods=["none"], seeds=[3], frames=6, twin_methods=(), progress=False,
             plots=False)


def _trajectories(out: Path) -> dict:
    return {p.name: p.read_bytes() for p in sorted((out / "trajectories").glob("*.txt"))}


@pytest.fixture(scope="module")
def study_ref(fault_world, tmp_path_factory):
    from d2slam.study import run_study

    out = tmp_path_factory.mktemp("study") / "ref"
    with pytest.MonkeyPatch.context() as mp:
        fault_world.env(mp)
        run_study(out, **STUDY)
    return out


@pytest.mark.parametrize("how", ["truncate", "bitflip"])
def test_feature_file(world, study_ref, tmp_path, capsys, how):
    from d2slam.study import run_study

    (feat,) = world.cache.glob("study/features/*.npz")
    _damage(feat, how)
    run_study(tmp_path / "out", **STUDY)
    _said(capsys.readouterr().err, "feature file", feat)
    assert _trajectories(tmp_path / "out") == _trajectories(study_ref)
    run_study(tmp_path / "again", **STUDY)  # written again whole: read back without a word
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("what", ["record-truncate", "record-bitflip", "arrays-truncate", "arrays-bitflip"])
def test_study_run_records(world, study_ref, tmp_path, capsys, what):
    """--resume reuses a run only when its record and arrays match their seal; a damaged one is run again."""
    from d2slam.study import run_study

    out = tmp_path / "out"
    shutil.copytree(study_ref, out)
    part, how = what.split("-")
    (path,) = (out / "runs").glob("*.json" if part == "record" else "*.npz")
    _damage(path, how)
    res = run_study(out, resume=True, **STUDY)
    err = capsys.readouterr().err
    _said(err, "study run record" if part == "record" else "study run arrays", path)
    assert res.manifest["grid"]["reused_runs"] == []
    assert _trajectories(out) == _trajectories(study_ref)
    assert run_study(out, resume=True, **STUDY).manifest["grid"]["reused_runs"] != []


def test_cached_sequence(world, tmp_path, capsys):
    """A cached sequence with a truncated image and a bit-flipped one: said and generated again, the same bytes. A
    flipped bit that kept the file's time (silent bit rot) is what `d2slam cache check --full` is for."""
    import os

    from d2slam.study.sequences import ensure_sequence, sequence_dir

    root = tmp_path / "sequences"
    path = sequence_dir(world.SCENARIO, world.SEED, world.FRAMES, False, root=root)
    shutil.copytree(world.seq, path)
    want = {p.relative_to(path): p.read_bytes() for p in path.rglob("*") if p.is_file()}
    rgb, depth = sorted((path / "rgb").iterdir())[2], sorted((path / "depth").iterdir())[3]
    _damage(rgb, "truncate")
    _damage(depth, "bitflip")
    assert ensure_sequence(world.SCENARIO, world.SEED, world.FRAMES, root=root, progress=False) == path
    err = capsys.readouterr().err
    _said(err, "cached sequence", path)
    assert f"{rgb.relative_to(path).as_posix()} has" in err and f"{depth.relative_to(path).as_posix()} changed" in err
    assert {p.relative_to(path): p.read_bytes() for p in path.rglob("*") if p.is_file() and p.name != ".complete"} \
        == {k: v for k, v in want.items() if k.name != ".complete"}
    st = rgb.stat()
    _damage(rgb, "bitflip")
    os.utime(rgb, ns=(st.st_atime_ns, st.st_mtime_ns))  # the time kept: the cheap check cannot see it
    from d2slam.study.sequences import sequence_problems

    assert sequence_problems(path) == [] and sequence_problems(path, full=True) == [
        f"{rgb.relative_to(path).as_posix()} changed (sha256)"]


KERNEL = "from numba import njit\n\n\n@njit(cache=True)\ndef twice_plus_one(x):\n    return 2 * x + 1\n"


@pytest.mark.parametrize("what", ["nbi-truncate", "nbi-bitflip", "nbc-truncate", "nbc-bitflip"])
def test_compiled_kernel(tmp_path, capsys, what):
    """numba's cache files of a kernel (through d2slam's guard, installed by d2slam.slam): a damaged index or data
    file is said and the kernel compiled again; the result is the same and the files are whole again."""
    import d2slam.slam  # noqa: F401 - installs the guard
    from d2slam.kernel_cache import check_file

    (tmp_path / "faultkernel.py").write_text(KERNEL)
    sys.path.insert(0, str(tmp_path))
    try:
        def call():
            sys.modules.pop("faultkernel", None)
            importlib.invalidate_caches()
            return importlib.import_module("faultkernel").twice_plus_one(20)

        assert call() == 41
        part, how = what.split("-")
        (path,) = (tmp_path / "__pycache__").glob(f"*.{part}")
        _damage(path, how)
        capsys.readouterr()
        assert call() == 41
        err = capsys.readouterr().err
        what = "compiled-kernel index" if part == "nbi" else "compiled kernel"
        assert err.count("\n") == 1 and err.startswith(f"d2slam: damaged {what} {path} ("), err
        assert call() == 41 and capsys.readouterr().err == ""  # rewritten: loaded without a word
        assert all(check_file(p) is None for p in (tmp_path / "__pycache__").glob("*.nb?"))
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("faultkernel", None)
        import d2slam.cachefiles as CF

        CF._REPORTED.clear()


def test_cache_check_finds_what_a_run_would_trip_on_and_fix_removes_it(fault_world, reference, study_ref, tmp_path,
                                                                       capsys, monkeypatch):
    """On a copy of the world's cache (its masks, bag of words, features and sequence made by the reference runs)."""
    from d2slam.outputs import temp_tag

    cache = tmp_path / "cache"
    shutil.copytree(fault_world.cache, cache, ignore=shutil.ignore_patterns("train"))
    fault_world.env(monkeypatch, cache=cache)
    assert main(["cache", "check"]) == 0
    capsys.readouterr()
    damaged = [next(cache.glob("masks/*/*/masks.npz")), next(cache.glob("vocab/bow/*.npz")),
               next(cache.glob("study/features/*.npz")), sorted(next(cache.glob("study/sequences/*/rgb")).iterdir())[0]]
    for path in damaged:
        _damage(path, "truncate")
    stale = cache / "study" / "features" / f"f.npz.tmp-{_dead_pid()}@{temp_tag().split('@')[1]}.npz"
    stale.write_bytes(b"half")
    assert main(["cache", "check"]) == 1
    out = capsys.readouterr().out.splitlines()
    assert out[-1].endswith("5 problems") and len(out) == 6
    for path in [*damaged[:3], damaged[3].parent.parent, stale]:
        assert any(str(path) in line for line in out[:-1]), (path, out)
    assert main(["cache", "check", "--fix"]) == 0
    assert main(["cache", "check"]) == 0 and capsys.readouterr().out.splitlines()[-1].endswith(" 0 problems")
    assert not any(p.exists() for p in damaged[:3]) and not stale.exists()


def _dead_pid() -> int:
    import subprocess

    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_two_runs_on_one_sequence_segment_it_once(fault_world, tmp_path):
    """`d2slam segment SEQ` twice at once on an empty cache: the second waits for the first (it says so) and reads
    its masks; the sequence is segmented once."""
    import subprocess

    w = fault_world
    cache = tmp_path / "cache"
    env = dict(w.child_env, D2SLAM_CACHE=str(cache))
    first = subprocess.Popen([w.python, str(w.repo / "tests" / "fault_hook.py"),
                              "d2slam.segmentation.onnx:OnnxSegmenter.__call__", "1", "sleep:3", "--", "segment",
                              str(w.seq)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    lines = []
    while "fault-hook: reached" not in lines and first.poll() is None:  # segmenting, holding the lock
        lines.append(first.stderr.readline().strip())
    second = w.run("segment", w.seq, cache=cache)
    out, err = first.communicate(timeout=300)
    assert first.returncode == 0 and second.returncode == 0, (err, second.stderr)
    assert f"{w.FRAMES} frames, 0 already cached, {w.FRAMES} segmented" in out
    assert "another process is segmenting" in second.stderr and "waiting for it" in second.stderr
    assert f"{w.FRAMES} frames, {w.FRAMES} already cached, 0 segmented" in second.stdout


def test_preload_loads_cached_kernels_and_compiles_none(tmp_path):
    """kernel_cache.preload: a kernel cached on disk is loaded before its first call (a run's clock then counts no
    loading); one never compiled stays uncompiled; a second preload loads nothing."""
    import d2slam.slam  # noqa: F401 - installs the guard
    from d2slam.kernel_cache import preload

    (tmp_path / "preloaded.py").write_text(KERNEL + "\n\n@njit(cache=True)\ndef never_called(x):\n    return x\n")
    sys.path.insert(0, str(tmp_path))
    try:
        def fresh_module():
            sys.modules.pop("preloaded", None)
            importlib.invalidate_caches()
            return importlib.import_module("preloaded")

        assert fresh_module().twice_plus_one(20) == 41  # compiled and cached for int64
        m = fresh_module()  # a new process's view: nothing loaded yet
        assert not m.twice_plus_one.overloads and not m.never_called.overloads
        assert preload(m) == 1
        assert len(m.twice_plus_one.overloads) == 1 and not m.never_called.overloads
        assert preload(m) == 0 and m.twice_plus_one(1) == 3
    finally:
        sys.path.remove(str(tmp_path))
        sys.modules.pop("preloaded", None)
