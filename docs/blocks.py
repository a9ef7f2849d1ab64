"""The code blocks of the documentation, and how the tests run them.

``tests/test_docs.py`` runs every block of the site's pages (``docs/pages``) and
``tests/test_readme.py`` every block of the README, one test per block named by page and line.
What a block is decides how it runs:

- ```` ```python ````: executed in the test's process, in a fresh namespace;
- ```` ```console ````: each ``$ command`` (continued over lines ending in ``\\``) runs as a
  subprocess; the lines after a command, up to the next ``$``, are its expected output;
- ```` ```sh ```` (or ``bash``, ``shell``): each line is a command, run as a subprocess in turn
  (``#`` starts a comment, ``\\`` continues a line);
- ```` ```toml ````: a scenario file: written to a file and run with ``canstack experiment``;
- any other language (``text``, a tree of folders, a scenario error message): shown, not run.

A command runs through ``bash`` with the test interpreter's ``bin`` folder first on ``PATH``,
so ``canstack`` and ``python`` are the installed checkout's, under a timeout. Only ``canstack``,
``python``/``python3`` and ``pip`` commands may appear in a runnable block (anything else —
``ip link``, ``dask scheduler`` — needs a ``skip`` tag). ``pip install`` is never run: the tests
run in an installed checkout; the commands chained after it with ``&&`` are. A command that
ends in ``&`` starts in the background; the next command runs once it has printed its first
line (``canstack serve`` prints its address when it listens), and it is ended when the block
is done. Port 29536 (``canstack serve``'s default) in a command is replaced by a free port.

A block runs in a fresh working folder holding a copy of ``examples/`` and links to ``dbc/``,
``profiles/`` and ``stack/``, so the paths a page gives from the root of a checkout work and
whatever a block writes stays in the folder.

Tags are HTML comments on the line before a block (blank lines between are allowed), invisible
on the site:

- ``<!-- skip: REASON -->``: the block is not run, and the test says why. REASON must name what
  this machine lacks (`SKIP_REASONS`); the tests count the skipped blocks.
- ``<!-- slow: REASON -->``: the block runs only with ``-m campaign`` (the suite's opt-in mark
  for long runs).

A block followed directly by a fenced block titled ``Output`` (```` ```text title="Output" ````)
must print that output. Expected output matches what the block printed line by line, after
trailing spaces are dropped; ``...`` in it matches any text (on one line or across lines), for
figures that vary from run to run.
"""

from __future__ import annotations

import contextlib
import io
import os
import re
import shlex
import shutil
import signal
import socket
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PAGES = ROOT / "docs" / "pages"

#: what a ``skip`` tag may give as the reason: each names something this machine does not have
SKIP_REASONS = (
    "needs SocketCAN",  # a vcan or CAN interface: the kernel here has no AF_CAN
    "needs a Dask cluster",  # a scheduler and workers on other machines
    "runs the test suite",  # the suite cannot run itself
    "installs packages",  # a registry and a fresh environment
)
RUNNABLE = {"python", "console", "sh", "bash", "shell", "toml"}
COMMANDS = {"canstack", "python", "python3", "pip"}
DEFAULT_PORT = "29536"
TIMEOUT = 120.0  # seconds for one command


@dataclass(frozen=True)
class Block:
    """One fenced code block of a page."""

    page: str  # path from the root of the checkout
    line: int  # the line of the opening fence, from 1
    lang: str
    code: str
    title: str | None = None
    skip: str | None = None
    slow: str | None = None
    output: str | None = None  # the expected output (a following block titled "Output")

    @property
    def name(self) -> str:
        return f"{self.page}:{self.line}"

    @property
    def runnable(self) -> bool:
        return self.lang in RUNNABLE


FENCE = re.compile(r"^(?P<indent>[ \t]*)(?P<fence>`{3,}|~{3,})\s*(?P<info>[^`]*)$")
TAG = re.compile(r"^\s*<!--\s*(?P<kind>skip|slow):\s*(?P<reason>.+?)\s*-->\s*$")
TITLE = re.compile(r'title="(?P<title>[^"]*)"')


def blocks(path: Path) -> list[Block]:
    """The fenced blocks of a markdown file, with their tags and expected output."""
    lines = path.read_text(encoding="utf-8").splitlines()
    page = path.relative_to(ROOT).as_posix()
    found: list[tuple[int, int, Block]] = []  # (first line index, last line index, block)
    i = 0
    while i < len(lines):
        m = FENCE.match(lines[i])
        if not m:
            i += 1
            continue
        indent, fence, info = m["indent"], m["fence"], m["info"].strip()
        body: list[str] = []
        j = i + 1
        while j < len(lines) and not (
            lines[j].strip().startswith(fence[0] * len(fence)) and not lines[j].strip().strip(fence[0])
        ):
            text = lines[j]
            body.append(text[len(indent) :] if text.startswith(indent) else text.lstrip())
            j += 1
        lang = info.split()[0].lstrip(".").lower() if info else ""
        title = TITLE.search(info)
        tags: dict[str, str] = {}
        k = i - 1
        while k >= 0 and not lines[k].strip():
            k -= 1
        while k >= 0 and (t := TAG.match(lines[k])):
            tags[t["kind"]] = t["reason"]
            k -= 1
        code = "\n".join(body) + "\n"
        found.append(
            (
                i,
                j,
                Block(page, i + 1, lang, code, title["title"] if title else None, tags.get("skip"), tags.get("slow")),
            )
        )
        i = j + 1
    out: list[Block] = []
    for n, (_, last, block) in enumerate(found):
        if block.title == "Output":
            continue
        if n + 1 < len(found):
            nfirst, _, nxt = found[n + 1]
            if nxt.title == "Output" and not any(s.strip() for s in lines[last + 1 : nfirst]):
                block = Block(**{**block.__dict__, "output": nxt.code})
        out.append(block)
    return out


def pages() -> list[Path]:
    """The site's markdown pages."""
    return sorted(PAGES.rglob("*.md"))


# ----------------------------------------------------------------------------- output matching
def matches(expected: str, actual: str) -> bool:
    """Whether ``actual`` is ``expected``, where ``...`` in ``expected`` stands for any text."""

    def norm(text: str) -> str:
        return "\n".join(ln.rstrip() for ln in text.strip("\n").splitlines())

    parts = [re.escape(p) for p in norm(expected).split("...")]
    return re.fullmatch(r"(?s:.*?)".join(parts), norm(actual)) is not None


# ------------------------------------------------------------------------------------ commands
@dataclass
class Command:
    """One command of a shell block, with the output the page shows for it."""

    text: str
    expected: str | None = None
    background: bool = False


def commands(block: Block) -> list[Command]:
    """The commands of a ``console`` or ``sh`` block, continuation lines joined."""
    out: list[Command] = []
    pending = ""
    output: list[str] = []
    console = block.lang == "console"
    for raw in block.code.splitlines():
        if console and not pending and not raw.startswith("$ "):
            if out:
                output.append(raw)
            continue
        text = raw[2:] if console and not pending else raw
        if not console:
            text = _strip_comment(text)
        if text.rstrip().endswith("\\"):
            pending += text.rstrip()[:-1].strip() + " "
            continue
        text = (pending + text.strip()).strip()
        pending = ""
        if not text:
            continue
        if console and out:
            out[-1].expected = "\n".join(output)
        output = []
        background = text.endswith("&") and not text.endswith("&&")
        out.append(Command(text.rstrip("&").strip() if background else text, background=background))
    if console and out:
        out[-1].expected = "\n".join(output)
    return out


def _strip_comment(line: str) -> str:
    """A shell line without its ``#`` comment (a ``#`` inside quotes or a word is kept)."""
    quote = None
    for i, ch in enumerate(line):
        if quote:
            if ch == quote:
                quote = None
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or line[i - 1].isspace()):
            return line[:i].rstrip()
    return line


def programs(command: str) -> list[str]:
    """The programs a command line starts (the first word of each part of a ``&&`` chain)."""
    return [shlex.split(part)[0] for part in command.split("&&") if part.strip()]


def _without_pip(command: str) -> str:
    return " && ".join(p.strip() for p in command.split("&&") if p.strip() and shlex.split(p)[0] != "pip")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def sandbox(folder: Path) -> Path:
    """Make ``folder`` look like the root of a checkout (see the module docstring)."""
    shutil.copytree(ROOT / "examples", folder / "examples")
    for name in ("dbc", "profiles", "stack"):
        (folder / name).symlink_to(ROOT / name, target_is_directory=True)
    return folder


def environment() -> dict[str, str]:
    env = dict(os.environ)
    env["PATH"] = f"{Path(sys.executable).parent}{os.pathsep}{env.get('PATH', '')}"
    env["PYTHONPATH"] = str(ROOT)  # python -c "import stack..." finds the checkout, as in its root
    env.pop("COLUMNS", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


@dataclass
class Runner:
    """Runs the commands of blocks in one working folder and ends what it started."""

    cwd: Path
    background: list[subprocess.Popen[str]] = field(default_factory=list)
    port: str | None = None

    def _line(self, command: str) -> str:
        if DEFAULT_PORT in command:
            self.port = self.port or str(free_port())
            command = command.replace(DEFAULT_PORT, self.port)
        return command

    def run(self, command: Command, timeout: float = TIMEOUT) -> str:
        """Run one command; return what it printed (stdout and stderr as they came). A non-zero exit
        status raises AssertionError with the output."""
        for program in programs(command.text):
            if program not in COMMANDS:
                raise AssertionError(
                    f"{command.text!r}: {program!r} is not a command the docs tests run; tag the block"
                )
        line = self._line(_without_pip(command.text))
        if not line:
            return ""
        if command.background:
            return self._start(line, timeout)
        proc = subprocess.run(
            ["bash", "-c", line],
            cwd=self.cwd,
            env=environment(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            timeout=timeout,
            stdin=subprocess.DEVNULL,
        )
        out = proc.stdout
        if proc.returncode != 0:
            raise AssertionError(f"{command.text!r} exited with status {proc.returncode}:\n{out}")
        return out

    def _start(self, line: str, timeout: float) -> str:
        proc = subprocess.Popen(
            ["bash", "-c", f"exec {line}"],
            cwd=self.cwd,
            env=environment(),
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            stdin=subprocess.DEVNULL,
            text=True,
            # Ctrl-C must reach it even when the tests run with SIGINT ignored (a background job)
            preexec_fn=_default_sigint,
        )
        self.background.append(proc)
        assert proc.stdout is not None
        first = _readline(proc, timeout)
        if not first:
            raise AssertionError(f"{line!r} ended before printing anything (status {proc.poll()})")
        return first

    def close(self) -> None:
        """End the background commands, the last started first, as a user would: Ctrl-C
        (SIGINT), then SIGTERM and SIGKILL for one that is still there after 5 s each."""
        for proc in reversed(self.background):
            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGKILL):
                if proc.poll() is not None:
                    break
                proc.send_signal(sig)
                with contextlib.suppress(subprocess.TimeoutExpired):
                    proc.wait(5)
            if proc.stdout:
                proc.stdout.close()
        self.background.clear()


def _default_sigint() -> None:
    signal.signal(signal.SIGINT, signal.SIG_DFL)


def _readline(proc: subprocess.Popen[str], timeout: float) -> str:
    """The first line a process prints, waited for on a thread (a pipe has no timeout)."""
    import threading

    got: list[str] = []
    done = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        got.append(proc.stdout.readline())
        done.set()

    threading.Thread(target=read, daemon=True).start()
    if not done.wait(timeout):
        raise AssertionError(f"no output within {timeout:g} s")
    return got[0]


# ---------------------------------------------------------------------------------- running
def run(block: Block, folder: Path) -> str:
    """Run ``block`` in ``folder`` (a `sandbox`) and return what it printed; check it against
    the output the page shows. A failure raises AssertionError naming the block."""
    if not block.runnable:
        raise ValueError(f"{block.name}: a {block.lang or 'plain'} block is not run")
    runner = Runner(folder)
    previous = Path.cwd()
    try:
        os.chdir(folder)
        printed = _run(block, runner)
    finally:
        os.chdir(previous)
        runner.close()
    if block.output is not None and not matches(block.output, printed):
        raise AssertionError(
            f"{block.name}: the output differs from the page's\n--- page\n{block.output}--- printed\n{printed}"
        )
    return printed


def _run(block: Block, runner: Runner) -> str:
    if block.lang == "python":
        out = io.StringIO()
        code = compile(block.code, block.name, "exec")
        with contextlib.redirect_stdout(out):
            exec(code, {"__name__": "__docs__"})
        return out.getvalue()
    if block.lang == "toml":
        path = runner.cwd / f"block_{block.line}.toml"
        path.write_text(block.code, encoding="utf-8")
        return runner.run(Command(f"canstack experiment {path.name}"))
    printed: list[str] = []
    for command in commands(block):
        out = runner.run(command)
        expected = command.expected
        if expected and runner.port:
            expected = expected.replace(DEFAULT_PORT, runner.port)
        if expected and not matches(expected, out):
            raise AssertionError(f"{block.name}: {command.text!r} printed\n{out}\n--- where the page shows\n{expected}")
        printed.append(out)
    return "".join(printed)
