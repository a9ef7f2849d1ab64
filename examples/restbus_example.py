"""Rest-bus simulation of the sample powertrain + body network around a cluster (IPC) under test.

Run: python examples/restbus_example.py

Every node but the instrument cluster is simulated from dbc/databases/powertrain_body.dbc with
its initial values and interaction layer; the "DUT" here is an Ecu too, so the example runs
anywhere. On a real bench, replace SimBus with stack.io.driver.PyCanDriver(interface="socketcan",
channel="vcan0") and drop the DUT Ecu: nothing else changes.
"""

from pathlib import Path

from dbc import Ecu, RestBus, load_database
from stack.bus.sim import SimBus

MS = 1_000_000
db = load_database(Path(__file__).resolve().parents[1] / "dbc" / "databases" / "powertrain_body.dbc")
bus = SimBus(500_000, seed=1)
rest = RestBus(db, bus, dut="IPC")
cluster = Ecu(db, "IPC", bus.node("IPC"))  # stand-in for the device under test

cluster.on_signal("GearSelected", lambda ch: print(f"{ch.time / 1e6:8.1f} ms  gear {ch.old} -> {ch.new}"))
cluster.on_signal("DoorFL", lambda ch: print(f"{ch.time / 1e6:8.1f} ms  door FL {ch.new}"))
cluster.on_check_failed(lambda f: print("check failed:", f.message, f.reason))

bus.run(until=100 * MS)
rest.set("TCM", "GearSelected", "D")
rest.set("ECM", "EngineSpeed", 2100)
rest.set("BCM", "DoorFL", "Open")  # OnChangeWithRepetition: 3 frames, 50 ms apart
bus.run(until=300 * MS)

print(
    f"engine speed seen by the cluster: {cluster.get('EngineSpeed')} rpm, "
    f"coolant {cluster.get('EngineTemp')} degC, alive counter {cluster.get('EngineCounter')}"
)
for rec in rest.from_dut()[:3]:
    print("DUT sent:", rec.as_json())
print(
    f"{len(rest.records)} frames on the bus, bus load {100 * bus.bus_load():.1f} %, "
    f"failed checks at the cluster: {cluster.failed_checks}"
)
