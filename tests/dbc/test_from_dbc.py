"""`canstack scenario from-dbc`: a real network description becomes a scenario that the pipeline
reads and `canstack experiment` runs; checked against cantools' reading of the same DBC."""

from __future__ import annotations

import os
import sys
from pathlib import Path

import cantools
import pytest

import stack.cli as cli
from dbc import load_database
from dbc.errors import DbcError
from dbc.scenario import scenario_from_dbc
from profiles.pipeline.scenario import load_scenario

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10
    import tomli as tomllib

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
SHARED = Path(os.environ.get("CANSTACK_SHARED") or Path(__file__).resolve().parents[3] / "shared")
CORPUS = sorted((SHARED / "corpus" / "dbc").glob("*/*.dbc")) if (SHARED / "corpus" / "dbc").is_dir() else []
FORD = SHARED / "corpus" / "dbc" / "opendbc" / "ford_lincoln_base_pt.dbc"
FD_ECUS = Path(__file__).resolve().parent / "data" / "fd_ecus.dbc"

# ISO 11898-1:2015, table 5: the data lengths a CAN FD DLC codes
ISO_FD_LENGTHS = [0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64]


def run(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    out, err = capsys.readouterr()
    return code, out, err


# Vector's interaction-layer send types that carry no period of their own (with or without the
# WithDelay / WithRepetition suffixes), and those that send at the fast cycle while active
SPONTANEOUS = ("spontaneous", "onwrite", "event", "onchange")
IF_ACTIVE = ("cyclicifactive", "ifactive", "enabledperiodic")


def _expected(db, default_cycle=None):
    """name -> (id, extended, data bytes, period ms) from cantools' own reading: ``cycle_time``
    (GenMsgCycleTime), ``send_type`` (GenMsgSendType) and GenMsgCycleTimeFast; a CAN FD message
    with its length padded to the next CAN FD length."""
    out = {}
    for m in db.messages:
        if m.length > (64 if m.is_fd else 8) or m.is_container:
            continue
        st = (m.send_type or "").lower().replace("withdelay", "").replace("withrepetition", "")
        period = m.cycle_time or None
        if st in IF_ACTIVE or st == "cyclicifactiveandspontaneous":
            fast = m.dbc.attributes.get("GenMsgCycleTimeFast") if m.dbc else None
            period = (fast.value if fast is not None and fast.value else None) or period
        elif st in SPONTANEOUS:
            period = None
        elif period is None and default_cycle is not None and not st.startswith(("cyclic", "eventperiodic")):
            period = default_cycle  # neither a known send type nor a cycle time
        if period:
            length = min(n for n in ISO_FD_LENGTHS if n >= m.length) if m.is_fd else m.length
            out[m.name] = (m.frame_id, bool(m.is_extended_frame), length, float(period))
    return out


def _read(path: Path):
    sc = load_scenario(path)
    return {
        msg.name: (
            msg.can_id,
            msg.extended,
            ISO_FD_LENGTHS[msg.dlc] if getattr(msg, "fd", False) else msg.dlc,
            msg.period_ns / 1e6,
            node.name,
            msg.deadline_ns / 1e6,
        )
        for node in sc.nodes
        for msg in node.messages
    }


def test_sample_network_becomes_a_scenario_the_experiment_runs(capsys, tmp_path):
    out_file = tmp_path / "pb.toml"
    code, out, err = run(capsys, "scenario", "from-dbc", SAMPLE, "--out", out_file)
    assert code == 0, err
    assert "6 nodes, 8 messages" in out
    db = cantools.database.load_file(str(SAMPLE))
    got = _read(out_file)
    want = _expected(db)
    assert {k: v[:4] for k, v in got.items()} == want
    for name, (_, _, _, period, node, deadline) in got.items():
        assert node == db.get_message_by_name(name).senders[0]
        assert deadline == period  # no CanstackDeadline in the sample
    # left out, each with its reason, on stderr and in the file
    assert "DoorStatus: left out" in err and "ClusterDiagResponse: left out: sent on request only" in err
    assert "# ClusterDiagResponse: left out" in out_file.read_text()
    # GenMsgStartDelayTime 5 ms becomes the offset
    assert load_scenario(out_file).nodes[1].messages[0].offset_ns == 5_000_000
    code, out, err = run(capsys, "experiment", out_file)
    assert code == 0, err
    assert "EngineData" in out and "RTA" in out


def test_deadline_attribute_bitrate_and_senders(capsys, tmp_path):
    dbc = tmp_path / "net.dbc"
    dbc.write_text(
        'VERSION ""\nBS_:\nBU_: A B C\n'
        'BO_ 100 M1: 8 A\n SG_ X : 0|8@1+ (1,0) [0|255] "" B\n'
        'BO_ 2147484160 M2: 3 B\n SG_ Y : 0|8@1+ (1,0) [0|255] "" A\n'
        'BO_ 300 M3: 2 Vector__XXX\n SG_ Z : 0|8@1+ (1,0) [0|255] "" A\n'
        "BO_TX_BU_ 100 : C,A;\n"
        'BA_DEF_ BO_ "GenMsgCycleTime" INT 0 65535;\nBA_DEF_ BO_ "CanstackDeadline" INT 0 65535;\n'
        'BA_DEF_ "Baudrate" INT 1000 1000000;\n'
        'BA_DEF_DEF_ "GenMsgCycleTime" 0;\nBA_DEF_DEF_ "CanstackDeadline" 0;\nBA_DEF_DEF_ "Baudrate" 500000;\n'
        'BA_ "Baudrate" 250000;\n'
        'BA_ "GenMsgCycleTime" BO_ 100 10;\nBA_ "CanstackDeadline" BO_ 100 4;\n'
        'BA_ "GenMsgCycleTime" BO_ 2147484160 20;\n'
    )
    out_file = tmp_path / "net.toml"
    code, out, err = run(capsys, "scenario", "from-dbc", dbc, "--out", out_file)
    assert code == 0, err
    sc = load_scenario(out_file)
    assert sc.bitrate == 250_000  # the DBC's Baudrate
    got = _read(out_file)
    assert got["M1"] == (100, False, 8, 10.0, "A", 4.0)  # the first of its senders; CanstackDeadline
    assert got["M2"] == (0x200, True, 3, 20.0, "B", 20.0)
    assert "M3" not in got and "M1: sent by A, C: given to A" in err
    code, out, err = run(
        capsys, "scenario", "from-dbc", dbc, "--out", out_file, "--bitrate", "125000", "--default-cycle", "50"
    )
    assert code == 0, err
    assert load_scenario(out_file).bitrate == 125_000
    assert _read(out_file)["M3"][3:5] == (50.0, "Vector__XXX")


@pytest.mark.parametrize(
    "argv, fragment",
    [
        (["--bitrate", "7"], "1000..1000000"),
        (["--duration", "0"], "--duration"),
        (["--default-cycle", "-5"], "--default-cycle"),
    ],
)
def test_bad_options_one_line_exit_2(capsys, tmp_path, argv, fragment):
    code, out, err = run(capsys, "scenario", "from-dbc", SAMPLE, "--out", tmp_path / "x.toml", *argv)
    assert code == 2 and fragment in err and len(err.strip().splitlines()) == 1, err


def test_nothing_periodic_offers_default_cycle(capsys, tmp_path):
    dbc = tmp_path / "quiet.dbc"
    dbc.write_text('VERSION ""\nBS_:\nBU_: A B\nBO_ 100 M: 1 A\n SG_ X : 0|8@1+ (1,0) [0|255] "" B\n')
    code, out, err = run(capsys, "scenario", "from-dbc", dbc)
    assert code == 2 and "quiet.dbc" in err and "--default-cycle" in err and len(err.strip().splitlines()) == 1


@pytest.mark.skipif(not CORPUS, reason="../shared/corpus/dbc is absent")
def test_every_corpus_database_gives_a_scenario_the_pipeline_reads(capsys, tmp_path, corpus_databases, read_once):
    """Each corpus DBC either becomes a scenario whose messages are cantools' (identifier, length,
    period) or is refused in one line; the two largest run as experiments."""
    assert list(corpus_databases) == CORPUS
    written = []
    for path in CORPUS:
        out_file = tmp_path / f"{path.parent.name}-{path.stem}.toml"
        code, out, err = run(capsys, "scenario", "from-dbc", path, "--out", out_file, "--default-cycle", "100")
        if code == 2:
            assert len(err.strip().splitlines()) == 1 and str(path) in err, err
            continue
        assert code == 0, err
        got = _read(out_file)
        # cantools' own reading of the file (the Database its parser made, nothing of canstack's)
        assert {k: v[:4] for k, v in got.items()} == _expected(corpus_databases[path], 100), path
        written.append((len(got), out_file))
    assert len(written) >= 40
    for _, out_file in sorted(written, key=lambda w: -w[0])[:2]:  # the two largest networks
        text = out_file.read_text().replace("duration = 1\n", "duration = 0.1\n")
        out_file.write_text(text)
        code, out, err = run(capsys, "experiment", out_file)
        assert code in (0, 1), err  # 1: the analysis finds a message unschedulable
        assert "RTA" in out


def _toml_messages(text: str) -> dict:
    raw = tomllib.loads(text)
    return raw, {m["name"]: m for n in raw["nodes"] for m in n["messages"]}


@pytest.mark.parametrize("data_bitrate", [None, 5_000_000])
def test_fd_messages_are_written_with_fd_brs_and_length(data_bitrate):
    """Each CAN FD message of the DBC (cantools' is_fd) is an FD message of the scenario: fd, brs
    as its CANFD_BRS attribute says, its length in bytes padded as ISO's DLC table; classical
    messages keep dlc; the bus gets the data bit rate (default 2 Mbit/s, with a note)."""
    sc = scenario_from_dbc(load_database(FD_ECUS), "fd_ecus.dbc", data_bitrate=data_bitrate)
    raw, msgs = _toml_messages(sc.text)
    assert raw["bus"]["data_bitrate"] == (data_bitrate or 2_000_000)
    assert any("CAN FD bus with a data phase at 2000000 bit/s" in n for n in sc.notes) == (data_bitrate is None)
    db = cantools.database.load_file(str(FD_ECUS))
    assert set(msgs) == {m.name for m in db.messages}
    for m in db.messages:
        w = msgs[m.name]
        assert w["id"] == m.frame_id and w.get("extended", False) == m.is_extended_frame
        if m.is_fd:
            brs_attr = m.dbc.attributes.get("CANFD_BRS")
            assert w["fd"] is True and "dlc" not in w
            assert w["brs"] is (brs_attr is None or str(brs_attr.value) == "1")
            assert w["length"] == min(n for n in ISO_FD_LENGTHS if n >= m.length)
        else:
            assert "fd" not in w and "length" not in w and w["dlc"] == m.length
        assert w["period_ms"] == m.cycle_time
    assert msgs["CameraStatus"]["brs"] is False and msgs["CameraStatus"]["length"] == 12


def test_classical_database_has_no_data_bitrate_unless_asked():
    raw, _ = _toml_messages(scenario_from_dbc(load_database(SAMPLE), "pb.dbc").text)
    assert "data_bitrate" not in raw["bus"]
    with pytest.raises(DbcError, match="data bit rate 250000 is below the bit rate 500000"):
        scenario_from_dbc(load_database(FD_ECUS), "fd_ecus.dbc", data_bitrate=250_000)


@pytest.mark.skipif(not FORD.is_file(), reason="../shared/corpus not present")
def test_ford_fd_database_gives_every_cyclic_message(corpus_databases):
    db = corpus_databases[FORD]  # cantools' reading of the file (strict, as cantools loads by default)
    sc = scenario_from_dbc(db, "ford.dbc", data_bitrate=4_000_000)
    raw, msgs = _toml_messages(sc.text)
    assert raw["bus"] == {"bitrate": 500_000, "data_bitrate": 4_000_000, "duration": 1, "seed": 0}
    want = _expected(db)
    assert {k: (w["id"], w.get("extended", False), w["length"], float(w["period_ms"])) for k, w in msgs.items()} == want
    assert all(w["fd"] is True and w["brs"] is True for w in msgs.values())  # no CANFD_BRS: on


@pytest.mark.skipif(not FORD.is_file(), reason="../shared/corpus not present")
def test_ford_scenario_runs_as_an_experiment(capsys, tmp_path, read_once):
    """End to end: the opendbc Ford DBC (all CAN FD) through from-dbc into canstack experiment,
    the simulation and the response-time analysis on a 500 k / 2 M CAN FD bus."""
    out_file = tmp_path / "ford.toml"
    code, out, err = run(capsys, "scenario", "from-dbc", FORD, "--data-bitrate", "2000000", "--out", out_file)
    assert code == 0, err
    out_file.write_text(out_file.read_text().replace("duration = 1\n", "duration = 0.2\n"))
    code, out, err = run(capsys, "experiment", out_file)
    assert code in (0, 1), err  # 1: the analysis finds a message unschedulable
    assert "RTA" in out and "data 2 Mbit/s" in out
