"""The architecture, checked: the import-linter contracts of pyproject.toml (the layers, and the
sans-IO core without python-can), no import cycles between modules, and no module importing
another module's private name or reading a private attribute of another module's object."""

from __future__ import annotations

import ast
import functools
import shutil
import subprocess
import sys
import textwrap
from collections.abc import Collection, Iterable
from pathlib import Path

import pytest

try:
    import tomllib
except ModuleNotFoundError:  # Python 3.10
    import tomli as tomllib

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


SANS_IO_CORE = ("stack.wire", "stack.controller", "stack.bus")


def _contract(name_part: str) -> dict:
    config = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["importlinter"]
    found = [c for c in config["contracts"] if name_part in c["name"]]
    assert len(found) == 1, f"one contract named '...{name_part}...' in pyproject.toml"
    return {**found[0], "include_external_packages": config.get("include_external_packages", False)}


@pytest.mark.subprocess
def test_the_sans_io_core_is_forbidden_python_can_and_the_contract_bites(tmp_path):
    """The contract names the three layers and python-can, external packages are in the graph
    (else import-linter cannot see `can` at all), and it breaks when one module of the core
    imports python-can: checked on a copy of the packages with such an import added."""
    contract = _contract("does not import python-can")
    assert contract["type"] == "forbidden" and contract["include_external_packages"] is True
    assert set(contract["source_modules"]) == set(SANS_IO_CORE) and contract["forbidden_modules"] == ["can"]
    for pkg in PACKAGES:
        shutil.copytree(ROOT / pkg, tmp_path / pkg, ignore=shutil.ignore_patterns("__pycache__"))
    shutil.copy(ROOT / "pyproject.toml", tmp_path)
    events = tmp_path / "stack" / "controller" / "events.py"
    events.write_text(events.read_text() + "\nimport can  # the break under test\n")
    out = subprocess.run(
        [sys.executable, "-c", "import sys; from importlinter.cli import lint_imports; sys.exit(lint_imports())"],
        cwd=tmp_path,  # the copy is the first on sys.path, before the installed checkout
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert out.returncode == 1, out.stdout[-2000:] + out.stderr[-2000:]
    assert "stack.controller is not allowed to import can" in out.stdout
    assert "stack.controller.events -> can" in out.stdout


CORE_WITHOUT_PYTHON_CAN = """
import importlib, pkgutil, sys
from types import SimpleNamespace

sys.modules["can"] = None  # `import can` raises ImportError from here on
for name in {core!r}:
    package = importlib.import_module(name)
    for info in pkgutil.walk_packages(package.__path__, name + "."):
        importlib.import_module(info.name)

from stack.bus.faults import FaultInjector
from stack.bus.sim import SimBus
from stack.wire.frame import Frame

bus = SimBus(500_000, seed=1, record=True)
engine, body, dash = bus.node("engine"), bus.node("body"), bus.node("dash")  # dash acknowledges
got = []
body.subscribe(lambda ev: got.append(ev.frame))
engine.send(Frame(0x123, b"\\x01\\x02"))
# a can.Message, read by its attributes (what python-can's would carry)
engine.send(SimpleNamespace(arbitration_id=0x1ABCDE, data=bytearray(b"\\xaa"), dlc=1, is_extended_id=True,
    is_remote_frame=False, is_error_frame=False, is_fd=False, bitrate_switch=False, error_state_indicator=False))
FaultInjector(bus).flip(can_id=0x123, occurrence=1, field="crc", bit=3, nodes=["body"])
bus.run(until=2_000_000)
print(sorted((f.can_id, f.extended, f.data.hex()) for f in got))
print([r.kind for r in bus.trace], body.rec, engine.tec)
print(sorted(m for m in sys.modules if m == "can" or m.startswith("can.")))
"""


@pytest.mark.subprocess
def test_the_sans_io_core_runs_a_simulation_where_python_can_cannot_be_imported():
    script = textwrap.dedent(CORE_WITHOUT_PYTHON_CAN.format(core=SANS_IO_CORE))
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-3000:]
    frames, trace, modules = out.stdout.splitlines()
    # both frames arrive; the extended one (base ID 0x006) wins the first arbitration
    assert frames == str(sorted([(0x123, False, "0102"), (0x1ABCDE, True, "aa")]))
    # body alone sees the CRC error of 0x123: rules 1 + 2 give it REC 9, the retransmission it
    # receives takes 1 off (rule 8); the transmitter's error flag adds 8 (rule 3), the
    # retransmission takes 1 off (rule 7; the first frame went when TEC was 0 already)
    assert trace == str(["frame", "error", "frame"]) + " 8 7"
    assert modules == "['can']"  # only the blocked entry: nothing of python-can was loaded


@functools.cache
def _parsed(path: Path) -> ast.Module:
    """A module's syntax tree, parsed once for every check here (read only)."""
    return ast.parse(path.read_text())


def _runtime_imports(path: Path, module: str, modules: Collection[str]) -> set[str]:
    """Modules of ``modules`` this file imports when it runs, at module level or inside a function
    (a cycle through a lazy import is still a knot); imports in ``if TYPE_CHECKING:`` blocks, which
    only annotations use, are left out. ``from pkg import sub`` of a submodule ``sub`` is an import
    of ``pkg.sub`` (its package's ``__init__`` runs first for any submodule, which is no edge);
    ``from pkg import name`` of anything else is an import of ``pkg``."""
    tree = _parsed(path)
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
            for a in node.names:
                sub = f"{base}.{a.name}"
                out.add(sub if sub in modules else base)
    return {m for m in out if m in modules and m != module}


def _modules(root: Path = ROOT, packages: Iterable[str] = PACKAGES) -> dict[str, Path]:
    mods = {}
    for pkg in packages:
        for p in (root / pkg).rglob("*.py"):
            rel = p.relative_to(root).with_suffix("")
            parts = list(rel.parts)
            if parts[-1] == "__init__":
                parts.pop()
            mods[".".join(parts)] = p
    return mods


def _import_cycles(mods: dict[str, Path]) -> list[list[str]]:
    """The import cycles between ``mods``: Tarjan's strongly connected components of the graph of
    `_runtime_imports` (a package importing its children and a child importing a name its
    package's ``__init__`` defines are edges like any other)."""
    graph = {m: _runtime_imports(p, m, mods) for m, p in mods.items()}
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
    return cycles


def test_no_import_cycles_between_modules():
    """No two modules import each other, directly or around a longer loop (annotation-only
    imports excepted)."""
    assert _import_cycles(_modules()) == []


def test_the_cycle_check_sees_two_way_imports_and_leaves_annotations_out(tmp_path):
    files = {
        "pkg/__init__.py": "from pkg.child import Child\nNAME = 1\n",
        "pkg/child.py": "from pkg import NAME\nclass Child: ...\n",  # a name of the package: a cycle
        "pkg/a.py": "from pkg.b import x\n",
        "pkg/b.py": "def x():\n    from pkg import a\n",  # lazy, still a cycle
        "pkg/c.py": "from typing import TYPE_CHECKING\nif TYPE_CHECKING:\n    from pkg.d import y\n",
        "pkg/d.py": "from pkg.c import *\ny = 1\n",  # c imports d only for annotations: no cycle
        "pkg/sub/__init__.py": "from pkg.sub.leaf import z\n",
        "pkg/sub/leaf.py": "from pkg.sub import other\nz = 1\n",  # a sibling submodule: no cycle
        "pkg/sub/other.py": "",
    }
    for name, text in files.items():
        (tmp_path / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / name).write_text(text)
    assert sorted(_import_cycles(_modules(tmp_path, ["pkg"]))) == [["pkg", "pkg.child"], ["pkg.a", "pkg.b"]]


def test_no_module_imports_a_private_name_of_another():
    bad = []
    for m, p in _modules().items():
        tree = _parsed(p)
        for node in ast.walk(tree):
            if isinstance(node, ast.ImportFrom) and (node.module or "").split(".")[0] in PACKAGES:
                for a in node.names:
                    if a.name.startswith("_") and not a.name.startswith("__"):
                        bad.append(f"{m}: from {node.module} import {a.name}")
    assert bad == []


# underscored names that are public API: the NamedTuple methods (underscored so as not to clash
# with fields) and argparse's subparsers type, which has no public name (annotations use it)
PUBLIC_UNDERSCORED = {"_replace", "_asdict", "_fields", "_field_defaults", "_make"}
ALLOWED_FOREIGN_READS = {"argparse._SubParsersAction"}


def _own_private_names(tree: ast.Module) -> set[str]:
    """The private names a module defines for its own objects: methods and class attributes,
    ``self._x`` / ``cls._x`` assignments, class-body annotations and ``__slots__`` entries."""
    own: set[str] = set()
    for node in ast.walk(tree):
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef, ast.ClassDef)):
            own.add(node.name)
        elif isinstance(node, ast.Attribute) and isinstance(node.ctx, ast.Store):
            if isinstance(node.value, ast.Name) and node.value.id in ("self", "cls"):
                own.add(node.attr)
        elif isinstance(node, (ast.Assign, ast.AnnAssign)):
            targets = node.targets if isinstance(node, ast.Assign) else [node.target]
            own.update(t.id for t in targets if isinstance(t, ast.Name))
            if any(isinstance(t, ast.Name) and t.id == "__slots__" for t in targets) and node.value is not None:
                own.update(
                    c.value for c in ast.walk(node.value) if isinstance(c, ast.Constant) and isinstance(c.value, str)
                )
    return {n for n in own if n.startswith("_") and not n.startswith("__")}


def _foreign_private_reads(path: Path, rel: str) -> list[str]:
    """``obj._name`` (read or set) where ``obj`` is not ``self``, ``cls`` or ``super()`` and the
    module does not define ``_name`` for objects of its own: another module's object's private
    attribute."""
    tree = _parsed(path)
    own = _own_private_names(tree)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Attribute):
            continue
        name, base = node.attr, node.value
        if not name.startswith("_") or name.startswith("__") or name in own or name in PUBLIC_UNDERSCORED:
            continue
        if isinstance(base, ast.Name) and base.id in ("self", "cls"):
            continue
        if isinstance(base, ast.Call) and isinstance(base.func, ast.Name) and base.func.id == "super":
            continue
        if ast.unparse(node) in ALLOWED_FOREIGN_READS:
            continue
        found.append(f"{rel}:{node.lineno}: {ast.unparse(node)}")
    return found


def test_no_module_reads_a_private_attribute_of_another_modules_object():
    """What one module needs of another's objects is public (the fault injector drives the
    simulated bus through `SimBus.attach_faults`, ``idle_at``, ``arbitration_due``, ...)."""
    found = [f for m, p in _modules().items() for f in _foreign_private_reads(p, m)]
    assert found == []


def test_the_private_read_check_tells_foreign_objects_from_own(tmp_path):
    src = tmp_path / "m.py"
    src.write_text(
        textwrap.dedent(
            """
            import argparse
            from other import Bus

            class Mine:
                __slots__ = ("_slot",)
                _flag = False

                def __init__(self, bus: Bus) -> None:
                    self._state = 0
                    self.bus = bus
                    bus._faults = self  # set on a foreign object: as bad as reading it

                def clone(self) -> "Mine":
                    new = Mine(self.bus)
                    new._state = self._state  # its own class's attribute: allowed
                    return new

                def _helper(self, other: "Mine", sub: argparse._SubParsersAction) -> int:
                    super()._hook()
                    point = other._replace(x=1)
                    return other._slot + other._flag + self.bus._tx + self.bus.node._queue
            """
        )
    )
    assert sorted(_foreign_private_reads(src, "m")) == [
        "m:12: bus._faults",
        "m:22: self.bus._tx",
        "m:22: self.bus.node._queue",
    ]


def test_the_engine_objects_keep_every_field_of_theirs_in_a_slot():
    """`Node` and `SimBus` declare their fields as slots (the engine reads them once a frame; an
    instance dict of over 30 keys is read more slowly): a field added in ``__init__`` without its
    slot lands in ``__dict__``, which this catches. Attributes of users' own still work."""
    from stack.bus.sim import SimBus
    from stack.controller.clock import LocalClock
    from stack.controller.events import TxDone

    bus = SimBus(250_000)
    node = bus.node("a", clock=LocalClock(drift_ppm=10))
    bus.node("b").listen(TxDone, print)
    assert vars(bus) == {} and vars(node) == {}
    node.note = "mine"
    assert vars(node) == {"note": "mine"}
