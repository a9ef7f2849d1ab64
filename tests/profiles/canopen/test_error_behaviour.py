"""Error behaviour, object 0x1029 (CiA 301 7.5.2.32): on a communication error — a heartbeat
consumer timeout, a life guarding event, bus off — the device goes to the NMT state sub-index 1
asks for: 0x00 pre-operational (only from operational), 0x01 no change, 0x02 stopped. The
object is set through the ``canopen`` library's SDO client, as a configuration tool would."""

import canopen
import pytest

from profiles.canopen.dictionary import DEFAULT_EDS
from profiles.canopen.emcy import decode_emcy
from profiles.canopen.nmt import NmtState
from stack import FaultInjector, Frame

MS = 1_000_000


def configured(bus, device, lib, behaviour, *, operational=True, **options):
    """Device 5 consuming node 9's heartbeat (50 ms), 0x1029:1 written by the library."""
    dev = device(5, heartbeat_consumers={9: 50}, start_operational=operational, **options)
    node = canopen.RemoteNode(5, str(DEFAULT_EDS))
    lib.add_node(node)
    lib.run(2 * MS)
    node.sdo[0x1029][1].raw = behaviour
    assert dev.read(0x1029, 1) == behaviour
    return dev


def beat_then_stop(bus, n=3):
    hb = bus.node("hb9")
    for k in range(n):
        hb.call_at(bus.now() + k * 20 * MS, lambda: hb.send(Frame(0x709, b"\x05")))
    bus.run(until=bus.now() + 200 * MS)


@pytest.mark.parametrize(
    "behaviour, operational, after",
    [
        (0x00, True, NmtState.PRE_OPERATIONAL),
        (0x01, True, NmtState.OPERATIONAL),
        (0x02, True, NmtState.STOPPED),
        (0x00, False, NmtState.PRE_OPERATIONAL),  # 0x00 acts only from operational
        (0x02, False, NmtState.STOPPED),
    ],
)
def test_a_heartbeat_consumer_timeout_changes_the_state_as_0x1029_says(bus, device, lib, behaviour, operational, after):
    dev = configured(bus, device, lib, behaviour, operational=operational)
    assert dev.state is (NmtState.OPERATIONAL if operational else NmtState.PRE_OPERATIONAL)
    beat_then_stop(bus)
    assert dev.state is after
    (t, what), *_ = dev.communication_errors
    assert what == "heartbeat of node 9 lost"
    # the heartbeat event: 50 ms after the last heartbeat from node 9 (40 ms after the first)
    assert dev.metrics()["heartbeat_consumer"][0]["timeouts"] == 1


def test_the_default_device_has_0x1029_with_pre_operational(bus, device):
    dev = device(5)
    assert dev.read(0x1029, 0) == 1 and dev.read(0x1029, 1) == 0x00


@pytest.mark.parametrize("behaviour, after", [(0x00, NmtState.PRE_OPERATIONAL), (0x02, NmtState.STOPPED)])
def test_bus_off_is_a_communication_error_and_recovery_sends_emcy_0x8140(bus, device, lib, spy, behaviour, after):
    """The device's transmitter is stuck recessive for 20 ms: every frame it sends fails, it goes
    bus off (and recovers, and goes bus off again, while the fault lasts)."""
    dev = configured(bus, device, lib, behaviour, heartbeat_ms=10)
    fi = FaultInjector(bus)
    t0 = bus.now()
    fi.stuck(dev.node, "recessive", start=t0, end=t0 + 20 * MS)
    bus.run(until=t0 + 200 * MS)
    errors = [w for _, w in dev.communication_errors]
    assert errors and set(errors) == {"bus off"}
    assert dev.state is after
    codes = [decode_emcy(f.data).code for t, f in spy if f.can_id == 0x85 and t > t0]
    if after is NmtState.PRE_OPERATIONAL:
        # each recovery: the error, then its reset, sent once the controller can send again
        assert codes == [0x8140, 0x0000] * len(errors)
    else:
        assert codes == []  # a stopped device sends no EMCY (CiA 301's NMT table)
