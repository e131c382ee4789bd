"""Temporary names owned by a process, whole-or-nothing files and folders, and the removal of what killed processes
left behind (never what running processes are writing)."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from d2slam.outputs import remove_stale_temps, replace_dir, stale_temp, staged_dir, staged_file, temp_name, temp_tag


@pytest.fixture(scope="module")
def dead_pid() -> int:
    """The id of a process that has exited."""
    p = subprocess.Popen([sys.executable, "-c", "pass"])
    p.wait()
    return p.pid


def test_temp_names_carry_the_process(tmp_path, dead_pid):
    name = temp_name(tmp_path / "seq").name
    assert name == f"seq.tmp-{os.getpid()}@{temp_tag().split('@')[1]}" and not stale_temp(name)
    host = temp_tag().split("@")[1]
    assert stale_temp(f"seq.tmp-{dead_pid}")  # an older name without host: this host's
    assert stale_temp(f"seq.tmp-{dead_pid}@{host}.old") and stale_temp(f"f.npz.tmp-{dead_pid}@{host}.npz")
    assert stale_temp(f".tmp-{dead_pid}@{host}-k2j_x9.npz")  # the mask cache's mkstemp names
    assert not stale_temp(f"seq.tmp-{dead_pid}@another_host")  # another host's process: not ours to judge
    assert not stale_temp(f".tmp-{dead_pid}abc.npz") and not stale_temp("seq") and not stale_temp("seq.lock")


def test_remove_stale_temps_keeps_the_work_of_running_processes(tmp_path, dead_pid):
    host = temp_tag().split("@")[1]
    dead = [tmp_path / f"a.tmp-{dead_pid}", tmp_path / f"b.tmp-{dead_pid}@{host}",
            tmp_path / f"c.npz.tmp-{dead_pid}@{host}.npz"]
    alive = [tmp_path / f"d.tmp-{os.getpid()}", tmp_path / f"e.tmp-{dead_pid}@another_host", tmp_path / "f.lock",
             tmp_path / "g"]
    for p in dead[:2] + alive[:2] + alive[3:]:
        p.mkdir()
        (p / "rgb.txt").write_text("half")
    dead[2].write_bytes(b"half")
    alive[2].write_text("")
    assert sorted(remove_stale_temps(tmp_path)) == sorted(dead)
    assert not any(p.exists() for p in dead) and all(p.exists() for p in alive)
    assert remove_stale_temps(tmp_path / "missing") == []


def test_staged_dir_is_whole_or_nothing(tmp_path):
    out = tmp_path / "seq"
    with staged_dir(out) as tmp:
        assert tmp.parent == tmp_path and tmp.is_dir() and not out.exists()
        (tmp / "a.txt").write_text("first")
    assert (out / "a.txt").read_text() == "first" and sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    with pytest.raises(KeyboardInterrupt):
        with staged_dir(out) as tmp:
            (tmp / "a.txt").write_text("half")
            raise KeyboardInterrupt
    assert (out / "a.txt").read_text() == "first" and sorted(p.name for p in tmp_path.iterdir()) == ["seq"]
    with staged_dir(out) as tmp:  # a finished one replaces the previous folder entirely
        (tmp / "b.txt").write_text("second")
    assert sorted(p.name for p in out.iterdir()) == ["b.txt"] and sorted(p.name for p in tmp_path.iterdir()) == ["seq"]


def test_replace_dir_puts_the_old_folder_back_when_the_move_fails(tmp_path):
    (tmp_path / "old").mkdir()
    (tmp_path / "old" / "x").write_text("kept")
    with pytest.raises(OSError):
        replace_dir(tmp_path / "missing", tmp_path / "old")
    assert (tmp_path / "old" / "x").read_text() == "kept" and sorted(p.name for p in tmp_path.iterdir()) == ["old"]


def test_staged_file(tmp_path):
    path = tmp_path / "r.json"
    with staged_file(path) as tmp:
        tmp.write_text("{}")
        assert not path.exists()
    assert path.read_text() == "{}"
    with pytest.raises(RuntimeError):
        with staged_file(path) as tmp:
            tmp.write_text("{half")
            raise RuntimeError
    assert path.read_text() == "{}" and sorted(p.name for p in tmp_path.iterdir()) == ["r.json"]
