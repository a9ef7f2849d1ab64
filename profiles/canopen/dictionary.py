"""The object dictionary of a device (CiA 301 7.4): described by an EDS/DCF that the ``canopen``
library reads (`load_od`, through ``canopen.objectdictionary.import_od``: this module never
parses an EDS itself), and held as values by `ObjectStore`.

The store keeps each sub-object's value as the bytes CANopen carries (little-endian, CiA 301
7.1.4), so an SDO upload or a TPDO reads them without conversion. Every write goes through the
same checks, in the order CiA 301's abort codes imply and CANopenNode applies them: the object
exists (0x0602 0000) and the sub-index too (0x0609 0011); the access type allows it (write to a
read-only object 0x0601 0002, read of a write-only one 0x0601 0001); the length matches the data
type (0x0607 0012 too long, 0x0607 0013 too short); the value lies inside LowLimit/HighLimit of
the EDS (0x0609 0031 too high, 0x0609 0032 too low); then the service that owns the object
(PDO, SYNC, heartbeat, EMCY, ...) validates it (`ObjectStore.validators`) before it is stored
and the owner is told (`ObjectStore.watch`).
"""

from __future__ import annotations

import configparser
import logging
import os
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

from canopen import objectdictionary as cod
from canopen.objectdictionary import ObjectDictionary, ODArray, ODRecord, ODVariable, datatypes

from profiles.canopen.cob import is_restricted
from profiles.canopen.edsvalues import EdsValueError, check_values, type_name
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort

__all__ = ["DEFAULT_EDS", "EdsError", "ObjectStore", "load_od", "check_od", "type_name", "COMMUNICATION_AREA"]

#: The small default device shipped with the package (CiA 301 mandatory objects, a few
#: manufacturer objects, four TPDOs and four RPDOs).
DEFAULT_EDS = Path(__file__).with_name("default.eds")

#: indices a reset communication restores (CiA 301 7.3.2.2.1: the communication profile area)
COMMUNICATION_AREA = (0x1000, 0x1FFF)

Validator = Callable[[int, Any, bytes], None]
"""``validator(sub, value, data)``: raise `SdoAbort` to refuse a write to the object."""
Watcher = Callable[[int, int], None]
"""``watcher(index, sub)``: called after a write was stored."""


# objects the services read, with the data type CiA 301 gives them (clause 7.5.2.x)
_TYPES = {
    0x1000: datatypes.UNSIGNED32,
    0x1001: datatypes.UNSIGNED8,
    0x1005: datatypes.UNSIGNED32,
    0x1006: datatypes.UNSIGNED32,
    0x1007: datatypes.UNSIGNED32,
    0x100C: datatypes.UNSIGNED16,
    0x100D: datatypes.UNSIGNED8,
    0x1012: datatypes.UNSIGNED32,
    0x1014: datatypes.UNSIGNED32,
    0x1015: datatypes.UNSIGNED16,
    0x1017: datatypes.UNSIGNED16,
    0x1019: datatypes.UNSIGNED8,
}
_PDO_COMM_TYPES = {
    1: datatypes.UNSIGNED32,
    2: datatypes.UNSIGNED8,
    3: datatypes.UNSIGNED16,
    5: datatypes.UNSIGNED16,
    6: datatypes.UNSIGNED8,
}


class EdsError(ValueError):
    """An EDS/DCF that cannot be read or that a device cannot run on: the message names the
    file and the problem (a missing mandatory object, a wrong data type, a value that does not
    fit its type, ...)."""


class _Collect(logging.Handler):
    """The canopen library's log records while it reads a file: what it would print on its own
    (a second line under canstack's output) becomes one warning naming the file."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(" ".join(record.getMessage().split()))


def load_od(
    eds: str | os.PathLike[str] | None, node_id: int, warn: Callable[[str], object] | None = None
) -> ObjectDictionary:
    """Read an EDS or DCF with ``canopen.objectdictionary.import_od`` (``$NODEID`` resolved for
    ``node_id``), check the values the library reads leniently (`profiles.canopen.edsvalues`:
    a value that is no number, a limit, SubNumber, AccessType, a ``$NODEID`` expression) and
    that a device can run on it (`check_od`); None gives the default device (`DEFAULT_EDS`).
    Raises `EdsError` naming the file and the problem. What the library would log on its own (a
    missing DeviceInfo section, a data type it does not know) goes to ``warn`` as one line naming
    the file (dropped without it)."""
    path = DEFAULT_EDS if eds is None else Path(eds)
    if path.suffix.lower() not in (".eds", ".dcf"):
        raise EdsError(
            f"{path}: an object dictionary is an .eds or .dcf file (CiA 306), not {path.suffix or 'a file without suffix'}"
        )
    if not path.is_file():
        raise EdsError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    lib = logging.getLogger("canopen")
    collect = _Collect()
    lib.addHandler(collect)
    propagate, lib.propagate = lib.propagate, False
    try:
        od = cod.import_od(str(path), node_id)
    except configparser.Error as exc:
        raise EdsError(f"{path}: not a valid EDS (CiA 306 INI syntax): {_one_line(exc)}") from None
    except UnicodeDecodeError:
        raise EdsError(f"{path}: not a text file (an EDS is INI text, CiA 306)") from None
    except KeyError as exc:
        raise EdsError(f"{path}: a sub-index section names an object that is not defined: {_one_line(exc)}") from None
    except (ValueError, TypeError, AttributeError, IndexError) as exc:
        raise EdsError(f"{path}: malformed entry: {_one_line(exc)}") from None
    finally:
        lib.removeHandler(collect)
        lib.propagate = propagate
    if warn is not None:
        for message in dict.fromkeys(collect.messages):
            warn(f"{path}: {message}")
    try:
        check_values(od, path, node_id)
    except EdsValueError as exc:
        raise EdsError(f"{path}: {exc}") from None
    check_od(od, str(path))
    return od


def _one_line(exc: BaseException) -> str:
    return " ".join(str(exc).split())[:200]


def check_od(od: ObjectDictionary, source: str = "object dictionary") -> None:
    """Check what the device needs from its dictionary (CiA 301 7.4.x, 7.5.2): the mandatory
    objects 0x1000 device type, 0x1001 error register and 0x1018 identity (with sub-index 1,
    vendor-ID); a producer heartbeat time 0x1017 unless node guarding (0x100C, 0x100D) is
    there; the data type CiA 301 gives every communication object the device uses; each PDO
    communication parameter with its mapping parameter and the sub-indices 1 and 2; and every
    default value fitting its data type. Raises `EdsError` naming ``source`` and the object."""

    def fail(why: str) -> None:
        raise EdsError(f"{source}: {why}")

    idx = od.indices
    for index, name in ((0x1000, "device type"), (0x1001, "error register"), (0x1018, "identity object")):
        if index not in idx:
            fail(f"mandatory object 0x{index:04X} ({name}) is missing (CiA 301 7.4.x mandatory objects)")
    if not isinstance(idx[0x1018], (ODRecord, ODArray)) or 1 not in idx[0x1018].subindices:
        fail("object 0x1018 (identity) must be a record with sub-index 1, vendor-ID (CiA 301 7.5.2.24)")
    if 0x1017 not in idx and not (0x100C in idx and 0x100D in idx):
        fail(
            "neither 0x1017 (producer heartbeat time) nor 0x100C/0x100D (node guarding) is defined: "
            "a device needs one error control protocol (CiA 301 7.2.8.3.2)"
        )
    for index, dtype in _TYPES.items():
        obj = idx.get(index)
        if obj is None:
            continue
        if not isinstance(obj, ODVariable):
            fail(f"object 0x{index:04X} ({obj.name}) must be a VAR of type {type_name(dtype)}")
        if obj.data_type != dtype:
            fail(
                f"object 0x{index:04X} ({obj.name}) must be {type_name(dtype)} (CiA 301 7.5.2), "
                f"not {type_name(obj.data_type)}"
            )
    for comm, mapping, kind in ((0x1400, 0x1600, "RPDO"), (0x1800, 0x1A00, "TPDO")):
        for n in range(512):
            c, m = idx.get(comm + n), idx.get(mapping + n)
            if c is None and m is None:
                continue
            if c is None or m is None:
                have, missing = (comm + n, mapping + n) if m is None else (mapping + n, comm + n)
                fail(
                    f"{kind}{n + 1}: 0x{have:04X} is defined without 0x{missing:04X} (a PDO needs its "
                    f"communication and its mapping parameter, CiA 301 7.5.2.35-7.5.2.38)"
                )
            if not isinstance(c, ODRecord) or 1 not in c.subindices or 2 not in c.subindices:
                fail(
                    f"0x{comm + n:04X} ({kind}{n + 1} communication parameter) must be a record with sub-index 1 "
                    f"(COB-ID) and 2 (transmission type)"
                )
            for sub, dtype in _PDO_COMM_TYPES.items():
                if sub in c.subindices and c.subindices[sub].data_type != dtype:
                    fail(
                        f"0x{comm + n:04X} sub-index {sub} must be {type_name(dtype)}, not "
                        f"{type_name(c.subindices[sub].data_type)}"
                    )
            try:
                word = int.from_bytes(_initial(c.subindices[1]), "little")
            except (ValueError, TypeError, OverflowError):
                word = 0x8000_0000  # a default that does not fit: named by the value check below
            if not word & 0x8000_0000 and is_restricted(word & 0x7FF):
                fail(
                    f"0x{comm + n:04X} sub-index 1 ({kind}{n + 1} COB-ID): CAN-ID 0x{word & 0x7FF:03X} is restricted "
                    "(CiA 301 7.3.5: reserved for NMT, the default SDOs, error control and LSS); set bit 31 to "
                    "leave the PDO unused"
                )
            if not isinstance(m, (ODRecord, ODArray)) or 0 not in m.subindices:
                fail(
                    f"0x{mapping + n:04X} ({kind}{n + 1} mapping parameter) must be a record with sub-index 0 "
                    f"(number of mapped objects)"
                )
            for sub, var in m.subindices.items():
                want = datatypes.UNSIGNED8 if sub == 0 else datatypes.UNSIGNED32
                if var.data_type != want:
                    fail(
                        f"0x{mapping + n:04X} sub-index {sub} must be {type_name(want)}, not {type_name(var.data_type)}"
                    )
            if len(m.subindices) - 1 > 64:
                fail(f"0x{mapping + n:04X}: at most 64 mapping entries (CiA 301 7.5.2.36)")
    for var in _variables(od):
        try:
            _initial(var)
        except (ValueError, TypeError, OverflowError) as exc:
            where = f"0x{var.index:04X}" + (
                f" sub-index {var.subindex}" if not isinstance(var.parent, ObjectDictionary) else ""
            )
            fail(
                f"{where} ({var.name}): default value {var.value if var.value is not None else var.default!r} "
                f"does not fit {type_name(var.data_type)}: {_one_line(exc)}"
            )


def _variables(od: ObjectDictionary) -> Iterator[ODVariable]:
    for index in sorted(od.indices):
        obj = od.indices[index]
        if isinstance(obj, ODVariable):
            yield obj
        else:
            for sub in sorted(obj.subindices):
                yield obj.subindices[sub]


def _size(var: ODVariable) -> int | None:
    """Bytes of a fixed-size type, None for strings and domains."""
    return len(var) // 8 if var.fixed_size else None


def _initial(var: ODVariable) -> bytes:
    """The power-on value: ParameterValue of a DCF, else DefaultValue, else zero/empty."""
    value = var.value if var.value is not None else var.default
    if value is None:
        size = _size(var)
        return bytes(size) if size else b""
    data = var.encode_raw(value)
    size = _size(var)
    if size is not None and len(data) != size:
        raise ValueError(f"{len(data)} bytes for a {size}-byte type")
    if var.data_type in datatypes.INTEGER_TYPES and isinstance(value, int):
        if (var.min is not None and value < var.min) or (var.max is not None and value > var.max):
            raise ValueError(f"outside LowLimit..HighLimit {var.min}..{var.max}")
    return bytes(data)


class ObjectStore:
    """The values of a device's object dictionary, with the access checks of CiA 301.

    ``od`` is the ``canopen`` ObjectDictionary that describes the objects. `read`/`write` are
    the device's own access (an RPDO writing, the application); `sdo_read`/`sdo_write` add the
    access-type checks an SDO client gets. ``validators[index]`` lets the service owning an
    object refuse a value; `watch` tells a service that an object was written.
    """

    def __init__(self, od: ObjectDictionary) -> None:
        self.od = od
        self.values: dict[tuple[int, int], bytes] = {}
        self.vars: dict[tuple[int, int], ODVariable] = {}
        for var in _variables(od):
            key = (var.index, 0 if isinstance(var.parent, ObjectDictionary) else var.subindex)
            self.vars[key] = var
            self.values[key] = _initial(var)
        self.initial = dict(self.values)
        self._sizes: dict[tuple[int, int], int | None] = {}
        self.validators: dict[int, Validator] = {}
        self.readers: dict[int, Callable[[int], bytes]] = {}
        self._watchers: dict[tuple[int, int], list[Watcher]] = {}
        self._index_watchers: dict[int, list[Watcher]] = {}
        self.writes = 0

    # ------------------------------------------------------------------ lookup
    def variable(self, index: int, sub: int = 0) -> ODVariable:
        """The sub-object's description; `SdoAbort` 0x0602 0000 (no object) or 0x0609 0011 (no
        sub-index) when the dictionary has none (CiA 301 7.2.4.3.17)."""
        var = self.vars.get((index, sub))
        if var is not None:
            return var
        if index not in self.od.indices:
            raise SdoAbort(abort.NO_OBJECT, f"object 0x{index:04X} does not exist")
        raise SdoAbort(abort.NO_SUBINDEX, f"object 0x{index:04X} has no sub-index {sub}")

    def __contains__(self, key: object) -> bool:
        return key in self.vars

    def size(self, index: int, sub: int = 0) -> int | None:
        """Bytes of the sub-object's data type, None for strings and domains."""
        return _size(self.variable(index, sub))

    # ------------------------------------------------------------------ the device's own access
    def read(self, index: int, sub: int = 0) -> bytes:
        """The sub-object's bytes (a service's dynamic value when it keeps one, e.g. 0x1003)."""
        reader = self.readers.get(index)
        if reader is not None:
            self.variable(index, sub)
            return reader(sub)
        try:
            return self.values[(index, sub)]
        except KeyError:
            self.variable(index, sub)  # raises the right abort (every sub-object has a value)
            raise

    def get(self, index: int, sub: int = 0) -> Any:
        """The sub-object's value, decoded by its data type (int, float, str or bytes)."""
        return self.variable(index, sub).decode_raw(self.read(index, sub))

    def set(self, index: int, sub: int, value: Any) -> bool:
        """Write a value as the application (no access-type check, every other check as for an
        SDO download; raises `SdoAbort` naming the rule). Returns whether the bytes changed."""
        var = self.variable(index, sub)
        try:
            data = var.encode_raw(value)
        except (ValueError, TypeError, OverflowError) as exc:
            raise SdoAbort(
                abort.INVALID_VALUE, f"{value!r} does not fit 0x{index:04X}:{sub} ({type_name(var.data_type)}): {exc}"
            ) from None
        return self.write(index, sub, bytes(data))

    def write(self, index: int, sub: int, data: bytes, *, sdo: bool = False) -> bool:
        """Store ``data`` after the checks of the module docstring (with ``sdo``, the access type
        too); tell the watchers. Returns whether the bytes changed. Raises `SdoAbort`."""
        key = (index, sub)
        var = self.vars.get(key)
        if var is None:
            var = self.variable(index, sub)  # raises the right abort
        if sdo and not var.writable:
            raise SdoAbort(abort.READ_ONLY, f"0x{index:04X}:{sub} ({var.name}) is {var.access_type}")
        size = self._sizes.get(key, -1)
        if size == -1:
            size = self._sizes[key] = _size(var)
        if size is not None and len(data) != size:
            code = abort.LENGTH_HIGH if len(data) > size else abort.LENGTH_LOW
            raise SdoAbort(code, f"0x{index:04X}:{sub} is {type_name(var.data_type)} ({size} bytes), got {len(data)}")
        validator = self.validators.get(index)
        limited = var.min is not None or var.max is not None
        if validator is not None or limited:  # decoding is not free: only when someone looks
            value = var.decode_raw(data) if size is not None else data
            if limited and var.data_type in datatypes.NUMBER_TYPES and isinstance(value, (int, float)):
                if var.max is not None and value > var.max:
                    raise SdoAbort(abort.VALUE_HIGH, f"0x{index:04X}:{sub}: {value} above HighLimit {var.max}")
                if var.min is not None and value < var.min:
                    raise SdoAbort(abort.VALUE_LOW, f"0x{index:04X}:{sub}: {value} below LowLimit {var.min}")
            if validator is not None:
                validator(sub, value, data)
        changed = self.values.get(key) != data
        self.values[key] = bytes(data)
        self.writes += 1
        for w in self._watchers.get(key, ()):
            w(index, sub)
        for w in self._index_watchers.get(index, ()):
            w(index, sub)
        return changed

    # ------------------------------------------------------------------ SDO access
    def sdo_read(self, index: int, sub: int) -> bytes:
        """An SDO upload's data: `SdoAbort` 0x0601 0001 for a write-only object."""
        var = self.variable(index, sub)
        if not var.readable:
            raise SdoAbort(abort.WRITE_ONLY, f"0x{index:04X}:{sub} ({var.name}) is write-only")
        return self.read(index, sub)

    def sdo_write(self, index: int, sub: int, data: bytes) -> None:
        """An SDO download's data (`write` with the access-type check)."""
        self.write(index, sub, data, sdo=True)

    def check_sdo_access(self, index: int, sub: int, upload: bool) -> ODVariable:
        """The checks an SDO server makes at the initiate request, before any data moves
        (CANopenNode does the same): existence and access type."""
        var = self.variable(index, sub)
        if upload and not var.readable:
            raise SdoAbort(abort.WRITE_ONLY, f"0x{index:04X}:{sub} ({var.name}) is write-only")
        if not upload and not var.writable:
            raise SdoAbort(abort.READ_ONLY, f"0x{index:04X}:{sub} ({var.name}) is {var.access_type}")
        return var

    # ------------------------------------------------------------------ owners
    def watch(self, index: int, sub: int | None, watcher: Watcher) -> None:
        """Call ``watcher(index, sub)`` after every write of ``index:sub`` (any sub when None)."""
        if sub is None:
            self._index_watchers.setdefault(index, []).append(watcher)
        else:
            self._watchers.setdefault((index, sub), []).append(watcher)

    def unwatch(self, index: int, sub: int | None, watcher: Watcher) -> None:
        """Stop a `watch`."""
        lst = self._index_watchers.get(index) if sub is None else self._watchers.get((index, sub))
        if lst and watcher in lst:
            lst.remove(watcher)

    def restore(self, lo: int = 0x0000, hi: int = 0xFFFF) -> None:
        """Power-on values for the indices lo..hi (a reset, CiA 301 7.3.2.2.1); nobody is told:
        the services re-read their configuration after a reset."""
        for key, data in self.initial.items():
            if lo <= key[0] <= hi:
                self.values[key] = data

    def indices(self) -> list[int]:
        """The indices of the dictionary, ascending."""
        return sorted(self.od.indices)

    def has(self, index: int, sub: int = 0) -> bool:
        """Whether ``index:sub`` exists."""
        return (index, sub) in self.vars

    def u(self, index: int, sub: int = 0, default: int = 0) -> int:
        """An unsigned value the services read (``default`` when the object does not exist)."""
        if (index, sub) not in self.vars:
            return default
        return int.from_bytes(self.read(index, sub), "little")
