"""Structure of the code base: the import graph of ``sim`` and ``compensation`` (imports for type
checking included) has no cycle, the simulator never imports the learning side, and the sources
cite no document outside the repository."""
from __future__ import annotations

import ast
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("sim", "compensation")


def module_files() -> dict[str, Path]:
    """Every module of the project packages by dotted name (a package by its ``__init__.py``)."""
    modules = {}
    for package in PACKAGES:
        for path in sorted((ROOT / package).rglob("*.py")):
            parts = path.relative_to(ROOT).with_suffix("").parts
            modules[".".join(parts[:-1] if parts[-1] == "__init__" else parts)] = path
    return modules


MODULES = module_files()


def _import_nodes(node: ast.AST):
    """``import`` / ``from … import`` statements anywhere in ``node``: functions and ``if
    TYPE_CHECKING:`` blocks included (a module that needs another's types depends on it)."""
    for child in ast.iter_child_nodes(node):
        if isinstance(child, (ast.Import, ast.ImportFrom)):
            yield child
        yield from _import_nodes(child)


def _project_module(name: str, modules) -> str | None:
    """The longest prefix of dotted ``name`` that is a project module (``sim.io.x`` → ``sim.io``)."""
    parts = name.split(".")
    for end in range(len(parts), 0, -1):
        if (prefix := ".".join(parts[:end])) in modules:
            return prefix
    return None


def imports_of(module: str, source: str, modules, is_package: bool = False) -> set[str]:
    """Project modules that ``module`` imports explicitly.

    ``from pkg import name`` counts as ``pkg.name`` when that is a module, else as ``pkg``; relative
    imports are resolved against ``module``'s package. The implicit import of a module's parent
    packages is not an edge.
    """
    package = module if is_package else module.rpartition(".")[0]
    found = set()
    for node in _import_nodes(ast.parse(source)):
        if isinstance(node, ast.Import):
            targets = [alias.name for alias in node.names]
        else:
            base = node.module or ""
            if node.level:
                anchor = package.split(".")[:len(package.split(".")) - (node.level - 1)]
                base = ".".join(anchor + ([base] if base else []))
            targets = [f"{base}.{alias.name}" if f"{base}.{alias.name}" in modules else base
                       for alias in node.names]
        found |= {t for name in targets if (t := _project_module(name, modules)) and t != module}
    return found


def import_graph() -> dict[str, set[str]]:
    return {name: imports_of(name, path.read_text(), MODULES, path.name == "__init__.py")
            for name, path in MODULES.items()}


def find_cycle(graph: dict[str, set[str]]) -> list[str] | None:
    """One cycle of ``graph`` as [a, b, …, a], or None."""
    state: dict[str, int] = {}  # 1: on the current path, 2: done
    path: list[str] = []

    def visit(node: str) -> list[str] | None:
        state[node] = 1
        path.append(node)
        for nxt in sorted(graph.get(node, ())):
            if state.get(nxt) == 1:
                return path[path.index(nxt):] + [nxt]
            if nxt not in state and (cycle := visit(nxt)):
                return cycle
        path.pop()
        state[node] = 2
        return None

    for start in sorted(graph):
        if start not in state and (cycle := visit(start)):
            return cycle
    return None


def test_import_resolution():
    """The rules of :func:`imports_of` on a made-up module of ``compensation.training``."""
    modules = {"compensation", "compensation.methods", "compensation.methods.base",
               "compensation.training", "compensation.training.config", "compensation.training.loop",
               "sim", "sim.io", "sim.errors"}
    source = """
from __future__ import annotations
import numpy
import sim.io
from typing import TYPE_CHECKING
from compensation.methods import base, METHODS
from .config import make_config
from . import loop
if TYPE_CHECKING:
    from sim.errors import ProcamError
else:
    pass

def late():
    from sim.errors import ProcamError
"""
    assert imports_of("compensation.training.made_up", source, modules) == {
        "sim.io", "compensation.methods.base", "compensation.methods", "compensation.training.config",
        "compensation.training.loop", "sim.errors"}
    typing_only = "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    import sim.io\n"
    assert imports_of("compensation.training.made_up", typing_only, modules) == {"sim.io"}
    assert find_cycle({"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}) == ["a", "b", "c", "a"]
    assert find_cycle({"a": {"b"}, "b": set(), "c": {"a", "b"}}) is None


def test_import_graph_has_no_cycle():
    graph = import_graph()
    assert len(graph) > 20 and "compensation.training.config" in graph["compensation.methods"]
    cycle = find_cycle(graph)
    assert cycle is None, "import cycle: " + " -> ".join(cycle)


def test_sim_does_not_import_compensation():
    graph = import_graph()
    wrong = sorted(f"{a} -> {b}" for a, targets in graph.items() if a.startswith("sim")
                   for b in targets if b.startswith("compensation"))
    assert not wrong, "the simulator imports the learning side: " + ", ".join(wrong)


OUTSIDE_DOCUMENTS = re.compile(r"design\.md|official-compat|\bissues? #?\d", re.IGNORECASE)
"""Citations of documents that are not part of the repository (design notes, issue numbers)."""


@pytest.mark.parametrize("package", PACKAGES)
def test_sources_cite_no_outside_documents(package):
    hits = [f"{path.relative_to(ROOT)}:{i}: {line.strip()}"
            for name, path in MODULES.items() if name.split(".")[0] == package
            for i, line in enumerate(path.read_text().splitlines(), start=1)
            if OUTSIDE_DOCUMENTS.search(line)]
    assert not hits, "cites documents outside the repository:\n" + "\n".join(hits)


FLOORS = {"compensation.scores": 1, "compensation.data": 2, "compensation.training": 3,
          "compensation.methods": 4, "compensation.experiments": 5, "compensation.reports": 6,
          "compensation.demo": 7, "compensation.cli": 8}
"""The floors of ``compensation`` (docs/architecture.md): a module imports only from its own floor
or below."""


def _floor(module: str) -> int | None:
    return next((floor for prefix, floor in FLOORS.items()
                 if module == prefix or module.startswith(prefix + ".")), None)


def test_compensation_imports_only_from_its_floor_or_below():
    graph = import_graph()
    floors = {m: _floor(m) for m in graph if m.startswith("compensation.")}
    assert None not in floors.values(), f"modules on no floor: {[m for m, f in floors.items() if f is None]}"
    upward = sorted(f"{a} -> {b}" for a in floors for b in graph[a] if b in floors and floors[b] > floors[a])
    assert not upward, "imports from a floor above: " + ", ".join(upward)
