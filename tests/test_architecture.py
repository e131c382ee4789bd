"""The package's shape, read from its source with ``ast``: every folder and top-level module of ``d2slam/`` sits in a
layer of ``CONTRIBUTING.md`` ("Layers") and imports only from its own layer and those below, at the top of a file and
inside functions alike (an upward import fails the check: shown on a copy of the package with one added), with no
import cycle; an import inside a function is one of the few listed here with the start-up cost that justifies it; the
engine (``slam/``) never imports the paper's modules (``dynamics/``); no function is longer than 60 lines (declarative
tables aside) and no dataclass has more than 40 fields."""

from __future__ import annotations

import ast
import re
import shutil
from pathlib import Path

PACKAGE = Path(__file__).resolve().parent.parent / "d2slam"
CONTRIBUTING = PACKAGE.parent / "CONTRIBUTING.md"
MAX_FUNCTION_LINES = 60
MAX_DATACLASS_FIELDS = 40

# Functions longer than MAX_FUNCTION_LINES that are declarative tables, kept as data.
TABLES = {
    "d2slam/synth/textures.py:make_texture": "the room's texture recipes, one branch of drawing calls per kind",
    "d2slam/synth/textures.py:_clothes": "the garments' texture recipes (patterns, prints, face), one branch per kind",
}

# Imports inside functions, each with the start-up cost that keeps it there (measured with `python -X importtime`,
# in a process that has imported the importing module; `d2slam run` never needs them, or needs them only on one path).
IN_FUNCTION_IMPORTS = {
    ("d2slam.baselines._orbslam3_worker", "pyorbslam3"): "ORB-SLAM3 itself: only the worker process loads it; the "
                                                          "parent imports this module for its frame store",
    ("d2slam.bench.engine", "g2opy"): "optional (the g2o comparison): not installed everywhere",
    ("d2slam.bench.engine", "gtsam"): "optional (the GTSAM comparison): not installed everywhere",
    ("d2slam.bench.engine", "gtsam.symbol_shorthand"): "optional, as gtsam",
    ("d2slam.dequantize", "onnx"): "54 ms, on every run that reads the segmenter's assets; only dequantizing needs it",
    ("d2slam.dynamics.depth", "scipy.stats"): "1.9 s; only the depth-edge test needs it, once per process",
    ("d2slam.dynamics.interaction", "scipy.stats"): "0.7 s after scipy.spatial; only the OIM's moving test needs "
                                                    "it (`none` and the runs without the OIM never do)",
    ("d2slam.eval.plots", "matplotlib.figure"): "0.7-1.3 s; `d2slam run` never plots",
    ("d2slam.eval.realism", "scipy.stats"): "1.8 s; only the exposure fit needs it",
    ("d2slam.eval.people_realism", "matplotlib.pyplot"): "0.95 s; only the notebook's figures need it",
    ("d2slam.eval.people_realism", "matplotlib.patches"): "as matplotlib.pyplot (imported with it)",
    ("d2slam.kernel_cache", "numba.core"): "1 s; the commands that only check the caches never compile a kernel",
    ("d2slam.study.executors", "distributed"): "1.6 s, and optional: only a Dask scheduler needs it",
    ("d2slam.study.plots", "matplotlib.figure"): "1.4 s; a study without plots (and --tables-only) never draws",
    ("d2slam.synth.actors", "scipy.ndimage"): "0.13-0.18 s, on every `d2slam run` (which imports the generator's "
                                              "package); only the people's routes need it",
    ("d2slam.synth.bodies", "body_models.anny.numpy"): "0.4 s and the body model's data; only generating people "
                                                       "needs it",
    ("d2slam.synth.bodies", "body_models.anny"): "as body_models.anny.numpy (its posing kernel)",
    ("d2slam.synth.gl", "pyrender"): "the OpenGL platform ($PYOPENGL_PLATFORM) must be set before pyrender is "
                                     "imported, and only rendering needs it",
    ("d2slam.synth.gl", "OpenGL"): "as pyrender",
}

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


def declared_layers(path: Path = CONTRIBUTING) -> list[list[str]]:
    """The layers of ``CONTRIBUTING.md``'s "Layers" section, bottom first: each numbered item's names in backticks
    before its colon."""
    text = path.read_text()
    section = text[text.index("## Layers"):]
    section = section[:section.index("\n## ", 1)] if "\n## " in section[1:] else section
    layers = []
    for line in section.splitlines():
        m = re.match(r"\d+\. (.*)", line)
        if m:
            layers.append(re.findall(r"`([\w.]+)`", m.group(1).split(":")[0]))
    return layers


def part(module: str) -> str:
    """The folder or top-level module of ``d2slam/`` a module belongs to (the package itself: ``d2slam``)."""
    parts = module.split(".")
    return parts[1] if len(parts) > 1 else parts[0]


def upward_imports(graph: dict[str, set[str]], layers: list[list[str]]) -> list[str]:
    """``importer -> imported (layer a < layer b)`` for every import from a lower layer to a higher one. The package's
    own ``__init__`` belongs to the foundation (layer 1)."""
    rank = {name: i for i, names in enumerate(layers) for name in names}
    out = []
    for importer, targets in sorted(graph.items()):
        a = rank.get(part(importer), 0)
        for target in sorted(targets):
            b = rank.get(part(target), 0)
            if b > a:
                out.append(f"{importer} -> {target} (layer {a + 1} < {b + 1})")
    return out


def in_function_imports(root: Path = PACKAGE) -> dict[tuple[str, str], list[str]]:
    """``(module, imported module)`` -> the places (``path:line function``) of every import inside a function."""
    out: dict[tuple[str, str], list[str]] = {}
    for name, path in modules(root).items():
        tree = ast.parse(path.read_text(), str(path))
        for fn in ast.walk(tree):
            if not isinstance(fn, (ast.FunctionDef, ast.AsyncFunctionDef)):
                continue
            for node in ast.walk(fn):
                if isinstance(node, ast.Import):
                    targets = [a.name for a in node.names]
                elif isinstance(node, ast.ImportFrom):
                    targets = [("." * node.level) + (node.module or "")]
                else:
                    continue
                for target in targets:
                    out.setdefault((name, target), []).append(f"{path.relative_to(root.parent)}:{node.lineno} "
                                                              f"{fn.name}")
    return out


def long_functions(paths, limit: int = MAX_FUNCTION_LINES, root: Path = PACKAGE) -> list[str]:
    """``path:name (n lines)`` of every function or method longer than ``limit`` lines (decorators left out)."""
    out = []
    for path in paths:
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > limit:
                    out.append(f"{path.relative_to(root.parent)}:{node.name} ({n} lines)")
    return out


def dataclass_fields(path: Path) -> dict[str, int]:
    """Class name -> its number of fields, for every ``@dataclass`` class of ``path`` (``ClassVar`` left out)."""
    out = {}
    for node in ast.walk(ast.parse(path.read_text(), str(path))):
        if isinstance(node, ast.ClassDef) and any(
                "dataclass" in ast.unparse(d) for d in node.decorator_list):
            out[node.name] = sum(1 for s in node.body if isinstance(s, ast.AnnAssign)
                                 and "ClassVar" not in ast.unparse(s.annotation))
    return out


def test_every_folder_and_module_is_in_one_layer():
    layers = declared_layers()
    names = [n for layer in layers for n in layer]
    assert len(names) == len(set(names)), "a name in two layers"
    parts = {part(m) for m in modules()} - {"d2slam"}
    assert sorted(parts - set(names)) == [], "not in a layer of CONTRIBUTING.md"
    assert sorted(set(names) - parts) == [], "a layer names what does not exist"


def test_imports_point_down():
    assert upward_imports(import_graph(), declared_layers()) == []


def test_a_deliberate_upward_import_fails(tmp_path):
    """The same check on a copy of the package whose engine imports the study inside a function: it is found."""
    copy = tmp_path / "d2slam"
    shutil.copytree(PACKAGE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    engine = copy / "slam" / "engine.py"
    engine.write_text(engine.read_text() + "\n\ndef _upward():\n    from d2slam.study.core import run_study\n\n"
                      "    return run_study\n")
    found = upward_imports(import_graph(copy), declared_layers())
    assert found == ["d2slam.slam.engine -> d2slam.study (layer 3 < 11)",
                     "d2slam.slam.engine -> d2slam.study.core (layer 3 < 11)"]


def test_no_import_cycle():
    assert cycles(import_graph()) == []


def test_imports_inside_functions_are_the_listed_ones():
    found = in_function_imports()
    unlisted = {k: v for k, v in found.items() if k not in IN_FUNCTION_IMPORTS}
    assert unlisted == {}, "move these to the top of their module, or list them with the start-up cost they save"
    assert sorted(set(IN_FUNCTION_IMPORTS) - set(found)) == [], "listed but gone: remove from the list"
    assert not any(m.startswith("d2slam") or m.startswith(".") for _, m in found), "d2slam imports at the top"


def test_the_engine_does_not_import_the_paper_modules():
    graph = import_graph()
    bad = {m: sorted(t for t in targets if t == "d2slam.dynamics" or t.startswith("d2slam.dynamics."))
           for m, targets in graph.items() if m.startswith("d2slam.slam")}
    assert {m: t for m, t in bad.items() if t} == {}


def test_functions_are_short():
    found = long_functions(sorted(PACKAGE.rglob("*.py")))
    assert [f for f in found if f.split(" ")[0] not in TABLES] == []
    assert all(any(f.startswith(name + " ") for f in found) for name in TABLES), "a table is short now: unlist it"


def test_dataclasses_are_small():
    big = {f"{p.relative_to(PACKAGE.parent)}:{cls}": n for p in sorted(PACKAGE.rglob("*.py"))
           for cls, n in dataclass_fields(p).items() if n > MAX_DATACLASS_FIELDS}
    assert big == {}


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
    assert long_functions([pkg / "e.py"], limit=MAX_FUNCTION_LINES + 1, root=pkg) == []
    assert long_functions([pkg / "e.py"], root=pkg) == ["pkg/e.py:g (61 lines)"]
    assert in_function_imports(pkg) == {("pkg.a", "pkg"): ["pkg/a.py:2 f"]}
