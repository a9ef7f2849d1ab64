"""A master switch that cuts the old master's basic cycle short (issue 26): the returning primary
whose oscillator is slow starts its reference message earlier, one NTU a cycle (ISO 11898-4
9.5.1, Ref_Trigger_Offset down to -127), until it wins — inside the cycle the backup started.
The monitor reports the switch with ``cut_cycle_short`` and no time after the cycle's end
(never a negative one).

Worked by hand from the schedule of the network of `test_tdma.py` (500 kbit/s, NTU = one bit = 2 µs, 5 ms
basic cycle, Initial_Ref_Offset 127 NTU) with gw's clock 1000 ppm slow:

- at power-up both masters request at the end of the first cycle plus 127 NTU, each on its own
  clock: eng (exact) at 5.254 ms, gw at 5.254 ms local = 5.259 ms on the bus: eng's reference
  goes first and eng is the current master, its references every 5 ms from 5.254 ms;
- gw is in schedule after the second reference (10.254 ms), a backup that sees a current master
  of lower priority: its offset becomes 0, then -1, -2, -3 NTU at the references of 15.254,
  20.254 and 25.254 ms;
- a gw cycle of 5000 µs local lasts 5000 / 0.999 = 5005.005 µs on the bus: at offset 0, -1, -2 gw
  requests 5005.0, 5003.0, 5001.0 µs after eng's reference and loses to eng's request at 5000 µs
  (its request is withdrawn when eng's reference completes); at -3 NTU it requests
  (5000 - 6) / 0.999 = 4998.999 µs after the reference of 25.254 ms and sends alone;
- that is 4998.999 µs after the last reference: shorter than a cycle of the new master (5005.005
  µs on the bus), so the switch cut the cycle short and comes 0 µs after its end.
"""

from __future__ import annotations

from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario

PPM = -1000.0

NET = {
    "bus": {"bitrate": 500000, "duration": 0.05, "seed": 1},
    "nodes": [
        {"name": "gw", "profile": "tdma", "drift_ppm": PPM, "messages": [{"name": "A", "id": 0x100, "dlc": 8}]},
        {"name": "eng", "profile": "tdma", "messages": [{"name": "B", "id": 0x110, "dlc": 8}]},
        {"name": "abs", "profile": "tdma", "messages": [{"name": "C", "id": 0x120, "dlc": 4}]},
    ],
    "tdma": {
        "reference_id": 0x010,
        "time_masters": ["gw", "eng"],
        "basic_cycle_us": 5000,
        "matrix_cycles": 4,
        "windows": [
            {"start_us": 500, "length_us": 400, "kind": "exclusive", "messages": ["A"]},
            {"start_us": 1000, "length_us": 400, "kind": "exclusive", "messages": ["B"], "repeat": 2},
            {"start_us": 1000, "length_us": 400, "kind": "exclusive", "messages": ["C"], "repeat": 2, "base_cycle": 1},
        ],
    },
}


def _local(t_bus: int) -> int:
    """gw's local time at bus time ``t_bus``: local = bus x (1 + ppm 1e-6), to the ns."""
    return t_bus + round(t_bus * PPM * 1e-6)


def _bus(t_local: int) -> int:
    """The first bus ns at which gw's local clock reads ``t_local``."""
    t = round(t_local / (1 + PPM * 1e-6)) - 2
    while _local(t) < t_local:
        t += 1
    return t


def test_a_slow_primary_takes_over_by_cutting_the_backups_cycle_short():
    res = run_scenario(parse_scenario(NET, "net.toml"), record=True)
    t = res.to_json()["tdma"]
    ntu, cycle, first = 2_000, 5_000_000, 5_254_000
    eng_refs = [first + k * cycle for k in range(5)]  # eng's references until gw wins
    ref = eng_refs[-1]
    takeover = _bus(_local(ref) + cycle - 3 * ntu)
    assert takeover == 30_252_999  # 4998.999 µs after eng's reference of 25.254 ms
    assert t["switches"] == [
        {
            "at_ms": takeover / 1e6,
            "from": "eng",
            "to": "gw",
            "after_reference_us": (takeover - ref) / 1000,
            "after_cycle_end_us": 0.0,
            "cut_cycle_short": True,
        }
    ]
    assert (takeover - ref) < _bus(_local(ref) + cycle) - ref  # shorter than gw's own cycle
    refs = [(r.start, r.frame.can_id) for r in res.trace if r.kind == "frame" and r.frame.can_id in (0x010, 0x011)]
    assert refs[:6] == [(s, 0x011) for s in eng_refs] + [(takeover, 0x010)]
    assert t["master_switches"] == 1 and t["nodes"]["gw"]["master_mode"] == "current_master"
