"""What a result depends on, as short digests: the code that computed it (:func:`source_digest`, comments and
docstrings left out), the synthetic generator that made its sequence (``d2slam.synth.version``) and any canonical
JSON description (:func:`digest`). The study keys its runs, sequences and feature files with them; the vocabulary
builder keys its training frames with the generator version."""

from __future__ import annotations

import ast
import hashlib
import json
import threading
from functools import lru_cache
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent

# CPython 3.11's AST constructor keeps its recursion count per interpreter, not per thread: two threads parsing at
# once, with a thread switch inside the construction (a study's runs keyed in one dask worker's two threads), fail
# with "SystemError: AST constructor recursion depth mismatch". Parsing is serialised.
_PARSE = threading.Lock()


def code_text(source: str) -> str:
    """What a Python file *does*, without its comments and docstrings: ``ast.dump`` of the parsed module with every
    module, class and function docstring removed (``ast.dump`` leaves out line numbers, so layout does not count
    either). Used for the run keys: a documentation fix keeps the committed study resumable."""
    with _PARSE:
        tree = ast.parse(source)
    for node in ast.walk(tree):
        if isinstance(node, (ast.Module, ast.ClassDef, ast.FunctionDef, ast.AsyncFunctionDef)) and node.body:
            first = node.body[0]
            if isinstance(first, ast.Expr) and isinstance(first.value, ast.Constant) \
                    and isinstance(first.value.value, str):
                node.body = node.body[1:] or [ast.Pass()]
    return ast.dump(tree)


@lru_cache(maxsize=8)
def source_digest(parts: tuple) -> str:
    """sha256 (16 hex) of the package source files under ``parts`` (folders or files of ``d2slam/``), each read as
    ``code_text`` (comments, docstrings and layout do not count)."""
    h = hashlib.sha256()
    for part in parts:
        p = PACKAGE / part
        files = sorted(p.rglob("*.py")) if p.is_dir() else [p]
        for f in files:
            if f.is_file():
                h.update(str(f.relative_to(PACKAGE)).encode())
                h.update(code_text(f.read_text(encoding="utf-8")).encode())
    return h.hexdigest()[:16]


def digest(ident: dict) -> str:
    """16 hex digits of sha256 over the canonical JSON of ``ident``."""
    return hashlib.sha256(json.dumps(ident, sort_keys=True, default=str).encode()).hexdigest()[:16]
