"""The estimators, the evaluation and the trainers import each other without a loop, counting imports inside
functions too (the layer test checks module-level cycles only): shared pieces sit where every network reaches
them, and segicp composes its network with icp's fit without icp importing segicp."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]
PACKAGES = ("simtest.estimators", "simtest.evaluation", "simtest.training")


def _modules() -> dict[str, Path]:
    out = {}
    for path in (ROOT / "simtest").rglob("*.py"):
        parts = [p for p in path.relative_to(ROOT).with_suffix("").parts if p != "__init__"]
        out[".".join(parts)] = path
    return out


MODULES = _modules()


def _imports(path: Path) -> set[str]:
    """Every simtest module ``path`` imports, at module level or in a function."""
    out = set()
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            out.add(node.module)
            out.update(f"{node.module}.{a.name}" for a in node.names)
        elif isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
    return {m for m in out if m in MODULES}


def _graph() -> dict[str, set[str]]:
    mine = {m for m in MODULES if m.startswith(PACKAGES)}
    return {m: {i for i in _imports(MODULES[m]) if i in mine and i != m} for m in mine}


def test_no_import_cycle_counting_function_level_imports():
    graph = _graph()
    state: dict[str, int] = {}
    stack: list[str] = []

    def visit(m: str) -> None:
        state[m] = 1
        stack.append(m)
        for n in sorted(graph[m]):
            if state.get(n) == 1:
                raise AssertionError("import cycle: " + " -> ".join(stack[stack.index(n):] + [n]))
            if n not in state:
                visit(n)
        stack.pop()
        state[m] = 2

    for m in sorted(graph):
        if m not in state:
            visit(m)


def test_icp_knows_no_network_and_networks_share_no_trainer():
    graph = _graph()
    assert not {m for m in graph["simtest.estimators.icp"] if m.startswith("simtest.estimators.segicp")}
    for m, deps in graph.items():
        if m.startswith("simtest.estimators.segicp"):
            assert not {d for d in deps if d.startswith("simtest.estimators.keypoints")}, m
        if m.startswith(("simtest.estimators", "simtest.evaluation")):
            assert not {d for d in deps if d.startswith("simtest.training")}, m
