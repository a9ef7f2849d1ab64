"""RestBus wiring and the benchmark's bookkeeping (its speed is not asserted here)."""

from pathlib import Path

from dbc.bench import benchmark
from dbc.restbus import RestBus
from stack.bus.sim import SimBus

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
MS = 1_000_000


def test_restbus_simulates_all_but_dut_and_decodes_dut(sample_db):
    bus = SimBus(500_000)
    rb = RestBus(sample_db, bus, dut="IPC")
    assert sorted(rb.ecus) == ["ABS", "BCM", "ECM", "GW", "TCM"]
    dut = bus.node("IPC")  # a stand-in DUT sending its own cluster frame
    msg = sample_db.get_message_by_name("ClusterStatus")
    from stack.wire.frame import Frame

    bus.run(until=3 * MS)
    dut.send(Frame(0x400, msg.encode({"Odometer": 1234.5, "FuelLevel": 50, "Brightness": 10})))
    bus.run(until=5 * MS)
    recs = rb.from_dut()
    assert len(recs) == 1 and recs[0].signals == {"Odometer": 1234.5, "FuelLevel": 50, "Brightness": 10}
    rb.set("BCM", "HeadLight", "High")
    bus.run(until=6 * MS)
    assert any(r.name == "LightControl" and r.signals["HeadLight"] == "High" for r in rb.records)


def test_benchmark_counts_every_scheduled_frame():
    res = benchmark(seconds=1.0, repeat=1)
    assert set(res) >= {"ecu_us_per_msg", "cantools_us_per_msg", "ratio", "frames"}
    # 1 s of the sample network's cyclic messages, from their cycle times and start delays:
    # EngineData 10 ms, GearboxData 20 ms (+5 ms), WheelSpeeds 20, VehicleSpeed 100, EEC1 50,
    # ClusterStatus 100, GatewayInfo 200 — each including the transmission at t = 1 s
    assert res["frames"] == 101 + 50 + 51 + 11 + 21 + 11 + 6


def test_monitor_matches_j1939_by_pgn_like_the_ecus(sample_db):
    from stack.wire.frame import Frame

    bus = SimBus(500_000)
    rb = RestBus(sample_db, bus, dut="ECM")
    msg = sample_db.get_message_by_name("EEC1")  # J1939 PGN 0xF004, sent by ECM (the DUT)
    data = msg.encode({"EngineSpeedJ1939": 1000, "DriverDemandTorque": 10})
    dut = bus.node("ECM")
    bus.run(until=1 * MS)
    # priority 6 and source address 0x17 instead of the DBC's 3 and 0x00; then an unknown PGN
    dut.send(Frame(0x18F00417, data, extended=True))
    dut.send(Frame(0x18F00517, data, extended=True))
    bus.run(until=3 * MS)
    recs = [r for r in rb.records if r.frame.can_id in (0x18F00417, 0x18F00517)]
    assert [(r.sender, r.name) for r in recs] == [("ECM", "EEC1"), ("?", None)]
    assert recs[0].signals == msg.decode(data) and recs[1].signals == {}
    assert rb.ecus["GW"].get("EngineSpeedJ1939") == msg.decode(data)["EngineSpeedJ1939"]
    assert [r.name for r in rb.from_dut()] == ["EEC1"]
