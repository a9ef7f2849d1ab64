"""Scenario files: one bus, its nodes with their scheduling profiles and messages, faults, and
what to analyse and plot — read from TOML and checked before anything runs.

    [bus]
    bitrate = 500000          # bit/s
    duration = 2.0            # simulated seconds
    seed = 1
    data_bitrate = 2000000    # optional: a CAN FD bus, the data phase's bit/s (no default)

    [[nodes]]
    name = "engine"
    profile = "csma"          # csma (default) | the profiles registered in `profiles.registry`
    queue = "priority"        # priority | fifo | mailboxes:N | mailboxes-abort:N
    drift_ppm = 0             # the node's oscillator (read for every profile)
    fd = "fd"                 # on a CAN FD bus: fd (default) | tolerant | classic

    [[nodes.messages]]
    name = "EngineData"
    id = 0x100
    extended = false
    dlc = 8                   # or: length = 8 (bytes); CAN FD: dlc 0..15, length up to 64
    fd = false                # a CAN FD frame (needs data_bitrate); brs = true: its data phase at it
    period_ms = 10            # or: sporadic_ms = 20 (minimum inter-arrival; mean_ms for the mean)
    offset_ms = 0
    jitter_ms = 0             # release jitter, uniform in [0, jitter], seeded
    deadline_ms = 10          # default: the period

    [[faults]]                # optional: the kinds of `profiles.pipeline.faults`
    kind = "bit_errors"       # bit_errors | flip | stuck | disconnect | babbling_idiot | never_ack
    rate = 1e-5

It reads TOML into the declarations of the profile contract (`profiles.declarations`).

Every error names the file, the table and the key, and the rule it breaks (`ScenarioError`, a
ValueError: the CLI prints it on one line and exits with status 2).
"""

from __future__ import annotations

import math
import re
import sys
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from profiles.analysis.model import MAX_DATA_BITRATE
from profiles.base import frame_of
from profiles.declarations import MessageDecl, NodeDecl, Scenario, ms_to_ns
from profiles.pipeline.faults import read_fault
from profiles.registry import profile_kind, profile_kinds
from profiles.schema import (
    MAX_TIME_S,
    REQUIRED,
    Key,
    ScenarioError,
    identifier_rule,
    in_range,
    non_negative,
    non_negative_time,
    one_of,
    positive_time,
    read_table,
    show,
    where,
)
from stack.controller.node import FD, FD_KINDS
from stack.wire.coding import INTERMISSION_BITS
from stack.wire.frame import FD_LENGTHS, data_length

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

__all__ = [
    "load_scenario",
    "read_toml",
    "parse_scenario",
    "ScenarioError",
    "parse_queue",
    "BUS_KEYS",
    "NODE_KEYS",
    "MESSAGE_KEYS",
    "ANALYSIS_KEYS",
    "PLOT_KEYS",
]

MAX_DURATION_S = MAX_TIME_S  # 11.6 simulated days: longer is a units mistake
MIN_DURATION_S = 1e-6  # a microsecond: no frame fits in less
MAX_QUEUE = 1_000_000  # frames in a node's queue: more only holds a backlog that never drains


BUS_KEYS = {
    "bitrate": Key(int, REQUIRED, in_range(1_000, 1_000_000, "a CAN 2.0 bus runs at 1 kbit/s .. 1 Mbit/s"), "bit/s"),
    "duration": Key(
        float,
        REQUIRED,
        lambda v: (
            None
            if MIN_DURATION_S <= v <= MAX_DURATION_S
            else f"{v!r} must be at least {MIN_DURATION_S:g} (a microsecond: shorter carries no frame) and at most "
            f"{MAX_DURATION_S:g} simulated seconds"
        ),
        "simulated seconds",
    ),
    "seed": Key(int, 0, doc="seed of every random choice (jitter, sporadic arrivals, bit errors)"),
    "data_bitrate": Key(
        int,
        None,
        in_range(1_000, MAX_DATA_BITRATE, "a CAN FD data phase runs at the bitrate .. 16 Mbit/s"),
        "bit/s of the CAN FD data phase (makes the bus a CAN FD bus; none: a classical CAN bus)",
    ),
}

NODE_KEYS = {
    "name": Key(
        str,
        REQUIRED,
        lambda v: (
            None
            if v and v.isprintable() and not any(c.isspace() for c in v)
            else f"{v!r}: a node name is non-empty, without spaces or control characters"
        ),
    ),
    "profile": Key(str, "csma"),
    "queue": Key(str, "priority", doc="priority | fifo | mailboxes:N | mailboxes-abort:N"),
    "tx_queue_size": Key(int, 1024, in_range(1, MAX_QUEUE, "frames")),
    "rx_fifo_size": Key(int, 64, in_range(1, MAX_QUEUE, "frames")),
    "drift_ppm": Key(float, 0.0, in_range(-100_000, 100_000, "ppm of the node's oscillator")),
    "clock_offset_ms": Key(float, 0.0, lambda v: non_negative_time("a clock offset")(abs(v))),
    "listen_only": Key(bool, False),
    "fd": Key(
        str,
        None,
        one_of(*FD_KINDS),
        "the controller towards CAN FD: fd (FD enabled) | tolerant (ISO protocol exception) | classic (CAN 2.0, "
        "destroys FD frames); default: fd on a bus with data_bitrate, classic without",
    ),
    "app": Key(
        str,
        None,
        lambda v: app_rule(v),
        "application code called with (node, profile, context)",
    ),
    "messages": Key(list, []),
}

MESSAGE_KEYS = {
    "name": Key(str, REQUIRED, lambda v: None if v else "a message needs a name"),
    "id": Key(int, REQUIRED, non_negative()),
    "extended": Key(bool, False),
    "dlc": Key(
        int,
        None,
        in_range(0, 15, "a DLC code: 0..8, and 9..15 for 12..64 bytes of CAN FD"),
        "the DLC code (0..8; 9..15 mean 12..64 bytes in a CAN FD frame), or give length",
    ),
    "length": Key(
        int,
        None,
        in_range(0, 64, "data bytes: 0..8, or 12, 16, 20, 24, 32, 48, 64 in a CAN FD frame"),
        "data bytes (0..8; 12, 16, 20, 24, 32, 48, 64 in a CAN FD frame), or give dlc",
    ),
    "fd": Key(bool, False, doc="a CAN FD frame (needs [bus] data_bitrate)"),
    "brs": Key(bool, False, doc="bit rate switch: the FD frame's data phase at [bus] data_bitrate"),
    "data": Key(str, None, doc="payload as hex (default zeros)"),
    "remote": Key(bool, False),
    "period_ms": Key(float, None, positive_time("a period")),
    "sporadic_ms": Key(float, None, positive_time("a minimum inter-arrival time")),
    "mean_ms": Key(float, None, positive_time("a mean inter-arrival time")),
    "offset_ms": Key(float, 0.0, non_negative_time("an offset")),
    "jitter_ms": Key(float, 0.0, non_negative_time("a release jitter")),
    "deadline_ms": Key(float, None, positive_time("a deadline")),
}

ANALYSIS_KEYS = {
    "t_error_ms": Key(float, None, positive_time("the minimum time between errors of the simple error model")),
    "error_burst": Key(
        int,
        1,
        lambda v: None if v >= 1 else f"{v!r} must be at least 1",
        "errors in any window of t_error_ms (1: Tindell and Burns' simple model; more: bursts)",
    ),
    "stuffing": Key(
        str,
        "worst",
        one_of("worst", "exact"),
        "frame lengths: worst-case stuffing (eq. 1), or the exact length of each message's payload",
    ),
}

PLOT_KEYS = {
    "window_ms": Key(list, None, doc="[start, end] of the timeline, ms"),
    "bin_ms": Key(
        float,
        10.0,
        lambda v: (
            positive_time("the bus-load bin")(v)
            or (
                None
                if v >= MIN_BIN_MS
                else f"{v!r} is below {MIN_BIN_MS:g} ms (a bin shorter than a bit shows nothing)"
            )
        ),
    ),
}

MIN_BIN_MS = 0.001
"""The shortest bus-load bin, ms (a microsecond: a bit at 1 Mbit/s)."""

_DOTTED = re.compile(r"[A-Za-z_][A-Za-z0-9_]*(\.[A-Za-z_][A-Za-z0-9_]*)*$")


def app_rule(spec: str) -> str | None:
    """Rule of ``app``: ``module:function``, each a dotted Python name (the module importable,
    the function called with (node, profile, context))."""
    mod, sep, fn = spec.partition(":")
    if not sep or not _DOTTED.match(mod) or not _DOTTED.match(fn):
        return f"{show(spec)}: give 'module:function' (e.g. 'my_ecu:setup'), each a Python name"
    return None


def parse_queue(text: str, loc: str) -> tuple[str, int | None, bool]:
    """'priority' | 'fifo' | 'mailboxes:N' | 'mailboxes-abort:N' as (policy, mailboxes, abort)."""
    if text in ("priority", "fifo"):
        return text, None, False
    kind, _, count = text.partition(":")
    # isdigit() takes '²' and other digits int() refuses: ASCII digits only
    if kind in ("mailboxes", "mailboxes-abort") and count.isascii() and count.isdigit() and len(count) <= 4:
        if int(count) >= 1:
            return "mailbox", int(count), kind == "mailboxes-abort"
    raise ScenarioError(
        f"{loc}: queue: {show(text)} is not one of 'priority', 'fifo', 'mailboxes:N', "
        "'mailboxes-abort:N' (N from 1 to 9999 transmit mailboxes)"
    )


def load_scenario(path: str | Path) -> Scenario:
    """Read and check a scenario file (see the module docstring)."""
    return parse_scenario(read_toml(path), str(Path(path)))


def read_toml(path: str | Path) -> dict[str, Any]:
    """A scenario file's TOML as a dictionary, unchecked (`ScenarioError` naming the file when it
    cannot be read or is not TOML); `parse_scenario` checks it."""
    p = Path(path)
    try:
        text = p.read_bytes()
    except IsADirectoryError:
        raise ScenarioError(f"{p}: is a directory, not a scenario file") from None
    except FileNotFoundError:
        raise ScenarioError(f"{p}: no such scenario file") from None
    except OSError as exc:
        raise ScenarioError(f"{p}: cannot read it ({exc.strerror})") from None
    try:
        raw = tomllib.loads(text.decode("utf-8"))
    except UnicodeDecodeError:
        raise ScenarioError(f"{p}: not a text file (a scenario is TOML in UTF-8)") from None
    except tomllib.TOMLDecodeError as exc:
        raise ScenarioError(f"{p}: not valid TOML: {exc}") from None
    except RecursionError:
        raise ScenarioError(f"{p}: not a scenario: its tables or lists are nested too deep to read") from None
    except ValueError as exc:  # an integer of more digits than Python converts (4,300)
        raise ScenarioError(f"{p}: not valid TOML: {' '.join(str(exc).split()[:12])}") from None
    return raw


def parse_scenario(raw: Mapping[str, Any], source: str = "scenario") -> Scenario:
    """Check a scenario given as the dictionary TOML gives (see the module docstring)."""
    _check_integers(raw, source)
    kinds = profile_kinds()
    top = {
        "bus": Key(dict, REQUIRED),
        "nodes": Key(list, REQUIRED),
        "faults": Key(list, []),
        "analysis": Key(dict, {}),
        "plot": Key(dict, {}),
    }
    for kind in kinds.values():
        for name in kind.tables:
            top[name] = Key((dict, list), None)
    t = read_table(raw, top, where(source, "top level"))
    bus = read_table(t["bus"], BUS_KEYS, where(source, "[bus]"))
    if bus["data_bitrate"] is not None and bus["data_bitrate"] < bus["bitrate"]:
        raise ScenarioError(
            f"{where(source, '[bus]')}: data_bitrate: {bus['data_bitrate']} is below the bitrate {bus['bitrate']} "
            "(the data phase of a CAN FD frame is at least as fast as its arbitration; equal: FD without BRS gain)"
        )
    if not t["nodes"]:
        raise ScenarioError(f"{where(source, '[[nodes]]')}: a scenario needs at least one node")
    nodes: list[NodeDecl] = []
    for i, rn in enumerate(t["nodes"], 1):
        nodes.append(_node(rn, i, source))
    _check_unique(nodes, source)
    faults = [read_fault(rf, i, source, {n.name for n in nodes}) for i, rf in enumerate(t["faults"], 1)]
    analysis = read_table(t["analysis"], ANALYSIS_KEYS, where(source, "[analysis]"))
    plot = read_table(t["plot"], PLOT_KEYS, where(source, "[plot]"))
    w = plot["window_ms"]
    if w is not None and not (
        len(w) == 2
        and all(isinstance(x, (int, float)) and not isinstance(x, bool) and math.isfinite(x) for x in w)
        and 0 <= w[0] < w[1] <= MAX_TIME_S * 1e3
    ):
        raise ScenarioError(
            f"{where(source, '[plot]')}: window_ms: {show(w)} must be [start, end] in ms with 0 <= start < end "
            "(finite numbers)"
        )
    sc = Scenario(
        source=source,
        bitrate=bus["bitrate"],
        duration_ns=round(bus["duration"] * 1e9),
        seed=bus["seed"],
        nodes=nodes,
        faults=faults,
        analysis=analysis,
        plot=plot,
        raw=dict(raw),
        data_bitrate=bus["data_bitrate"],
    )
    _check_fd(sc)
    for kind in kinds.values():
        if kind.parse is not None:
            kind.parse(sc, {name: raw[name] for name in kind.tables if name in raw})
    sc.warnings.extend(_frame_time_warnings(sc))
    return sc


def _check_fd(sc: Scenario) -> None:
    """CAN FD on this bus (ISO 11898-1:2015, as `stack.bus.sim.SimBus` runs it): an FD frame or
    an FD-enabled node needs a bus with a data bit rate — there is no default, since a bus without
    one is a classical CAN bus whose nodes are CAN 2.0 controllers (give data_bitrate = bitrate for
    FD frames without a faster data phase); only an FD-enabled node sends FD frames. An FD message
    that no other FD-enabled node can acknowledge is a warning."""
    fd_bus = sc.data_bitrate is not None
    for n in sc.nodes:
        loc = where(sc.source, f"[[nodes]] {n.name!r}")
        if n.fd == FD and not fd_bus:
            raise ScenarioError(
                f"{loc}: fd: 'fd': an FD-enabled controller needs a CAN FD bus: give [bus] data_bitrate (bit/s of "
                "the data phase; equal to bitrate for FD frames without bit rate switching)"
            )
        for m in n.messages:
            mloc = where(sc.source, f"[[nodes]] {n.name!r}", f"[[nodes.messages]] {m.name!r}")
            key = "brs" if m.brs else "fd"
            if m.fd and not fd_bus:
                raise ScenarioError(
                    f"{mloc}: {key}: true: a CAN FD frame needs a CAN FD bus: give [bus] data_bitrate (bit/s of the "
                    "data phase; equal to bitrate for FD frames without bit rate switching)"
                )
            if m.fd and n.fd is not None and n.fd != FD:
                raise ScenarioError(
                    f"{mloc}: fd: true: node {n.name!r} is {n.fd!r} (fd = {n.fd!r}): only an FD-enabled controller "
                    "(fd = 'fd') sends CAN FD frames"
                )
            if m.fd and not any(o is not n and o.fd in (None, FD) and not o.listen_only for o in sc.nodes):
                # only FD-enabled nodes acknowledge an FD frame (a tolerant one integrates meanwhile)
                sc.warnings.append(
                    f"{mloc}: fd: true: no other FD-enabled node acknowledges it: every attempt ends in an ACK error"
                )


def _check_integers(raw: Any, source: str, path: str = "") -> None:
    """Refuse an integer beyond 64 bits anywhere in the file, naming where it is: no key of a
    scenario takes one, and one of thousands of digits cannot even be printed in a message."""
    items = raw.items() if isinstance(raw, Mapping) else enumerate(raw) if isinstance(raw, list) else ()
    for k, v in items:
        here = f"{path}.{k}" if path and isinstance(k, str) else f"{path}[{k}]" if path else str(k)
        if isinstance(v, int) and not isinstance(v, bool) and abs(v) >= 1 << 64:
            raise ScenarioError(f"{source}: {here}: {show(v)} is outside any range a scenario uses (at most 64 bits)")
        if isinstance(v, (Mapping, list)):
            _check_integers(v, source, here)


def _frame_time_warnings(sc: Scenario) -> list[str]:
    """Periods and deadlines shorter than the message's own frame on this bus (its exact stuffed
    length with the intermission): allowed, but the queue only grows, or every instance misses.
    A period shorter than one bit is refused (`ScenarioError`)."""
    out = []
    for n in sc.nodes:
        for m in n.messages:
            bits = frame_of(m).bits
            frame_ns = bits.duration_ns(sc.bitrate, sc.data_bitrate) + INTERMISSION_BITS * 1e9 / sc.bitrate
            loc = where(sc.source, f"[[nodes]] {n.name!r}", f"[[nodes.messages]] {m.name!r}")
            what = f"the frame's own time on the bus ({frame_ns / 1e6:.4g} ms at {sc.bitrate} bit/s)"
            key = "period_ms" if m.period_ns is not None else "sporadic_ms"
            if m.interval_ns is not None and m.interval_ns * sc.bitrate < 1e9:
                raise ScenarioError(
                    f"{loc}: {key}: {m.interval_ns / 1e6:g} is shorter than one bit at {sc.bitrate} bit/s "
                    f"({1e3 / sc.bitrate:g} ms): nothing on a CAN bus happens that often"
                )
            if m.interval_ns is not None and m.interval_ns < frame_ns:
                out.append(f"{loc}: {key}: {m.interval_ns / 1e6:g} is shorter than {what}: its queue only grows")
            if m.deadline_ns is not None and m.deadline_ns < frame_ns:
                out.append(f"{loc}: deadline_ms: {m.deadline_ns / 1e6:g} is shorter than {what}: every instance misses")
    return out


def _node(rn: Any, i: int, source: str) -> NodeDecl:
    label = f"[[nodes]] #{i}" + (f" {show(rn.get('name'))}" if isinstance(rn, Mapping) and "name" in rn else "")
    loc = where(source, label)
    if not isinstance(rn, Mapping):
        raise ScenarioError(f"{loc}: expected a table, got {show(rn)}")
    profile = rn.get("profile", "csma")
    kinds = profile_kinds()
    if not isinstance(profile, str) or profile not in kinds:
        raise ScenarioError(f"{loc}: profile: {show(profile)} is not one of {', '.join(map(repr, sorted(kinds)))}")
    kind = profile_kind(profile)
    if not kind.fd_messages:
        _refuse_fd(rn, loc, profile, kind.fd_note)
    d = read_table(rn, NODE_KEYS, loc, extra=kind.node_keys)
    _policy, mailboxes, abort = parse_queue(d["queue"], loc)
    messages = []
    for j, rm in enumerate(d["messages"], 1):
        messages.append(_message(rm, j, source, label, d["name"], kind.timed_messages, kind.message_keys))
    options = {k: d[k] for k in kind.node_keys}
    return NodeDecl(
        name=d["name"],
        profile=profile,
        queue=d["queue"],
        mailboxes=mailboxes,
        abort=abort,
        tx_queue_size=d["tx_queue_size"],
        rx_fifo_size=d["rx_fifo_size"],
        drift_ppm=float(d["drift_ppm"]),
        clock_offset_ns=ms_to_ns(d["clock_offset_ms"]),
        listen_only=d["listen_only"],
        app=d["app"],
        messages=messages,
        options=options,
        fd=d["fd"],
    )


def _refuse_fd(rn: Mapping[str, Any], loc: str, profile: str, note: str) -> None:
    """A profile whose frames are classical: a node's ``fd = true`` or a message's is refused
    here, before the keys' own checks, with the profile's reason (``ProfileKind.fd_note``)."""
    why = note or f"{profile} nodes send classical CAN frames only (CAN FD messages go on csma nodes)"
    if rn.get("fd") is True:
        raise ScenarioError(f"{loc}: fd: true: {why}")
    messages = rn.get("messages")
    if isinstance(messages, list):
        for j, rm in enumerate(messages, 1):
            if isinstance(rm, Mapping) and rm.get("fd") is True:
                label = f"[[nodes.messages]] #{j}" + (f" {show(rm.get('name'))}" if "name" in rm else "")
                raise ScenarioError(f"{loc} > {label}: fd: true: {why}")


def _message(
    rm: Any, j: int, source: str, node_label: str, node: str, timed: bool, extra: Mapping[str, Key]
) -> MessageDecl:
    label = f"[[nodes.messages]] #{j}" + (
        f" {show(rm.get('name'))}" if isinstance(rm, Mapping) and "name" in rm else ""
    )
    loc = where(source, node_label, label)
    d = read_table(rm, MESSAGE_KEYS, loc, extra=extra)
    rule = identifier_rule(d["extended"])(d["id"])
    if rule is not None:
        raise ScenarioError(f"{loc}: id: {rule}")
    if d["period_ms"] is not None and d["sporadic_ms"] is not None:
        raise ScenarioError(f"{loc}: give period_ms (periodic) or sporadic_ms (sporadic), not both")
    if timed and d["period_ms"] is None and d["sporadic_ms"] is None:
        raise ScenarioError(f"{loc}: key 'period_ms' or 'sporadic_ms' is required (when the message is released)")
    if d["mean_ms"] is not None:
        if d["sporadic_ms"] is None:
            raise ScenarioError(f"{loc}: mean_ms: only a sporadic message (sporadic_ms) has a mean inter-arrival time")
        if d["mean_ms"] < d["sporadic_ms"]:
            raise ScenarioError(
                f"{loc}: mean_ms: {d['mean_ms']!r} is below the minimum inter-arrival sporadic_ms {d['sporadic_ms']!r}"
            )
    interval = d["period_ms"] if d["period_ms"] is not None else d["sporadic_ms"]
    if interval is not None and d["jitter_ms"] >= interval:
        raise ScenarioError(f"{loc}: jitter_ms: {d['jitter_ms']!r} must be below the period {interval!r} ms")
    dlc = _dlc(d, loc)
    data = None
    if d["data"] is not None:
        try:
            data = bytes.fromhex(d["data"])
        except ValueError:
            raise ScenarioError(f"{loc}: data: {show(d['data'])} is not hex bytes") from None
        want = data_length(dlc, d["fd"])
        if len(data) != want and not d["remote"]:
            size = (
                f"length {want}"
                if d["length"] is not None
                else f"dlc {dlc}" + (f" ({want} bytes)" if want != dlc else "")
            )
            raise ScenarioError(f"{loc}: data: {len(data)} byte{'s' if len(data) != 1 else ''} given for {size}")
    if d["remote"] and data is not None:
        raise ScenarioError(f"{loc}: data: a remote frame carries no data (its dlc is the length it requests)")
    deadline = d["deadline_ms"] if d["deadline_ms"] is not None else interval
    return MessageDecl(
        name=d["name"],
        node=node,
        can_id=d["id"],
        extended=d["extended"],
        dlc=dlc,
        data=data,
        remote=d["remote"],
        period_ns=None if d["period_ms"] is None else ms_to_ns(d["period_ms"]),
        sporadic_ns=None if d["sporadic_ms"] is None else ms_to_ns(d["sporadic_ms"]),
        mean_ns=None if d["mean_ms"] is None else ms_to_ns(d["mean_ms"]),
        offset_ns=ms_to_ns(d["offset_ms"]),
        jitter_ns=ms_to_ns(d["jitter_ms"]),
        deadline_ns=None if deadline is None else ms_to_ns(deadline),
        options={k: d[k] for k in extra},
        fd=d["fd"],
        brs=d["brs"],
    )


def _dlc(d: Mapping[str, Any], loc: str) -> int:
    """The DLC code of a message from ``dlc`` or ``length`` (one of them, not both), checked
    against its format (ISO 11898-1:2015): a classical frame 0..8 (a remote frame's dlc is the
    length it requests), a CAN FD frame 0..15 — 9..15 are 12, 16, 20, 24, 32, 48, 64 bytes — and
    no remote frame in CAN FD (RRS is always dominant); ``brs`` only in an FD frame."""
    if d["brs"] and not d["fd"]:
        raise ScenarioError(f"{loc}: brs: true needs fd = true (bit rate switching exists only in CAN FD frames)")
    if d["fd"] and d["remote"]:
        raise ScenarioError(
            f"{loc}: remote: true with fd = true: CAN FD has no remote frames (its RRS bit is always dominant); "
            "a remote frame is classical (fd = false)"
        )
    if d["dlc"] is not None and d["length"] is not None:
        raise ScenarioError(f"{loc}: give dlc (the DLC code) or length (data bytes), not both")
    if d["dlc"] is None and d["length"] is None:
        raise ScenarioError(f"{loc}: key 'dlc' or 'length' is required (the DLC code, or the data bytes)")
    if d["length"] is not None:
        n = d["length"]
        if d["fd"]:
            if n not in FD_LENGTHS:
                raise ScenarioError(
                    f"{loc}: length: {n} is not a CAN FD data length: one of 0..8, 12, 16, 20, 24, 32, 48, 64"
                )
            return FD_LENGTHS.index(n)
        if n > 8:
            raise ScenarioError(
                f"{loc}: length: {n} is outside 0..8 (a CAN 2.0 data frame carries 0..8 bytes; up to 64 with fd = true)"
            )
        return int(n)
    dlc = int(d["dlc"])
    if not d["fd"] and dlc > 8:
        raise ScenarioError(
            f"{loc}: dlc: {dlc} is outside 0..8 (a CAN 2.0 data frame carries 0..8 bytes; dlc 9..15 are CAN FD "
            "lengths: fd = true)"
        )
    return dlc


def _check_unique(nodes: list[NodeDecl], source: str) -> None:
    seen: dict[str, int] = {}
    for i, n in enumerate(nodes, 1):
        if n.name in seen:
            raise ScenarioError(
                f"{where(source, f'[[nodes]] #{i} {n.name!r}')}: name: {n.name!r} is already the "
                f"name of node #{seen[n.name]} (node names are unique on a bus)"
            )
        seen[n.name] = i
    names: dict[str, str] = {}
    ids: dict[tuple[int, bool, bool], str] = {}
    for n in nodes:
        for m in n.messages:
            loc = where(source, f"[[nodes]] {n.name!r}", f"[[nodes.messages]] {m.name!r}")
            if m.name in names:
                raise ScenarioError(
                    f"{loc}: name: {m.name!r} is already a message of node {names[m.name]!r} "
                    "(message names are unique in a scenario)"
                )
            names[m.name] = n.name
            key = (m.can_id, m.extended, m.remote)
            if key in ids:
                raise ScenarioError(
                    f"{loc}: id: {m.id_text} is already used by message {ids[key]!r}: two senders "
                    "of one identifier collide on the bus (each identifier has one sender)"
                )
            ids[key] = m.name
