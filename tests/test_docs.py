"""The documentation site (``docs/``): it builds with warnings as errors, its generated reference
covers every command and every exported name, and every code block of its pages runs as the
page says — one test per block, named by page and line (``docs/blocks.py`` says how each kind of
block runs and how a block that cannot run here is tagged)."""

from __future__ import annotations

import importlib.util
import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def _load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module  # dataclasses look their module up by name
    spec.loader.exec_module(module)
    return module


docs = _load("canstack_docs_blocks", ROOT / "docs" / "blocks.py")
ALL = [b for page in docs.pages() for b in docs.blocks(page)]
RUNNABLE = [b for b in ALL if b.runnable]

#: The blocks that cannot run here, by reason, and the blocks that run only with ``-m campaign``
#: (minutes long). A new one is a decision: count it here.
SKIPPED = {"needs SocketCAN": 2, "needs a Dask cluster": 2, "runs the test suite": 1, "installs packages": 1}
SLOW = 3


def _marks(block) -> list[pytest.MarkDecorator]:
    marks = []
    if block.lang != "python":
        marks.append(pytest.mark.subprocess)
    if "&" in block.code and block.lang in ("sh", "console"):
        marks.append(pytest.mark.socket)  # a background `canstack serve`
    if block.slow:
        marks.append(pytest.mark.campaign)
    return marks


@pytest.mark.parametrize("block", [pytest.param(b, id=b.name, marks=_marks(b)) for b in RUNNABLE])
def test_block_runs_as_the_page_says(block, tmp_path):
    if block.skip:
        pytest.skip(f"{block.name}: {block.skip}")
    docs.run(block, docs.sandbox(tmp_path))


def test_the_pages_have_blocks_of_every_kind():
    kinds = {b.lang for b in RUNNABLE}
    assert {"python", "console", "sh", "toml"} <= kinds
    assert sum(b.output is not None for b in RUNNABLE) >= 5  # outputs the pages show are checked
    assert len({b.page for b in RUNNABLE}) >= 12


def test_every_block_is_run_or_shown_on_purpose():
    """A block in a language the tests do not run is a display (``text``); a misspelt language
    (``pyhton``, ``shell-session``) would otherwise never run."""
    shown = {"text"}
    odd = [f"{b.name} ({b.lang or 'no language'})" for b in ALL if not b.runnable and b.lang not in shown]
    assert not odd, "blocks that would never run: " + ", ".join(odd)


def test_skipped_blocks_name_what_is_missing_and_are_counted():
    skipped = [b for b in RUNNABLE if b.skip]
    for b in skipped:
        assert b.skip.startswith(docs.SKIP_REASONS), (
            f"{b.name}: skip reason {b.skip!r} is not one of {docs.SKIP_REASONS}"
        )
    counts: dict[str, int] = {}
    for b in skipped:
        reason = next(r for r in docs.SKIP_REASONS if b.skip.startswith(r))
        counts[reason] = counts.get(reason, 0) + 1
    assert counts == {k: v for k, v in SKIPPED.items() if v}, [b.name for b in skipped]
    assert not [b.name for b in ALL if (b.skip or b.slow) and not b.runnable], "a tag on a block that never runs"
    assert len([b for b in RUNNABLE if b.slow]) == SLOW, [b.name for b in RUNNABLE if b.slow]


# ------------------------------------------------------------------------- the harness itself
def test_a_block_whose_output_differs_from_the_page_fails(tmp_path, monkeypatch):
    monkeypatch.setattr(docs, "ROOT", tmp_path)
    page = tmp_path / "page.md"
    page.write_text('```python\nprint(6 * 7)\n```\n\n```text title="Output"\n41\n```\n', encoding="utf-8")
    (block,) = docs.blocks(page)
    assert block.output == "41\n" and block.line == 1
    with pytest.raises(AssertionError, match="differs"):
        docs.run(block, tmp_path)
    page.write_text('```python\nprint(6 * 7)\n```\n\n```text title="Output"\n4...\n```\n', encoding="utf-8")
    (block,) = docs.blocks(page)
    assert docs.run(block, tmp_path) == "42\n"


def test_console_blocks_split_commands_continuations_and_outputs(tmp_path, monkeypatch):
    monkeypatch.setattr(docs, "ROOT", tmp_path)
    page = tmp_path / "page.md"
    page.write_text(
        "<!-- skip: needs SocketCAN -->\n"
        "```console\n$ canstack frame --id 0x0C1 \\\n    --data 40\nCRC ...\n$ canstack --version\ncanstack ...\n```\n",
        encoding="utf-8",
    )
    (block,) = docs.blocks(page)
    assert block.skip == "needs SocketCAN"
    cmds = docs.commands(block)
    assert [c.text for c in cmds] == ["canstack frame --id 0x0C1 --data 40", "canstack --version"]
    assert [c.expected for c in cmds] == ["CRC ...", "canstack ..."]


def test_shell_lines_lose_comments_but_not_quoted_hashes():
    assert docs._strip_comment("canstack demo   # the demo") == "canstack demo"
    assert docs._strip_comment("python -c 'print(\"#\")'") == "python -c 'print(\"#\")'"
    assert docs.programs("pip install -e . && canstack demo") == ["pip", "canstack"]


def test_output_matching_takes_ellipses_for_any_text():
    assert docs.matches("a ... c\nd", "a b b c\nd  \n")
    assert docs.matches("first\n...\nlast", "first\nx\ny\nlast")
    assert not docs.matches("a ... c", "a b d")
    assert not docs.matches("exact", "exact and more")


def test_a_command_outside_the_allowed_ones_must_be_tagged(tmp_path):
    runner = docs.Runner(tmp_path)
    with pytest.raises(AssertionError, match="not a command"):
        runner.run(docs.Command("ip link add dev vcan0 type vcan"))


# ------------------------------------------------------------------------------- the site build
@pytest.mark.subprocess
def test_the_site_builds_with_warnings_as_errors(tmp_path):
    site = tmp_path / "site"
    out = subprocess.run(
        [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "docs" / "mkdocs.yml"), "-d", str(site)],
        capture_output=True,
        text=True,
        timeout=300,
        env={**os.environ, "NO_MKDOCS_2_WARNING": "1"},
    )
    assert out.returncode == 0, out.stderr[-4000:]
    cli = (site / "reference" / "cli.html").read_text(encoding="utf-8")
    from stack.cli import build_parser

    commands = docs_commands(build_parser())
    assert len(commands) >= 12
    for command in commands:  # every command's --help is on the page, under its own heading
        assert f'id="{command.replace(" ", "-")}"' in cli, command
    api = (site / "reference" / "api" / "index.html").read_text(encoding="utf-8")
    import importlib

    for package in ("stack", "profiles", "dbc"):  # every exported name links into the reference
        names = importlib.import_module(package).__all__
        assert names, package
        for name in names:
            assert re.search(rf'href="[^"]*#{package}(\.[\w.]*)?\.{name}"', api), f"{package}.{name}"
    inventory = (site / "objects.inv").read_bytes()
    assert inventory.startswith(b"# Sphinx inventory version 2")
    search = json.loads((site / "search" / "search_index.json").read_text(encoding="utf-8"))
    assert any("fault confinement" in doc["text"].lower() for doc in search["docs"])


def docs_commands(parser) -> list[str]:
    """Every `canstack` command path, from the parser (as the CLI reference must list them)."""
    hooks = _load("canstack_docs_hooks", ROOT / "docs" / "hooks.py")
    return [command for command, _, _ in hooks.commands(parser, "canstack")]


# ------------------------------------------------------------------ names the prose cites
def _resolves(dotted: str) -> bool:
    """Whether ``dotted`` is a module, or an attribute reached from the longest module prefix."""
    import importlib

    parts = dotted.split(".")
    for cut in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:cut]))
        except ImportError:
            continue
        for attr in parts[cut:]:
            if not hasattr(obj, attr):
                return False
            obj = getattr(obj, attr)
        return True
    return False


def test_every_module_and_name_the_pages_cite_exists():
    """A page citing `stack.sim` or `profiles.sweep.run_sweep` after the code moved on would
    mislead silently; every dotted name in backticks must import."""
    cited: dict[str, str] = {}
    for path in [*docs.pages(), ROOT / "README.md"]:
        for name in re.findall(r"`((?:stack|profiles|dbc)(?:\.[A-Za-z_]\w*)+)", path.read_text(encoding="utf-8")):
            if name.rsplit(".", 1)[1] not in ("png", "md", "toml", "py", "json", "csv"):  # a file name
                cited.setdefault(name, path.relative_to(ROOT).as_posix())
    assert len(cited) >= 30
    missing = {name: page for name, page in cited.items() if not _resolves(name)}
    assert not missing, missing
