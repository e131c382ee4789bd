"""`d2slam demo` (what `make demo` runs): generates, runs none and d2slam on the sequence and its twin, prints."""

import re

import numpy as np

from d2slam.baselines.vocab import build_tree
from d2slam.cli import main


def test_demo_runs_the_main_job(tmp_path, monkeypatch, capsys, assets_kept):
    monkeypatch.setenv("D2SLAM_CACHE", str(tmp_path))
    # the engine's loop closing reads the ORB vocabulary: a small one here (an empty cache would build the project's)
    desc = np.random.default_rng(0).integers(0, 256, (2000, 32), dtype=np.uint8)
    build_tree(desc, np.arange(2000) // 100, k=6, L=3).save(tmp_path / "voc.txt")
    monkeypatch.setenv("PYORBSLAM3_VOCAB", str(tmp_path / "voc.txt"))
    assert main(["demo", "--frames", "12", "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    assert "12 frames of walking_halfsphere" in out and "static twin" in out
    table = out.split("== 2.")[1]
    assert table.count("none") >= 2 and table.count("d2slam") >= 2  # both methods on the sequence and its twin
    summary = r"^ATE: none \d\.\d{4} m, d2slam \d\.\d{4} m; the static twin without people: none \d\.\d{4} m\.$"
    assert re.search(summary, out, re.M)
    assert len([p for p in (tmp_path / "study" / "sequences").glob("walking_halfsphere_s0_n12*") if p.is_dir()]) == 2
    assert not (tmp_path / "demo" / "walking_halfsphere").exists()  # one sequence cache: the study's
    assert (tmp_path / "demo" / "study" / "runs.csv").is_file() and (tmp_path / "demo" / "study" / "tables.md").is_file()
    # it says where everything went, first and last
    first, last = out.splitlines()[0], out.strip().splitlines()[-2]
    assert first == (f"d2slam demo: sequences into {tmp_path / 'study' / 'sequences'}, results into "
                     f"{tmp_path / 'demo' / 'study'}")
    assert last.startswith(f"Results in {tmp_path / 'demo' / 'study'}: runs.csv, tables.md")


def test_demo_help_says_where_outputs_go(capsys):
    import pytest

    with pytest.raises(SystemExit):
        main(["demo", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "~/.cache/d2slam" in text and "demo/study/" in text and "study/sequences/" in text
