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
def test_wallclock_example_runs_on_the_virtual_bus():
    pytest.importorskip("can")
    sc = load_scenario(ROOT / "examples" / "tdma_wallclock.toml")
    res = run_on_pycan(sc, "virtual", "tdma-test", duration_s=0.4)
    data = res.to_json()
    t = data["tdma"]
    assert data["driver"] == "virtual tdma-test"
    # 0.4 s of 25 ms cycles: the first reference at 25 ms + 127 NTU, about 15 then
    assert t["reference_messages"] >= 5
    assert t["references_by_master"]["gateway"] == t["reference_messages"]
    assert t["nodes"]["gateway"]["master_mode"] == "current_master"
    assert sum(m["frames"] for m in t["messages"]) > 0
    assert any(n["sync_mode"] == "in_schedule" for name, n in t["nodes"].items() if name != "gateway")
