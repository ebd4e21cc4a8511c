"""The layout is the architecture: physics at the bottom (``scaletwin_envs``), analysis above it (``scaling``,
``discrepancy``, neither importing the other), artefacts (``zoo``), the command line on top (``scaletwin``).

Read from the source (no module is imported): every ``import`` counts, whether at module level, inside a function
(a lazy import to keep ``scaletwin --help`` light) or under ``TYPE_CHECKING``, so a circle cannot hide in any of
them.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LAYERS = {"scaletwin_envs": 0, "scaling": 1, "discrepancy": 1, "zoo": 2, "scaletwin": 3}


def _modules() -> dict[str, Path]:
    mods = {}
    for package in LAYERS:
        for path in (ROOT / package).rglob("*.py"):
            parts = list(path.relative_to(ROOT).with_suffix("").parts)
            if parts[-1] == "__init__":
                parts.pop()
            mods[".".join(parts)] = path
    return mods


MODULES = _modules()


def _owner(name: str) -> str | None:
    """The project module ``name`` (a module, or a name inside one) resolves to; None outside the project."""
    while name and name not in MODULES:
        name = name.rpartition(".")[0]
    return name or None


def _imports(module: str) -> set[str]:
    """The project modules ``module`` imports anywhere in its source (itself and its own package excluded)."""
    tree = ast.parse(MODULES[module].read_text(), filename=str(MODULES[module]))
    found: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            names = [a.name for a in node.names]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names = [f"{node.module}.{a.name}" for a in node.names]
        else:
            continue
        found.update(t for n in names if (t := _owner(n)) is not None and not module.startswith(t))
    return found


GRAPH = {m: _imports(m) for m in MODULES}


def _cycles(graph: dict[str, set[str]]) -> list[list[str]]:
    """Strongly connected components with more than one module (Tarjan's algorithm, iterative)."""
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()
    found: list[list[str]] = []
    for root in sorted(graph):
        if root in index:
            continue
        work = [(root, iter(sorted(graph[root])))]
        index[root] = low[root] = len(index)
        stack.append(root)
        on_stack.add(root)
        while work:
            v, edges = work[-1]
            w = next(edges, None)
            if w is not None:
                if w not in index:
                    index[w] = low[w] = len(index)
                    stack.append(w)
                    on_stack.add(w)
                    work.append((w, iter(sorted(graph.get(w, ())))))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
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
    return found


def test_the_scan_sees_the_project() -> None:
    assert len(MODULES) > 100
    assert "scaletwin_envs.specs.loader" in GRAPH["scaletwin_envs.specs.machines"]
    # a function-level import is seen (the command line imports lazily to keep --help light)
    assert "scaling.runs.pipeline" in GRAPH["scaletwin.cli.fit"]


def test_the_cycle_finder_finds_a_hidden_circle() -> None:
    graph = {"a": {"b"}, "b": {"c"}, "c": {"a"}, "d": {"a"}}
    assert _cycles(graph) == [["a", "b", "c"]]
    assert _cycles({"a": {"b"}, "b": set()}) == []


def test_no_import_circle_anywhere() -> None:
    circles = _cycles(GRAPH)
    detail = ["; ".join(f"{a} -> {b}" for a in c for b in sorted(GRAPH[a]) if b in c) for c in circles]
    assert not circles, "import circles:\n" + "\n".join(detail)


@pytest.mark.parametrize("package", sorted(LAYERS))
def test_no_import_runs_upward_or_sideways(package: str) -> None:
    bad = sorted(f"{m} -> {t}" for m, targets in GRAPH.items() if m.split(".")[0] == package for t in targets
                 if t.split(".")[0] != package and LAYERS[t.split(".")[0]] >= LAYERS[package])
    assert not bad, f"{package} (layer {LAYERS[package]}) imports a package at its own layer or above: {bad}"


#: ``scaling``'s stages in the order data flows (README): no stage imports a later one.
SCALING_STAGES = ("dimensions", "data", "models", "evaluation", "runs")


def test_scaling_stages_import_only_earlier_ones() -> None:
    def stage(module: str) -> int | None:
        parts = module.split(".")
        return SCALING_STAGES.index(parts[1]) if len(parts) > 1 and parts[1] in SCALING_STAGES else None

    bad = sorted(f"{m} -> {t}" for m, targets in GRAPH.items() if m.startswith("scaling.") for t in targets
                 if (a := stage(m)) is not None and (b := stage(t)) is not None and b > a)
    assert not bad, f"a stage of scaling imports a later one: {bad}"
