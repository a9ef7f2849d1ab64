"""What the commands that run a simulation or write files share: output paths and the optional
libraries their writers need, checked before a run (a long simulation must not end in an error
with nothing written), and writing with the path in every error. (A simulation run in slices,
with a progress bar and Ctrl-C between slices, is `stack.io.progress`: library code runs it too.)
"""

from __future__ import annotations

import importlib.util
import os
from collections.abc import Callable
from pathlib import Path
from typing import Any, TypeVar

from stack.cli import CliError, plural

__all__ = [
    "check_output",
    "check_trace_output",
    "check_plot_output",
    "check_plot_dir",
    "writing",
    "WRITER_EXTRAS",
    "MAX_SIM_SECONDS",
    "trace_note",
    "trc_dropped",
]

T = TypeVar("T")

#: Trace suffixes whose python-can writer needs a library that is not a dependency of canstack:
#: suffix -> (module, canstack extra that installs it).
WRITER_EXTRAS = {".mf4": ("asammdf", "mf4")}

#: Longest simulated run a command accepts, in seconds of bus time: an hour at 1 Mbit/s is
#: about 30 million frames, minutes of computing; anything longer is a typo or needs a script.
MAX_SIM_SECONDS = 3600.0


def check_output(path: str, option: str) -> None:
    """An output file named on the command line: it must name a file (not a directory), in a
    directory that exists and can be written. Each failure names the option, the path and
    what is wrong with it."""
    if not path:
        raise CliError(f"{option} needs a file name")
    if os.path.isdir(path):
        raise CliError(f"{option} {path!r} is a directory, not a file")
    parent = os.path.dirname(os.path.abspath(path))
    # walk up to the first part that exists: a file there is not 'a missing directory'
    probe = parent
    while not os.path.exists(probe):
        probe = os.path.dirname(probe)
    if not os.path.isdir(probe):
        raise CliError(f"{option} {path!r}: {probe!r} is a file, not a directory")
    if probe != parent:
        raise CliError(f"{option} {path!r}: directory {parent!r} does not exist")
    if os.path.exists(path) and not os.access(path, os.W_OK):
        raise CliError(f"{option} {path!r}: the file exists and is not writable")
    if not os.access(parent, os.W_OK):
        raise CliError(f"{option} {path!r}: directory {parent!r} is not writable")


def check_trace_output(path: str, option: str = "--trace") -> str:
    """A trace file: a writable path, a suffix python-can has a writer for, and that writer's
    library installed. Returns the suffix."""
    from stack.io.tracefile import check_suffix

    check_output(path, option)
    suffix = check_suffix(path)
    need = WRITER_EXTRAS.get(suffix)
    if need is not None and importlib.util.find_spec(need[0]) is None:
        module, extra = need
        raise CliError(
            f"{option} {path!r}: python-can writes {suffix} files with {module}, which is not "
            f"installed: pip install 'canstack[{extra}]'"
        )
    return suffix


def check_plot_output(path: str, option: str = "--plot") -> None:
    """A plot file: a writable path, matplotlib installed (the optional ``plot`` extra), and a
    format matplotlib writes (by suffix; none means PNG)."""
    check_output(path, option)
    if importlib.util.find_spec("matplotlib") is None:
        raise CliError(f"{option} needs matplotlib, which is not installed: pip install 'canstack[plot]'")
    suffix = Path(path).suffix.lower().lstrip(".")
    known = ("png", "svg", "pdf", "ps", "eps", "jpg", "jpeg", "tif", "tiff", "webp")
    if suffix and suffix not in known:
        raise CliError(
            f"{option} {path!r}: unknown image suffix '.{suffix}'; use one of " + ", ".join("." + k for k in known)
        )


def check_plot_dir(path: str, option: str = "--plot") -> None:
    """A directory for plots: an existing directory, or new ones (``a/b``: both are made) under
    the first part of the path that exists, which must be a writable directory; and matplotlib
    installed (the optional ``plot`` extra)."""
    if not path:
        raise CliError(f"{option} needs a directory name")
    p = Path(path)
    if p.exists() and not p.is_dir():
        raise CliError(f"{option} {path!r}: is a file; give a directory for the plots")
    probe = p.absolute()
    while not probe.exists():
        probe = probe.parent
    if not probe.is_dir():
        raise CliError(f"{option} {path!r}: {str(probe)!r} is a file, not a directory")
    if not os.access(probe, os.W_OK):
        raise CliError(f"{option} {path!r}: directory {str(probe)!r} is not writable")
    if importlib.util.find_spec("matplotlib") is None:
        raise CliError(f"{option} needs matplotlib, which is not installed: pip install 'canstack[plot]'")


def writing(path: str, option: str, write: Callable[[], T]) -> T:
    """Run ``write`` (which writes ``path``); an OSError becomes one line naming the option, the
    path and the reason (an error such as a full disk carries no file name of its own)."""
    try:
        return write()
    except OSError as exc:
        reason = exc.strerror or str(exc)
        raise CliError(f"{option} {path!r}: cannot write: {reason}") from None


def trace_note(path: str, dropped: int) -> str:
    """What a trace format left out, said once: python-can's .trc writer holds no remote or
    error frames (``dropped`` of them were in the run)."""
    if not str(path).lower().endswith(".trc") or not dropped:
        return ""
    return f" ({plural(dropped, 'remote or error frame')} left out: .trc cannot hold them)"


def trc_dropped(bus: Any) -> int:
    """Remote and error frames in a simulated trace: what a .trc file cannot hold."""
    return sum(1 for r in bus.trace if r.kind != "frame" or r.frame.remote)
