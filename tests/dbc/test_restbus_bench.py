"""RestBus wiring and the benchmark's bookkeeping (its speed is not asserted here)."""

from pathlib import Path

from dbc.bench import benchmark
from dbc.restbus import RestBus
from stack.sim import SimBus

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
MS = 1_000_000


def test_restbus_simulates_all_but_dut_and_decodes_dut(sample_db):
    bus = SimBus(500_000)
    rb = RestBus(sample_db, bus, dut="IPC")
    assert sorted(rb.ecus) == ["ABS", "BCM", "ECM", "GW", "TCM"]
    dut = bus.node("IPC")  # a stand-in DUT sending its own cluster frame
    msg = sample_db.get_message_by_name("ClusterStatus")
    from stack.frame import Frame

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
