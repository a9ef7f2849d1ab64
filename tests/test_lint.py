"""The house rules, checked: ruff's lint rules and its formatter (configured in pyproject.toml)
find nothing in the library, the tests or the examples, and mypy (configured there too) finds no
type error in the library."""

from __future__ import annotations

import importlib.util
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _ruff() -> str:
    exe = shutil.which("ruff")
    if exe is None:
        pytest.skip("ruff is not installed (pip install -e '.[test]' brings it)")
    return exe


@pytest.mark.subprocess
def test_ruff_lint_finds_nothing():
    out = subprocess.run(
        [_ruff(), "check", "--output-format", "concise", "."], cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.mark.subprocess
def test_ruff_format_leaves_every_file_as_it_is():
    out = subprocess.run([_ruff(), "format", "--check", "."], cwd=ROOT, capture_output=True, text=True)
    assert out.returncode == 0, out.stdout + out.stderr


@pytest.mark.subprocess
def test_mypy_finds_no_type_error_in_the_library():
    if importlib.util.find_spec("mypy") is None:
        pytest.skip("mypy is not installed (pip install -e '.[test]' brings it)")
    # the packages and per-module settings are pyproject.toml's [tool.mypy]; the cache in the
    # checkout makes a second run incremental
    out = subprocess.run(
        [sys.executable, "-m", "mypy", "--no-error-summary", "--no-pretty"], cwd=ROOT, capture_output=True, text=True
    )
    assert out.returncode == 0 and out.stdout == "", out.stdout + out.stderr
