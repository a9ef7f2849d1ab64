"""Identifier plans of the master/slave profile: which CAN identifier each frame of a poll
transaction uses.

**DeviceNet** (the default, ``plan = "devicenet"``): the Predefined Master/Slave Connection Set
of ODVA's *CIP Networks Library, Volume 3: DeviceNet Adaptation of CIP*, chapter 3. The
standard itself is not freely available; the numbers below were checked against:

- Wireshark's DeviceNet dissector (``epan/dissectors/packet-devicenet.c``, which says it follows
  CIP Volume 3 Edition 1.14): Message Group 1 is identifiers 0x000..0x3FF (bit 10 = 0) with the
  Group 1 message ID in bits 9..6 and the *source* MAC ID in bits 5..0; message IDs
  0xC..0xF are the slave's I/O messages: 0x300 multicast poll response, 0x340 change of state or
  cyclic, 0x380 bit-strobe response, 0x3C0 poll response or COS/cyclic acknowledge. Message
  Group 2 is 0x400..0x5FF (bits 10..9 = 10) with a MAC ID in bits 8..3 and the Group 2 message
  ID in bits 2..0: 0 bit-strobe command, 1 multicast poll, 2 COS/cyclic acknowledge, 3 the
  slave's explicit/unconnected response, 4 the master's explicit request, 5 poll command /
  COS / cyclic, 6 Group-2-only unconnected explicit request, 7 duplicate MAC ID check.
- Whose MAC ID a Group 2 identifier carries — the tables the spec's identifier table is
  reprinted in by device manuals: ICP DAS CAN-8124/8224/8424 user manual section 7.1 (bit-strobe
  command: *source* MAC ID, i.e. the master's; COS acknowledge, explicit request, poll command:
  *destination* MAC ID, the slave's; explicit response: source), the same in the MKS Baratron
  DMA manual (Table 17) and Rockwell's Powermonitor 3000 manual (1404-UM001D, Table 4.7).
- The bit-strobe command's data (National Instruments NI-DNET user manual, Appendix A): 8
  bytes, one output bit per MAC ID (bit n for MAC ID n); every strobed slave answers whatever its
  bit says, with 0..8 bytes. The byte order (MAC ID n in byte n // 8, bit n % 8) follows the
  register maps of the Delta DVPDNET-SL and AH10DNET manuals (bit 0 of the first word is node 0).

What this means against the issue's numbers: the poll command 0x400 | MAC << 3 | 5 carries the
*slave's* MAC ID and the poll response 0x3C0 | MAC the slave's — both as the issue says. The
bit-strobe command 0x400 | MAC << 3 | 0 is right as a formula, but its MAC ID is the *master's*
(the source), not a slave's: one strobe identifier per master, and the slaves answer it with
**bit-strobe responses 0x380 | MAC** (Group 1 message 0xE), not poll responses. A slave's change of
state / cyclic message is 0x340 | MAC (Group 1 message 0xD) and the master's acknowledgement
0x400 | MAC << 3 | 2 (Group 2 message 2, the slave's MAC ID as destination).

Arbitration follows from the groups: every slave's I/O message (Group 1, below 0x400) beats
every master command (Group 2), and bit-strobe responses arrive in MAC ID order.

DeviceNet has no remote frames. The ``remote`` poll style (a remote frame that the slave's
controller answers from its remote-reply mailbox) uses the response's identifier for the remote
frame, as CAN does; under the DeviceNet plan that is the poll response 0x3C0 | MAC.

**Custom** (``plan = "custom"``): every identifier is given in the scenario (standard or
extended), for home-grown ECU networks.
"""

from __future__ import annotations

__all__ = [
    "PLANS",
    "MAC_MAX",
    "poll_command",
    "poll_response",
    "bit_strobe_command",
    "bit_strobe_response",
    "cos_message",
    "cos_ack",
    "strobe_data",
    "describe",
]

PLANS = ("devicenet", "custom")
"""The identifier plans a master may use."""

MAC_MAX = 63
"""DeviceNet MAC IDs are 0..63 (6 bits)."""

GROUP_1_POLL_RESPONSE = 0xF
GROUP_1_BIT_STROBE_RESPONSE = 0xE
GROUP_1_COS = 0xD
GROUP_2_BIT_STROBE = 0
GROUP_2_COS_ACK = 2
GROUP_2_POLL = 5


def _group_1(message: int, source_mac: int) -> int:
    """Message Group 1: 0 | message ID (4 bits) | source MAC ID (6 bits)."""
    return message << 6 | _mac(source_mac)


def _group_2(mac: int, message: int) -> int:
    """Message Group 2: 10 | MAC ID (6 bits) | message ID (3 bits)."""
    return 0x400 | _mac(mac) << 3 | message


def _mac(mac: int) -> int:
    if isinstance(mac, bool) or not isinstance(mac, int) or not 0 <= mac <= MAC_MAX:
        raise ValueError(f"MAC ID {mac!r} is not 0..{MAC_MAX}")
    return mac


def poll_command(slave_mac: int) -> int:
    """The master's I/O poll command to a slave: Group 2 message 5, destination MAC ID."""
    return _group_2(slave_mac, GROUP_2_POLL)


def poll_response(slave_mac: int) -> int:
    """The slave's I/O poll response: Group 1 message 0xF, source MAC ID (0x3C0 | MAC)."""
    return _group_1(GROUP_1_POLL_RESPONSE, slave_mac)


def bit_strobe_command(master_mac: int) -> int:
    """The master's I/O bit-strobe command: Group 2 message 0 with the *master's* MAC ID (source)."""
    return _group_2(master_mac, GROUP_2_BIT_STROBE)


def bit_strobe_response(slave_mac: int) -> int:
    """A slave's answer to the bit-strobe command: Group 1 message 0xE, source MAC ID (0x380 | MAC)."""
    return _group_1(GROUP_1_BIT_STROBE_RESPONSE, slave_mac)


def cos_message(slave_mac: int) -> int:
    """A slave's change-of-state or cyclic I/O message: Group 1 message 0xD (0x340 | MAC)."""
    return _group_1(GROUP_1_COS, slave_mac)


def cos_ack(slave_mac: int) -> int:
    """The master's acknowledgement of a slave's COS/cyclic message: Group 2 message 2, the slave's
    MAC ID as destination."""
    return _group_2(slave_mac, GROUP_2_COS_ACK)


def strobe_data(macs: list[int] | tuple[int, ...]) -> bytes:
    """The 8-byte bit-strobe command with the bits of ``macs`` set (MAC ID n: byte n // 8, bit n % 8)."""
    out = bytearray(8)
    for m in macs:
        m = _mac(m)
        out[m // 8] |= 1 << (m % 8)
    return bytes(out)


_GROUP_1_NAMES = {
    0xC: "multicast poll response",
    0xD: "change of state / cyclic",
    0xE: "bit-strobe response",
    0xF: "poll response or COS/cyclic acknowledge",
}
_GROUP_2_NAMES = {
    0: "bit-strobe command (source MAC ID)",
    1: "multicast poll command",
    2: "COS/cyclic acknowledge (destination)",
    3: "explicit/unconnected response (source)",
    4: "explicit request (destination)",
    5: "poll command / COS / cyclic (destination)",
    6: "Group 2 only unconnected explicit request",
    7: "duplicate MAC ID check",
}


def describe(can_id: int) -> str:
    """What a standard identifier means in the Predefined Master/Slave Connection Set."""
    if 0 <= can_id <= 0x3FF:
        msg, mac = can_id >> 6, can_id & 0x3F
        name = _GROUP_1_NAMES.get(msg)
        return f"Group 1 message 0x{msg:X} of MAC ID {mac}" + (f": {name}" if name else "")
    if 0x400 <= can_id <= 0x5FF:
        mac, msg = (can_id >> 3) & 0x3F, can_id & 7
        return f"Group 2 message {msg} of MAC ID {mac}: {_GROUP_2_NAMES[msg]}"
    return f"0x{can_id:03X} is outside Message Groups 1 and 2"
