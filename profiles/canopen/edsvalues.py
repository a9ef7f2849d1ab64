"""The values of an EDS/DCF that ``canopen.objectdictionary.import_od`` reads leniently, checked
against CiA 306 (`check_values`).

The canopen library reads the dictionary's structure and converts each value, but when a
conversion fails it keeps going: ``DefaultValue=abc`` becomes no default (so the device starts
with 0), ``LowLimit=abc`` and ``HighLimit=abc`` become no limit, ``SubNumber`` is never read,
an ``AccessType`` it does not know makes an object neither readable nor writable, and
a sub-index's ``ObjectType`` is not read, ``$NODEID`` alone (or ``$NODEID+`` with nothing after
it) gives no value at all, so that a COB-ID
of ``$NODEID`` would be 0 in the dictionary. This module reads the same file with the same INI
reader the library uses (``configparser.RawConfigParser``), looks at the raw text of those keys
only, and either refuses the file with `EdsValueError` naming the section, the key, the value
and the rule, or — for a CiA 306 ``$NODEID`` expression the library cannot evaluate — computes
the value the device uses and puts it into the dictionary, so that the dictionary and the
device agree.

CiA 306-1 (4.6.3) writes a node-ID relative value as ``$NODEID+<number>`` (the library also takes
``<number>+$NODEID``); ``$NODEID`` alone is the node-ID itself. Numbers are C integer literals
(decimal, ``0x`` hexadecimal, ``0`` octal), as ``int(text, 0)`` reads them.
"""

from __future__ import annotations

import configparser
import re
from pathlib import Path
from typing import Any

from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable, datatypes

__all__ = ["EdsValueError", "check_values", "nodeid_expression", "type_name", "ACCESS_TYPES"]

#: CiA 306-1 4.6.3: the access types of an object description
ACCESS_TYPES = frozenset({"ro", "wo", "rw", "rwr", "rww", "const"})

_INDEX = re.compile(r"^([0-9A-Fa-f]{4})$")
_SUB = re.compile(r"^([0-9A-Fa-f]{4})[Ss]ub([0-9A-Fa-f]+)$")
_NODEID = re.compile(r"\$nodeid", re.IGNORECASE)
_FLOATS = (datatypes.REAL32, datatypes.REAL64)


_TYPE_NAMES = {
    v: k
    for k, v in vars(datatypes).items()
    if k.isupper() and isinstance(v, int) and k not in ("SIGNED_TYPES", "UNSIGNED_TYPES")
}


def type_name(data_type: int | None) -> str:
    """The CiA 301 name of a data type code (0x0007 -> 'UNSIGNED32')."""
    if data_type is None:
        return "no type"
    return _TYPE_NAMES.get(data_type, f"0x{data_type:04X}")


class EdsValueError(ValueError):
    """A value of the file that breaks a rule of CiA 306 (the message names the section, the
    key, the value and the rule; the caller adds the file)."""


def nodeid_expression(text: str, node_id: int) -> int:
    """The value of a CiA 306 node-ID relative value: ``$NODEID``, ``$NODEID+<number>`` or
    ``<number>+$NODEID`` (spaces and the case of ``$NODEID`` do not matter). ValueError for
    anything else (``$NODEID+``, ``$NODEID*2``, two ``$NODEID``, ``$NODEID+abc``)."""
    terms = text.replace(" ", "").split("+")
    if "" in terms:
        raise ValueError("a '+' with no number beside it")
    ids = [t for t in terms if _NODEID.fullmatch(t)]
    numbers = [t for t in terms if not _NODEID.fullmatch(t)]
    if len(ids) != 1 or len(numbers) > 1:
        raise ValueError("not $NODEID, $NODEID+<number> or <number>+$NODEID")
    try:
        offset = int(numbers[0], 0) if numbers else 0
    except ValueError:
        raise ValueError(f"{numbers[0]!r} is not a number") from None
    return node_id + offset


def _read(path: Path) -> configparser.RawConfigParser:
    ini = configparser.RawConfigParser(inline_comment_prefixes=(";",))
    ini.optionxform = str  # type: ignore[assignment,method-assign]  # keys keep their case, as the library reads them
    with open(path, encoding="utf-8", errors="strict") as f:
        ini.read_file(f)
    return ini


def _variable(od: ObjectDictionary, section: str) -> tuple[Any, ODVariable | None]:
    """The object of an index section and, for a VAR or a sub-index section, its variable."""
    m = _INDEX.match(section)
    if m:
        obj = od.indices.get(int(m.group(1), 16))
        return obj, obj if isinstance(obj, ODVariable) else None
    m = _SUB.match(section)
    if m:
        obj = od.indices.get(int(m.group(1), 16))
        if isinstance(obj, (ODRecord, ODArray)):
            return obj, obj.subindices.get(int(m.group(2), 16))
    return None, None


def _number(var: ODVariable, text: str) -> int | float:
    """A limit as the variable's data type reads it."""
    if var.data_type in _FLOATS:
        return float(text)
    value = int(text, 0)
    if var.data_type in datatypes.SIGNED_TYPES and value < 0:
        return value
    if var.data_type in datatypes.SIGNED_TYPES:
        # the library reads signed limits as two's complement of the type's width (0xFF.. = -1)
        bits = len(var)
        return value - (1 << bits) if value >= 1 << (bits - 1) and value < 1 << bits else value
    return value


def check_values(od: ObjectDictionary, path: Path, node_id: int) -> None:
    """Check the raw values the library may have let through (see the module docstring) and fill
    in the node-ID relative values it could not evaluate. Raises `EdsValueError`."""
    ini = _read(path)
    subs: dict[str, int] = {}
    for section in ini.sections():
        m = _SUB.match(section)
        if m:
            key = m.group(1).upper()
            subs[key] = subs.get(key, 0) + 1
    for section in ini.sections():
        obj, var = _variable(od, section)
        if obj is None:
            continue
        where = f"[{section}]"
        raw = dict(ini.items(section))
        if "SubNumber" in raw and _INDEX.match(section) and not isinstance(obj, ODVariable):
            _check_sub_number(where, raw["SubNumber"], subs.get(section.upper(), 0))
        if var is None:
            continue
        if _SUB.match(section) and "ObjectType" in raw:
            _check_sub_object_type(where, raw["ObjectType"])
        access = raw.get("AccessType")
        if access is not None and access.strip().lower() not in ACCESS_TYPES:
            raise EdsValueError(
                f"{where} AccessType {access!r}: not an access type of CiA 306 ({', '.join(sorted(ACCESS_TYPES))})"
            )
        for key, attr in (("DefaultValue", "default"), ("ParameterValue", "value")):
            text = raw.get(key)
            if text is not None:
                _check_value(where, key, text, var, attr, node_id)
        _check_limits(where, raw, var)


def _check_sub_number(where: str, text: str, sections: int) -> None:
    try:
        n = int(text, 0)
    except ValueError:
        raise EdsValueError(f"{where} SubNumber {text!r}: not a number (CiA 306: how many sub-indices)") from None
    if not 0 <= n <= 255:
        raise EdsValueError(f"{where} SubNumber {text!r}: out of 0..255 (a sub-index is 8 bits)")
    if n != sections:
        raise EdsValueError(
            f"{where} SubNumber {text!r}: {sections} sub-index section(s) follow "
            "(CiA 306: SubNumber counts the sub-indices described)"
        )


def _check_sub_object_type(where: str, text: str) -> None:
    try:
        kind = int(text, 0)
    except ValueError:
        kind = -1
    if kind != 0x7:
        raise EdsValueError(f"{where} ObjectType {text!r}: a sub-index is a VAR (0x7, CiA 306)")


def _check_value(where: str, key: str, text: str, var: ODVariable, attr: str, node_id: int) -> None:
    if _NODEID.search(text):
        if var.data_type not in datatypes.INTEGER_TYPES:
            raise EdsValueError(f"{where} {key} {text!r}: $NODEID belongs in an integer value")
        try:
            value = nodeid_expression(text, node_id)
        except ValueError as exc:
            raise EdsValueError(
                f"{where} {key} {text!r}: {exc} (CiA 306: a node-ID relative value is $NODEID+<number>)"
            ) from None
        setattr(var, attr, value)  # what the device uses: the dictionary says the same
        return
    if getattr(var, attr) is None and text.strip():
        kind = "a number" if var.data_type in datatypes.NUMBER_TYPES else "hexadecimal bytes"
        raise EdsValueError(
            f"{where} {key} {text!r}: not {kind}, as its data type ({type_name(var.data_type)}) needs "
            "(the canopen library would read it as no value, 0)"
        )


def _check_limits(where: str, raw: dict[str, str], var: ODVariable) -> None:
    limits: dict[str, int | float] = {}
    for key, attr in (("LowLimit", "min"), ("HighLimit", "max")):
        text = raw.get(key)
        if text is None or not text.strip():
            continue
        if var.data_type not in datatypes.NUMBER_TYPES:
            raise EdsValueError(f"{where} {key} {text!r}: a limit belongs to a number, not {type_name(var.data_type)}")
        try:
            value = _number(var, text)
        except ValueError:
            raise EdsValueError(f"{where} {key} {text!r}: not a number (the canopen library would ignore it)") from None
        setattr(var, attr, value)  # REAL limits, which the library does not read
        limits[key] = value
    if len(limits) == 2 and limits["LowLimit"] > limits["HighLimit"]:
        raise EdsValueError(
            f"{where} LowLimit {raw['LowLimit']!r} is above HighLimit {raw['HighLimit']!r}: no value could be written"
        )
