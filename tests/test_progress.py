"""One-off costs are announced with an estimate before they start and followed on stderr: a line every few seconds
when stderr is not a terminal (CI, nohup, a pipe), a tqdm bar when it is."""

from __future__ import annotations

import io

from d2slam.progress import PROGRESS, announce, duration, progress


class Clock:
    """A clock that advances 2 s at every reading."""

    def __init__(self):
        self.t = 0.0

    def __call__(self):
        self.t += 2.0
        return self.t


def test_log_lines_every_interval_when_not_a_terminal():
    stream = io.StringIO()
    items = list(progress(range(10), desc="segment room", stream=stream, interval=5.0, clock=Clock()))
    assert items == list(range(10))
    lines = stream.getvalue().splitlines()
    assert lines[0] == "d2slam: segment room: 3/10 frames, 6 s, about 14 s left"
    assert lines[-1] == "d2slam: segment room: 10/10 frames in 22 s"
    assert len(lines) == 4  # at 3, 6 and 9 frames (every 6 s of the fake clock), then the end
    quiet = io.StringIO()
    assert list(progress(range(3), stream=quiet, enabled=False)) == [0, 1, 2] and quiet.getvalue() == ""
    assert PROGRESS.progress_log_s > 0


def test_time_left_follows_the_work_done_when_items_differ_in_cost():
    """Four long items done first (a 1200-frame sequence each) and 12 short ones left (300 frames): the time left is
    what the frames left take at the pace so far, not what the items left would take at the pace of the long ones."""
    stream = io.StringIO()
    cost = [1200.0] * 4 + [300.0] * 12
    done = list(progress(range(16), desc="segmentation", unit="sequence", stream=stream, interval=8.0, clock=Clock(),
                         weight=lambda i: cost[i], total_weight=sum(cost)))
    assert done == list(range(16))
    assert stream.getvalue().splitlines()[0] == "d2slam: segmentation: 4/16 sequences, 8 s, about 6 s left"


def test_a_terminal_gets_a_bar():
    class Tty(io.StringIO):
        def isatty(self):
            return True

    stream = Tty()
    assert list(progress(iter(range(4)), total=4, desc="synth", stream=stream)) == [0, 1, 2, 3]
    assert "synth: 100%" in stream.getvalue() and "d2slam:" not in stream.getvalue()


def test_announce_with_an_estimate():
    stream = io.StringIO()
    announce("generating x", 150.0, stream=stream)
    announce("building y", None, stream=stream)
    assert stream.getvalue() == "d2slam: generating x (about 2 min)\nd2slam: building y\n"
    assert [duration(s) for s in (0.2, 45, 61, 5400)] == ["1 s", "45 s", "1 min", "1.5 h"]


def test_generation_is_announced_before_it_starts(tmp_path, monkeypatch, capsys):
    """`d2slam synth` and the sequence cache (ensure_sequence) say what they generate and how long it should take
    before the generator runs."""
    import importlib

    import d2slam.commands.synth as synth_command
    import d2slam.study.sequences as sequences
    from d2slam.study.sequences import ensure_sequence

    gen = importlib.import_module("d2slam.synth.generate")  # the module (the package exports its function)

    seen = []

    def fake_generate(scenario, out, frames=300, seed=0, static_twin=False, workers=None, progress=True, **kw):
        seen.append(capsys.readouterr().err)  # what was printed before the generator started
        from pathlib import Path

        Path(out).mkdir(parents=True, exist_ok=True)
        raise KeyboardInterrupt  # stop here: only the announcement is under test

    monkeypatch.setattr(synth_command, "generate", fake_generate)  # the generator as its two callers call it
    monkeypatch.setattr(sequences, "generate", fake_generate)
    from d2slam.cli import main

    assert main(["synth", "walking_xyz", "--frames", "40", "--seed", "3", "--out", str(tmp_path / "s")]) == 130
    est = gen.estimated_seconds(40)
    assert seen[0].startswith("d2slam: generating 40 frames of walking_xyz (seed 3) into ")
    assert f"with {gen.worker_count(40)} worker" in seen[0] and f"(about {round(est)} s)" in seen[0]
    capsys.readouterr()
    try:
        ensure_sequence("walking_static", 5, 20, twin=True, root=tmp_path / "cache")
    except KeyboardInterrupt:
        pass
    assert seen[1].startswith("d2slam: generating walking_static_s5_n20_twin (once; cached in ")
    assert f"(about {round(gen.estimated_seconds(20, 1))} s)" in seen[1]
