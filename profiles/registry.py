"""The profiles a scenario can name, and what each adds to scenario files and results.

One convention for every profile package, built in or not: the package describes what it adds
in its ``kind`` module, as `ProfileKind` values gathered in a tuple ``KINDS``
(`profiles.csma.kind`, `profiles.polling.kind`, `profiles.tdma.kind`, `profiles.canopen.kind`).
Nothing registers itself when imported: on first use `profile_kinds()` reads the ``KINDS`` of
the built-in packages (`BUILT_IN`) and of every entry of the ``canstack.profiles`` entry point
group (`ENTRY_POINT_GROUP`), through which an installed distribution adds its own::

    [project.entry-points."canstack.profiles"]
    mine = "my_profile.kind:KINDS"

An entry may name a `ProfileKind` or a sequence of them. `register` adds one by hand (a test, a
notebook). The module of a kind's ``build`` is the profile's module: the experiment command
reads its ``PLOTS`` and the profiles study its ``express_message_set`` there.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Protocol

if TYPE_CHECKING:  # pragma: no cover
    from profiles.analysis.rta import MessageSpec
    from profiles.base import Context, Profile
    from profiles.declarations import NodeDecl, Scenario
    from profiles.schema import Key
    from stack.controller.api import NodeAPI

__all__ = [
    "ProfileKind",
    "register",
    "profile_kinds",
    "profile_kind",
    "BUILT_IN",
    "ENTRY_POINT_GROUP",
    "TimelineLayer",
    "FinishedRun",
]

BUILT_IN = ("profiles.csma.kind", "profiles.tdma.kind", "profiles.canopen.kind", "profiles.polling.kind")
"""The ``kind`` modules of the profile packages that ship with canstack (each has ``KINDS``)."""

ENTRY_POINT_GROUP = "canstack.profiles"
"""The entry point group through which installed distributions add profile kinds."""


class FinishedRun(Protocol):
    """What a profile's plot layer reads of a finished run (the pipeline's `Result` has it): the
    scenario, the bus trace (recorded runs) and the profiles' own figures by result key."""

    scenario: Scenario
    trace: list[Any]
    profiles: dict[str, Any]


TimelineLayer = Callable[[FinishedRun, Any, int, int, Mapping[str, Any]], None]
"""What a profile's module lists in ``PLOTS`` (name -> layer): ``layer(run, ax, t0, t1, colours)``
draws behind the frames of the bus timeline of a finished run, on the matplotlib axes ``ax``
between bus times ``t0`` and ``t1`` (ns), with the timeline's colour of each node. The experiment
pipeline draws the timeline around it (``canstack experiment --plot`` writes one image per name),
so a profile never imports the pipeline."""


@dataclass(frozen=True)
class ProfileKind:
    """What a profile brings to scenarios.

    ``name`` is the value of ``profile = ...`` in ``[[nodes]]``; ``build(node, decl, context)``
    makes the profile on a node; ``node_keys`` and ``message_keys`` are the keys it adds to
    ``[[nodes]]`` and ``[[nodes.messages]]`` of its nodes; ``timed_messages`` is False when its
    messages are released by the profile itself (a schedule, a poll) rather than by a period;
    ``tables`` are the top-level tables it owns (e.g. ``tdma``), checked by ``parse(scenario,
    tables)``, which may also check the nodes against them and store what it read in
    ``scenario.tables``; ``result_key`` and ``summarize(profiles, context)`` give the profile's
    own figures in the results (e.g. ``"master_slave"``); ``traffic(decl, scenario)`` is the
    worst-case model of a node's traffic for the response-time analysis (`MessageSpec` list) —
    without it the analysis does not apply to a bus that carries this profile's frames;
    ``bounds(scenario)`` gives the profile's own analytic worst case per message where it has one
    (message name -> (bound on the measured response in ns or None, a note)), printed as
    ``rta_ms`` where the CAN response-time analysis gives none; ``text(figures)`` the lines the
    readable table prints of the profile's figures (those under ``result_key``); ``fd_messages``
    is True when its messages may be CAN FD frames (``fd = true``), otherwise such a message —
    and a node's ``fd = true`` — is refused with ``fd_note`` saying why.
    """

    name: str
    build: Callable[[NodeAPI, NodeDecl, Context], Profile]
    node_keys: Mapping[str, Key] = field(default_factory=dict)
    message_keys: Mapping[str, Key] = field(default_factory=dict)
    timed_messages: bool = True
    tables: tuple[str, ...] = ()
    parse: Callable[[Scenario, dict[str, Any]], None] | None = None
    result_key: str | None = None
    summarize: Callable[[list[Profile], Context], dict[str, Any]] | None = None
    traffic: Callable[[NodeDecl, Scenario], list[MessageSpec]] | None = None
    bounds: Callable[[Scenario], dict[str, tuple[int | None, str | None]]] | None = None
    text: Callable[[dict[str, Any]], list[str]] | None = None
    description: str = ""
    fd_messages: bool = False
    fd_note: str = ""


_KINDS: dict[str, ProfileKind] = {}
_loaded = False


def register(kind: ProfileKind) -> ProfileKind:
    """Make a profile known to scenario files (the name must be new)."""
    if kind.name in _KINDS and _KINDS[kind.name] is not kind:
        raise ValueError(f"profile {kind.name!r} is registered twice")
    _KINDS[kind.name] = kind
    return kind


def _kinds_of(value: object, where: str) -> Iterable[ProfileKind]:
    """The kinds ``value`` holds: one `ProfileKind`, or a sequence of them (ValueError otherwise)."""
    items = (value,) if isinstance(value, ProfileKind) else value
    if not isinstance(items, (tuple, list)) or not all(isinstance(k, ProfileKind) for k in items):
        raise ValueError(f"{where}: {value!r} is not a ProfileKind nor a sequence of them")
    return items


def _load() -> None:
    """Register the built-in kinds, then those of the ``canstack.profiles`` entry points."""
    for module in BUILT_IN:
        for kind in _kinds_of(getattr(importlib.import_module(module), "KINDS", None), f"{module}.KINDS"):
            register(kind)
    from importlib.metadata import entry_points

    for ep in sorted(entry_points(group=ENTRY_POINT_GROUP), key=lambda e: e.name):
        where = f"entry point {ep.name} = {ep.value!r} ({ENTRY_POINT_GROUP})"
        try:
            value = ep.load()
        except Exception as exc:
            raise ValueError(f"{where}: cannot load it ({type(exc).__name__}: {exc})") from None
        for kind in _kinds_of(value, where):
            register(kind)


def profile_kinds() -> dict[str, ProfileKind]:
    """Every registered profile by name (the built-in packages and the entry points are read on
    first use)."""
    global _loaded
    if not _loaded:
        _loaded = True  # before loading: a kind module that asks for the kinds gets those so far
        try:
            _load()
        except BaseException:
            _loaded = False
            raise
    return dict(_KINDS)


def profile_kind(name: str) -> ProfileKind:
    """The profile named ``name`` (KeyError naming the known ones)."""
    kinds = profile_kinds()
    try:
        return kinds[name]
    except KeyError:
        raise KeyError(f"no profile {name!r}: one of {', '.join(sorted(kinds))}") from None
