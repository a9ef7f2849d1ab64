"""PDO mapping (CiA 301 7.5.2.36/7.5.2.38, objects 0x1600.. and 0x1A00..).

A mapping entry is an UNSIGNED32: bits 31..16 the index, 15..8 the sub-index, 7..0 the length
in bits of the mapped object. Mapping is byte-wise here, as in CANopenNode without its bit-wise
option (the EDS says ``Granularity=8``): a length that is not a multiple of 8, or longer than
the object, cannot be mapped (0x0604 0041). Entries 0x0001..0x001F with sub-index 0 are dummy
mappings (the data type indices): a TPDO sends zeros there, an RPDO skips the bytes. At most 8
bytes in all (0x0604 0042, PDO length exceeded). A TPDO can map objects that are readable and
marked ``PDOMapping=1``; an RPDO objects that are writable and mappable.
"""

from __future__ import annotations

from dataclasses import dataclass

from profiles.canopen.dictionary import ObjectStore
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort

__all__ = [
    "MappedObject",
    "parse_entry",
    "check_entry",
    "check_mapping",
    "pack",
    "unpack",
    "entry_value",
    "MAX_PDO_BYTES",
]

MAX_PDO_BYTES = 8


@dataclass(frozen=True, slots=True)
class MappedObject:
    """One mapping entry: ``index:sub`` over ``size`` bytes (a dummy when ``dummy``). (A frozen
    dataclass rather than a NamedTuple: its ``index``, CiA 301's word, would shadow
    ``tuple.index``.)"""

    index: int
    sub: int
    size: int
    dummy: bool = False


def entry_value(index: int, sub: int, bits: int) -> int:
    """The UNSIGNED32 of a mapping entry."""
    return (index << 16) | (sub << 8) | bits


def parse_entry(value: int) -> tuple[int, int, int]:
    """(index, sub-index, length in bits) of a mapping entry."""
    return (value >> 16) & 0xFFFF, (value >> 8) & 0xFF, value & 0xFF


def check_entry(store: ObjectStore, value: int, *, receive: bool) -> MappedObject:
    """The mapped object an entry names, or `SdoAbort`: 0x0602 0000 / 0x0609 0011 when it does
    not exist, 0x0604 0041 when it cannot be mapped (not mappable, wrong access for the
    direction, not whole bytes, longer than the object)."""
    index, sub, bits = parse_entry(value)
    where = f"0x{index:04X}:{sub} ({bits} bits)"
    if bits == 0 or bits % 8:
        raise SdoAbort(abort.NOT_MAPPABLE, f"{where}: mapping is byte-wise (Granularity 8), {bits} bits")
    size = bits // 8
    if size > MAX_PDO_BYTES:
        raise SdoAbort(abort.PDO_LENGTH, f"{where}: longer than a PDO")
    if 0x0001 <= index <= 0x001F and sub == 0:
        return MappedObject(index, sub, size, True)
    var = store.variable(index, sub)
    if not var.pdo_mappable:
        raise SdoAbort(abort.NOT_MAPPABLE, f"{where}: {var.name} is not PDO-mappable")
    if receive and not var.writable:
        raise SdoAbort(abort.NOT_MAPPABLE, f"{where}: {var.name} is {var.access_type}, an RPDO cannot write it")
    if not receive and not var.readable:
        raise SdoAbort(abort.NOT_MAPPABLE, f"{where}: {var.name} is {var.access_type}, a TPDO cannot read it")
    obj_size = store.size(index, sub)
    if obj_size is None or size > obj_size:
        raise SdoAbort(abort.NOT_MAPPABLE, f"{where}: {var.name} has {obj_size or 'no fixed'} bytes")
    return MappedObject(index, sub, size)


def check_mapping(store: ObjectStore, values: list[int], *, receive: bool) -> list[MappedObject]:
    """Every entry checked (`check_entry`) and their total length (0x0604 0042 beyond 8 bytes)."""
    mapped = [check_entry(store, v, receive=receive) for v in values]
    total = sum(m.size for m in mapped)
    if total > MAX_PDO_BYTES:
        raise SdoAbort(abort.PDO_LENGTH, f"{len(mapped)} objects make {total} bytes, a PDO carries {MAX_PDO_BYTES}")
    return mapped


def pack(store: ObjectStore, mapped: list[MappedObject]) -> bytes:
    """A TPDO's data: each object's low ``size`` bytes (little-endian), zeros for dummies."""
    out = bytearray()
    for m in mapped:
        out += bytes(m.size) if m.dummy else store.read(m.index, m.sub)[: m.size]
    return bytes(out)


def unpack(store: ObjectStore, mapped: list[MappedObject], data: bytes) -> list[tuple[int, int, bytes]]:
    """An RPDO's data as (index, sub, bytes of the object's full size) for every non-dummy
    object (a mapping shorter than the object is padded with zeros, as CANopenNode does)."""
    out = []
    pos = 0
    for m in mapped:
        chunk = data[pos : pos + m.size]
        pos += m.size
        if m.dummy:
            continue
        full = store.size(m.index, m.sub) or m.size
        out.append((m.index, m.sub, bytes(chunk).ljust(full, b"\x00")))
    return out
