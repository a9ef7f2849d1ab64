"""The public API of `stack`, `profiles` and `dbc`: what ``__all__`` declares imports from the
package, and each name says what it is (a docstring of its own, or an attribute docstring in its
source). (That each one is in the API reference, the site build checks: tests/test_docs.py.)"""

from __future__ import annotations

import ast
import importlib
import inspect
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _attribute_docstrings(package: str) -> set[str]:
    """Names assigned at module level anywhere in ``package`` with a string right after them
    (the attribute docstring convention Sphinx and mkdocstrings read)."""
    out = set()
    for path in (ROOT / package).rglob("*.py"):
        body = ast.parse(path.read_text()).body
        for stmt, nxt in zip(body, body[1:]):
            targets = (
                stmt.targets
                if isinstance(stmt, ast.Assign)
                else [stmt.target]
                if isinstance(stmt, ast.AnnAssign)
                else []
            )
            if isinstance(nxt, ast.Expr) and isinstance(nxt.value, ast.Constant) and isinstance(nxt.value.value, str):
                out.update(t.id for t in targets if isinstance(t, ast.Name))
    return out


def _own_doc(obj: object) -> str:
    doc = obj.__doc__ or ""
    if inspect.isclass(obj) and doc.startswith(f"{obj.__name__}("):  # a dataclass's generated signature
        return ""
    return doc.strip()


@pytest.mark.parametrize("package", ["stack", "profiles", "dbc"])
def test_every_public_name_imports_from_the_package_and_says_what_it_is(package):
    mod = importlib.import_module(package)
    assert len(mod.__all__) == len(set(mod.__all__))
    documented = _attribute_docstrings(package)
    undocumented = []
    for name in mod.__all__:
        obj = getattr(mod, name)  # raises if the name does not import
        if inspect.isclass(obj) or inspect.isfunction(obj) or inspect.ismodule(obj):
            if not _own_doc(obj):
                undocumented.append(name)
        elif name not in documented:
            undocumented.append(name)
    assert undocumented == []


@pytest.mark.parametrize("package", ["stack", "profiles"])
def test_the_package_exports_each_name_from_a_module_that_declares_it_public(package):
    pkg = importlib.import_module(package)
    assert sorted(pkg._EXPORTS) == sorted(pkg.__all__)
    for name, module in pkg._EXPORTS.items():
        mod = importlib.import_module(module)
        assert name in mod.__all__, f"{module} does not declare {name}"
        assert getattr(pkg, name) is getattr(mod, name)
    with pytest.raises(AttributeError, match="no attribute 'nothing_here'"):
        pkg.nothing_here


@pytest.mark.subprocess
@pytest.mark.parametrize("package", ["stack", "profiles"])
def test_importing_the_package_loads_none_of_its_modules(package):
    """The names load on first use: ``import stack`` or ``import profiles`` alone imports none of
    its subpackages (no layer, no profile, not the pipeline)."""
    code = f"import sys, {package}; print(sorted(m for m in sys.modules if m.startswith('{package}.')))"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, timeout=60, check=True)
    assert out.stdout.strip() == "[]"
