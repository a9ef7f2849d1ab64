"""PDO configuration through SDO (CiA 301 7.5.2.35-38) with the ``canopen`` library as the
configuring master: it reads the PDOs, re-maps them in pre-operational in the order the standard
gives (its ``PdoMap.save``), and every refused step aborts with the code CiA 301 names."""

import canopen
import pytest
from canopen.sdo import SdoAbortedError

from profiles.canopen.dictionary import DEFAULT_EDS

MS = 1_000_000
REMOTE_OPTIONS = {"heartbeat_ms": 0}  # the `remote` fixture's device: no heartbeat frames


def test_the_library_reads_the_pdo_configuration(remote):
    dev, node = remote
    node.tpdo.read()
    node.rpdo.read()
    for n in range(1, 5):
        ours, theirs = dev.tpdo(n), node.tpdo[n]
        assert theirs.cob_id == ours.can_id and theirs.enabled == ours.valid
        assert theirs.trans_type == ours.transmission_type
        assert [(v.index, v.subindex, v.length) for v in theirs.map] == [
            (m.index, m.sub, 8 * m.size) for m in ours.mapped
        ]
    assert node.rpdo[1].cob_id == 0x205 and [v.name for v in node.rpdo[1].map] == ["Digital outputs"]
    assert node.rpdo[4].enabled is False


def test_remap_in_pre_operational_then_tpdos_after_each_sync(remote, lib):
    dev, node = remote
    node.tpdo.read()
    pdo = node.tpdo[1]
    pdo.clear()
    pdo.add_variable(0x2003)  # Temperature, INTEGER16
    pdo.add_variable(0x2001, 1)  # Analog input 1
    pdo.add_variable(0x2002)  # Cycle counter
    pdo.trans_type = 2
    pdo.enabled = True
    pdo.save()  # disable, count 0, entries, count, enable
    assert [(m.index, m.sub, m.size) for m in dev.tpdo(1).mapped] == [(0x2003, 0, 2), (0x2001, 1, 2), (0x2002, 0, 4)]
    assert dev.tpdo(1).valid and dev.tpdo(1).transmission_type == 2
    received = []
    pdo.add_callback(
        lambda m: received.append((m["Temperature"].raw, m["Analog inputs.Analog input 1"].raw, m["Cycle counter"].raw))
    )
    dev.write(0x2003, 0, -55)
    dev.write(0x2001, 1, 321)
    node.nmt.state = "OPERATIONAL"
    for k in range(10):
        dev.write(0x2002, 0, k)
        lib.sync.transmit()
    # type 2: every second SYNC, the first at SYNC 2 (2 // 2 + 1)
    assert received == [(-55, 321, k) for k in (1, 3, 5, 7, 9)]


def test_the_library_drives_an_rpdo(remote, lib):
    dev, node = remote
    node.rpdo.read()
    node.nmt.state = "OPERATIONAL"
    lib.run(1 * MS)
    node.rpdo[1]["Digital outputs"].raw = 0x3C
    node.rpdo[1].transmit()
    assert dev.read(0x2100) == 0x3C


def test_remapping_in_operational_is_refused_with_0x08000022(remote, lib):
    dev, node = remote
    node.tpdo.read()
    node.nmt.state = "OPERATIONAL"
    lib.run(1 * MS)
    pdo = node.tpdo[2]
    pdo.clear()
    pdo.add_variable(0x2002)
    with pytest.raises(SdoAbortedError) as exc:
        pdo.save()
    assert exc.value.code == 0x0800_0022  # present device state
    assert [m.index for m in dev.tpdo(2).mapped] == [0x2001, 0x2001]  # mapping unchanged


def test_remapping_in_operational_when_the_device_allows_it(lib, device):
    dev = device(6, heartbeat_ms=0, remap_in_operational=True)
    node = canopen.RemoteNode(6, str(DEFAULT_EDS))
    lib.add_node(node)
    node.tpdo.read()
    node.nmt.state = "OPERATIONAL"
    lib.run(1 * MS)
    pdo = node.tpdo[2]
    pdo.clear()
    pdo.add_variable(0x2002)
    pdo.save()
    assert [m.index for m in dev.tpdo(2).mapped] == [0x2002] and dev.tpdo(2).valid


def write(node, index, sub, value):
    node.sdo[index][sub].raw = value


REFUSALS = [
    # (why, steps before, the refused write, abort code)
    ("mapping while the PDO is valid", [], (0x1A00, 0, 0), 0x0601_0000),
    (
        "an entry while the number of objects is not 0",
        [(0x1800, 1, 0x8000_0185)],
        (0x1A00, 1, 0x2003_0010),
        0x0601_0000,
    ),
    (
        "an object that does not exist",
        [(0x1800, 1, 0x8000_0185), (0x1A00, 0, 0)],
        (0x1A00, 1, 0x3000_0008),
        0x0602_0000,
    ),
    (
        "an object that is not mappable",
        [(0x1800, 1, 0x8000_0185), (0x1A00, 0, 0)],
        (0x1A00, 1, 0x1017_0010),
        0x0604_0041,
    ),
    (
        "more bits than the object has",
        [(0x1800, 1, 0x8000_0185), (0x1A00, 0, 0)],
        (0x1A00, 1, 0x2000_0010),
        0x0604_0041,
    ),
    (
        "a length that is not whole bytes",
        [(0x1800, 1, 0x8000_0185), (0x1A00, 0, 0)],
        (0x1A00, 1, 0x2002_0004),
        0x0604_0041,
    ),
    (
        "a read-only object in an RPDO",
        [(0x1400, 1, 0x8000_0205), (0x1600, 0, 0)],
        (0x1600, 1, 0x2202_0010),
        0x0604_0041,
    ),
    (
        "more than 8 bytes",
        [
            (0x1800, 1, 0x8000_0185),
            (0x1A00, 0, 0),
            (0x1A00, 1, 0x2002_0020),
            (0x1A00, 2, 0x2002_0020),
            (0x1A00, 3, 0x2000_0008),
        ],
        (0x1A00, 0, 3),
        0x0604_0042,
    ),
    ("a new CAN-ID while valid", [], (0x1800, 1, 0x0000_0190), 0x0609_0030),
    ("a restricted CAN-ID", [(0x1800, 1, 0x8000_0185)], (0x1800, 1, 0x0000_0605), 0x0609_0030),
    ("an extended CAN-ID (bit 29)", [(0x1800, 1, 0x8000_0185)], (0x1800, 1, 0x2000_0185), 0x0609_0030),
    ("valid without mapped objects", [(0x1800, 1, 0x8000_0185), (0x1A00, 0, 0)], (0x1800, 1, 0x0000_0185), 0x0609_0030),
    ("a reserved TPDO transmission type", [], (0x1800, 2, 245), 0x0609_0030),
    ("a reserved RPDO transmission type", [], (0x1400, 2, 252), 0x0609_0030),
    ("the inhibit time while valid", [], (0x1800, 3, 10), 0x0609_0030),
    ("the SYNC start value while valid", [], (0x1800, 6, 3), 0x0609_0030),
    ("a SYNC start value above 240", [(0x1800, 1, 0x8000_0185)], (0x1800, 6, 241), 0x0609_0030),
]


@pytest.mark.parametrize("why, before, refused, code", REFUSALS, ids=[r[0] for r in REFUSALS])
def test_refused_pdo_configuration(remote, why, before, refused, code):
    dev, node = remote
    for step in before:
        write(node, *step)
    with pytest.raises(SdoAbortedError) as exc:
        write(node, *refused)
    assert exc.value.code == code


def test_the_allowed_order_works_step_by_step(remote, lib, bus, spy, frames_with):
    dev, node = remote
    for step in [
        (0x1800, 1, 0x8000_0185),
        (0x1A00, 0, 0),
        (0x1A00, 1, 0x2002_0020),
        (0x1A00, 0, 1),
        (0x1800, 1, 0x0000_0199),
        (0x1800, 2, 1),
    ]:
        write(node, *step)
    node.nmt.state = "OPERATIONAL"
    lib.sync.transmit()
    assert [f.data for _, f in frames_with(spy, 0x199)] == [bytes(4)]
    assert frames_with(spy, 0x185) == []
