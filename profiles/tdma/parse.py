"""Reading the ``[tdma]`` table of a scenario (ISO 11898-4, TTCAN; the terms, the ranges and
their sources are in `profiles.tdma.schedule`): its keys, the checks of the table and of each
time window against the scenario's nodes, and the profile's ``parse`` hook. Every refusal is a
`ScenarioError` naming the file, the table, the key and the rule."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

from profiles.analysis.rta import ERROR_FRAME_BITS, frame_bits_worst
from profiles.schema import (
    REQUIRED,
    Key,
    ScenarioError,
    in_range,
    non_negative,
    non_negative_time,
    one_of,
    positive,
    positive_time,
    read_table,
    where,
)
from profiles.tdma.schedule import (
    ARBITRATING,
    CYCLE_TIME_NTU,
    EXCLUSIVE,
    FREE,
    MATRIX_SIZES,
    MAX_TIME_MASTERS,
    MERGED,
    REF_OFFSET_LIMIT,
    SINGLE,
    TUR_RANGE,
    TX_ENABLE_NTU,
    Schedule,
    Window,
    frame_ns_worst,
)

if TYPE_CHECKING:  # pragma: no cover
    from profiles.declarations import MessageDecl, NodeDecl, Scenario

__all__ = ["parse_schedule", "check_scenario", "TDMA_KEYS", "WINDOW_KEYS"]

DEFAULT_TX_ENABLE_NTU = 16
DEFAULT_INITIAL_REF_OFFSET = 127


def _power_of_two(v: int) -> bool:
    return v >= 1 and v & (v - 1) == 0


def _us(v: float) -> int:
    return round(v * 1000)


TDMA_KEYS = {
    "reference_id": Key(
        int,
        REQUIRED,
        non_negative(),
        "identifier of the reference message; its 3 LSBs carry the time master's priority",
    ),
    "reference_extended": Key(bool, False),
    "time_masters": Key(list, REQUIRED, doc="potential time masters (node names), highest priority first"),
    "basic_cycle_us": Key(float, REQUIRED, positive_time("the basic cycle", "us"), "µs"),
    "matrix_cycles": Key(
        int,
        1,
        lambda v: (
            None
            if v in MATRIX_SIZES
            else f"{v!r} is not one of {', '.join(map(str, MATRIX_SIZES))} (a system matrix has 2^n basic "
            "cycles, Cycle_Count 0..63)"
        ),
    ),
    "tx_enable_us": Key(
        float, None, positive_time("the Tx_Enable window", "us"), f"default {DEFAULT_TX_ENABLE_NTU} NTU; 1..16 NTU"
    ),
    "level": Key(
        int,
        1,
        lambda v: (
            None
            if v in (1, 2)
            else f"{v!r} is not 1 or 2 (TTCAN level 1: cycle "
            "synchronisation; level 2: global time and drift correction)"
        ),
    ),
    "initial_ref_offset": Key(
        int, DEFAULT_INITIAL_REF_OFFSET, in_range(0, REF_OFFSET_LIMIT, "NTU, the backup masters' Initial_Ref_Offset")
    ),
    "watch_trigger_us": Key(
        float,
        None,
        positive_time("the Watch_Trigger", "us"),
        "cycle time at which a missing reference message is an error",
    ),
    "error_budget_bits": Key(int, 0, non_negative("bits an error may add inside a window")),
    "tur": Key(
        float,
        None,
        lambda v: (
            None
            if TUR_RANGE[0] <= v <= TUR_RANGE[1]
            else f"{v!r} is not {TUR_RANGE[0]:.4f}..{TUR_RANGE[1]:g} (a time unit ratio NC/DC with NC "
            "0x10000..0x1FFFF and DC 0x0001..0x3FFF)"
        ),
        "level 2: NTU / CAN clock period",
    ),
    "can_clock_mhz": Key(
        float, None, in_range(1, 1000, "MHz, a CAN controller's clock"), "level 2: the clock the NTU is counted in, MHz"
    ),
    "gap_mode": Key(bool, False, doc="Next_is_Gap (event-synchronised cycles): not modelled, refused"),
    "windows": Key(list, REQUIRED),
}

WINDOW_KEYS = {
    "start_us": Key(float, REQUIRED, non_negative_time("", "us"), "cycle time of the window's start, µs"),
    "length_us": Key(float, REQUIRED, positive_time("a window length", "us"), "µs"),
    "kind": Key(str, REQUIRED, one_of(EXCLUSIVE, ARBITRATING, FREE)),
    "messages": Key(list, []),
    "base_cycle": Key(int, 0, non_negative(), "the first basic cycle of the matrix that uses the window"),
    "repeat": Key(int, 1, positive("a repeat factor"), "the window is used every `repeat` basic cycles"),
    "arbitration": Key(str, None, one_of(SINGLE, MERGED), "arbitrating windows: single | merged (default)"),
}


def parse_schedule(scenario: Scenario, raw: Any) -> Schedule:
    """Check the ``[tdma]`` table of ``scenario`` against its nodes and return the `Schedule`.
    Every refusal is a `ScenarioError` naming the file, the table, the key and the rule."""
    src = scenario.source
    loc = where(src, "[tdma]")
    t = read_table(raw, TDMA_KEYS, loc)
    bitrate = scenario.bitrate
    bit_ns = 1e9 / bitrate
    tdma_nodes = {n.name: n for n in scenario.nodes if n.profile == "tdma"}
    owners = {m.name: n.name for n in tdma_nodes.values() for m in n.messages}
    decls = {m.name: m for n in tdma_nodes.values() for m in n.messages}

    masters = t["time_masters"]
    if not masters or len(masters) > MAX_TIME_MASTERS:
        raise ScenarioError(
            f"{loc}: time_masters: {len(masters)} names given: a TTCAN network has 1 to "
            f"{MAX_TIME_MASTERS} potential time masters (three identifier bits carry the priority)"
        )
    for name in masters:
        if not isinstance(name, str) or name not in tdma_nodes:
            raise ScenarioError(f"{loc}: time_masters: {name!r} is not a node with profile = 'tdma'")
    if len(set(masters)) != len(masters):
        dup = next(m for m in masters if masters.count(m) > 1)
        raise ScenarioError(
            f"{loc}: time_masters: {dup!r} is named twice (each potential time master has one priority)"
        )

    ref_id, ref_ext = t["reference_id"], t["reference_extended"]
    top = 0x1FFFFFFF if ref_ext else 0x7FF
    if ref_id & 7:
        raise ScenarioError(
            f"{loc}: reference_id: 0x{ref_id:X} has its three least significant bits set: they carry "
            f"the time master's priority (ISO 11898-4); give 0x{ref_id & ~7:X}"
        )
    if ref_id + len(masters) - 1 > top:
        kind = "an extended (29-bit)" if ref_ext else "a standard (11-bit)"
        raise ScenarioError(
            f"{loc}: reference_id: 0x{ref_id:X} with {len(masters)} time masters is not {kind} identifier 0..0x{top:X}"
        )
    for m in scenario.messages:
        if m.extended == ref_ext and not m.remote and ref_id <= m.can_id < ref_id + len(masters):
            raise ScenarioError(
                f"{loc}: reference_id: 0x{ref_id:X}..0x{ref_id + len(masters) - 1:X} (the reference "
                f"messages of {len(masters)} time masters) includes message {m.name!r} ({m.id_text}): "
                "each identifier has one sender"
            )

    if t["gap_mode"]:
        raise ScenarioError(
            f"{loc}: gap_mode: gap mode (Next_is_Gap: a basic cycle that waits for an event before its "
            "reference message, ISO 11898-4) is not modelled: canstack's time masters send every reference "
            "message at its time mark (leave gap_mode out)"
        )
    level = t["level"]
    ntu = _ntu_of(t, level, bit_ns, loc)
    basic = _us(t["basic_cycle_us"])
    _whole_ntu(basic, ntu, loc, "basic_cycle_us", t["basic_cycle_us"])
    if basic > CYCLE_TIME_NTU * ntu:
        raise ScenarioError(
            f"{loc}: basic_cycle_us: {t['basic_cycle_us']:g} µs is {basic / ntu:.0f} NTU "
            f"({ntu / 1000:g} µs each): Cycle_Time counts 16 bits (at most {CYCLE_TIME_NTU} NTU = "
            f"{CYCLE_TIME_NTU * ntu / 1000:g} µs)"
        )
    if t["tx_enable_us"] is not None:
        tx_enable = _us(t["tx_enable_us"])
        _whole_ntu(tx_enable, ntu, loc, "tx_enable_us", t["tx_enable_us"])
        lo, hi = TX_ENABLE_NTU
        if not lo <= round(tx_enable / ntu) <= hi:
            raise ScenarioError(
                f"{loc}: tx_enable_us: {t['tx_enable_us']:g} µs is {tx_enable / ntu:g} NTU: the Tx_Enable window "
                f"is {lo}..{hi} NTU ({lo * ntu / 1000:g}..{hi * ntu / 1000:g} µs of {ntu / 1000:g} µs NTU; "
                "ISO 11898-4 as M_TTCAN's TTOCF.TEW holds it)"
            )
    else:
        tx_enable = round(DEFAULT_TX_ENABLE_NTU * ntu)
    ref_dlc = 1 if level == 1 else 4
    ref_ns = frame_ns_worst(ref_dlc, ref_ext, False, bit_ns)
    if basic < ref_ns:
        raise ScenarioError(
            f"{loc}: basic_cycle_us: {t['basic_cycle_us']:g} µs is shorter than the reference message that "
            f"starts every basic cycle ({ref_ns / 1000:g} µs at {bitrate} bit/s, worst-case stuffing)"
        )
    offset = t["initial_ref_offset"]
    latest_ref = basic + round(offset * ntu) + ref_ns
    if t["watch_trigger_us"] is None:
        # past the backups' Tx_Ref_Trigger and room for their reference message and one
        # retransmission after an error frame, rounded up to a whole NTU
        watch = latest_ref + 2 * round((frame_bits_worst(ref_dlc, ref_ext) + ERROR_FRAME_BITS) * bit_ns)
        watch = math.ceil(watch / ntu - 1e-9) * ntu
        watch = round(watch)
    else:
        watch = _us(t["watch_trigger_us"])
        _whole_ntu(watch, ntu, loc, "watch_trigger_us", t["watch_trigger_us"])
        if watch <= latest_ref:
            raise ScenarioError(
                f"{loc}: watch_trigger_us: {t['watch_trigger_us']:g} µs must be after the backup "
                f"masters' reference message (the basic cycle {basic / 1000:g} µs + "
                f"Initial_Ref_Offset {offset} NTU + its {ref_ns / 1000:g} µs = "
                f"{latest_ref / 1000:g} µs)"
            )
    if watch > CYCLE_TIME_NTU * ntu:
        raise ScenarioError(
            f"{loc}: watch_trigger_us: the Watch_Trigger at {watch / 1000:g} µs is past the 16-bit "
            f"Cycle_Time ({CYCLE_TIME_NTU} NTU = {CYCLE_TIME_NTU * ntu / 1000:g} µs): shorten "
            "basic_cycle_us"
        )
    budget_ns = round(t["error_budget_bits"] * bit_ns)
    matrix = t["matrix_cycles"]

    windows: list[Window] = []
    for i, rw in enumerate(t["windows"], 1):
        windows.append(
            _window(
                rw,
                i,
                src,
                decls,
                owners,
                tdma_nodes,
                scenario,
                basic,
                matrix,
                ref_ns,
                budget_ns,
                tx_enable,
                bit_ns,
                ntu,
            )
        )
    _check_overlaps(windows, src, matrix)

    message_windows: dict[str, list[int]] = {}
    for pos, w in enumerate(windows):
        for name in w.messages:
            message_windows.setdefault(name, []).append(pos)
    for n in tdma_nodes.values():
        for m in n.messages:
            mloc = where(src, f"[[nodes]] {n.name!r}", f"[[nodes.messages]] {m.name!r}")
            if m.name not in message_windows:
                raise ScenarioError(
                    f"{mloc}: in no [[tdma.windows]]: a TDMA message is sent only in its time windows "
                    "(name it in a window's messages)"
                )
            _check_untimed(m, mloc)

    frame_ns = {name: frame_ns_worst(d.dlc, d.extended, d.remote, bit_ns) for name, d in decls.items()}
    gated = tuple(n.name for n in scenario.nodes if n.profile == "csma" and n.options.get("tdma_gated", True))
    sched = Schedule(
        reference_id=ref_id,
        reference_extended=ref_ext,
        masters=tuple(masters),
        basic_cycle_ns=basic,
        matrix_cycles=matrix,
        tx_enable_ns=tx_enable,
        level=level,
        initial_ref_offset=offset,
        watch_ns=watch,
        error_budget_bits=t["error_budget_bits"],
        bitrate=bitrate,
        windows=tuple(windows),
        ntu_ns=ntu,
        tur=t["tur"],
        can_clock_mhz=t["can_clock_mhz"],
        message_windows={k: tuple(v) for k, v in message_windows.items()},
        owners=owners,
        frame_ns=frame_ns,
        gated=gated,
    )
    _check_gated(scenario, sched)
    return sched


def _window(
    rw: Any,
    i: int,
    src: str,
    decls: dict[str, MessageDecl],
    owners: dict[str, str],
    tdma_nodes: dict[str, NodeDecl],
    scenario: Scenario,
    basic: int,
    matrix: int,
    ref_ns: int,
    budget_ns: int,
    tx_enable: int,
    bit_ns: float,
    ntu: float,
) -> Window:
    loc = where(src, "[tdma]", f"[[tdma.windows]] #{i}")
    d = read_table(rw, WINDOW_KEYS, loc)
    start, length = _us(d["start_us"]), _us(d["length_us"])
    _whole_ntu(start, ntu, loc, "start_us", d["start_us"])
    _whole_ntu(length, ntu, loc, "length_us", d["length_us"])
    kind = d["kind"]
    arbitration = d["arbitration"]
    if arbitration is not None and kind != ARBITRATING:
        raise ScenarioError(
            f"{loc}: arbitration: {arbitration!r}: only an arbitrating window is single or merged (this one is {kind})"
        )
    if kind == ARBITRATING and arbitration is None:
        arbitration = MERGED
    triggered = kind == EXCLUSIVE or arbitration == SINGLE
    repeat, base = d["repeat"], d["base_cycle"]
    if not _power_of_two(repeat):
        raise ScenarioError(
            f"{loc}: repeat: {repeat} is not a power of two (a message repeats every 1, 2, 4, … "
            "basic cycles: the standard's Repeat_Factor)"
        )
    if repeat > matrix:
        raise ScenarioError(
            f"{loc}: repeat: {repeat} is more than matrix_cycles {matrix} (the matrix repeats every "
            f"{matrix} basic cycles)"
        )
    if base >= repeat:
        raise ScenarioError(
            f"{loc}: base_cycle: {base} must be below repeat {repeat} (the first basic cycle of the "
            f"matrix that uses the window, 0..{repeat - 1}: the standard's Cycle_Offset)"
        )
    if start < ref_ns:
        raise ScenarioError(
            f"{loc}: start_us: {d['start_us']:g} µs overlaps the reference message, which takes "
            f"the first {ref_ns / 1000:g} µs of every basic cycle (its worst-case length with "
            "intermission)"
        )
    if start + length > basic:
        raise ScenarioError(
            f"{loc}: length_us: the window ends at {(start + length) / 1000:g} µs, past the end of "
            f"the basic cycle ({basic / 1000:g} µs, where the next reference message starts)"
        )
    names = d["messages"]
    for name in names:
        if not isinstance(name, str):
            raise ScenarioError(f"{loc}: messages: {name!r} is not a message name")
        if name not in decls:
            other = next((n for n in scenario.nodes for m in n.messages if m.name == name), None)
            if other is not None:
                raise ScenarioError(
                    f"{loc}: messages: {name!r} is a message of node {other.name!r} (profile "
                    f"{other.profile!r}): only messages of nodes with profile = 'tdma' go in windows "
                    "(CSMA nodes are gated into arbitrating windows)"
                )
            raise ScenarioError(f"{loc}: messages: {name!r} is not a message of a node with profile = 'tdma'")
    if len(set(names)) != len(names):
        raise ScenarioError(f"{loc}: messages: {next(n for n in names if names.count(n) > 1)!r} is named twice")
    if kind == FREE and names:
        raise ScenarioError(f"{loc}: messages: a free window is reserved: it carries no message (got {len(names)})")
    if kind == EXCLUSIVE:
        senders = sorted({owners[n] for n in names})
        if len(senders) > 1:
            a = next(n for n in names if owners[n] == senders[0])
            b = next(n for n in names if owners[n] == senders[1])
            raise ScenarioError(
                f"{loc}: messages: {a!r} (node {senders[0]!r}) and {b!r} (node {senders[1]!r}): an "
                "exclusive window belongs to one node; make it arbitrating to let nodes compete"
            )
        if len(names) != 1:
            raise ScenarioError(
                f"{loc}: messages: an exclusive window carries exactly one message (got {len(names)}); "
                "give each message its own window, or different base_cycle in the matrix"
            )
    for name in names:
        m = decls[name]
        f = frame_ns_worst(m.dlc, m.extended, m.remote, bit_ns)
        need = f + budget_ns + (tx_enable if triggered else 0)
        if need > length:
            parts = f"its worst case {f / 1000:g} µs ({f / bit_ns:.0f} bits with intermission)"
            if triggered:
                parts += f" after a Tx_Enable window of {tx_enable / 1000:g} µs"
            if budget_ns:
                parts += f" plus the error budget {budget_ns / 1000:g} µs"
            raise ScenarioError(
                f"{loc}: length_us: message {name!r} does not fit: {parts} needs {need / 1000:g} µs, "
                f"the window is {length / 1000:g} µs"
            )
    return Window(
        index=i,
        start_ns=start,
        length_ns=length,
        kind=kind,
        messages=tuple(names),
        base_cycle=base,
        repeat=repeat,
        arbitration=arbitration or "",
    )


def _share_cycles(a: Window, b: Window) -> int | None:
    """The first basic cycle both windows are used in, or None (c = base mod repeat for both:
    with powers of two, they meet iff the bases agree modulo the smaller repeat)."""
    r = min(a.repeat, b.repeat)
    if a.base_cycle % r != b.base_cycle % r:
        return None
    c = a.base_cycle
    while c % b.repeat != b.base_cycle:
        c += a.repeat
    return c


def _ntu_of(t: dict[str, Any], level: int, bit_ns: float, loc: str) -> float:
    """One NTU in ns: the nominal bit time at level 1; TUR times the CAN clock's period at level 2
    (both keys required there, refused at level 1)."""
    tur, clock = t["tur"], t["can_clock_mhz"]
    if level == 1:
        for key, value in (("tur", tur), ("can_clock_mhz", clock)):
            if value is not None:
                raise ScenarioError(
                    f"{loc}: {key}: level 1's NTU is the nominal bit time (ISO 11898-4); the time unit ratio "
                    "configures the NTU at level 2 (set level = 2, or leave it out)"
                )
        return bit_ns
    for key, value in (("tur", tur), ("can_clock_mhz", clock)):
        if value is None:
            raise ScenarioError(
                f"{loc}: key {key!r} is required at level 2: the NTU is the time unit ratio (tur) times the "
                "period of the CAN clock it counts (can_clock_mhz), e.g. tur = 16 and can_clock_mhz = 8 for 2 µs"
            )
    return float(tur) * 1000.0 / float(clock)


def _whole_ntu(ns: int, ntu: float, loc: str, key: str, value: float) -> None:
    """Times of the schedule are whole NTU (time marks count NTU): within 1 ns of one."""
    n = ns / ntu
    if abs(n - round(n)) * ntu > 1:
        raise ScenarioError(
            f"{loc}: {key}: {value:g} µs is {n:g} NTU: a time of the schedule is a whole number of NTU "
            f"({ntu / 1000:g} µs each)"
        )


def _check_overlaps(windows: list[Window], src: str, matrix: int) -> None:
    for j, b in enumerate(windows):
        for a in windows[:j]:
            if a.start_ns < b.end_ns and b.start_ns < a.end_ns:
                c = _share_cycles(a, b)
                if c is not None:
                    raise ScenarioError(
                        f"{where(src, '[tdma]', f'[[tdma.windows]] #{b.index}')}: start_us: overlaps "
                        f"{a.label()} in basic cycle {c} of the matrix (windows of one basic cycle "
                        "do not overlap)"
                    )


def _check_untimed(m: MessageDecl, loc: str) -> None:
    for key, value in (("period_ms", m.period_ns), ("sporadic_ms", m.sporadic_ns), ("mean_ms", m.mean_ns)):
        if value is not None:
            raise ScenarioError(
                f"{loc}: {key}: a TDMA message is released by its time window, not by a period: remove it"
            )
    for key, value in (("offset_ms", m.offset_ns), ("jitter_ms", m.jitter_ns)):
        if value:
            raise ScenarioError(f"{loc}: {key}: a TDMA message is released at its window's start: remove it")


def _check_gated(scenario: Scenario, sched: Schedule) -> None:
    arb = sched.arbitrating()
    for n in scenario.nodes:
        if n.name not in sched.gated:
            continue
        for m in n.messages:
            if m.fd:
                loc = where(scenario.source, f"[[nodes]] {n.name!r}", f"[[nodes.messages]] {m.name!r}")
                raise ScenarioError(
                    f"{loc}: fd: true: the TDMA gate fits classical CAN frames into its arbitrating windows, not "
                    "CAN FD frames (set tdma_gated = false on the node to let it send at any time)"
                )
            f = frame_ns_worst(m.dlc, m.extended, m.remote, sched.bit_ns)
            if not any(w.length_ns >= f + sched.budget_ns for w in arb):
                loc = where(scenario.source, f"[[nodes]] {n.name!r}", f"[[nodes.messages]] {m.name!r}")
                widest = max((w.length_ns for w in arb), default=0)
                raise ScenarioError(
                    f"{loc}: no arbitrating window fits it ({f / 1000:g} µs worst case"
                    + (f" + error budget {sched.budget_ns / 1000:g} µs" if sched.budget_ns else "")
                    + (f"; the widest is {widest / 1000:g} µs" if arb else "; the schedule has none")
                    + "): a gated CSMA node sends only in arbitrating windows (set tdma_gated = false "
                    "on the node to let it send at any time)"
                )


def check_scenario(scenario: Scenario, tables: dict[str, Any]) -> None:
    """The profile's ``parse`` hook: read ``[tdma]`` when the scenario has TDMA nodes (refusing
    one without the other), store the `Schedule` in ``scenario.tables["tdma"]``, and give each
    TDMA message that has a single window its period (repeat × basic cycle), so that the
    per-message rows report its start-to-start jitter like a periodic CSMA message's."""
    tdma_nodes = [n for n in scenario.nodes if n.profile == "tdma"]
    if "tdma" not in tables:
        if tdma_nodes:
            n = tdma_nodes[0]
            raise ScenarioError(
                f"{where(scenario.source, f'[[nodes]] {n.name!r}')}: profile: 'tdma' needs a [tdma] "
                "table in the scenario (the schedule: reference_id, time_masters, basic_cycle_us, "
                "[[tdma.windows]])"
            )
        return
    if not tdma_nodes:
        raise ScenarioError(
            f"{where(scenario.source, '[tdma]')}: no node has profile = 'tdma' (a schedule needs its "
            "time-triggered nodes)"
        )
    sched = parse_schedule(scenario, tables["tdma"])
    scenario.tables["tdma"] = sched
    for n in tdma_nodes:
        for m in n.messages:
            ws = sched.windows_of(m.name)
            if len(ws) == 1:
                m.period_ns = ws[0].repeat * sched.basic_cycle_ns
