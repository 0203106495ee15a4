"""The layers of the house: low modules never import high ones, and no module-level import cycle."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
#: Source folders and the import name each is installed under.
PACKAGES = {"simtest": ROOT / "simtest", "simtest.objects": ROOT / "objects",
            "simtest.generators": ROOT / "generators", "simtest.envs": ROOT / "envs"}
#: Low layers: pure data, geometry, files, metrics and rendering.
LOW = ("simtest.metrics", "simtest.io", "simtest.camera", "simtest.geometry", "simtest.raster", "simtest.render",
       "simtest.errors", "simtest.rng", "simtest.backend")
#: High layers: orchestration, the object library, generation and the env.
HIGH = ("simtest.envs", "simtest.generators", "simtest.eval", "simtest.eval_images", "simtest.eval_tracking",
        "simtest.scoring", "simtest.sweep", "simtest.report",
        "simtest.cli", "simtest.objects", "simtest.benchmarks", "simtest.cells")


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


def _within(name: str, prefixes: tuple[str, ...]) -> bool:
    return any(name == p or name.startswith(p + ".") for p in prefixes)


MODULES = _modules()


@pytest.mark.parametrize("module", sorted(m for m in MODULES if _within(m, LOW)))
def test_low_layers_never_import_high_ones(module):
    bad = sorted(m for m in _imports(MODULES[module], top_level_only=False) if _within(m, HIGH))
    assert not bad, f"{module} imports {bad}"


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
