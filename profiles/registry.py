"""The profiles a scenario can name, and what each adds to scenario files and results.

A profile module describes itself with a `ProfileKind` and registers it (`register`) when it is
imported; `profile_kinds()` imports the modules listed in `PROFILE_MODULES` first, so the
scenario checker and the runner know every profile without importing them by hand.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from profiles.analysis.rta import MessageSpec
    from profiles.base import Context, Profile
    from profiles.declarations import NodeDecl, Scenario
    from profiles.schema import Key
    from stack.controller.api import NodeAPI

__all__ = ["ProfileKind", "register", "profile_kinds", "profile_kind", "PROFILE_MODULES"]

PROFILE_MODULES = ["profiles.csma", "profiles.tdma", "profiles.canopen.scenario", "profiles.polling"]
"""Modules that register a profile when imported (each scheduling layer adds its own)."""


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
    readable table prints of the profile's figures (those under ``result_key``).
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


_KINDS: dict[str, ProfileKind] = {}
_loaded = False


def register(kind: ProfileKind) -> ProfileKind:
    """Make a profile known to scenario files (the name must be new)."""
    if kind.name in _KINDS and _KINDS[kind.name] is not kind:
        raise ValueError(f"profile {kind.name!r} is registered twice")
    _KINDS[kind.name] = kind
    return kind


def profile_kinds() -> dict[str, ProfileKind]:
    """Every registered profile by name (the profile modules are imported on first use)."""
    global _loaded
    if not _loaded:
        _loaded = True
        for mod in PROFILE_MODULES:
            importlib.import_module(mod)
    return dict(_KINDS)


def profile_kind(name: str) -> ProfileKind:
    """The profile named ``name`` (KeyError naming the known ones)."""
    kinds = profile_kinds()
    try:
        return kinds[name]
    except KeyError:
        raise KeyError(f"no profile {name!r}: one of {', '.join(sorted(kinds))}") from None
