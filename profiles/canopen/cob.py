"""COB-IDs of the pre-defined connection set (CiA 301 7.3.5, table "broadcast objects" and
"peer-to-peer objects"): the 11-bit identifier is a 4-bit function code followed by the 7-bit
node-ID, except for the broadcast objects NMT (0x000), SYNC (0x080) and TIME (0x100).

======================  =============  ==========================
object                  function code  COB-ID
======================  =============  ==========================
NMT                     0000b          0x000
SYNC                    0001b          0x080
EMCY                    0001b          0x080 + node-ID
TIME                    0010b          0x100
TPDO1 / RPDO1           0011b / 0100b  0x180 / 0x200 + node-ID
TPDO2 / RPDO2           0101b / 0110b  0x280 / 0x300 + node-ID
TPDO3 / RPDO3           0111b / 1000b  0x380 / 0x400 + node-ID
TPDO4 / RPDO4           1001b / 1010b  0x480 / 0x500 + node-ID
SDO (tx, server→client) 1011b          0x580 + node-ID
SDO (rx, client→server) 1100b          0x600 + node-ID
NMT error control       1110b          0x700 + node-ID
======================  =============  ==========================

CAN-IDs a device must refuse for its configurable objects (PDOs, SYNC, EMCY, TIME), because they
belong to NMT, SDO, error control and LSS of the pre-defined set (CiA 301 7.3.5, "restricted
CAN-IDs"): 0x000, 0x001-0x07F, 0x101-0x180, 0x581-0x5FF, 0x601-0x67F, 0x6E0-0x6FF,
0x701-0x77F, 0x780-0x7FF.
"""

from __future__ import annotations

__all__ = [
    "NMT",
    "SYNC",
    "TIME",
    "EMCY",
    "TPDO",
    "RPDO",
    "SDO_TX",
    "SDO_RX",
    "HEARTBEAT",
    "tpdo_cob_id",
    "rpdo_cob_id",
    "is_restricted",
    "check_node_id",
]

NMT = 0x000
SYNC = 0x080
TIME = 0x100
EMCY = 0x080
TPDO = (0x180, 0x280, 0x380, 0x480)
RPDO = (0x200, 0x300, 0x400, 0x500)
SDO_TX = 0x580
SDO_RX = 0x600
HEARTBEAT = 0x700

_RESTRICTED = ((0x000, 0x07F), (0x101, 0x180), (0x581, 0x5FF), (0x601, 0x67F), (0x6E0, 0x6FF), (0x701, 0x7FF))


def check_node_id(node_id: object) -> int:
    """A CANopen node-ID: an int 1..127 (CiA 301 7.2.8.1; 0 addresses all nodes in NMT
    commands and is no device's ID). Raises ValueError naming the value and the rule."""
    if isinstance(node_id, bool) or not isinstance(node_id, int) or not 1 <= node_id <= 127:
        raise ValueError(f"node_id {node_id!r}: a CANopen node-ID is an integer 1..127 (CiA 301 7.2.8.1)")
    return node_id


def tpdo_cob_id(n: int, node_id: int) -> int:
    """The pre-defined COB-ID of TPDO ``n`` (1..4) of ``node_id``: 0x180/0x280/0x380/0x480 + ID."""
    return TPDO[n - 1] + node_id


def rpdo_cob_id(n: int, node_id: int) -> int:
    """The pre-defined COB-ID of RPDO ``n`` (1..4) of ``node_id``: 0x200/0x300/0x400/0x500 + ID."""
    return RPDO[n - 1] + node_id


def is_restricted(can_id: int) -> bool:
    """True for the restricted CAN-IDs of CiA 301 7.3.5 (see the module docstring)."""
    return any(lo <= can_id <= hi for lo, hi in _RESTRICTED)
