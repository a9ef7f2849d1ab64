"""The architecture, checked: the import-linter layer contracts of pyproject.toml, no import
cycles between modules, and no module importing another module's private name."""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
PACKAGES = ("stack", "profiles", "dbc")


def test_import_linter_contracts_are_kept():
    importlinter = pytest.importorskip("importlinter.cli")
    import os

    cwd = os.getcwd()
    os.chdir(ROOT)  # the contracts live in the checkout's pyproject.toml
    try:
        assert importlinter.lint_imports() == 0, "a layer contract is broken: run `lint-imports` for the chain"
    finally:
        os.chdir(cwd)


def _runtime_imports(path: Path, module: str) -> set[str]:
    """Modules of the project this file imports when it runs (TYPE_CHECKING blocks left out)."""
    tree = ast.parse(path.read_text())
    out: set[str] = set()
    skip: set[int] = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.If) and "TYPE_CHECKING" in ast.dump(node.test):
            skip.update(id(n) for n in ast.walk(node))
    pkg = module if path.name == "__init__.py" else module.rpartition(".")[0]
    for node in ast.walk(tree):
        if id(node) in skip:
            continue
        if isinstance(node, ast.Import):
            out.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom):
            base = node.module or ""
            if node.level:
                parts = pkg.split(".")
                parent = ".".join(parts[: len(parts) - node.level + 1])
                base = f"{parent}.{base}" if base else parent
            out.add(base)
            out.update(f"{base}.{a.name}" for a in node.names)
    return {m for m in out if m.split(".")[0] in PACKAGES}


def _modules() -> dict[str, Path]:
    mods = {}
    for pkg in PACKAGES:
        for p in (ROOT / pkg).rglob("*.py"):
            rel = p.relative_to(ROOT).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts.pop()
            mods[".".join(parts)] = p
    return mods


def test_no_import_cycles_between_modules():
    """Tarjan's strongly connected components over module-level imports (imports inside functions
    count too: a cycle through a lazy import is still a knot). A package's __init__ re-exporting
    its children is not a cycle of the children."""
    mods = _modules()
    graph = {
        m: {i for i in _runtime_imports(p, m) if i in mods and i != m and not m.startswith(i + ".")}
        for m, p in mods.items()
    }
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    stack: list[str] = []
    on: set[str] = set()
    cycles: list[list[str]] = []
    counter = [0]

    def strong(v: str) -> None:
        index[v] = low[v] = counter[0]
        counter[0] += 1
        stack.append(v)
        on.add(v)
        for w in graph[v]:
            if w not in index:
                strong(w)
                low[v] = min(low[v], low[w])
            elif w in on:
                low[v] = min(low[v], index[w])
        if low[v] == index[v]:
            comp = []
            while True:
                w = stack.pop()
                on.discard(w)
                comp.append(w)
                if w == v:
                    break
            if len(comp) > 1:
                cycles.append(sorted(comp))

    for m in sorted(graph):
        if m not in index:
            strong(m)
    assert cycles == []


def test_no_module_imports_a_private_name_of_another():
    bad = []
    for m, p in _modules().items():
        tree = ast.parse(p.read_text())
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in PACKAGES:
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        bad.append(f"{m}: from {node.module} import {a.name}")
    assert bad == []


def test_the_engine_objects_keep_every_field_of_theirs_in_a_slot():
    """`Node` and `SimBus` declare their fields as slots (the engine reads them once a frame; an
    instance dict of over 30 keys is read more slowly): a field added in ``__init__`` without its
    slot lands in ``__dict__``, which this catches. Attributes of users' own still work."""
    from stack.bus.sim import SimBus
    from stack.controller.clock import LocalClock

    bus = SimBus(250_000)
    node = bus.node("a", clock=LocalClock(drift_ppm=10))
    bus.node("b").listen(object, print)
    assert vars(bus) == {} and vars(node) == {}
    node.note = "mine"
    assert vars(node) == {"note": "mine"}
