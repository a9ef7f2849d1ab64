"""The house rules, checked: ruff's lint rules and its formatter (configured in pyproject.toml)
find nothing in the library, the tests or the examples, mypy (configured there too) finds no
type error in the library, and no speed figure sits in a comment or docstring of the library."""

from __future__ import annotations

import ast
import importlib.util
import io
import re
import shutil
import subprocess
import sys
import tokenize
from collections.abc import Iterator
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


# a speed figure: "3x faster", "40 % cheaper", "costs ~37 us", "2 % of the bench", callgrind counts
_FIGURE = re.compile(
    r"callgrind|instructions a frame|bench machine"
    r"|\d[\d.,]*\s*(?:x|×|%)\s+(?:faster|cheaper|slower|dearer)\b"
    r"|\b(?:faster|cheaper|slower|dearer|costs?)\b[^.;:]{0,40}?~?\d[\d.,]*\s*(?:x|×|%|µs|us|ns|ms|k)\b"
    r"|\d[\d.,]*\s*%\s+of\b[^;]{0,40}?\bbench",
    re.IGNORECASE,
)
# a figure in a file whose owner is moving it to the benchmarks page (the row is there)
_FIGURES_BEING_MOVED: set[tuple[str, str]] = set()


def _comments_and_docstrings(path: Path) -> Iterator[tuple[int, str]]:
    src = path.read_text()
    for tok in tokenize.generate_tokens(io.StringIO(src).readline):
        if tok.type == tokenize.COMMENT:
            yield tok.start[0], tok.string
    for node in ast.walk(ast.parse(src)):
        # docstrings and the attribute docstrings under assignments: string statements
        if isinstance(node, ast.Expr) and isinstance(node.value, ast.Constant) and isinstance(node.value.value, str):
            yield node.lineno, node.value.value


def _figures(path: Path, rel: str) -> list[str]:
    if not _FIGURE.search(" ".join(path.read_text().split())):
        return []  # nowhere in the file, so not in its comments either (tokenizing costs more)
    found = []
    for line, text in _comments_and_docstrings(path):
        for m in _FIGURE.finditer(" ".join(text.split())):
            if (rel, m.group(0)) not in _FIGURES_BEING_MOVED:
                found.append(f"{rel}:{line}: {m.group(0)!r}")
    return found


def test_no_speed_figure_in_a_comment_or_docstring_of_the_library():
    """Performance figures go stale where the code is; they live on docs/pages/benchmarks.md
    (the table of what the hand-written fast paths buy) and in `python -m stack.bench`."""
    found = [
        f
        for pkg in ("stack", "profiles", "dbc")
        for p in sorted((ROOT / pkg).rglob("*.py"))
        for f in _figures(p, p.relative_to(ROOT).as_posix())
    ]
    assert found == [], "move these figures to docs/pages/benchmarks.md:\n" + "\n".join(found)


def test_the_figure_check_sees_comments_and_docstrings_but_not_code(tmp_path):
    src = tmp_path / "m.py"
    src.write_text(
        '"""A module, about 5x faster than a dataclass."""\n'
        "X = 1  # a global: 40 % cheaper than an Enum lookup\n"
        "def f():\n"
        '    """Costs ~37 us a frame (callgrind: 24.5 k instructions a frame)."""\n'
        '    return f"{3}x faster"  # costs nothing measurable: the reason, no number\n'
        "Y = 2\n"
        '"""An attribute docstring: 2 % of `python -m stack.bench`\'s 1 -> 1."""\n'
    )
    assert sorted(_figures(src, "m.py")) == sorted(
        [
            "m.py:1: '5x faster'",
            "m.py:2: '40 % cheaper'",
            "m.py:4: 'Costs ~37 us'",
            "m.py:4: 'callgrind'",
            "m.py:4: 'instructions a frame'",
            "m.py:7: '2 % of `python -m stack.bench'",
        ]
    )
