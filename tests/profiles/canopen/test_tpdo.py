"""Transmit PDOs on the simulated bus: every transmission type of CiA 301 7.2.2 / 7.5.2.37,
inhibit time and event timer, the SYNC start value, and the synchronous window (0x1007)."""

import pytest

from profiles.canopen.emcy import decode_emcy
from stack import Frame

MS = 1_000_000
US = 1_000

ONE = {"mapping": ["0x2002:0/32"]}  # the cycle counter, UNSIGNED32


def operational(bus, master_node, *node_ids):
    for nid in node_ids:
        master_node.send(Frame(0x000, bytes([0x01, nid])))
    bus.run(until=bus.now() + 2 * MS)


def syncs(bus, master_node, n, period_us=1000, counter=None, before=None):
    """Send ``n`` SYNCs ``period_us`` apart (with a counter 1..``counter``); ``before(k)`` runs
    just before SYNC k (1-based)."""
    for k in range(1, n + 1):
        if before is not None:
            before(k)
        master_node.send(Frame(0x080, bytes([(k - 1) % counter + 1]) if counter else b""))
        bus.run(until=bus.now() + period_us * US)


def sync_index(spy, t):
    """Number of SYNCs received up to ``t``."""
    return sum(1 for ts, f in spy if f.can_id == 0x80 and ts <= t)


def test_type_1_every_sync_carrying_the_value_sampled_then(bus, device, master_node, spy, frames_with):
    d = device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=1)})
    operational(bus, master_node, 1)
    syncs(bus, master_node, 6, before=lambda k: d.write(0x2002, 0, 100 + k))
    got = [int.from_bytes(f.data, "little") for _, f in frames_with(spy, 0x181)]
    assert got == [101, 102, 103, 104, 105, 106]


@pytest.mark.parametrize("n", [2, 3, 7])
def test_type_n_every_nth_sync(bus, device, master_node, spy, frames_with, n):
    device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=n)})
    operational(bus, master_node, 1)
    syncs(bus, master_node, 30)
    at = [sync_index(spy, t) for t, _ in frames_with(spy, 0x181)]
    assert {b - a for a, b in zip(at, at[1:])} == {n}
    assert at[0] == n // 2 + 1  # CANopenNode's first one, in the middle of the period


def test_sync_start_value_picks_the_first_sync(bus, device, master_node, spy, frames_with):
    device(1, heartbeat_ms=0, sync_overflow=10, tpdo={1: dict(ONE, transmission_type=5, sync_start=3)})
    operational(bus, master_node, 1)
    syncs(bus, master_node, 20, counter=10)
    counters = []
    for t, _ in frames_with(spy, 0x181):
        last_sync = [f for ts, f in spy if f.can_id == 0x80 and ts <= t][-1]
        counters.append(last_sync.data[0])
    assert counters == [3, 8, 3, 8]  # first at counter 3, then every 5th SYNC


def test_type_0_goes_at_the_sync_after_an_event_only(bus, device, master_node, spy, frames_with):
    d = device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=0)})
    operational(bus, master_node, 1)
    syncs(bus, master_node, 4)  # the first SYNC in operational sends once, then nothing changes
    assert len(frames_with(spy, 0x181)) == 1
    d.write(0x2002, 0, 7)
    bus.run(until=bus.now() + 1 * MS)
    assert len(frames_with(spy, 0x181)) == 1  # not before the SYNC
    syncs(bus, master_node, 3)
    frames = frames_with(spy, 0x181)
    assert len(frames) == 2 and frames[1][1].data == (7).to_bytes(4, "little")
    assert sync_index(spy, frames[1][0]) == 5
    d.request_tpdo(1)  # the application's event, same value
    syncs(bus, master_node, 2)
    assert len(frames_with(spy, 0x181)) == 3


def test_type_252_answers_a_remote_request_with_data_sampled_at_the_last_sync(
    bus, device, master_node, spy, frames_with
):
    d = device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=252)})
    operational(bus, master_node, 1)
    d.write(0x2002, 0, 11)
    syncs(bus, master_node, 1)
    d.write(0x2002, 0, 12)  # after the SYNC: not in the sample
    assert frames_with(spy, 0x181) == []  # nothing without a request
    master_node.send(Frame(0x181, remote=True, dlc=4))
    bus.run(until=bus.now() + 1 * MS)
    assert [f.data for _, f in frames_with(spy, 0x181)] == [(11).to_bytes(4, "little")]


def test_type_253_samples_on_the_remote_request(bus, device, master_node, spy, frames_with):
    d = device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=253)})
    operational(bus, master_node, 1)
    d.write(0x2002, 0, 13)
    syncs(bus, master_node, 2)
    assert frames_with(spy, 0x181) == []
    master_node.send(Frame(0x181, remote=True, dlc=4))
    bus.run(until=bus.now() + 1 * MS)
    assert [f.data for _, f in frames_with(spy, 0x181)] == [(13).to_bytes(4, "little")]


def test_no_answer_to_a_remote_request_when_bit_30_forbids_rtr(bus, device, master_node, spy, frames_with):
    device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=253, rtr=False)})
    operational(bus, master_node, 1)
    master_node.send(Frame(0x181, remote=True, dlc=4))
    bus.run(until=bus.now() + 2 * MS)
    assert frames_with(spy, 0x181) == []


def test_type_255_on_change_never_sooner_than_the_inhibit_time(bus, device, master_node, spy, frames_with):
    # inhibit 50 x 100 us = 5 ms; the value changes every 1 ms
    d = device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=255, inhibit_100us=50)})
    starts = []
    bus.node("sof-spy").subscribe(lambda ev: starts.append(ev.sof) if ev.frame.can_id == 0x181 else None)
    operational(bus, master_node, 1)
    t0 = bus.now()
    written = []
    for k in range(1, 31):
        d.write(0x2002, 0, k)
        written.append((bus.now(), k))
        bus.run(until=t0 + k * MS)
    frames = frames_with(spy, 0x181)
    assert min(b - a for a, b in zip(starts, starts[1:])) >= 5 * MS  # start of frame to start of frame
    assert len(frames) == 1 + 6  # once on entering operational, then one per inhibit time over 30 ms
    # an event inside the inhibit time goes when it ends, with the data of that moment
    expected = [max(k for t, k in written if t <= sof) for sof in starts[1:]]
    assert [int.from_bytes(f.data, "little") for _, f in frames[1:]] == expected


def test_type_255_unchanged_writes_are_no_event(bus, device, master_node, spy, frames_with):
    d = device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=255)})
    operational(bus, master_node, 1)
    for _ in range(5):
        d.write(0x2002, 0, 0)
        bus.run(until=bus.now() + 1 * MS)
    assert len(frames_with(spy, 0x181)) == 1  # the one on entering operational


def test_type_254_event_timer_sends_without_changes(bus, device, master_node, spy, frames_with):
    device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=254, event_timer_ms=10)})
    operational(bus, master_node, 1)
    bus.run(until=bus.now() + 55 * MS)
    times = [t for t, _ in frames_with(spy, 0x181)][1:]  # the first shared the bus with the boot traffic
    assert len(times) == 5 and {b - a for a, b in zip(times, times[1:])} == {10 * MS}


def test_event_timer_restarts_after_each_event(bus, device, master_node, spy, frames_with):
    d = device(1, heartbeat_ms=0, tpdo={1: dict(ONE, transmission_type=255, event_timer_ms=10)})
    operational(bus, master_node, 1)
    bus.run(until=bus.now() + 4 * MS)
    d.write(0x2002, 0, 1)
    t_event = bus.now()
    bus.run(until=t_event + 12 * MS)
    times = [t for t, _ in frames_with(spy, 0x181)]
    assert len(times) == 3 and times[2] - times[1] == 10 * MS


def window_devices(device, n=4):
    # three synchronous TPDOs of 8 bytes per device, every SYNC: 12 frames of ~130 us per cycle
    full = ["0x2002:0/32", "0x2001:1/16", "0x2001:2/16"]
    return [
        device(
            k,
            heartbeat_ms=0,
            sync_window_us=300,
            tpdo={
                1: {"transmission_type": 1, "mapping": full},
                2: {"transmission_type": 1, "mapping": full},
                3: {"transmission_type": 1, "mapping": full},
                4: {"valid": False},
            },
        )
        for k in range(1, n + 1)
    ]


def test_a_tpdo_that_cannot_start_inside_the_window_is_not_sent_late(bus, device, master_node):
    devs = window_devices(device)
    log = []
    bus.node("sof-spy").subscribe(lambda ev: log.append((ev.sof, ev.time, ev.frame)))
    operational(bus, master_node, *range(1, 5))
    syncs(bus, master_node, 10)
    sync_times = [t for _, t, f in log if f.can_id == 0x80]
    for sof, _, f in log:
        if 0x181 <= f.can_id <= 0x3FF:
            last = max(t for t in sync_times if t < sof)  # the device's window starts at reception
            assert sof <= last + 300 * US  # every PDO on the bus started inside its window
    late = sum(tp.late for d in devs for tp in d.tpdos)
    sent = sum(tp.sent for d in devs for tp in d.tpdos)
    on_bus = sum(1 for _, _, f in log if 0x181 <= f.can_id <= 0x3FF)
    assert late > 0 and sent == on_bus and sent + late == 4 * 3 * 10
    assert all(tp.queued == tp.sent + tp.late for d in devs for tp in d.tpdos)


def test_late_tpdos_raise_emcy_0x8100_once(bus, device, master_node, spy, frames_with):
    devs = window_devices(device)
    operational(bus, master_node, *range(1, 5))
    syncs(bus, master_node, 10)
    late_devices = [d for d in devs if any(tp.late for tp in d.tpdos)]
    assert late_devices
    for d in late_devices:
        codes = [decode_emcy(f.data).code for _, f in frames_with(spy, 0x80 + d.node_id)]
        assert codes == [0x8100]  # raised once, not at every late SYNC
        assert d.metrics()["tpdos"][0]["not_in_window"] == d.tpdos[0].late
