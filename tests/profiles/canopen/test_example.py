"""The example network (examples/canopen_network.py) and the CANopen docs page: the figures the
page quotes are the example's output, and every test the comparison table names exists."""

import importlib.util
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
SECTION = (ROOT / "docs" / "pages" / "experiments" / "canopen.md").read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def example():
    spec = importlib.util.spec_from_file_location("canopen_network", ROOT / "examples" / "canopen_network.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def result(example):
    return example.run(2.0)


def test_the_readme_quotes_the_examples_output(example, result):
    quoted = [ln for ln in SECTION.splitlines() if re.match(r"(bus load|node \d|  PDO|0x[0-9A-F]{3})", ln)]
    assert quoted == example.report(result).splitlines()


def test_the_network_behaves_as_the_example_says(result):
    m = result["master"]
    states = {n["node_id"]: n["nmt_state"] for n in m["nodes"]}
    assert states == {1: "OPERATIONAL", 2: "OPERATIONAL", 3: "UNKNOWN", 4: "OPERATIONAL", 5: "OPERATIONAL"}
    node3 = m["nodes"][2]
    assert node3["heartbeat_timeouts"] == 1 and node3["heartbeats_missed"] == 20  # 1.5 s / 75 ms
    assert all(n["heartbeats_missed"] == 0 for n in m["nodes"] if n["node_id"] != 3)
    for d in result["devices"]:
        for t in d["tpdos"]:
            assert t["queued"] == t["sent"] + t["not_in_window"]  # dropped in the window, nothing else lost
    types = {(p["node_id"], p["pdo"]): p["transmission_type"] for p in m["pdos"]}
    assert [types[(k, "TPDO3")] for k in range(1, 6)] == [2, 3, 4, 0, 5]


def test_every_test_the_comparison_table_names_exists():
    names = re.findall(r"`((?:test_\w+\.py)?)(?:::)?(test_\w+?)(?:\.\.\.)?`", SECTION)
    files = {p.name: p.read_text() for p in Path(__file__).parent.glob("test_*.py")}
    current = None
    checked = 0
    for file, name in names:
        current = file or current
        if not name.startswith("test_") or name.endswith(".py"):
            continue
        assert current in files, current
        assert re.search(rf"^def {re.escape(name.rstrip('_'))}", files[current], re.M), f"{current}::{name}"
        checked += 1
    assert checked >= 15


def test_the_plot_is_optional(example, result, tmp_path):
    pytest.importorskip("matplotlib")
    out = tmp_path / "latency.png"
    example.plot(result, str(out))
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
