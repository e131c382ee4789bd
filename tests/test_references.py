"""Every reference a reader can follow resolves inside the repository: relative markdown links, and paths to
documents (``docs/design.md#geometric-module-eq-4-6``, ``README.md``, ``notebooks/03_geometric.ipynb``), in
``d2slam/`` (comments and docstrings), ``docs/``, ``notebooks/``, ``README.md`` and ``CONTRIBUTING.md``.

A reference resolves when it names a file (or folder) of the repository, relative to the referring file or to the
repository's root, and, when it carries ``#anchor``, a heading of that document whose anchor is ``anchor``, computed
as GitHub does (:func:`github_anchor`). Nothing may point outside the repository (``../shared/``: a user's clone has
no such folder). Checked: markdown links ``[text](target)`` in markdown (``.md`` files, notebooks' markdown cells)
and path-like references anywhere in those texts (a repository folder followed by a document, ``docs/x.md``; a
root document in capitals, ``README.md``; a document named through ``../``). Folders named in prose (the shared
assets folder ``../shared`` beside a checkout, looked up by ``d2slam.assets``) are places, not references. A bare
lowercase file name in prose (``tables.md``, a file the study writes) names an output, not a document of the
repository, and is not checked.
"""

from __future__ import annotations

import ast
import io
import json
import re
import tokenize
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
TOP_FOLDERS = ("docs", "notebooks", "d2slam", "data", "results", "tests")
# a document's file name; a source file named in capitals (d2slam/commands/NAME.py) is a placeholder
DOC = r"(?:[\w.-]+\.(?:md|ipynb)|[\w.-]*[a-z0-9][\w.-]*\.(?:tex|txt|csv|py|json|yaml))"
PATH_REF = re.compile(
    r"(?<![\w/.{}$-])"  # not the tail of a longer path, URL or f-string expression
    rf"((?:\.\./)+(?:[\w.-]+/)*{DOC}"  # a document outside the referring folder
    rf"|(?:{'|'.join(TOP_FOLDERS)})/(?:[\w.-]+/)*{DOC}"  # a document under a repository folder
    r"|[A-Z][A-Z_]*\.md)"  # a root document: README.md, CONTRIBUTING.md
    r"(?:#([\w-]+))?")
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^(```|~~~).*?^\1", re.S | re.M)
HEADING = re.compile(r"^ {0,3}(#{1,6})\s+(.*?)\s*#*\s*$", re.M)


def github_anchor(heading: str) -> str:
    """The anchor GitHub gives a markdown heading: its text (code spans and links reduced to their text) in
    lowercase, punctuation dropped (letters, digits, '_', '-' and spaces stay), spaces turned into '-'."""
    text = re.sub(r"`([^`]*)`", r"\1", heading)
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", text)
    text = re.sub(r"[^\w\- ]", "", text.strip().lower())
    return text.replace(" ", "-")


def anchors(markdown: str) -> set[str]:
    """The anchors of every heading of a markdown text; a repeated heading gets -1, -2, ... as on GitHub."""
    out: set[str] = set()
    seen: dict[str, int] = {}
    for _, heading in HEADING.findall(FENCE.sub("", markdown)):
        base = github_anchor(heading)
        n = seen.get(base, 0)
        seen[base] = n + 1
        out.add(base if n == 0 else f"{base}-{n}")
    return out


def markdown_of(path: Path) -> str:
    """The markdown a reader sees in ``path``: a .md file, or a notebook's markdown cells."""
    if path.suffix == ".ipynb":
        nb = json.loads(path.read_text())
        return "\n\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "markdown")
    return path.read_text()


def python_prose(path: Path) -> str:
    """The comments and docstrings of a Python file (its code strings are code, not references)."""
    src = path.read_text()
    parts = [tok.string for tok in tokenize.generate_tokens(io.StringIO(src).readline) if tok.type == tokenize.COMMENT]
    for node in ast.walk(ast.parse(src)):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)):
            doc = ast.get_docstring(node, clean=False)
            if doc:
                parts.append(doc)
    return "\n".join(parts)


def texts() -> list[tuple[Path, str, bool]]:
    """(file, text, is markdown) of every text whose references are checked."""
    out = [(p, python_prose(p), False) for p in sorted((ROOT / "d2slam").rglob("*.py"))]
    out += [(p, p.read_text(), True) for p in sorted((ROOT / "docs").rglob("*.md"))]
    out += [(ROOT / name, (ROOT / name).read_text(), True) for name in ("README.md", "CONTRIBUTING.md")]
    for p in sorted((ROOT / "notebooks").glob("*.ipynb")):
        nb = json.loads(p.read_text())
        out.append((p, markdown_of(p), True))
        out.append((p, "\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code"), False))
    return out


def references(text: str, markdown: bool) -> list[str]:
    refs = []
    if markdown:
        for target in LINK.findall(text):
            if not re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto: are not ours to check
                refs.append(target)
    for m in PATH_REF.finditer(LINK.sub(" ", text) if markdown else text):
        refs.append(m.group(0))
    return refs


def problem(source: Path, ref: str) -> str | None:
    """Why ``ref`` (as written in ``source``) does not resolve, or None when it does."""
    path, _, anchor = ref.partition("#")
    if not path:
        target = source
    else:
        candidates = [(source.parent / path).resolve(), (ROOT / path).resolve()]
        found = [c for c in candidates if c.exists()]
        if not found:
            return "no such file in the repository"
        target = found[0]
        if not target.is_relative_to(ROOT):
            return "outside the repository"
    if anchor:
        if target.suffix not in (".md", ".ipynb"):
            return f"an anchor into {target.suffix or 'a folder'}"
        if anchor not in anchors(markdown_of(target)):
            return f"no heading with the anchor #{anchor} in {target.relative_to(ROOT)}"
    return None


def test_github_anchor():
    assert github_anchor("Semantic module (eq 1-2)") == "semantic-module-eq-1-2"
    assert github_anchor("Unmatched keypoints take their neighbours' P_g") == \
        "unmatched-keypoints-take-their-neighbours-p_g"
    assert github_anchor("The `oracle`: a ceiling, not a method") == "the-oracle-a-ceiling-not-a-method"
    assert github_anchor("Équation 5, α(z)") == "équation-5-αz"
    assert anchors("# A\n## A\n```\n# not a heading\n```\n### A b #\n") == {"a", "a-1", "a-b"}


def test_reference_checker_finds_broken_ones(tmp_path):
    text = ("see DESIGN.md section 1, ../shared/DESIGN.md, docs/design.md#no-such-heading, "
            "[x](docs/nothing.md), docs/design.md#semantic-module-eq-1-2, [ok](README.md), OUT/tables.md, "
            "d2slam/commands/NAME.py, $D2SLAM_SHARED (default ../shared)")
    refs = references(text, markdown=True)
    assert refs == ["docs/nothing.md", "README.md", "DESIGN.md", "../shared/DESIGN.md",
                    "docs/design.md#no-such-heading", "docs/design.md#semantic-module-eq-1-2"]
    verdicts = [problem(ROOT / "README.md", r) for r in refs]
    assert verdicts[0] == verdicts[2] == "no such file in the repository" and verdicts[1] is None
    if (ROOT.parent / "shared" / "DESIGN.md").exists():
        assert verdicts[3] == "outside the repository"
    else:
        assert verdicts[3] == "no such file in the repository"
    assert verdicts[4].startswith("no heading") and verdicts[5] is None


TEXTS = texts()


@pytest.mark.parametrize("source,text,markdown", TEXTS,
                         ids=[f"{p.relative_to(ROOT).as_posix()}:{'text' if md else 'code'}" for p, _, md in TEXTS])
def test_references_resolve(source, text, markdown):
    bad = [f"{ref}: {why}" for ref in references(text, markdown) if (why := problem(source, ref))]
    assert not bad, f"{source.relative_to(ROOT)}: " + "; ".join(bad)
