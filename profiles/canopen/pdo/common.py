"""What TPDOs and RPDOs share: the communication parameter (0x1400 + n-1 for RPDO n, 0x1800 +
n-1 for TPDO n), the mapping parameter (0x1600.., 0x1A00..) and the rules for changing them
(CiA 301 7.5.2.35-7.5.2.38; the refusals and their abort codes are CANopenNode's, which
follows the standard's procedure).

Communication parameter: sub-index 1 the COB-ID (bit 31 set: the PDO is not valid; bit 30 set:
no RTR allowed on it; bits 29..11 must be 0 here, 11-bit identifiers only; bits 10..0 the
CAN-ID), 2 the transmission type, 3 the inhibit time (100 µs units), 5 the event timer (ms), 6
the SYNC start value.

Changing a PDO goes in CiA 301's order: (1) make it not valid (COB-ID bit 31 = 1); (2) set the
number of mapped objects (mapping sub-index 0) to 0; (3) write the entries; (4) set the number
of mapped objects; (5) make it valid again. Refused otherwise:

- a new CAN-ID while the PDO is valid, a restricted CAN-ID (`profiles.canopen.cob`), making a
  PDO valid without mapped objects, bits 29..11 set: 0x0609 0030 (invalid value);
- a reserved transmission type (TPDO 241..251, RPDO 241..253): 0x0609 0030;
- the inhibit time or the SYNC start value while the TPDO is valid, a start value above 240:
  0x0609 0030;
- any mapping write while the PDO is valid, or an entry while the number of mapped objects is
  not 0: 0x0601 0000 (unsupported access);
- an entry naming no object 0x0602 0000 / 0x0609 0011, an object that cannot be mapped 0x0604
  0041, more than 8 bytes in all 0x0604 0042;
- mapping writes in operational, unless the device allows re-mapping there
  (``remap_in_operational``; CiA 301 lets a device choose): 0x0800 0022 (present device state).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Protocol

from profiles.canopen import cob
from profiles.canopen._state import NmtState
from profiles.canopen.dictionary import ObjectStore
from profiles.canopen.pdo.mapping import MappedObject, check_entry, check_mapping
from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import SdoAbort

if TYPE_CHECKING:  # pragma: no cover
    from stack import NodeAPI

__all__ = ["Pdo", "PdoHost", "NOT_VALID", "NO_RTR"]

NOT_VALID = 0x8000_0000
NO_RTR = 0x4000_0000
_RESERVED_BITS = 0x3FFF_F800


class PdoHost(Protocol):
    """What a PDO needs from its device."""

    node: NodeAPI
    store: ObjectStore
    node_id: int
    remap_in_operational: bool

    def nmt_state(self) -> NmtState:
        """The device's NMT state."""
        ...

    def pdo_changed(self, pdo: Pdo) -> None:
        """A PDO's configuration changed (routes and timers follow)."""
        ...


class Pdo:
    """One PDO's configuration, read from the dictionary and kept valid by the validators it
    registers (see the module docstring for the rules)."""

    receive = False
    kind = "PDO"

    def __init__(self, host: PdoHost, n: int, comm_index: int, map_index: int, predefined: tuple[int, ...]) -> None:
        self.host = host
        self.store = host.store
        self.n = n
        self.comm_index = comm_index
        self.map_index = map_index
        self.predefined = predefined[n - 1] + host.node_id if n <= len(predefined) else None
        self.mapped: list[MappedObject] = []
        self.mapping_error: SdoAbort | None = None
        self.load()
        self.store.validators[comm_index] = self._check_comm
        self.store.validators[map_index] = self._check_map
        self.store.watch(comm_index, None, self._written)
        self.store.watch(map_index, None, self._written)

    @property
    def name(self) -> str:
        """'TPDO1', 'RPDO3', ..."""
        return f"{self.kind}{self.n}"

    def load(self) -> None:
        """Read the communication and mapping parameters from the dictionary."""
        s, c, m = self.store, self.comm_index, self.map_index
        word = s.u(c, 1)
        self.cob_word = word
        self.can_id = word & 0x7FF
        self.rtr_allowed = not word & NO_RTR
        self.transmission_type = s.u(c, 2, 255)
        self.inhibit_ns = s.u(c, 3) * 100_000
        self.event_ns = s.u(c, 5) * 1_000_000
        self.sync_start = s.u(c, 6)
        count = s.u(m, 0)
        try:
            self.mapped = check_mapping(s, [s.u(m, k) for k in range(1, count + 1)], receive=self.receive)
            self.mapping_error = None
        except SdoAbort as exc:
            self.mapped = []
            self.mapping_error = exc
        self.size = sum(x.size for x in self.mapped)
        self.valid = not word & NOT_VALID and self.can_id != 0 and bool(self.mapped)

    def start(self) -> None:
        """Entering operational (each kind of PDO does its own)."""
        raise NotImplementedError

    def stop(self) -> None:
        """Leaving operational (each kind of PDO does its own)."""
        raise NotImplementedError

    @property
    def configured_valid(self) -> bool:
        """The COB-ID says valid (bit 31 clear) — even if the mapping made it unusable."""
        return not self.cob_word & NOT_VALID

    @property
    def synchronous(self) -> bool:
        """Transmission types 0..240 (and 252 for a TPDO): tied to SYNC."""
        return self.transmission_type <= 240 or self.transmission_type == 252

    # ------------------------------------------------------------------ validators
    def _check_comm(self, sub: int, value: Any, data: bytes) -> None:
        where = f"0x{self.comm_index:04X}:{sub} ({self.name})"
        if sub == 1:
            can_id = value & 0x7FF
            valid = not value & NOT_VALID
            if value & _RESERVED_BITS:
                raise SdoAbort(abort.INVALID_VALUE, f"{where}: bits 29..11 must be 0 (11-bit CAN-IDs only)")
            if valid:
                if self.valid and can_id != self.can_id:
                    raise SdoAbort(
                        abort.INVALID_VALUE,
                        f"{where}: set bit 31 (not valid) before changing the CAN-ID "
                        f"0x{self.can_id:03X} to 0x{can_id:03X}",
                    )
                if cob.is_restricted(can_id):
                    raise SdoAbort(abort.INVALID_VALUE, f"{where}: CAN-ID 0x{can_id:03X} is restricted (CiA 301 7.3.5)")
                if not self.mapped:
                    raise SdoAbort(abort.INVALID_VALUE, f"{where}: no objects mapped, the PDO cannot be made valid")
        elif sub == 2:
            reserved = range(241, 254) if self.receive else range(241, 252)
            if value in reserved:
                raise SdoAbort(abort.INVALID_VALUE, f"{where}: transmission type {value} is reserved for a {self.kind}")
        elif sub == 3 and not self.receive and self.valid:
            raise SdoAbort(abort.INVALID_VALUE, f"{where}: the inhibit time can change only while the PDO is not valid")
        elif sub == 6 and (self.valid or value > 240):
            raise SdoAbort(
                abort.INVALID_VALUE,
                f"{where}: the SYNC start value (0..240) can change only while the PDO is not valid",
            )

    def _check_map(self, sub: int, value: Any, data: bytes) -> None:
        where = f"0x{self.map_index:04X}:{sub} ({self.name} mapping)"
        if self.host.nmt_state() is NmtState.OPERATIONAL and not self.host.remap_in_operational:
            raise SdoAbort(abort.DEVICE_STATE, f"{where}: re-mapping is done in pre-operational")
        if self.valid:
            raise SdoAbort(
                abort.UNSUPPORTED_ACCESS,
                f"{where}: set bit 31 of 0x{self.comm_index:04X}:1 (PDO not valid) before changing the mapping",
            )
        if sub == 0:
            entries = [k for k in self.store.od.indices[self.map_index].subindices if k]
            if value > len(entries):
                raise SdoAbort(abort.PDO_LENGTH, f"{where}: {value} objects, the mapping has {len(entries)} entries")
            check_mapping(
                self.store, [self.store.u(self.map_index, k) for k in range(1, value + 1)], receive=self.receive
            )
        else:
            if self.store.u(self.map_index, 0):
                raise SdoAbort(
                    abort.UNSUPPORTED_ACCESS,
                    f"{where}: set the number of mapped objects (sub-index 0) to 0 before writing entries",
                )
            check_entry(self.store, value, receive=self.receive)

    def _written(self, index: int, sub: int) -> None:
        self.load()
        self.host.pdo_changed(self)

    def info(self) -> dict[str, Any]:
        """The configuration, JSON-ready."""
        return {
            "pdo": self.name,
            "cob_id": self.can_id,
            "valid": self.valid,
            "transmission_type": self.transmission_type,
            "mapping": [f"0x{m.index:04X}:{m.sub}/{8 * m.size}" for m in self.mapped],
        }
