"""Constructor options of `CanopenDevice` and `CanopenMaster`, checked the way a scenario file
gives them (a TOML table: ints, floats, bools, strings, arrays and tables; table keys are
strings, so node-IDs and PDO numbers may come as "5" as well as 5).

Every refusal is a ValueError naming the option, the value and the rule (the scenario runner
adds the file and table). Device options are objects of the dictionary set before boot-up, as a
DCF would set them, so a reset restores them too.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field, fields
from typing import TYPE_CHECKING, Any

from profiles.canopen import cob
from profiles.canopen.pdo.common import NO_RTR, NOT_VALID
from profiles.canopen.pdo.mapping import check_mapping, entry_value
from profiles.canopen.sdo.abort import SdoAbort

if TYPE_CHECKING:  # pragma: no cover
    from profiles.canopen.dictionary import ObjectStore

__all__ = [
    "DeviceOptions",
    "MasterOptions",
    "PdoOptions",
    "parse_object_key",
    "parse_mapping_entry",
    "apply_device_options",
]

_U16 = 0xFFFF
_U32 = 0xFFFF_FFFF


def _int(name: str, value: Any, lo: int, hi: int, rule: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        if isinstance(value, str):
            try:
                value = int(value, 0)
            except ValueError:
                raise ValueError(f"{name} {value!r}: an integer {lo}..{hi} ({rule})") from None
        else:
            raise ValueError(f"{name} {value!r}: an integer {lo}..{hi} ({rule})")
    if not lo <= value <= hi:
        raise ValueError(f"{name} {value!r}: {lo}..{hi} ({rule})")
    return value


def _bool(name: str, value: Any) -> bool:
    if not isinstance(value, bool):
        raise ValueError(f"{name} {value!r}: true or false")
    return value


def _number(name: str, value: Any, lo: float, rule: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value) or value < lo:
        raise ValueError(f"{name} {value!r}: a number >= {lo:g} ({rule})")
    return float(value)


def _node_id(name: str, value: Any) -> int:
    try:
        return cob.check_node_id(_int(name, value, 1, 127, "CiA 301 node-ID"))
    except ValueError as exc:
        raise ValueError(str(exc).replace("node_id", name, 1)) from None


def parse_object_key(name: str, key: Any) -> tuple[int, int]:
    """'0x2001:1' (index:sub-index), '0x2003' (sub-index 0) or [index, sub] -> (index, sub)."""
    if isinstance(key, (list, tuple)) and len(key) == 2:
        return _int(name, key[0], 0, _U16, "index"), _int(name, key[1], 0, 255, "sub-index")
    if isinstance(key, str):
        m = re.fullmatch(r"\s*(0x[0-9a-fA-F]{1,4}|\d+)\s*(?::\s*(0x[0-9a-fA-F]{1,2}|\d+))?\s*", key)
        if m:
            index = int(m.group(1), 0)
            sub = int(m.group(2), 0) if m.group(2) else 0
            if index <= _U16 and sub <= 255:
                return index, sub
    raise ValueError(
        f"{name} {key!r}: an object is 'INDEX' or 'INDEX:SUB' ('0x2001:1'), index 0..0xFFFF, sub-index 0..255"
    )


def parse_mapping_entry(name: str, value: Any) -> int:
    """A mapping entry as '0x2002:0/32' (index:sub/bits), [index, sub, bits] or the UNSIGNED32
    itself (CiA 301 7.5.2.36)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return _int(name, value, 0, _U32, "a mapping entry is an UNSIGNED32")
    if isinstance(value, (list, tuple)) and len(value) == 3:
        return entry_value(
            _int(name, value[0], 0, _U16, "index"),
            _int(name, value[1], 0, 255, "sub-index"),
            _int(name, value[2], 1, 64, "length in bits"),
        )
    if isinstance(value, str):
        m = re.fullmatch(r"\s*(0x[0-9a-fA-F]{1,4}|\d+)\s*:\s*(0x[0-9a-fA-F]{1,2}|\d+)\s*/\s*(\d+)\s*", value)
        if m:
            index, sub, bits = (int(g, 0) for g in m.groups())
            if index <= _U16 and sub <= 255 and 1 <= bits <= 64:
                return entry_value(index, sub, bits)
    raise ValueError(
        f"{name} {value!r}: a mapping entry is 'INDEX:SUB/BITS' ('0x2002:0/32'), [index, sub, bits] or the UNSIGNED32"
    )


@dataclass
class PdoOptions:
    """Overrides of one PDO's communication and mapping parameters (None: keep the EDS's)."""

    cob_id: int | None = None
    valid: bool | None = None
    rtr: bool | None = None
    transmission_type: int | None = None
    inhibit_100us: int | None = None
    event_timer_ms: int | None = None
    sync_start: int | None = None
    mapping: list[int] | None = None

    @classmethod
    def parse(cls, name: str, table: Any, *, receive: bool) -> PdoOptions:
        """One ``tpdo.N`` / ``rpdo.N`` table."""
        if not isinstance(table, Mapping):
            raise ValueError(f"{name} {table!r}: a table of PDO parameters")
        known = {f.name for f in fields(cls)} - ({"inhibit_100us", "sync_start"} if receive else set())
        out = cls()
        for key, value in table.items():
            if key not in known:
                raise ValueError(f"{name}: unknown key {key!r}; known: {', '.join(sorted(known))}")
            where = f"{name}.{key}"
            if key == "cob_id":
                out.cob_id = _int(where, value, 1, 0x7FF, "an 11-bit CAN-ID")
                if cob.is_restricted(out.cob_id):
                    raise ValueError(f"{where} 0x{out.cob_id:03X}: a restricted CAN-ID (CiA 301 7.3.5)")
            elif key in ("valid", "rtr"):
                setattr(out, key, _bool(where, value))
            elif key == "transmission_type":
                tt = _int(where, value, 0, 255, "CiA 301 transmission type")
                if 241 <= tt <= (253 if receive else 251):
                    raise ValueError(
                        f"{where} {tt}: reserved for {'an RPDO' if receive else 'a TPDO'} "
                        f"(0..240, {'' if receive else '252, 253, '}254, 255)"
                    )
                out.transmission_type = tt
            elif key == "inhibit_100us":
                out.inhibit_100us = _int(where, value, 0, _U16, "0x1800 sub-index 3, 100 µs units")
            elif key == "event_timer_ms":
                out.event_timer_ms = _int(where, value, 0, _U16, "sub-index 5, ms")
            elif key == "sync_start":
                out.sync_start = _int(where, value, 0, 240, "0x1800 sub-index 6")
            elif key == "mapping":
                if not isinstance(value, (list, tuple)) or len(value) > 8:
                    raise ValueError(f"{where} {value!r}: a list of at most 8 mapping entries")
                out.mapping = [parse_mapping_entry(f"{where}[{i}]", v) for i, v in enumerate(value)]
        return out


def _pdo_tables(name: str, value: Any, *, receive: bool) -> dict[int, PdoOptions]:
    if not isinstance(value, Mapping):
        raise ValueError(f"{name} {value!r}: a table of PDO numbers ('1' = {{ transmission_type = 1 }})")
    return {
        _int(f"{name} key", k, 1, 512, "PDO number"): PdoOptions.parse(f"{name}.{k}", v, receive=receive)
        for k, v in value.items()
    }


def _consumers(name: str, value: Any) -> dict[int, int]:
    """{node-ID: consumer time ms} from a table or a list of [node-ID, ms] pairs."""
    pairs: list[tuple[Any, Any]]
    if isinstance(value, Mapping):
        pairs = list(value.items())
    elif isinstance(value, (list, tuple)) and all(isinstance(p, (list, tuple)) and len(p) == 2 for p in value):
        pairs = [tuple(p) for p in value]
    else:
        raise ValueError(f"{name} {value!r}: a table {{ NODE_ID = MS }} or a list of [node_id, ms] pairs")
    out: dict[int, int] = {}
    for k, v in pairs:
        nid = _node_id(f"{name} node-ID", k)
        if nid in out:
            raise ValueError(f"{name}: node {nid} twice (one consumer time per node, CiA 301 0x1016)")
        out[nid] = _int(f"{name}.{nid}", v, 1, _U16, "consumer heartbeat time in ms")
    return out


@dataclass
class DeviceOptions:
    """Options of `CanopenDevice` (each maps to an object of CiA 301, named below)."""

    heartbeat_ms: int | None = None  # 0x1017
    heartbeat_consumers: dict[int, int] = field(default_factory=dict)  # 0x1016
    guard_time_ms: int | None = None  # 0x100C
    life_time_factor: int | None = None  # 0x100D
    sync_period_us: int | None = None  # 0x1006
    sync_window_us: int | None = None  # 0x1007
    sync_producer: bool | None = None  # 0x1005 bit 30
    sync_cob_id: int | None = None  # 0x1005 bits 10..0
    sync_overflow: int | None = None  # 0x1019
    emcy_inhibit_100us: int | None = None  # 0x1015
    time_producer_ms: int = 0  # 0x1012 bit 30 and the producer's period
    time_epoch_s: float | None = None  # Unix time at node time 0 (the TIME producer's reference)
    start_operational: bool = False  # NMT auto start (CiA 302)
    boot_delay_ms: float = 0.0
    remap_in_operational: bool = False
    sdo_timeout_ms: int = 1000
    sdo_block_size: int = 127
    tpdo: dict[int, PdoOptions] = field(default_factory=dict)
    rpdo: dict[int, PdoOptions] = field(default_factory=dict)
    values: dict[tuple[int, int], Any] = field(default_factory=dict)

    @classmethod
    def parse(cls, options: Mapping[str, Any]) -> DeviceOptions:
        """Check every option (ValueError naming the option, the value and the rule)."""
        known = {f.name for f in fields(cls)}
        out = cls()
        for key, value in options.items():
            if key not in known:
                raise ValueError(f"unknown option {key!r} for a CANopen device; known: {', '.join(sorted(known))}")
            if key == "heartbeat_ms":
                out.heartbeat_ms = _int(key, value, 0, _U16, "0x1017 producer heartbeat time, ms")
            elif key == "heartbeat_consumers":
                out.heartbeat_consumers = _consumers(key, value)
            elif key == "guard_time_ms":
                out.guard_time_ms = _int(key, value, 0, _U16, "0x100C guard time, ms")
            elif key == "life_time_factor":
                out.life_time_factor = _int(key, value, 0, 255, "0x100D life time factor")
            elif key in ("sync_period_us", "sync_window_us"):
                setattr(
                    out, key, _int(key, value, 0, _U32, f"0x{0x1006 if key == 'sync_period_us' else 0x1007:04X}, µs")
                )
            elif key in ("sync_producer", "start_operational", "remap_in_operational"):
                setattr(out, key, _bool(key, value))
            elif key == "sync_cob_id":
                out.sync_cob_id = _int(key, value, 1, 0x7FF, "0x1005, an 11-bit CAN-ID")
                if cob.is_restricted(out.sync_cob_id):
                    raise ValueError(f"{key} 0x{out.sync_cob_id:03X}: a restricted CAN-ID (CiA 301 7.3.5)")
            elif key == "sync_overflow":
                v = _int(key, value, 0, 240, "0x1019: 0, or 2..240")
                if v == 1:
                    raise ValueError(f"{key} 1: the SYNC counter overflow value is 0 or 2..240 (CiA 301 7.5.2.40)")
                out.sync_overflow = v
            elif key == "emcy_inhibit_100us":
                out.emcy_inhibit_100us = _int(key, value, 0, _U16, "0x1015, 100 µs units")
            elif key == "time_producer_ms":
                out.time_producer_ms = _int(key, value, 0, 86_400_000, "TIME producer period in ms, 0: none")
            elif key == "time_epoch_s":
                out.time_epoch_s = _number(key, value, 441_763_200, "Unix time, not before 1984-01-01")
            elif key == "boot_delay_ms":
                out.boot_delay_ms = _number(key, value, 0, "ms from start() to the boot-up message")
            elif key == "sdo_timeout_ms":
                out.sdo_timeout_ms = _int(key, value, 1, 600_000, "SDO server timeout in ms")
            elif key == "sdo_block_size":
                out.sdo_block_size = _int(key, value, 1, 127, "segments per SDO block, CiA 301 7.2.4.3.9")
            elif key in ("tpdo", "rpdo"):
                setattr(out, key, _pdo_tables(key, value, receive=key == "rpdo"))
            elif key == "values":
                if not isinstance(value, Mapping):
                    raise ValueError(f"values {value!r}: a table {{ 'INDEX:SUB' = value }}")
                out.values = {parse_object_key("values key", k): v for k, v in value.items()}
        return out


@dataclass
class MasterOptions:
    """Options of `CanopenMaster`."""

    nodes: list[int] = field(default_factory=list)
    sync_period_us: int = 0
    sync_overflow: int = 0
    sync_cob_id: int = 0x80
    heartbeat_ms: int = 0
    heartbeat_consumer_ms: int | None = None
    node_guarding_ms: int = 0
    boot_timeout_ms: float = 2000.0
    start_nodes: bool = True
    reset_nodes: bool = True
    read_pdo_config: bool = True
    sdo_timeout_ms: int = 500
    configure: dict[int, dict[tuple[int, int], Any]] = field(default_factory=dict)

    @classmethod
    def parse(cls, options: Mapping[str, Any]) -> MasterOptions:
        """Check every option (ValueError naming the option, the value and the rule)."""
        known = {f.name for f in fields(cls)}
        out = cls()
        for key, value in options.items():
            if key not in known:
                raise ValueError(f"unknown option {key!r} for a CANopen master; known: {', '.join(sorted(known))}")
            if key == "nodes":
                if not isinstance(value, (list, tuple)) or not value:
                    raise ValueError(f"nodes {value!r}: a non-empty list of node-IDs 1..127")
                ids = [_node_id("nodes", v) for v in value]
                if len(set(ids)) != len(ids):
                    raise ValueError(f"nodes {value!r}: a node-ID appears twice (node-IDs are unique on a network)")
                out.nodes = ids
            elif key == "sync_period_us":
                out.sync_period_us = _int(key, value, 0, _U32, "SYNC period in µs, 0x1006; 0: no SYNC")
            elif key == "sync_overflow":
                v = _int(key, value, 0, 240, "0x1019: 0, or 2..240")
                if v == 1:
                    raise ValueError(f"{key} 1: the SYNC counter overflow value is 0 or 2..240 (CiA 301 7.5.2.40)")
                out.sync_overflow = v
            elif key == "sync_cob_id":
                out.sync_cob_id = _int(key, value, 1, 0x7FF, "an 11-bit CAN-ID")
            elif key == "heartbeat_ms":
                out.heartbeat_ms = _int(key, value, 0, _U16, "producer heartbeat time written to each node's 0x1017")
            elif key == "heartbeat_consumer_ms":
                out.heartbeat_consumer_ms = _int(key, value, 1, _U16, "consumer heartbeat time, ms")
            elif key == "node_guarding_ms":
                out.node_guarding_ms = _int(key, value, 0, _U16, "guard time in ms, 0: no node guarding")
            elif key == "boot_timeout_ms":
                out.boot_timeout_ms = _number(key, value, 0, "ms to wait for boot-up messages")
            elif key in ("start_nodes", "reset_nodes", "read_pdo_config"):
                setattr(out, key, _bool(key, value))
            elif key == "sdo_timeout_ms":
                out.sdo_timeout_ms = _int(key, value, 1, 600_000, "SDO client timeout in ms")
            elif key == "configure":
                if not isinstance(value, Mapping):
                    raise ValueError(f"configure {value!r}: a table {{ NODE_ID = {{ 'INDEX:SUB' = value }} }}")
                conf: dict[int, dict[tuple[int, int], Any]] = {}
                for k, writes in value.items():
                    nid = _node_id("configure node-ID", k)
                    if not isinstance(writes, Mapping):
                        raise ValueError(f"configure.{k} {writes!r}: a table {{ 'INDEX:SUB' = value }}")
                    conf[nid] = {parse_object_key(f"configure.{k} key", o): v for o, v in writes.items()}
                out.configure = conf
        if not out.nodes:
            raise ValueError("nodes: the master needs the list of node-IDs it manages")
        unknown = set(out.configure) - set(out.nodes)
        if unknown:
            raise ValueError(f"configure names node {min(unknown)}, which is not in nodes {out.nodes}")
        if out.heartbeat_consumer_ms is None and out.heartbeat_ms:
            out.heartbeat_consumer_ms = out.heartbeat_ms * 3 // 2 + 1
        return out


def apply_device_options(s: ObjectStore, o: DeviceOptions) -> None:
    """Write the options into the dictionary before boot-up, as a DCF would (every object through
    `ObjectStore.set`: its type and limits apply); a value the dictionary refuses is a ValueError
    naming the option. CiA 301 objects: 0x1017, 0x100C/0x100D, 0x1016, 0x1006, 0x1007, 0x1019,
    0x1005, 0x1015, 0x1012, the PDO parameters 0x1400../0x1600../0x1800../0x1A00.."""
    od = s.od

    def put(index: int, sub: int, value: Any, option: str) -> None:
        if not s.has(index, sub):
            raise ValueError(f"{option}: the dictionary has no object 0x{index:04X}:{sub}")
        try:
            s.set(index, sub, value)
        except SdoAbort as exc:
            raise ValueError(f"{option} {value!r}: {exc}") from None

    if o.heartbeat_ms is not None:
        put(0x1017, 0, o.heartbeat_ms, "heartbeat_ms")
    if o.guard_time_ms is not None:
        put(0x100C, 0, o.guard_time_ms, "guard_time_ms")
    if o.life_time_factor is not None:
        put(0x100D, 0, o.life_time_factor, "life_time_factor")
    if o.heartbeat_consumers:
        subs = sorted(k for k in od.indices[0x1016].subindices if k) if 0x1016 in od.indices else []
        if len(o.heartbeat_consumers) > len(subs):
            raise ValueError(
                f"heartbeat_consumers: {len(o.heartbeat_consumers)} nodes, the dictionary's 0x1016 "
                f"has {len(subs)} entries"
            )
        for sub, (nid, ms) in zip(subs, sorted(o.heartbeat_consumers.items())):
            put(0x1016, sub, (nid << 16) | ms, "heartbeat_consumers")
    if o.sync_period_us is not None:
        put(0x1006, 0, o.sync_period_us, "sync_period_us")
    if o.sync_window_us is not None:
        put(0x1007, 0, o.sync_window_us, "sync_window_us")
    if o.sync_overflow is not None:
        put(0x1019, 0, o.sync_overflow, "sync_overflow")
    if o.sync_producer is not None or o.sync_cob_id is not None:
        word = s.u(0x1005, 0, 0x80)
        if o.sync_cob_id is not None:
            word = (word & ~0x7FF) | o.sync_cob_id
        if o.sync_producer is not None:
            word = (word | 0x4000_0000) if o.sync_producer else (word & ~0x4000_0000)
        put(0x1005, 0, word, "sync_producer")
    if o.emcy_inhibit_100us is not None:
        put(0x1015, 0, o.emcy_inhibit_100us, "emcy_inhibit_100us")
    if o.time_producer_ms:
        put(0x1012, 0, s.u(0x1012, 0, 0x100) | 0x4000_0000, "time_producer_ms")
    for key, table, comm_base, map_base in (("tpdo", o.tpdo, 0x1800, 0x1A00), ("rpdo", o.rpdo, 0x1400, 0x1600)):
        for n, p in table.items():
            comm, mapping = comm_base + n - 1, map_base + n - 1
            name = f"{key}.{n}"
            if comm not in od.indices:
                raise ValueError(f"{name}: the dictionary has no {key.upper()}{n} (0x{comm:04X})")
            word = s.u(comm, 1)
            if p.cob_id is not None:
                word = (word & ~0x7FF) | p.cob_id
            if p.valid is not None:
                word = (word & ~NOT_VALID) | (0 if p.valid else NOT_VALID)
            if p.rtr is not None:
                word = (word & ~NO_RTR) | (0 if p.rtr else NO_RTR)
            put(comm, 1, word, f"{name}.cob_id")
            if p.transmission_type is not None:
                put(comm, 2, p.transmission_type, f"{name}.transmission_type")
            if p.inhibit_100us is not None:
                put(comm, 3, p.inhibit_100us, f"{name}.inhibit_100us")
            if p.event_timer_ms is not None:
                put(comm, 5, p.event_timer_ms, f"{name}.event_timer_ms")
            if p.sync_start is not None:
                put(comm, 6, p.sync_start, f"{name}.sync_start")
            if p.mapping is not None:
                try:
                    check_mapping(s, p.mapping, receive=key == "rpdo")
                except SdoAbort as exc:
                    raise ValueError(f"{name}.mapping: {exc}") from None
                entries = sorted(k for k in od.indices[mapping].subindices if k)
                if len(p.mapping) > len(entries):
                    raise ValueError(f"{name}.mapping: {len(p.mapping)} entries, 0x{mapping:04X} has {len(entries)}")
                for sub, value in zip(entries, p.mapping):
                    put(mapping, sub, value, f"{name}.mapping")
                put(mapping, 0, len(p.mapping), f"{name}.mapping")
    for (index, sub), value in o.values.items():
        put(index, sub, value, f"values.0x{index:04X}:{sub}")
