"""What a careless user can point the commands at: outputs onto inputs (directly, through links, inside a sequence,
inside the cache), two outputs on one file, ``synth --out`` onto a folder holding the user's own files, config values
that cannot be right, a full disk, a cache that cannot be written, two studies on one folder. Each is one error line
before any work (exit 2) or a documented recovery; the user's files are byte-identical afterwards (sha256)."""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest

from d2slam.cli import main


def _sha(root: Path) -> dict[str, str]:
    """sha256 of every file under ``root`` (a file: itself), links not followed."""
    root = Path(root)
    files = [root] if root.is_file() else sorted(p for p in root.rglob("*") if p.is_file())
    return {str(p): hashlib.sha256(p.read_bytes()).hexdigest() for p in files}


@pytest.fixture(scope="module")
def user_seq(fault_world, tmp_path_factory):
    """The user's own copy of the world's sequence (outside the cache), and a trajectory of it."""
    root = tmp_path_factory.mktemp("user")
    seq = root / "SEQ"
    shutil.copytree(fault_world.seq, seq, ignore=shutil.ignore_patterns(".complete"))
    traj = root / "traj.txt"
    shutil.copyfile(seq / "groundtruth.txt", traj)
    return seq, traj


@pytest.fixture
def world(fault_world, monkeypatch):
    fault_world.env(monkeypatch)
    return fault_world


def _refused(capsys, argv, *named) -> str:
    """``d2slam ARGV`` exits 2 with one line ``d2slam: error: ...`` naming every path of ``named``."""
    assert main([str(a) for a in argv]) == 2
    err = capsys.readouterr().err
    assert err.startswith("d2slam: error: ") and err.count("\n") == 1 and "Traceback" not in err, err
    for path in named:
        assert str(path) in err, (path, err)
    return err


RUN = ["--method", "none", "--no-loop-closing", "--quiet"]


def test_outputs_onto_the_runs_inputs_are_refused_before_any_work(world, user_seq, tmp_path, capsys, monkeypatch):
    """The cases of the issue and their variants through links: the ground truth, rgb.txt, the metrics JSON onto
    the ground truth, --out and --metrics-json on one file, a link or a hard link to an input, a path through `..`
    or through a link to the sequence, another sequence's file, the cache's own folders, the config file."""
    import d2slam.commands.run as M  # run_method as the command calls it

    seq, _ = user_seq
    monkeypatch.setattr(M, "run_method", lambda *a, **k: pytest.fail("ran before the outputs were checked"))
    before = _sha(seq)
    link, hard, dirlink = tmp_path / "link.txt", tmp_path / "hard.txt", tmp_path / "seqlink"
    link.symlink_to(seq / "groundtruth.txt")
    os.link(seq / "depth.txt", hard)
    dirlink.symlink_to(seq)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("dynamics: {z_far: 5.0}\n")
    cases = [
        (["--out", seq / "groundtruth.txt"], [seq / "groundtruth.txt", seq]),
        (["--out", seq / "rgb.txt"], [seq / "rgb.txt", seq]),
        (["--out", tmp_path / "t.txt", "--metrics-json", seq / "groundtruth.txt"], [seq / "groundtruth.txt", seq]),
        (["--out", tmp_path / "x.txt", "--metrics-json", tmp_path / "x.txt"], [tmp_path / "x.txt"]),
        (["--out", link], [link, seq / "groundtruth.txt", seq]),
        (["--out", hard], [hard]),
        (["--out", f"{seq}/rgb/../results.txt"], [seq]),
        (["--out", dirlink / "traj.txt"], [dirlink / "traj.txt", seq]),
        (["--out", world.seq / "groundtruth.txt"], [world.seq]),
        (["--out", world.cache / "masks" / "t.txt"], [world.cache / "masks"]),
        (["--out", cfg, "--config", cfg], [cfg]),
    ]
    for extra, named in cases:
        err = _refused(capsys, ["run", seq, *RUN, *extra], *named)
        assert "--out" in err or "--metrics-json" in err
    assert _sha(seq) == before and not (tmp_path / "x.txt").exists() and not (tmp_path / "t.txt").exists()
    assert (seq / "groundtruth.txt").read_bytes() == link.read_bytes()  # the link and the file it points at kept


def test_eval_plot_and_segment_overlays_onto_inputs_are_refused(world, user_seq, tmp_path, capsys):
    seq, traj = user_seq
    before = {**_sha(seq), **_sha(traj)}
    _refused(capsys, ["eval", seq, traj, "--plot", seq / "plot.png"], seq / "plot.png", seq)
    _refused(capsys, ["eval", seq / "groundtruth.txt", traj, "--plot", traj], traj)
    images = sorted((seq / "rgb").iterdir())[:2]
    _refused(capsys, ["segment", *images, "--overlay", seq / "overlays"], seq / "overlays", seq)
    a, b = tmp_path / "a", tmp_path / "b"  # two images of one name: one overlay file for both
    a.mkdir(), b.mkdir()
    shutil.copyfile(images[0], a / "1.png")
    shutil.copyfile(images[1], b / "1.png")
    _refused(capsys, ["segment", a / "1.png", b / "1.png", "--overlay", tmp_path / "ov"], tmp_path / "ov" /
             "1_persons.png")
    assert {**_sha(seq), **_sha(traj)} == before and not (tmp_path / "ov").exists()


def test_an_overlay_beside_its_image_is_written_but_never_over_it(world, tmp_path, capsys, user_seq):
    """`--overlay DIR` with DIR the images' own folder is allowed (the overlays have their own names) unless an
    overlay would be one of the images: `x.png` and `x_persons.png` given together."""
    seq, _ = user_seq
    img = sorted((seq / "rgb").iterdir())[0]
    d = tmp_path / "imgs"
    d.mkdir()
    shutil.copyfile(img, d / "x.png")
    shutil.copyfile(img, d / "x_persons.png")
    before = _sha(d)
    _refused(capsys, ["segment", d / "x.png", d / "x_persons.png", "--overlay", d], d / "x_persons.png")
    assert _sha(d) == before


def test_study_out_onto_a_sequence_or_the_cache_is_refused(world, user_seq, tmp_path, capsys):
    seq, _ = user_seq
    before = _sha(seq)
    args = ["study", "--scenarios", "sitting_static", "--methods", "none", "--seeds", "3", "--twin-methods",
            "--no-plots", "--quiet", "--out"]
    _refused(capsys, args + [seq], seq)
    _refused(capsys, args + [seq / "results"], seq)
    _refused(capsys, args + [world.cache / "study" / "sequences" / "mine"], world.cache / "study" / "sequences")
    assert _sha(seq) == before and not (seq / "results").exists()


def test_vocab_build_out_inside_its_training_images_is_refused(world, tmp_path, capsys):
    from d2slam.assets import tum_frames

    imgs = tmp_path / "imgs"
    imgs.mkdir()
    for f in tum_frames()[:2]:
        shutil.copyfile(f, imgs / f.name)
    before = _sha(imgs)
    _refused(capsys, ["vocab", "build", "--images-dir", imgs, "--no-synthetic", "--no-real", "--out",
                      imgs / "v.txt"], imgs / "v.txt", imgs)
    assert _sha(imgs) == before


def test_synth_replaces_only_its_own_sequence_and_names_what_it_would_delete(world, tmp_path, capsys, monkeypatch):
    """A folder holding a sequence d2slam synth wrote plus the user's notes and results: refused, naming them (and
    nothing rendered); the same with a file slipped into rgb/; a folder of an earlier version (scene.json, no marker)
    with the user's file too; a sequence folder nested in another."""
    import importlib

    from d2slam.commands.synth import OWNER, foreign_entries, write_owner

    G = importlib.import_module("d2slam.synth.generate")
    monkeypatch.setattr(G, "render_frame", lambda *a: pytest.fail("rendered before the output was checked"))
    s = tmp_path / "S"
    shutil.copytree(world.seq, s, ignore=shutil.ignore_patterns(".complete"))
    write_owner(s, {"scenario": world.SCENARIO, "seed": world.SEED, "frames": world.FRAMES, "static_twin": False})
    assert foreign_entries(s) == []  # nothing but its own: replaceable
    (s / "my_notes.txt").write_text("mine")
    (s / "results").mkdir()
    (s / "results" / "ate.csv").write_text("1,2\n")
    (s / "rgb" / "keep.txt").write_text("mine too")
    before = _sha(s)
    argv = ["synth", world.SCENARIO, "--frames", "2", "--out", s]
    err = _refused(capsys, argv, s)
    assert "(my_notes.txt, results/, rgb/keep.txt)" in err and "would delete them" in err
    (s / OWNER).unlink()  # a sequence of an earlier version: its layout is its own, the rest is not
    err = _refused(capsys, argv, s)
    assert "(my_notes.txt, results/, rgb/keep.txt)" in err
    assert _sha(s) == {k: v for k, v in before.items() if not k.endswith(OWNER)}
    _refused(capsys, ["synth", world.SCENARIO, "--frames", "2", "--out", s / "results" / "nested"], s)


@pytest.mark.parametrize("text,message", [
    ("dynamics: {z_far: .nan}", r"dynamics.z_far = nan is out of range: a finite number in \(0, 20\]"),
    ("dynamics: {dynamic_threshold: -0.2}", r"dynamics.dynamic_threshold = -0.2 is out of range: .* in \[0, 1\]"),
    ("orb: {n_features: 1000000000}", r"orb.n_features = 1000000000 is out of range: an integer in \[1, 100000\]"),
    ("orb: {n_features: 0}", r"orb.n_features = 0 is out of range"),
    ("engine: {min_depth: 9.0}", r"engine.min_depth = 9.0 must be below engine.max_depth = 8.0"),
    ("dynamics: {uncertainty_prob: 1.5}", r"dynamics.uncertainty_prob = 1.5 is out of range"),
    ("dynamics: {z_far: .inf}", r"dynamics.z_far = inf is out of range"),
])
def test_values_that_cannot_be_right_are_one_line_before_the_run(world, user_seq, tmp_path, capsys, text, message):
    import re

    seq, _ = user_seq
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text(text + "\n")
    err = _refused(capsys, ["run", seq, *RUN, "--config", cfg, "--out", tmp_path / "t.txt"], cfg)
    assert re.search(message, err), err
    assert not (tmp_path / "t.txt").exists()


def test_a_full_disk_is_one_line_and_the_previous_output_stays(world, user_seq, tmp_path):
    """The trajectory write fails (file size limit: what a full disk does to a write): one line, exit 2, the
    previous file at --out as it was, no temporary file left."""
    import resource
    import signal

    seq, _ = user_seq
    out = tmp_path / "t.txt"
    out.write_text("the previous trajectory\n")

    def limited():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a write past the limit fails with EFBIG instead
        resource.setrlimit(resource.RLIMIT_FSIZE, (300, 300))

    p = world.run("run", seq, *RUN, "--out", out, preexec_fn=limited)
    assert p.returncode == 2 and p.stderr.count("\n") == 1, p.stderr
    assert p.stderr.startswith(f"d2slam: error: {out}: cannot write (File too large); nothing was written")
    assert out.read_text() == "the previous trajectory\n" and sorted(tmp_path.iterdir()) == [out]


def test_a_cache_that_cannot_be_written_is_one_line(world, user_seq, tmp_path, capsys, monkeypatch):
    seq, _ = user_seq
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    monkeypatch.setenv("D2SLAM_CACHE", str(blocker / "cache"))
    _refused(capsys, ["run", seq, "--method", "d2slam", "--no-loop-closing", "--quiet", "--out", tmp_path / "t.txt"],
             blocker / "cache")
    assert not (tmp_path / "t.txt").exists()
    monkeypatch.setenv("D2SLAM_CACHE", str(blocker))
    assert main(["cache", "check"]) == 1
    assert "is not a folder" in capsys.readouterr().out


def test_two_studies_on_one_folder_the_second_is_refused(world, tmp_path, capsys):
    """A study holds its output folder's lock while it runs: a second one on the folder is refused in one line (and
    so is --tables-only), the first goes on."""
    import subprocess

    out = tmp_path / "out"
    code = ("from d2slam.study import run_study\n"
            f"run_study({str(out)!r}, scenarios=['sitting_static'], methods=['none'], seeds=[3], frames=6, "
            "twin_methods=(), progress=False, plots=False)\n")
    first = subprocess.Popen([world.python, str(world.repo / "tests" / "fault_hook.py"),
                              "d2slam.study.core:execute_run", "1", "sleep:60", "--", "--python", code],
                             stderr=subprocess.PIPE, text=True, env=world.child_env)
    try:
        lines = []
        while "fault-hook: reached" not in lines and first.poll() is None:  # inside its first run, holding the lock
            lines.append(first.stderr.readline().strip())
        assert "fault-hook: reached" in lines, lines
        err = _refused(capsys, ["study", "--out", out, "--scenarios", "sitting_static", "--methods", "none",
                                "--seeds", "3", "--frames", "40", "--twin-methods", "--no-plots", "--quiet"], out)
        assert "another d2slam study is writing into this folder" in err
        (out / "runs.csv").write_text("")  # --tables-only meets the lock before it reads anything
        err = _refused(capsys, ["study", "--out", out, "--tables-only"], out)
        assert "another d2slam study is writing into this folder" in err
    finally:
        first.kill()
        first.wait()
