"""The CANopen master on the simulated bus: booting a network (CiA 302's simplified boot-up),
SDO configuration, SYNC, heartbeat consumption and the SYNC-to-PDO latency it measures."""

import pytest

from profiles.canopen import CanopenMaster
from profiles.canopen.sdo.client import SdoClient
from stack import Frame

MS = 1_000_000
US = 1_000


@pytest.fixture
def network(bus, device):
    def make(node_ids=(1, 2, 3), devices=None, **options):
        devs = [device(n, heartbeat_ms=0) for n in (devices if devices is not None else node_ids)]
        m = CanopenMaster(bus.node("master-profile"), nodes=list(node_ids), **options)
        m.start()
        return m, devs

    return make


def test_boot_resets_configures_and_starts_every_node(bus, network, spy, frames_with):
    m, devs = network(heartbeat_ms=50, sync_period_us=1000)
    bus.run(until=100 * MS)
    assert spy[0][1] == Frame(0x000, b"\x82\x00")  # reset communication, all nodes
    for d in devs:
        assert d.state.name == "OPERATIONAL" and d.boot_ups == 2 and d.read(0x1017) == 50
        assert m.nodes[d.node_id].status == "started"
        assert Frame(0x000, bytes([0x01, d.node_id])) in [f for _, f in spy]  # started one by one
    assert m.metrics()["nodes"][0]["nmt_state"] == "OPERATIONAL"
    # SYNC starts once every node is started, on its period
    syncs = [t for t, _ in frames_with(spy, 0x080)]
    assert syncs[0] > max(m.nodes[n].start_time for n in m.nodes)
    # (the first one may wait for the frame on the wire: the nodes' first PDOs)
    assert {b - a for a, b in zip(syncs[1:], syncs[2:])} == {1 * MS}


def test_configure_writes_with_the_size_the_node_reports(bus, network):
    m, devs = network(node_ids=(1,), configure={1: {"0x2003": -55, "0x2200": "hello", "0x1800:2": 3}})
    bus.run(until=50 * MS)
    d = devs[0]
    assert (d.read(0x2003), d.read(0x2200), d.read(0x1800, 2)) == (-55, "hello", 3)
    assert m.nodes[1].pdo_types[0x181] == 3  # read back with the PDO configuration
    assert m.nodes[1].config_errors == []


def test_configuration_refusals_are_recorded_and_the_node_still_starts(bus, network):
    m, devs = network(node_ids=(1,), configure={1: {"0x1000": 5, "0x3000": 1}})
    bus.run(until=50 * MS)
    errors = m.nodes[1].config_errors
    assert len(errors) == 2 and "abort 0x06010002" in errors[0] and "abort 0x06020000" in errors[1]
    assert devs[0].state.name == "OPERATIONAL"


def test_a_node_without_boot_up_is_missing_and_sync_starts_at_the_deadline(bus, network, spy, frames_with):
    m, devs = network(node_ids=(1, 2), devices=(1,), boot_timeout_ms=30, sync_period_us=1000)
    bus.run(until=29 * MS)
    assert frames_with(spy, 0x080) == []
    bus.run(until=40 * MS)
    assert m.nodes[2].status == "missing" and m.nodes[1].status == "started"
    assert frames_with(spy, 0x080)[0][0] >= 30 * MS


def test_a_node_that_boots_again_is_configured_and_started_again(bus, network, master_node):
    m, devs = network(node_ids=(1,), heartbeat_ms=20)
    bus.run(until=50 * MS)
    master_node.send(Frame(0x000, b"\x81\x01"))  # someone resets node 1
    bus.run(until=100 * MS)
    assert devs[0].state.name == "OPERATIONAL" and devs[0].read(0x1017) == 20
    assert m.nodes[1].boots == 2


def test_heartbeat_loss_is_detected_and_counted(bus, network):
    m, devs = network(heartbeat_ms=10, heartbeat_consumer_ms=25)
    bus.run(until=100 * MS)
    devs[1].stop()
    t_stop = bus.now()
    bus.run(until=t_stop + 200 * MS)
    node = {n["node_id"]: n for n in m.metrics()["nodes"]}[2]
    last = m.consumer.nodes[2].last
    assert node["nmt_state"] == "UNKNOWN" and node["last_state"] == "OPERATIONAL"
    assert node["heartbeat_timeouts"] == 1 and node["heartbeats_missed"] == (bus.now() - last) // (25 * MS)
    lost = [t for t, nid, what in m.events if what == "heartbeat lost"]
    assert len(lost) == 1 and lost[0] - last == 25 * MS
    assert {n["node_id"]: n["nmt_state"] for n in m.metrics()["nodes"]} == {
        1: "OPERATIONAL",
        2: "UNKNOWN",
        3: "OPERATIONAL",
    }


def test_sync_to_pdo_latency_is_from_the_sync_sof_to_the_pdo_end(bus, network):
    m, devs = network(node_ids=(1,), sync_period_us=1000)
    log = []
    bus.node("sof-spy").subscribe(lambda ev: log.append((ev.sof, ev.time, ev.frame)))
    bus.run(until=50 * MS)
    sync_sofs = [s for s, _, f in log if f.can_id == 0x80]
    pdo_ends = [t for _, t, f in log if f.can_id == 0x181]
    expected = [end - max(s for s in sync_sofs if s < end) for end in pdo_ends]
    assert sorted(m.pdos[0x181].latencies.values) == sorted(expected)
    lat = {p["cob_id"]: p for p in m.metrics()["pdos"]}[0x181]["sync_latency_ms"]
    assert lat["count"] == len(expected) and lat["min"] == min(expected) / MS and lat["max"] == max(expected) / MS


def test_event_driven_pdos_have_no_sync_latency(bus, network):
    m, devs = network(node_ids=(1,), sync_period_us=1000)
    bus.run(until=20 * MS)
    pdos = {p["cob_id"]: p for p in m.metrics()["pdos"]}
    assert pdos[0x281]["transmission_type"] == 255 and pdos[0x281]["sync_latency_ms"]["count"] == 0


def test_emcy_of_a_node_is_logged(bus, network):
    m, devs = network(node_ids=(1,))
    bus.run(until=20 * MS)
    devs[0].report_error(0x5000, b"\x07")
    bus.run(until=25 * MS)
    ((t, e),) = m.nodes[1].emcy
    assert e.code == 0x5000 and e.info[0] == 7 and (1, "emcy 0x5000") in [(n, w) for _, n, w in m.events]


def test_the_sdo_client_times_out_and_aborts(bus):
    sent = []
    node = bus.node("c")
    results = []
    c = SdoClient(sent.append, node.call_later, timeout_ns=10 * MS)
    c.upload(0x1000, 0, results.append)
    bus.run(until=20 * MS)
    assert results[0].abort_code == 0x0504_0000
    assert sent[-1][0] == 0x80 and int.from_bytes(sent[-1][4:8], "little") == 0x0504_0000


def test_metrics_are_json_ready(bus, network):
    import json

    m, devs = network(heartbeat_ms=10, sync_period_us=1000)
    bus.run(until=30 * MS)
    assert json.loads(json.dumps(m.metrics())) == m.metrics()
    for d in devs:
        assert json.loads(json.dumps(d.metrics())) == d.metrics()
