"""The distribution ships every package: pyproject.toml lists them (examples/ is installed as the
package ``canstack_examples``), so a package added under stack/, profiles/ or dbc/ and not listed
would be missing from a plain ``pip install``."""

from __future__ import annotations

import sys
from pathlib import Path

from setuptools import find_packages

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[1]


def _setuptools() -> dict:
    return tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]


def test_every_package_under_the_source_folders_is_listed():
    found = set(find_packages(where=str(ROOT), include=["stack*", "profiles*", "dbc*"]))
    listed = set(_setuptools()["packages"])
    assert found - listed == set(), f"packages missing from pyproject.toml: {sorted(found - listed)}"
    assert listed - found == {"canstack_examples"}, sorted(listed - found)


def test_the_examples_folder_is_the_canstack_examples_package():
    cfg = _setuptools()
    assert cfg["package-dir"] == {"canstack_examples": "examples"}
    assert (ROOT / "examples" / "__init__.py").is_file()
    # every kind of file the examples folder holds ships as package data
    patterns = {p.removeprefix("*") for p in cfg["package-data"]["canstack_examples"]}
    kinds = {p.suffix for p in (ROOT / "examples").iterdir() if p.is_file()}
    assert kinds <= patterns, sorted(kinds - patterns)


def test_no_setup_py_beside_pyproject():
    # pyproject.toml says everything; a setup.py would be a second place to look
    assert not (ROOT / "setup.py").exists()
