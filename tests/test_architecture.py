"""The package's shape, read from its source with ``ast``: no import cycle among the modules of ``d2slam/`` (imports
at the top or inside functions alike), the engine (``slam/``) never imports the paper's modules (``dynamics/``), and
no function of ``slam/`` or ``dynamics/`` is longer than 80 lines."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

PACKAGE = Path(__file__).resolve().parent.parent / "d2slam"
MAX_FUNCTION_LINES = 80


def module_name(path: Path, root: Path = PACKAGE) -> str:
    parts = (root.name,) + path.relative_to(root).with_suffix("").parts
    return ".".join(parts[:-1] if parts[-1] == "__init__" else parts)


def modules(root: Path = PACKAGE) -> dict[str, Path]:
    return {module_name(p, root): p for p in sorted(root.rglob("*.py"))}


def _is_package(name: str, known: dict[str, Path]) -> bool:
    return name in known and known[name].name == "__init__.py"


def _imported(node: ast.AST, importer: str, known: dict[str, Path]) -> list[str]:
    """The modules of ``known`` that an import statement names: ``import a.b`` names ``a.b``; ``from a.b import c``
    names ``a.b.c`` when ``c`` is a module, and ``a.b`` when ``c`` is a name defined there. Relative imports are
    resolved against ``importer``."""
    if isinstance(node, ast.Import):
        return [a.name for a in node.names if a.name in known]
    base = node.module or ""
    if node.level:
        pkg = importer if _is_package(importer, known) else importer.rpartition(".")[0]
        for _ in range(node.level - 1):
            pkg = pkg.rpartition(".")[0]
        base = f"{pkg}.{base}" if base else pkg
    submodules = [f"{base}.{a.name}" for a in node.names if f"{base}.{a.name}" in known]
    names_there = len(submodules) < len(node.names)
    return ([base] if base in known and names_there else []) + submodules


def import_graph(root: Path = PACKAGE) -> dict[str, set[str]]:
    """Module -> the modules it imports, anywhere in its code. Importing ``a.b.c`` runs the ``__init__`` of ``a`` and
    ``a.b`` first, so those packages count as imported too, except the importer's own enclosing packages (already
    being initialised when it runs)."""
    known = modules(root)
    graph: dict[str, set[str]] = {}
    for name, path in known.items():
        enclosing = {name.rsplit(".", k)[0] for k in range(1, name.count(".") + 1)}
        if _is_package(name, known):
            enclosing.add(name)
        out: set[str] = set()
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.Import, ast.ImportFrom)):
                for target in _imported(node, name, known):
                    out.add(target)
                    parts = target.split(".")
                    out.update(p for p in (".".join(parts[:k]) for k in range(1, len(parts)))
                               if p in known and p not in enclosing)
        out.discard(name)
        graph[name] = out
    return graph


def cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph.get(v, ())):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            component = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                component.append(w)
                if w == v:
                    break
            if len(component) > 1:
                found.append(sorted(component))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return found


def long_functions(paths, limit: int = MAX_FUNCTION_LINES) -> list[str]:
    """``path:line name (n lines)`` of every function or method longer than ``limit`` lines (decorators left out)."""
    out = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    out.append(f"{path.relative_to(PACKAGE.parent)}:{node.lineno} {node.name} ({n} lines)")
    return out


def test_no_import_cycle():
    assert cycles(import_graph()) == []


def test_the_engine_does_not_import_the_paper_modules():
    graph = import_graph()
    bad = {m: sorted(t for t in targets if t == "d2slam.dynamics" or t.startswith("d2slam.dynamics."))
           for m, targets in graph.items() if m.startswith("d2slam.slam")}
    assert {m: t for m, t in bad.items() if t} == {}


def test_engine_and_dynamics_functions_are_short():
    paths = sorted((PACKAGE / "slam").glob("*.py")) + sorted((PACKAGE / "dynamics").glob("*.py"))
    assert long_functions(paths) == []


def _write(root: Path, files: dict[str, str]) -> Path:
    for rel, text in files.items():
        path = root / "pkg" / rel
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(text)
    return root / "pkg"


def test_the_checks_see_cycles_through_functions_packages_and_relative_imports(tmp_path):
    pkg = _write(tmp_path, {
        "__init__.py": "",
        "a.py": "def f():\n    from pkg import b\n",
        "b.py": "from .sub.c import x\n",
        "sub/__init__.py": "from pkg.a import f\n",
        "sub/c.py": "from pkg.sub import d\n",
        "sub/d.py": "from pkg.sub import c, y\n",
        "d.py": "import pkg.sub.c\n",
        "e.py": "def g():\n" + "    pass\n" * MAX_FUNCTION_LINES,
    })
    graph = import_graph(pkg)
    assert graph["pkg.b"] == {"pkg.sub", "pkg.sub.c"} and graph["pkg.d"] == {"pkg.sub", "pkg.sub.c"}
    assert graph["pkg.sub.c"] == {"pkg.sub.d"}  # its own package, entered already, is no import ...
    assert graph["pkg.sub.d"] == {"pkg.sub", "pkg.sub.c"}  # ... unless a name defined there is imported
    assert cycles(graph) == [["pkg.a", "pkg.b", "pkg.sub", "pkg.sub.c", "pkg.sub.d"]]
    assert long_functions([pkg / "e.py"], limit=MAX_FUNCTION_LINES + 1) == []
    with pytest.raises(ValueError):  # outside d2slam/: the report names paths relative to it
        long_functions([pkg / "e.py"])
