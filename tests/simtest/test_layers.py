"""The layers of the house (docs/architecture.md): no module imports a higher layer, no module-level import
cycle, no private name imported from another module, and modules and functions of a readable size."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Source folders and the import name each is installed under.
PACKAGES = {"simtest": ROOT / "simtest", "simtest.objects": ROOT / "objects",
            "simtest.generators": ROOT / "generators", "simtest.envs": ROOT / "envs"}
#: Layer of each package or module (the longest matching prefix counts); a module may import its own layer and
#: the ones below, never one above, neither at module level nor lazily inside a function.
LAYERS = {
    # base: errors, seeds, poses, the camera model, config trees, where units of work run
    "simtest.errors": 0, "simtest.rng": 0, "simtest.geometry": 0, "simtest.camera": 0, "simtest.schema": 0,
    "simtest.backend": 0,
    # files, metrics, rendering
    "simtest.io": 1, "simtest.metrics": 1, "simtest.render": 1,
    # what a scene is made of and what happens to finished images
    "simtest.corrupt": 2, "simtest.robot": 2, "simtest.objects": 2, "simtest.materials": 2, "simtest.sensors": 2,
    # generation, training feeds, estimators
    "simtest.generators": 3, "simtest.data": 3, "simtest.estimators": 3,
    # evaluation and the closed loop
    "simtest.evaluation": 4, "simtest.envs": 4,
    # orchestration: sweeps, benchmarks, training (it drives feeds and evaluation), the command line
    "simtest.sweeps": 5, "simtest.benchmarks": 5, "simtest.viz": 5, "simtest.training": 5, "simtest.cli": 6,
    # the Python front door: one function per job over the layers below
    "simtest.api": 6,
}
#: Modules directly under simtest/ (the package face and the base); everything else lives in a package.
MAX_TOP_LEVEL_MODULES = 8
MAX_FILE_LINES = 550
MAX_FUNCTION_LINES = 120


def _modules() -> dict[str, Path]:
    out = {}
    for pkg, folder in PACKAGES.items():
        for path in folder.rglob("*.py"):
            rel = path.relative_to(folder).with_suffix("")
            parts = [p for p in rel.parts if p != "__init__"]
            name = ".".join([pkg, *parts])
            if pkg == "simtest" and parts and parts[0] in ("objects", "generators", "envs"):
                continue
            out[name] = path
    return out


def _imports(path: Path, top_level_only: bool) -> set[str]:
    tree = ast.parse(path.read_text())
    nodes = tree.body if top_level_only else ast.walk(tree)
    out = set()
    for node in nodes:
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m.startswith("simtest")}


def layer(name: str) -> int | None:
    """The layer of a dotted module name (None for the package face ``simtest`` itself)."""
    best = max((p for p in LAYERS if name == p or name.startswith(p + ".")), key=len, default=None)
    return None if best is None else LAYERS[best]


MODULES = _modules()


def test_every_module_has_a_layer():
    assert sorted(m for m in MODULES if layer(m) is None) == ["simtest", "simtest.__main__"]


@pytest.mark.parametrize("module", sorted(m for m in MODULES if layer(m) is not None))
def test_no_upward_import(module):
    own = layer(module)
    bad = sorted(m for m in _imports(MODULES[module], top_level_only=False) if (layer(m) or 0) > own)
    assert not bad, f"{module} (layer {own}) imports higher layers: {bad}"


def test_no_module_level_import_cycle():
    graph = {m: {i for i in _imports(p, top_level_only=True) if i in MODULES and i != m} for m, p in MODULES.items()}
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in graph[m]:
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(n):] + [n]))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def _type_checking_nodes(tree: ast.AST) -> set[int]:
    """ids of the nodes inside ``if TYPE_CHECKING:`` blocks (imports for annotations only, never run)."""
    out: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.unparse(node.test):
            out.update(id(n) for stmt in node.body for n in ast.walk(stmt))
    return out


def _module_of(name: str) -> str | None:
    """The longest prefix of a dotted import name that is one of the modules (``a.b.C`` -> ``a.b``)."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _run_time_graph() -> dict[str, set[str]]:
    """Module -> the modules it imports when run, inside functions too (``TYPE_CHECKING`` blocks excluded; a
    module importing its own parent package is not an edge: the package face re-exports its modules)."""
    graph: dict[str, set[str]] = {}
    for m, path in MODULES.items():
        tree = ast.parse(path.read_text())
        skip = _type_checking_nodes(tree)
        names: set[str] = set()
        for node in ast.walk(tree):
            if id(node) in skip:
                continue
            if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
                names.update(f"{node.module}.{a.name}" for a in node.names)
            elif isinstance(node, ast.Import):
                names.update(a.name for a in node.names)
        deps = {_module_of(n) for n in names if n.startswith("simtest")}
        graph[m] = {d for d in deps if d and d != m and not m.startswith(d + ".")}
    return graph


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """The strongly connected components with more than one module (Tarjan), each sorted."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    out: list[list[str]] = []

    def visit(v: str) -> None:
        index[v] = low[v] = len(index)
        stack.append(v)
        on_stack.add(v)
        for w in sorted(graph[v]):
            if w not in index:
                visit(w)
                low[v] = min(low[v], low[w])
            elif w in on_stack:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on_stack.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                out.append(sorted(comp))

    for v in sorted(graph):
        if v not in index:
            visit(v)
    return out


def test_no_import_cycle_even_inside_functions():
    """A loop hidden in a function-level import is a loop all the same: modules of one layer included, the
    run-time import graph has no cycle (imports for type annotations only do not count)."""
    found = _cycles(_run_time_graph())
    assert not found, "import cycles: " + "; ".join(" <-> ".join(c) for c in found)


def test_no_private_name_imported_from_another_module():
    bad = []
    for m, path in MODULES.items():
        for node in ast.walk(ast.parse(path.read_text())):
            if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("simtest"):
                bad += [f"{m}: from {node.module} import {a.name}" for a in node.names
                        if a.name.startswith("_") and not a.name.startswith("__")]
    assert not bad, bad


def test_top_level_holds_only_the_base():
    top = sorted(p.name for p in (ROOT / "simtest").glob("*.py"))
    assert len(top) <= MAX_TOP_LEVEL_MODULES, top


def test_modules_and_functions_have_a_readable_size():
    long_files, long_functions = [], []
    for m, path in MODULES.items():
        text = path.read_text()
        if len(text.splitlines()) > MAX_FILE_LINES:
            long_files.append(f"{path.relative_to(ROOT)} ({len(text.splitlines())} lines)")
        for node in ast.walk(ast.parse(text)):
            if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
                n = node.end_lineno - node.lineno + 1
                if n > MAX_FUNCTION_LINES:
                    long_functions.append(f"{m}.{node.name} ({n} lines)")
    assert not long_files and not long_functions, (long_files, long_functions)


def test_tests_mirror_the_packages():
    """Every package of simtest/ with tests of its own has them in tests/simtest/<package>/."""
    packages = {p.name for p in (ROOT / "simtest").iterdir() if (p / "__init__.py").is_file()}
    folders = {p.name for p in (ROOT / "tests" / "simtest").iterdir() if p.is_dir() and p.name != "__pycache__"}
    assert folders <= packages, sorted(folders - packages)
