"""MkDocs hooks: the parts of the site that are generated from the code when it is built, so
that they cannot go stale.

- ``<!-- generated: cli-reference -->`` becomes the command-line reference: a table of every
  ``canstack`` command with its one-line help, then each command's ``--help`` as argparse prints
  it, walked from the parser that `stack.cli.build_parser` builds (the commands of ``dbc`` and
  ``profiles`` come in through the ``canstack.commands`` entry points, as on the command line).
- ``<!-- generated: public-api PACKAGE -->`` becomes a table of what ``PACKAGE.__all__`` exports,
  each name linked to its entry in the API reference under the module that defines it (a name
  whose module has no page there breaks the strict build).
- The plots in ``examples/plots`` are copied into the site as ``img/plots/NAME.png``.
"""

from __future__ import annotations

import argparse
import importlib
import inspect
import os
import re
from collections.abc import Iterator
from pathlib import Path
from typing import Any

from mkdocs.structure.files import File, Files

ROOT = Path(__file__).resolve().parents[1]
PLOTS = ROOT / "examples" / "plots"
HELP_COLUMNS = 80  # the width argparse wraps the help to (it reads $COLUMNS): the page's code width
MARKER = re.compile(r"<!-- generated: ([a-z-]+)(?: ([\w.]+))? -->")


def on_files(files: Files, config: Any) -> Files:
    """Add the example plots to the site (they live beside the examples that draw them)."""
    for png in sorted(PLOTS.glob("*.png")):
        files.append(File.generated(config, f"img/plots/{png.name}", abs_src_path=str(png)))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Files) -> str:
    """Expand the ``<!-- generated: ... -->`` markers of a page."""

    def expand(match: re.Match[str]) -> str:
        kind, arg = match.group(1), match.group(2)
        if kind == "cli-reference":
            return cli_reference()
        if kind == "public-api" and arg:
            return public_api(arg)
        raise ValueError(f"{page.file.src_uri}: unknown marker {match.group(0)!r}")

    return MARKER.sub(expand, markdown)


def _subcommands(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str, argparse.ArgumentParser]]:
    """(name, one-line help, parser) of each subcommand of ``parser``, in the order --help lists them.

    argparse offers no public way to list a parser's subcommands: the subparsers action and its
    pseudo-actions are read as argparse's own help formatter reads them."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for choice in action._choices_actions:
                yield choice.dest, choice.help or "", action.choices[choice.dest]


def commands(parser: argparse.ArgumentParser, prefix: str) -> Iterator[tuple[str, str, argparse.ArgumentParser]]:
    """(command line, one-line help, parser) of every command below ``parser``, depth first."""
    for name, summary, sub in _subcommands(parser):
        yield f"{prefix} {name}", summary, sub
        yield from commands(sub, f"{prefix} {name}")


def _anchor(command: str) -> str:
    return command.replace(" ", "-")


def cli_reference() -> str:
    """Markdown: a table of every command, then each one's ``--help``."""
    from stack.cli import build_parser

    saved = os.environ.get("COLUMNS")
    os.environ["COLUMNS"] = str(HELP_COLUMNS)
    try:
        parser = build_parser()
        found = list(commands(parser, "canstack"))
        helps = {command: sub.format_help() for command, _, sub in found}
        top = parser.format_help()
    finally:
        if saved is None:
            del os.environ["COLUMNS"]
        else:
            os.environ["COLUMNS"] = saved
    out = ["| command | what it does |", "|---|---|"]
    out += [f"| [`{c}`](#{_anchor(c)}) | {_cell(summary)} |" for c, summary, _ in found]
    out += ["", "## canstack", "", "```text", top.rstrip(), "```", ""]
    for command, _, _ in found:
        out += [f"## {command} {{#{_anchor(command)}}}", "", "```text", helps[command].rstrip(), "```", ""]
    return "\n".join(out)


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


def _summary(obj: Any) -> str:
    """The first sentence of an object's own docstring, on one line: up to the first full stop
    outside parentheses that ends a word (not one of the dots of ``0..15``)."""
    if not (inspect.isclass(obj) or inspect.isroutine(obj) or inspect.ismodule(obj)):
        return ""
    text = " ".join((inspect.getdoc(obj) or "").split("\n\n", 1)[0].split())
    depth = 0
    for i, ch in enumerate(text):
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if ch == "." and depth <= 0 and text[i + 1 : i + 2] in (" ", "") and text[i - 1 : i] != ".":
            return text[: i + 1]
    return text


def public_api(package: str) -> str:
    """Markdown: the names ``package`` exports, the module that defines each, and its summary."""
    mod = importlib.import_module(package)
    rows = ["| name | defined in | what it is |", "|---|---|---|"]
    for name in getattr(mod, "__all__", ()):
        obj = getattr(mod, name)
        where = getattr(obj, "__module__", None) if not inspect.ismodule(obj) else None
        if inspect.ismodule(obj):
            where, target = obj.__name__, obj.__name__
        elif where is None or not where.startswith(package):
            where, target = package, f"{package}.{name}"
        else:
            target = f"{where}.{getattr(obj, '__qualname__', name)}"
        rows.append(f"| [`{name}`][{target}] | `{where}` | {_cell(_summary(obj))} |")
    if len(rows) == 2:
        return f"`{package}` declares no `__all__` yet: import from the defining modules below."
    return "\n".join(rows)
