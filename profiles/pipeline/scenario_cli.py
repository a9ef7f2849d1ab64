"""`canstack scenario TOOL ...`: tools that read a scenario file and write one.

The ``scenario`` command is registered under the ``canstack.commands`` entry point group; its
tools come from the ``canstack.scenario`` group, so that another package adds one without
touching this module: an entry point there names a function that takes the tools' subparsers
(argparse's ``add_subparsers`` object) and adds its parser, as `register_assign_ids` does.

``canstack scenario assign-ids IN.toml --out OUT.toml [--order opa|rpa|dm]`` writes the same
scenario with the messages' identifiers handed out again in the priority order the response-time
analysis finds (`profiles.analysis.priority`): Audsley's optimal assignment (the default), Davis
and Burns' robust assignment, or deadline monotonic. The set of identifiers stays the file's own;
everything else in the file — comments, layout, number formats — is kept (tomlkit edits the
document in place). Exit status 0 when every message is schedulable in the new order, 1 when no
order makes them so, or with ``dm`` when that order does not (the file is still written: the
messages no level could take are put at the top in deadline order), 2 on bad input. Only ``dm``
takes nodes with FIFO queues or mailboxes without abort; its verdict is then that of the FIFO
and mailbox bounds (`profiles.analysis.rta.analyse` with the nodes' queues), as
``canstack experiment`` gives it, not D07's priority-queue test.
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path
from typing import Any

from stack.cli import CliError
from stack.cli.runs import check_output

__all__ = ["register", "register_assign_ids"]


def register(sub: Any) -> None:
    """Add the ``scenario`` command and every tool of the ``canstack.scenario`` group."""
    from importlib.metadata import entry_points

    p = sub.add_parser(
        "scenario",
        help="tools that read a scenario file and write one (assign-ids, ...)",
        description="Tools on scenario files: each reads a scenario (TOML) and writes one.",
    )
    tools = p.add_subparsers(dest="tool", metavar="TOOL", parser_class=type(p))
    tools.required = True
    for ep in sorted(entry_points(group="canstack.scenario"), key=lambda e: e.name):
        ep.load()(tools)


def register_assign_ids(tools: Any) -> None:
    """Add ``assign-ids`` to the ``scenario`` command."""
    from profiles.analysis.priority import ORDERS

    p = tools.add_parser(
        "assign-ids",
        help="reassign the messages' identifiers in an optimal priority order",
        description="Write the scenario with its messages' identifiers handed out again in the priority order of "
        "Audsley's optimal assignment (opa, the default), Davis and Burns' robust assignment (rpa) or deadline "
        "monotonic (dm), by the response-time analysis of Davis et al. 2007. The file's own identifiers are reused; "
        "the rest of the file is kept as it is. Exit 0 when every message is schedulable in the new order, 1 when "
        "no order makes it so (the file is written all the same), 2 on bad input.",
    )
    p.add_argument("scenario", help="the scenario file (TOML)")
    p.add_argument("--out", required=True, help="the scenario file to write")
    p.add_argument("--order", choices=ORDERS, default="opa", help="the priority assignment (default: opa)")
    p.set_defaults(func=_assign_ids)


def _priority_like(d: Any) -> bool:
    """Whether the node offers its best pending frame, as D07's test assumes: a priority queue,
    mailboxes with abort (the engine aborts at once), or a single message."""
    return bool(len(d.messages) <= 1 or d.priority_queue or (d.policy == "mailbox" and d.abort))


def _eligible(scenario: Any, order: str) -> None:
    """Refuse a scenario whose identifiers the command may not permute, naming why."""
    for d in scenario.nodes:
        if d.profile != "csma":
            raise CliError(
                f"{scenario.source}: node {d.name!r} runs profile {d.profile!r}: identifiers are reassigned only on "
                "CSMA/CR buses (another profile's identifiers are part of its protocol)"
            )
        for m in d.messages:
            if m.interval_ns is None:
                raise CliError(f"{scenario.source}: message {m.name!r} has no period or minimum inter-arrival time")
        if order != "dm" and not _priority_like(d):
            raise CliError(
                f"{scenario.source}: node {d.name!r} uses a {d.queue} queue: --order {order} needs priority queues "
                "(its test is the priority-queue analysis); --order dm does not"
            )


def _rewrite(text: str, source: str, ids: dict[str, int]) -> str:
    """``text`` with the ``id`` of each message named in ``ids`` set to its new value, in the
    number format the file used (hexadecimal keeps its width)."""
    import tomlkit

    doc = tomlkit.parse(text)
    seen: set[str] = set()
    for node in doc.get("nodes", []):
        for msg in node.get("messages", []):
            name = str(msg.get("name"))
            if name not in ids:
                continue
            raw = msg["id"].as_string().strip() if hasattr(msg["id"], "as_string") else str(msg["id"])
            new = ids[name]
            if raw.lower().startswith("0x"):
                digits = f"{new:0{len(raw) - 2}X}"
                msg["id"] = tomlkit.value(
                    raw[:2] + (digits if raw[2:].isupper() or raw[2:].isdigit() else digits.lower())
                )
            else:
                msg["id"] = new
            seen.add(name)
    missing = sorted(set(ids) - seen)
    if missing:  # pragma: no cover - load_scenario read them from the same text
        raise CliError(f"{source}: message(s) {', '.join(missing)} not found in the file's [[nodes.messages]]")
    return tomlkit.dumps(doc)


def _assign_ids(args: argparse.Namespace) -> int:
    from profiles.analysis.priority import assign_priorities, identifiers_for
    from profiles.analysis.rta import ErrorModel, NodeQueue, analyse
    from profiles.pipeline.scenario import load_scenario
    from profiles.registry import profile_kind

    check_output(args.out, "--out")
    scenario = load_scenario(args.scenario)
    _eligible(scenario, args.order)
    # the CSMA/CR profile's model of its nodes' traffic (the experiments' analysis reads the same)
    specs = [s for d in scenario.nodes for s in (profile_kind(d.profile).traffic or (lambda d, sc: []))(d, scenario)]
    if not specs:
        raise CliError(f"{scenario.source}: no messages to reassign")
    errors = None
    if scenario.analysis.get("t_error_ms") is not None:
        errors = ErrorModel(round(scenario.analysis["t_error_ms"] * 1e6), scenario.analysis.get("error_burst") or 1)
    result = assign_priorities(
        specs, scenario.bitrate, order=args.order, errors=errors, data_bitrate=scenario.data_bitrate
    )
    ids = identifiers_for(specs, result.order)
    text = Path(args.scenario).read_text(encoding="utf-8")
    Path(args.out).write_text(_rewrite(text, scenario.source, ids), encoding="utf-8")
    by_name = {s.name: s for s in specs}
    changed = sum(1 for name, new in ids.items() if by_name[name].can_id != new)
    print(f"{args.out}: {args.order}: {changed} of {len(ids)} identifiers changed; priority order (highest first):")
    for name in result.order:
        ext = by_name[name].extended
        print(f"  {name}: 0x{ids[name]:{'08X' if ext else '03X'}}")
    queued = [d for d in scenario.nodes if not _priority_like(d)]  # only with --order dm (_eligible)
    if queued:
        # D07's test, which ordered the set, assumes priority queues: the verdict on this file is
        # the one `canstack experiment` gives, with the FIFO and mailbox bounds of its nodes
        queues = {d.name: NodeQueue(d.policy, d.mailboxes, d.abort) for d in scenario.nodes}
        renumbered = [dataclasses.replace(s, can_id=ids[s.name]) for s in specs]
        verdict = analyse(
            renumbered, scenario.bitrate, errors=errors, queues=queues, data_bitrate=scenario.data_bitrate
        )
        missed = [name for name, r in verdict.items() if not r.schedulable]
        if not missed:
            print("every message schedulable (Davis et al. 2007; FIFO and mailbox bounds of profiles.analysis.rta)")
            return 0
        print(
            f"not every message is schedulable in deadline-monotonic order with the FIFO and mailbox queues of "
            f"{', '.join(d.name for d in queued)}: {', '.join(missed)}",
            file=sys.stderr,
        )
        return 1
    if result.schedulable:
        print("every message schedulable (Davis et al. 2007)")
        return 0
    if args.order == "dm":
        print("not every message is schedulable in deadline-monotonic order (try --order opa)", file=sys.stderr)
    else:
        print(
            f"no order makes every message schedulable: {', '.join(result.unplaced)} could not be placed "
            "(put at the top in deadline order)",
            file=sys.stderr,
        )
    return 1
