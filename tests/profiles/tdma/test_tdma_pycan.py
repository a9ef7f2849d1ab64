"""The TDMA profile on a python-can bus (python-can's virtual interface, wall-clock timers): the
same code runs, reference messages flow, nodes synchronise and send in their windows. Timing is
the wall clock's, so only what must hold whatever the machine's load is asserted."""

from __future__ import annotations

from pathlib import Path

import pytest

from profiles.pipeline.runner import run_on_pycan
from profiles.pipeline.scenario import load_scenario

ROOT = Path(__file__).resolve().parents[3]


@pytest.mark.wallclock
def test_wallclock_example_runs_on_the_virtual_bus(rerun_until):
    pytest.importorskip("can")

    def run():
        sc = load_scenario(ROOT / "examples" / "tdma_wallclock.toml")
        data = run_on_pycan(sc, "virtual", "tdma-test", duration_s=0.4).to_json()
        assert data["driver"] == "virtual tdma-test"
        t = data["tdma"]
        assert t["references_by_master"].get("gateway", 0) == t["reference_messages"]  # the only master
        return t

    # 0.4 s of 25 ms cycles: the first reference at 25 ms + 127 NTU, about 15 then. A reference
    # whose timer fires after its window (a starved thread) fails the master, which then waits a
    # whole Init_Watch_Trigger (0.52 s) before it tries again: such a run shows none
    def timely(t):
        return (
            t["reference_messages"] >= 5
            and t["nodes"]["gateway"]["master_mode"] == "current_master"
            and any(n["sync_mode"] == "in_schedule" for name, n in t["nodes"].items() if name != "gateway")
        )

    t = rerun_until(run, timely)
    assert t["nodes"]["gateway"]["master_mode"] == "current_master"
    assert sum(m["frames"] for m in t["messages"]) > 0
    assert any(n["sync_mode"] == "in_schedule" for name, n in t["nodes"].items() if name != "gateway")
