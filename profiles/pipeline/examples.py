"""The shipped examples (``examples/`` in the repository, the package ``canstack_examples`` once
installed): ``canstack examples`` lists them and copies them (``--to DIR``); a scenario named
``examples/NAME.toml`` on the command line that is not a file where the command runs is the
shipped one, so the README's commands work after a plain ``pip install``, from any directory.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from importlib import resources
from pathlib import Path
from typing import Any

from stack.cli import CliError

__all__ = ["register", "examples", "example_path", "scenario_path", "describe", "PACKAGE"]

PACKAGE = "canstack_examples"
"""The package the examples are installed as (pyproject.toml maps ``examples/`` to it)."""

SUFFIXES = (".toml", ".py", ".md", ".jsonl", ".vcd", ".csv")
"""What ``canstack examples`` lists and copies: scenarios, scripts, notes and the data they read."""


def _root() -> Any:
    try:
        return resources.files(PACKAGE)
    except ModuleNotFoundError:
        raise CliError(f"the examples are not installed ({PACKAGE} is missing): reinstall canstack") from None


def examples() -> dict[str, Any]:
    """Every shipped example by file name (scenarios first, then scripts and the rest)."""
    files = [f for f in _root().iterdir() if f.is_file() and f.name.endswith(SUFFIXES) and f.name != "__init__.py"]
    files.sort(key=lambda f: (not f.name.endswith(".toml"), f.name))
    return {f.name: f for f in files}


_DATA = {
    ".vcd": "a CAN_RX waveform (VCD) of four frames: canstack decode reads it",
    ".jsonl": "frames as JSON lines: canstack render draws their waveform",
    ".csv": "signal changes over time: canstack restbus --stimulus plays them",
}


def describe(name: str, text: str) -> str:
    """An example's one-line description: the first sentence of its leading comment (the ``#``
    lines of a scenario, a script's docstring, a Markdown title), or what a data file is."""
    suffix = Path(name).suffix
    if suffix in _DATA:
        return _DATA[suffix]
    lines: list[str] = []
    in_doc = False
    for raw in text.splitlines():
        line = raw.strip()
        if not lines and not in_doc:
            if line.startswith('"""'):
                in_doc = True
                line = line[3:]
            elif line.startswith("#"):
                line = line.lstrip("#").strip()
            else:
                continue
        elif in_doc:
            line = line.split('"""')[0]
        elif line.startswith("#"):
            line = line.lstrip("#").strip()
        else:
            break
        if not line:
            if lines:
                break
            continue
        lines.append(line.strip())
        if '"""' in raw and lines and not raw.strip().startswith('"""'):
            break
    first = " ".join(lines).split(". ")[0].rstrip(".")
    return first if len(first) <= 110 else first[:109] + "…"


def example_path(name: str) -> Any:
    """The shipped example ``name`` (with or without its suffix), or None."""
    found = examples()
    return found.get(name) or found.get(f"{name}.toml")


def scenario_path(text: str) -> str:
    """The scenario file a command line names: the file itself when it exists; else, for
    ``examples/NAME.toml`` (or a bare ``NAME.toml``) that is a shipped example, the installed
    copy (a note on stderr says so); else the text as given (its reader names what is wrong)."""
    p = Path(text)
    if p.exists() or p.parent.name not in ("examples", "") or len(p.parts) > 2:
        return text
    try:
        shipped = example_path(p.name)
    except CliError:
        return text
    if shipped is None or not p.name.endswith(".toml"):
        return text
    print(
        f"canstack: {text}: not a file here: the shipped example (canstack examples --to DIR copies it)",
        file=sys.stderr,
    )
    return str(shipped)


def _examples(args: argparse.Namespace) -> int:
    found = examples()
    names = args.names or list(found)
    unknown = [n for n in names if n not in found and f"{n}.toml" not in found]
    if unknown:
        raise CliError(f"no example {unknown[0]!r}: one of {', '.join(found)}")
    chosen = [n if n in found else f"{n}.toml" for n in names]
    if args.to is None:
        if args.names:
            for n in chosen:
                sys.stdout.write(found[n].read_text(encoding="utf-8"))
            return 0
        width = max(len(n) for n in found)
        for n, f in found.items():
            print(f"{n:<{width}}  {describe(n, f.read_text(encoding='utf-8'))}")
        print("\ncanstack examples --to DIR copies them (or NAME... only); canstack examples NAME prints one")
        return 0
    dest = Path(args.to)
    if dest.exists() and not dest.is_dir():
        raise CliError(f"--to {args.to!r}: is a file; give a directory")
    clash = [n for n in chosen if (dest / n).exists()]
    if clash and not args.force:
        raise CliError(f"--to {args.to!r}: {clash[0]} is there already (--force replaces it)")
    try:
        dest.mkdir(parents=True, exist_ok=True)
        for n in chosen:
            with resources.as_file(found[n]) as src:
                shutil.copyfile(src, dest / n)
    except OSError as exc:
        raise CliError(f"--to {args.to!r}: cannot write: {exc.strerror or exc}") from None
    print(f"{len(chosen)} example{'s' if len(chosen) != 1 else ''} copied to {dest}")
    return 0


def register(sub: Any) -> None:
    """Add the `examples` subcommand."""
    p = sub.add_parser(
        "examples",
        help="list the shipped example scenarios and scripts, print one, or copy them into a folder",
        description="The examples that come with canstack (scenario files for canstack experiment, sweep and "
        "study, and scripts). With no argument: the list. NAME...: print those files. --to DIR: copy them (all, "
        "or NAME... only) into DIR, made if missing. A command line that names examples/NAME.toml, where there "
        "is no such file, runs the shipped one.",
    )
    p.add_argument("names", nargs="*", metavar="NAME", help="examples by file name (the .toml may be left out)")
    p.add_argument("--to", metavar="DIR", help="copy the examples into DIR")
    p.add_argument("--force", action="store_true", help="with --to: replace files that are there already")
    p.set_defaults(func=_examples)
