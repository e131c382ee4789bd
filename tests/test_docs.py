"""The README and docs/: one screen, runnable example, links that exist, and results pages generated from results/
(never edited by hand: `d2slam docs` reproduces them byte for byte)."""

from __future__ import annotations

import dataclasses
import re
import shutil
from pathlib import Path

import pytest

from d2slam.cli import main
from d2slam.config import DEFAULT
from d2slam.errors import D2SlamError
from d2slam.study import docs as D

ROOT = Path(__file__).resolve().parent.parent
README = ROOT / "README.md"


def test_readme_is_one_screen_and_its_links_exist():
    text = README.read_text()
    assert len(text.splitlines()) <= 200
    links = re.findall(r"\]\(([^)#]+)\)", text)
    assert "notebooks/quickstart.ipynb" in links and "docs/results.md" in links
    for link in links:
        if not link.startswith("http"):
            assert (ROOT / link).exists(), link
    for doc in ("design", "deviations", "results", "benchmarks"):
        assert (ROOT / "docs" / f"{doc}.md").is_file()


def test_notebooks_have_unique_numbers():
    numbers = [p.name.split("_")[0] for p in (ROOT / "notebooks").glob("[0-9]*.ipynb")]
    assert len(numbers) == len(set(numbers)) > 0


def test_readme_python_example_runs(tmp_path, monkeypatch, capsys):
    code = re.search(r"```python\n(.*?)```", README.read_text(), re.S).group(1)
    exec(compile(code, "README.md", "exec"), {})
    assert re.fullmatch(r"ATE 0\.\d{4} m\n", capsys.readouterr().out)


def test_results_pages_are_generated_from_results():
    """docs/results.md and the README's table are what `d2slam docs` makes of results/ (no hand-copied number)."""
    assert (ROOT / "docs" / "results.md").read_text() == D.results_markdown(ROOT / "results", link="../results")
    assert D.replace_headline(README.read_text(), D.headline_markdown(ROOT / "results")) == README.read_text()


def test_docs_command_writes_both(tmp_path, capsys):
    results = shutil.copytree(ROOT / "results", tmp_path / "res", ignore=shutil.ignore_patterns("runs", "trajectories"))
    readme = tmp_path / "README.md"
    readme.write_text(f"intro\n{D.HEADLINE_START}\nold table\n{D.HEADLINE_END}\nrest\n")
    (tmp_path / "docs").mkdir()
    assert main(["docs", "--results", str(results), "--docs", str(tmp_path / "docs"), "--readme", str(readme)]) == 0
    text = readme.read_text()
    assert text.startswith("intro\n") and text.endswith("rest\n") and "old table" not in text and "`d2slam`" in text
    assert "](../res/plots/ate_bars.png)" in (tmp_path / "docs" / "results.md").read_text()
    readme.write_text("no markers\n")
    with pytest.raises(D2SlamError, match="exactly one"):
        D.replace_headline(readme.read_text(), "table")
    assert main(["docs", "--results", str(tmp_path / "nothing"), "--docs", str(tmp_path / "docs"), "--no-readme"]) == 2


def test_deviations_name_real_config_fields():
    text = (ROOT / "docs" / "deviations.md").read_text()
    sections = {f.name: getattr(DEFAULT, f.name) for f in dataclasses.fields(DEFAULT)}
    named = re.findall(r"`(Engine|Dynamics|Synth|Segmentation)Config\.(\w+)`", text)
    assert len(named) >= 8
    for section, field in named:
        assert hasattr(sections[section.lower()], field), f"{section}Config.{field}"


def test_headline_reads_the_runs_with_loop_closing_on():
    """The README's loop row is the engine's default (loop closing on), not a median over runs with it on and off."""
    import numpy as np

    from d2slam.study import tables as T

    df = T.read_runs_csv(ROOT / "results" / "runs.csv")
    loop = df[(df["scenario"] == "office_loop") & (df["twin"] == 0) & (df["method"] == "none")]
    on = loop[loop["loop_closing"].astype(bool)]["ate_rmse_m"]
    assert len(on) and len(on) < len(loop)
    assert f"| loop (ours) | {np.median(on):.4f} [" in D.headline_markdown(ROOT / "results")



def test_headline_of_a_study_without_loop_closing_keeps_its_runs(tmp_path):
    """A study made before loop closing (its runs read with loop_closing 0) still fills the README's table."""
    from d2slam.study import tables as T

    df = T.read_runs_csv(ROOT / "results" / "runs.csv")
    old = df[df["scenario"] == "walking_xyz"].drop(columns="loop_closing")
    (tmp_path / "old").mkdir()
    old.to_csv(tmp_path / "old" / "runs.csv", index=False)
    ours = D.headline_markdown(ROOT / "results").splitlines()
    assert D.headline_markdown(tmp_path / "old").splitlines()[2] == next(r for r in ours if r.startswith("| w/xyz |"))
