"""The README's examples run as written: every code block, one test per block named by its line,
run the way ``docs/blocks.py`` runs the site's pages (python blocks executed, commands run as
subprocesses with the output the README shows checked)."""

from __future__ import annotations

import importlib.util
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


docs = sys.modules.get("canstack_docs_blocks") or _load("canstack_docs_blocks", ROOT / "docs" / "blocks.py")
BLOCKS = docs.blocks(ROOT / "README.md")
RUNNABLE = [b for b in BLOCKS if b.runnable]


@pytest.mark.parametrize(
    "block",
    [pytest.param(b, id=b.name, marks=[] if b.lang == "python" else [pytest.mark.subprocess]) for b in RUNNABLE],
)
def test_readme_block_runs_as_shown(block, tmp_path):
    if block.skip:
        pytest.skip(f"{block.name}: {block.skip}")
    docs.run(block, docs.sandbox(tmp_path))


def test_the_readme_stays_short_and_shows_each_use():
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) <= 200
    # the two set-up commands: the second is exactly what .ci/run runs
    commands = [b.code.strip() for b in BLOCKS if b.lang == "sh"]
    assert commands[:2] == ["pip install -e . && canstack demo", "pip install -e '.[test]' && python -m pytest -q"]
    assert "pip install -e '.[test]' && python -m pytest -q" in (ROOT / ".ci" / "run").read_text(encoding="utf-8")
    code = "\n".join(b.code for b in RUNNABLE)
    for use in ("Ecu(db", "canstack experiment", "encode_frame", 'interface="canstack"'):
        assert use in code, use
    assert sum(b.output is not None or b.lang == "console" for b in RUNNABLE) >= 4  # outputs shown are checked
    assert [b.skip for b in BLOCKS if b.skip] == [
        "runs the test suite (it is the suite's own command: .ci/run runs it)"
    ]


def test_the_readme_links_resolve():
    import re

    text = (ROOT / "README.md").read_text(encoding="utf-8")
    links = re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text)
    assert len(links) >= 10
    missing = [link for link in links if not link.startswith("http") and not (ROOT / link).exists()]
    assert not missing, missing
