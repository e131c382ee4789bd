"""The notebooks' prose carries no figure of its own: a number a notebook computes reaches its text only through an
output cell (``display(Markdown(f"..."))`` after the computation), so that text and numbers cannot disagree after a
re-execution (nbval compares outputs, never markdown).

A *figure* in a markdown cell is a number with a decimal point (``0.908``), a percentage (``11 %``), a number with a
unit (``4.6 mm``, ``22 px``, ``3 ms``, ``1.2x``), a count ``N of M`` (``421 of 2785``) or a number of counted things
(``785 flips``, ``8 people``, ``30 frames``). A bare integer (eq 7, seed 101, notebook 03, frame 12) names something
and is no figure; code spans and fenced code are code. Every figure must be

- quoted with its source in the same sentence: the paper (``(paper, eq 2)``, ``(paper, Table 1)``), another paper
  (``Nguyen et al. 2012``), a published value (``[published: ...]``), or a document of this repository that records
  the measurement with its command (``docs/deviations.md#...``, ``data/paper_tables.csv``); or
- inside a definition listed in ``DEFINITIONS`` for its notebook, with the reason: an equation's constant, a config
  default, a file format, the setting of a committed study.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
NOTEBOOKS = sorted((ROOT / "notebooks").glob("*.ipynb"))

# Definitions a notebook may state in its prose: the snippet (as in a markdown cell, line breaks as spaces) -> why it
# is no measurement.
DEFINITIONS: dict[str, dict[str, str]] = {
    "11_online.ipynb": {
        "online at 30 Hz": "the rate the notebook sets (AT_30HZ: online.rate_hz), the issue's Kinect rate",
        "Online runs at 30 Hz": "the same rate, as a heading",
    },
    "01_data.ipynb": {
        "within 0.02 s (TUM's `associate.py`)": "the TUM association tolerance (DataConfig.max_dt)",
        "motion capture at 100 Hz": "the TUM RGB-D ground-truth format",
    },
    "02_semantic.ipynb": {
        "then 90 % of the true edge": "what p90 means (SynthEvalConfig.seg_eval_boundary_percentile)",
    },
    "06_slam_engine.ipynb": {
        "with 0.02 s association": "TUM's evaluate_ate.py association (DataConfig.max_dt)",
    },
    "07_ablations.ipynb": {
        "0.02 s association (TUM `evaluate_ate.py` convention)":
            "TUM's evaluate_ate.py association (DataConfig.max_dt)",
    },
    "quickstart.ipynb": {
        "Python 3.11": "the Python version the set-up is made for (README.md)",
    },
}

FENCE = re.compile(r"^(```|~~~).*?^\1[^\n]*$", re.S | re.M)
CODE_SPAN = re.compile(r"(`+)(?:(?!\1).)+?\1")
LINK_URL = re.compile(r"\]\([^)]*\)")
NUMBER = re.compile(r"(?<![\w.])\d+(?:[.,]\d+)*")
_N = r"\d+(?:\.\d+)?"
_RANGE = rf"(?:\s?[-–]\s?{_N})?"
UNITS = r"(?:mm|cm|m|km|px|ms|s|min|h|Hz|fps|deg|°|GB|MB|kB|frames/s)"
COUNTED = (r"(?:keypoints?|flips?|people|persons?|matches|runs?|masks?|tracks?|hits?|pixels?|frames?|seeds|repeats|"
           r"observations?|sequences)")
AFTER = re.compile(
    rf"{_RANGE}(?:\s?%"  # 11 %, 8-23 %
    rf"|\s?{UNITS}(?![\w/])"  # 4.6 mm, 22 px, 3 ms
    r"|[x×](?![\w])"  # 1.2x, 5x (a ratio; 640x480 is a size)
    r"|\s+of\s+(?:the\s+)?\d"  # 421 of 2785
    rf"|\s+(?:[a-z-]+\s+)?{COUNTED}\b)")  # 785 flips, 12 walking runs
OF_BEFORE = re.compile(r"\d\s+of\s+(?:the\s+)?$")
SOURCE = re.compile(r"\(paper[,)]|\[published: |\bet al\.? \d{4}|\b(?:docs/[\w.-]+\.md|data/[\w.-]+\.csv)")
SENTENCE_END = re.compile(r"(?<!\bal\.)(?<!e\.g\.)(?<!i\.e\.)(?<=[.!?])\s+(?=[A-Z(\[*$`])")


def units(markdown: str) -> list[str]:
    """The sentences of a markdown cell: fenced code dropped; headings, list items and table rows apart; paragraphs
    split after '.', '!' or '?' followed by a capital or an opening mark."""
    out = []
    for block in re.split(r"\n\s*\n", FENCE.sub("", markdown)):
        items, cur = [], []
        for line in block.splitlines():
            if re.match(r"\s*(?:[-*+] |\d+\. |\||#)", line) and cur:
                items.append(" ".join(cur))
                cur = []
            cur.append(line.strip())
        if cur:
            items.append(" ".join(cur))
        for item in items:
            out += [s for s in SENTENCE_END.split(item) if s.strip()]
    return out


def figures(sentence: str) -> list[tuple[int, str]]:
    """(position, text) of each figure of a sentence (outside code spans and link targets)."""
    skip = [m.span() for m in CODE_SPAN.finditer(sentence)] + [m.span() for m in LINK_URL.finditer(sentence)]
    out = []
    for m in NUMBER.finditer(sentence):
        if any(a <= m.start() < b for a, b in skip):
            continue
        decimal = "." in m.group(0)
        if decimal or AFTER.match(sentence, m.end()) or OF_BEFORE.search(sentence[:m.start()]):
            out.append((m.start(), m.group(0)))
    return out


def unsourced(sentence: str, definitions: dict[str, str]) -> list[str]:
    """The figures of ``sentence`` that are neither quoted with a source nor inside one of ``definitions``."""
    if SOURCE.search(sentence):
        return []
    allowed = [(m.start(), m.end()) for d in definitions for m in re.finditer(re.escape(d), sentence)]
    return [f for pos, f in figures(sentence) if not any(a <= pos < b for a, b in allowed)]


def markdown_cells(path: Path) -> list[str]:
    return ["".join(c["source"]) for c in json.loads(path.read_text())["cells"] if c["cell_type"] == "markdown"]


def test_figures_are_found():
    text = ("Recall 0.908 -> 0.942; 421 of 2785 flags on dynamic truth. Only 11 % were, 4.6 mm and 22 px. "
            "On seeds 3-5 (300 frames) the OIM made 785 flips and 12 walking runs met it, 1.2x its twin. "
            "Eq 7, seed 101, notebook 03, frame 12, people 1..2, `p_g_exceed` 0.7 and `0.5`; a 640x480 image.")
    found = [f for s in units(text) for _, f in figures(s)]
    assert found == ["0.908", "0.942", "421", "2785", "11", "4.6", "22", "300", "785", "12", "1.2", "0.7"]


def test_sources_and_definitions_pass():
    assert unsourced("The paper's range is [0.05, 0.25] (paper, eq 2).", {}) == []
    assert unsourced("sigma(z) = 0.0012 + 0.0019 (z - 0.4)^2 m (Nguyen et al. 2012).", {}) == []
    assert unsourced("It lowered the ATE on 13 of 15 runs (docs/deviations.md#feature-budget-with-a-filter).", {}) == []
    assert unsourced("The band is 22 px near.", {}) == ["22"]
    assert unsourced("with z_far = 4.5 m, the range.", {"z_far = 4.5 m": "the Kinect range (DynamicsConfig)"}) == []
    assert unsourced("far at 4.5 m.", {"z_far = 4.5 m": "..."}) == ["4.5"]


def test_units_split_sentences_items_and_rows():
    text = "A first one. B second (Nguyen et al. 2012) e.g. here.\n\n- item 0.5\n- item 2\n\n| a | 0.1 |\n| b | 2 |"
    assert units(text) == ["A first one.", "B second (Nguyen et al. 2012) e.g. here.", "- item 0.5", "- item 2",
                           "| a | 0.1 |", "| b | 2 |"]


def test_definitions_are_used():
    """Every listed definition still occurs in its notebook (a stale entry would hide a figure elsewhere)."""
    for name, defs in DEFINITIONS.items():
        text = " ".join(" ".join(markdown_cells(ROOT / "notebooks" / name)).split())  # as sentences are joined
        assert all(reason for reason in defs.values()), name
        missing = [d for d in defs if d not in text]
        assert not missing, f"{name}: definitions no longer in its markdown: {missing}"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=[p.name for p in NOTEBOOKS])
def test_markdown_figures_are_sourced_or_defined(path):
    defs = DEFINITIONS.get(path.name, {})
    bad = []
    for cell in markdown_cells(path):
        for sentence in units(cell):
            if found := unsourced(sentence, defs):
                bad.append(f"{', '.join(found)} in: {sentence[:160]}")
    assert not bad, (f"{path.name}: figures in markdown without a source or a definition (print them from code, "
                     "quote them with their source, or list the definition in DEFINITIONS):\n" + "\n".join(bad))
