"""CAN FD in scenario files: ``[bus] data_bitrate``, a message's ``fd``, ``brs``, ``dlc`` or
``length``, a node's ``fd``; one line per broken rule naming the file, the table, the key and the
rule. The lengths are ISO 11898-1:2015's DLC table, written out here (not read from the code)."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from profiles.pipeline.scenario import parse_scenario
from profiles.schema import ScenarioError

# ISO 11898-1:2015, table of the DLC: CAN FD data lengths of the DLC codes 9..15
ISO_FD_LENGTH = {9: 12, 10: 16, 11: 20, 12: 24, 13: 32, 14: 48, 15: 64}

BASE = {
    "bus": {"bitrate": 500000, "data_bitrate": 2000000, "duration": 0.05, "seed": 1},
    "nodes": [
        {
            "name": "gateway",
            "messages": [
                {"name": "Big", "id": 0x100, "fd": True, "brs": True, "length": 64, "period_ms": 5},
                {"name": "Mid", "id": 0x180, "fd": True, "dlc": 10, "period_ms": 10},
                {"name": "Plain", "id": 0x200, "dlc": 8, "period_ms": 10},
            ],
        },
        {"name": "legacy", "fd": "tolerant"},
    ],
}


def _with(path: str, value, base=BASE):
    raw = copy.deepcopy(base)
    cur = raw
    parts = path.split(".")
    for p in parts[:-1]:
        cur = cur[int(p)] if p.isdigit() else cur[p]
    last = parts[-1]
    if value is _DELETE:
        del cur[int(last) if last.isdigit() else last]
    else:
        cur[int(last) if last.isdigit() else last] = value
    return raw


_DELETE = object()


def test_fd_keys_read_into_declarations():
    sc = parse_scenario(BASE, "fd.toml")
    assert sc.data_bitrate == 2_000_000
    big, mid, plain = sc.nodes[0].messages
    assert (big.fd, big.brs, big.dlc, big.length) == (True, True, 15, 64)
    assert (mid.fd, mid.brs, mid.dlc, mid.length) == (True, False, 10, ISO_FD_LENGTH[10])
    assert (plain.fd, plain.brs, plain.dlc, plain.length) == (False, False, 8, 8)
    assert sc.nodes[0].fd is None and sc.nodes[1].fd == "tolerant"


@pytest.mark.parametrize("dlc,length", sorted(ISO_FD_LENGTH.items()) + [(n, n) for n in range(9)])
def test_dlc_and_length_agree_with_the_iso_table(dlc, length):
    by_dlc = parse_scenario(_with("nodes.0.messages.1.dlc", dlc), "fd.toml").nodes[0].messages[1]
    raw = _with("nodes.0.messages.1.dlc", _DELETE)
    by_len = parse_scenario(_with("nodes.0.messages.1.length", length, raw), "fd.toml").nodes[0].messages[1]
    assert (by_dlc.dlc, by_dlc.length) == (by_len.dlc, by_len.length) == (dlc, length)


def _classical_bus():
    raw = _with("bus.data_bitrate", _DELETE)
    raw["nodes"][0]["messages"] = [raw["nodes"][0]["messages"][2]]
    return raw


@pytest.mark.parametrize(
    "path,value,expected",
    [
        ("bus.data_bitrate", 250000, "fd.toml: [bus]: data_bitrate: 250000 is below the bitrate 500000"),
        ("bus.data_bitrate", 20_000_000, "fd.toml: [bus]: data_bitrate: 20000000 is outside 1000..16000000"),
        ("bus.data_bitrate", 2.5e6, "fd.toml: [bus]: data_bitrate: 2500000.0 is a number, expected an integer"),
        ("bus.data_bitrate", True, "fd.toml: [bus]: data_bitrate: True is a boolean, expected an integer"),
        (
            "nodes.0.messages.0.length",
            13,
            "[[nodes.messages]] #1 'Big': length: 13 is not a CAN FD data length: one of 0..8, 12, 16, 20, 24, 32, "
            "48, 64",
        ),
        ("nodes.0.messages.0.length", 65, "'Big': length: 65 is outside 0..64"),
        ("nodes.0.messages.0.length", -1, "'Big': length: -1 is outside 0..64"),
        ("nodes.0.messages.1.dlc", 16, "'Mid': dlc: 16 is outside 0..15"),
        ("nodes.0.messages.0.dlc", 15, "'Big': give dlc (the DLC code) or length (data bytes), not both"),
        ("nodes.0.messages.2.dlc", 9, "'Plain': dlc: 9 is outside 0..8 (a CAN 2.0 data frame carries 0..8 bytes"),
        ("nodes.0.messages.2.dlc", _DELETE, "'Plain': key 'dlc' or 'length' is required"),
        ("nodes.0.messages.2.length", 8, "'Plain': give dlc (the DLC code) or length (data bytes), not both"),
        ("nodes.0.messages.2.brs", True, "'Plain': brs: true needs fd = true"),
        ("nodes.0.messages.0.fd", "yes", "'Big': fd: 'yes' is a string, expected true or false"),
        ("nodes.0.messages.0.brs", 1, "'Big': brs: 1 is an integer, expected true or false"),
        ("nodes.0.messages.1.remote", True, "'Mid': remote: true with fd = true: CAN FD has no remote frames"),
        ("nodes.0.messages.1.data", "00" * 15, "'Mid': data: 15 bytes given for dlc 10 (16 bytes)"),
        ("nodes.0.messages.0.data", "00" * 63, "'Big': data: 63 bytes given for length 64"),
        ("nodes.1.fd", "maybe", "[[nodes]] #2 'legacy': fd: 'maybe' is not one of 'fd', 'tolerant', 'classic'"),
        ("nodes.1.fd", True, "[[nodes]] #2 'legacy': fd: True is a boolean, expected a string"),
        ("nodes.0.fd", "classic", "'Big': fd: true: node 'gateway' is 'classic' (fd = 'classic'): only an FD-enabled"),
    ],
)
def test_each_broken_fd_rule_is_one_line_naming_it(path, value, expected):
    with pytest.raises(ScenarioError) as err:
        parse_scenario(_with(path, value), "fd.toml")
    text = str(err.value)
    assert expected in text and "\n" not in text, text
    assert text.startswith("fd.toml: "), text


def test_fd_on_a_bus_without_a_data_bitrate_is_refused_naming_the_key():
    raw = _with("bus.data_bitrate", _DELETE)
    with pytest.raises(ScenarioError, match=r"'Big': brs: true: a CAN FD frame needs a CAN FD bus: give \[bus\] "):
        parse_scenario(raw, "fd.toml")
    raw["nodes"][0]["messages"] = raw["nodes"][0]["messages"][1:]
    with pytest.raises(ScenarioError, match=r"'Mid': fd: true: a CAN FD frame needs a CAN FD bus"):
        parse_scenario(raw, "fd.toml")
    raw = _classical_bus()
    raw["nodes"][1]["fd"] = "fd"
    with pytest.raises(ScenarioError, match=r"\[\[nodes\]\] 'legacy': fd: 'fd': an FD-enabled controller needs"):
        parse_scenario(raw, "fd.toml")
    raw["nodes"][1]["fd"] = "classic"  # a CAN 2.0 controller on a classical bus: what it is by default
    assert parse_scenario(raw, "fd.toml").data_bitrate is None


def test_fd_without_brs_at_the_nominal_rate_is_legal():
    """FDF without BRS: an FD frame at one bit rate (data_bitrate = bitrate)."""
    raw = _with("bus.data_bitrate", 500000)
    raw["nodes"][0]["messages"][0]["brs"] = False
    raw["nodes"].append({"name": "dash"})  # an FD-enabled receiver: no warning
    sc = parse_scenario(raw, "fd.toml")
    assert sc.data_bitrate == sc.bitrate and not sc.warnings


@pytest.mark.parametrize(
    "node,expected",
    [
        ({"name": "m", "profile": "canopen", "fd": True}, "[[nodes]] #3 'm': fd: true: CANopen FD (CiA 1301) is out"),
        (
            {"name": "m", "profile": "canopen-master", "fd": True},
            "[[nodes]] #3 'm': fd: true: CANopen FD (CiA 1301) is out of scope",
        ),
        (
            {"name": "s", "profile": "slave", "messages": [{"name": "X", "id": 0x300, "fd": True, "length": 12}]},
            "[[nodes]] #3 's' > [[nodes.messages]] #1 'X': fd: true: master/slave polling sends classical CAN frames",
        ),
        (
            {"name": "t", "profile": "tdma", "messages": [{"name": "X", "id": 0x300, "fd": True, "length": 12}]},
            "[[nodes]] #3 't' > [[nodes.messages]] #1 'X': fd: true: TDMA nodes send classical CAN frames only",
        ),
    ],
)
def test_profiles_without_fd_refuse_it_with_their_reason(node, expected):
    raw = copy.deepcopy(BASE)
    raw["nodes"].append(node)
    with pytest.raises(ScenarioError) as err:
        parse_scenario(raw, "fd.toml")
    assert expected in str(err.value) and "\n" not in str(err.value), str(err.value)


def test_a_gated_csma_node_refuses_fd_messages():
    raw = copy.deepcopy(BASE)
    raw["tdma"] = {
        "reference_id": 0x010,
        "time_masters": ["tm"],
        "basic_cycle_us": 2000,
        "windows": [
            {"kind": "exclusive", "start_us": 200, "length_us": 400, "messages": ["T"]},
            {"kind": "arbitrating", "start_us": 700, "length_us": 1200},
        ],
    }
    raw["nodes"].append(
        {"name": "tm", "profile": "tdma", "messages": [{"name": "T", "id": 0x050, "dlc": 8}]},
    )
    with pytest.raises(ScenarioError) as err:
        parse_scenario(raw, "fd.toml")
    assert "'Big': fd: true: the TDMA gate fits classical CAN frames" in str(err.value), str(err.value)
    raw["nodes"][0]["tdma_gated"] = False
    assert parse_scenario(raw, "fd.toml").nodes[0].messages[0].fd


def test_cli_data_bitrate_and_set_reach_the_bus(tmp_path, capsys):
    """``--data-bitrate`` and ``--set bus.data_bitrate`` change the scenario as read: a faster data
    phase shortens a BRS frame by the data-phase bits' share (checked on the JSON's bus load)."""
    from stack.cli import main

    path = tmp_path / "fd.toml"
    path.write_text(
        "[bus]\nbitrate = 500000\nduration = 0.05\n\n[[nodes]]\nname = 'gateway'\n\n[[nodes.messages]]\n"
        "name = 'Big'\nid = 0x100\nfd = true\nbrs = true\nlength = 64\nperiod_ms = 5\n\n[[nodes]]\nname = 'rx'\n"
    )
    loads = {}
    for args in (["--data-bitrate", "2000000"], ["--set", "bus.data_bitrate=8000000"]):
        assert main(["experiment", str(path), "--json", *args]) == 0
        data = json.loads(capsys.readouterr().out)
        loads[data["data_bitrate"]] = data["bus_load"]
    assert loads[8_000_000] < loads[2_000_000]


def test_the_run_sends_fd_frames_and_its_bus_load_counts_both_rates():
    """Every frame of the run as declared (FDF, BRS, length), and the bus load from a second
    computation: each frame's bits at the nominal rate up to BRS and after the CRC delimiter,
    at the data rate between (ISO 11898-1:2015; `FrameBits.data_bits` counts the latter), plus
    the 3-bit intermission at the nominal rate, over the run's 50 ms. (Without an FD-enabled
    receiver no one acknowledges the FD frames: the tolerant node integrates meanwhile.)"""
    from profiles.pipeline.runner import run_scenario

    raw = copy.deepcopy(BASE)
    raw["nodes"].append({"name": "dash"})  # FD enabled (the default): it acknowledges FD frames
    res = run_scenario(parse_scenario(raw, "fd.toml"), record=True)
    frames = [r.frame for r in res.trace if r.kind == "frame"]
    by_id = {f.can_id: f for f in frames}
    assert (by_id[0x100].fd, by_id[0x100].brs, len(by_id[0x100].data)) == (True, True, 64)
    assert (by_id[0x180].fd, by_id[0x180].brs, len(by_id[0x180].data)) == (True, False, 16)
    assert (by_id[0x200].fd, len(by_id[0x200].data)) == (False, 8)
    assert len(frames) == 10 + 5 + 5 and res.error_frames == 0
    busy = 0.0
    for f in frames:
        bits = f.bits
        data = bits.data_bits if f.brs else 0
        busy += (len(bits.bits) - data + 3) / 500_000 + data / 2_000_000
    assert res.bus_load == pytest.approx(busy / 0.05, abs=1e-6)
    row = {m["name"]: m for m in res.to_json()["messages"]}["Big"]
    assert (row["fd"], row["brs"], row["dlc"]) == (True, True, 15)
    assert res.to_json()["data_bitrate"] == 2_000_000
    # the legacy node is tolerant: it received the classical frames only
    assert res.nodes["legacy"]["rx_frames"] == 5


def test_sweep_varies_the_data_bitrate(capsys):
    """``sweep --vary bus.data_bitrate=...``: a faster data phase, a lower bus load and a lower
    bound for a BRS frame (its data-phase bits take less time), everything else equal."""
    from stack.cli import main

    example = str(Path(__file__).resolve().parents[3] / "examples" / "fd_packed.toml")
    args = ["sweep", example, "--vary", "bus.data_bitrate=1000000,4000000", "--duration", "0.02", "--workers", "1"]
    assert main([*args, "--json"]) == 0
    data = json.loads(capsys.readouterr().out.splitlines()[0])
    slow, fast = sorted(data["rows"], key=lambda r: r["bus.data_bitrate"])
    assert (slow["bus.data_bitrate"], fast["bus.data_bitrate"]) == (1_000_000, 4_000_000)
    assert fast["bus_load"] < slow["bus_load"] and fast["Adas.rta_ms"] < slow["Adas.rta_ms"]
    assert slow["error_frames"] == fast["error_frames"] == 0


def test_a_classic_node_destroys_fd_frames_and_the_analysis_says_it_does_not_apply():
    """examples/fd_intolerant.toml: a CAN 2.0 node's error flags destroy FD frames (each costs
    the transmitter 8, ISO 11898-1 rule 3) until its receive errors make it error passive; with
    the node tolerant, no error frame and the analysis bounds every message."""
    from profiles.pipeline.runner import run_scenario
    from profiles.pipeline.scenario import load_scenario

    example = Path(__file__).resolve().parents[3] / "examples" / "fd_intolerant.toml"
    classic = run_scenario(load_scenario(example)).to_json()
    assert classic["error_frames"] > 0
    assert classic["nodes"]["gateway"]["retransmissions"] == classic["error_frames"]
    assert classic["nodes"]["legacy"]["rxerr"] >= 127  # error passive at some point: FD frames then pass
    assert classic["analysis"]["applies"] is False
    assert any("fd = 'classic'" in n for n in classic["analysis"]["notes"])
    assert all(m["rta_ms"] is None for m in classic["messages"])
    raw = load_scenario(example).raw
    raw["nodes"][-1]["fd"] = "tolerant"
    tolerant = run_scenario(parse_scenario(raw, str(example))).to_json()
    assert tolerant["error_frames"] == 0 and tolerant["analysis"]["applies"] is True
    assert all(m["response_ms"]["max"] < m["rta_ms"] for m in tolerant["messages"])


def test_assign_ids_orders_fd_messages_by_deadline(tmp_path, capsys):
    """``canstack scenario assign-ids --order dm`` on an FD scenario (BRS frames need the data bit
    rate in the analysis): identifiers handed out again shortest deadline first."""
    from stack.cli import main

    src = tmp_path / "fd.toml"
    src.write_text(
        "[bus]\nbitrate = 500000\ndata_bitrate = 2000000\nduration = 0.05\n\n[[nodes]]\nname = 'a'\n\n"
        "[[nodes.messages]]\nname = 'slow'\nid = 0x100\nfd = true\nbrs = true\nlength = 64\nperiod_ms = 20\n\n"
        "[[nodes.messages]]\nname = 'fast'\nid = 0x200\nfd = true\nbrs = true\nlength = 16\nperiod_ms = 2\n\n"
        "[[nodes]]\nname = 'rx'\n"
    )
    out = tmp_path / "dm.toml"
    assert main(["scenario", "assign-ids", str(src), "--out", str(out), "--order", "dm"]) == 0
    capsys.readouterr()
    from profiles.pipeline.scenario import load_scenario

    ids = {m.name: m.can_id for m in load_scenario(out).messages}
    assert ids["fast"] < ids["slow"]


def test_an_fd_message_nobody_can_acknowledge_is_a_warning():
    """Only FD-enabled nodes acknowledge an FD frame (ISO 11898-1:2015: a tolerant node
    integrates, a listen-only one sends no ACK): BASE's only other node is tolerant."""
    sc = parse_scenario(BASE, "fd.toml")
    assert [w.split(": fd: ")[0] for w in sc.warnings] == [
        "fd.toml: [[nodes]] 'gateway' > [[nodes.messages]] 'Big'",
        "fd.toml: [[nodes]] 'gateway' > [[nodes.messages]] 'Mid'",
    ]
    assert all("no other FD-enabled node acknowledges it" in w for w in sc.warnings)
    raw = copy.deepcopy(BASE)
    raw["nodes"].append({"name": "dash", "listen_only": True})
    assert len(parse_scenario(raw, "fd.toml").warnings) == 2
    raw["nodes"][-1]["listen_only"] = False
    assert parse_scenario(raw, "fd.toml").warnings == []
