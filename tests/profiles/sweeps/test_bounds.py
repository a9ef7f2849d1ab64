"""`canstack study bounds`: the analysis' bounds against the simulated bus on random networks.

A small campaign finds no measured time above its bound (the analysis' claim) and reports the
three methods; its figures are the max, median and 10th percentile of the per-message rows it
writes (recomputed here with `statistics.quantiles`); the same seed gives the same report; a
bound one bit below what the simulation reaches — the analysis broken on purpose on the issue's
hand-worked network — is reported as a defect, loudly, with exit status 3; bad arguments are one
line and exit status 2. With ``--fd`` the same holds on CAN FD and mixed networks, whose frames
follow ISO 11898-1:2015 (the FD lengths, BRS only in FD frames, FD frames only from FD-enabled
controllers), and an error frame on such a bus (a classical controller destroying FD frames)
fails the network rather than pass for a measurement.
"""

from __future__ import annotations

import csv
import dataclasses
import importlib.util
import json
import re
import statistics

import pytest

import profiles.sweeps.bounds as bounds
from profiles.sweeps.bounds import bounds_study, measure, summarise
from profiles.sweeps.networks import MS, NetMsg, NetNode, Network
from profiles.sweeps.releases import ModelAssumptionError
from stack.cli import main

TAU = 2_000  # ns, one bit at 500 kbit/s
#: the data lengths a CAN FD frame can have (ISO 11898-1:2015, Table 5: DLC 0..15)
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)


def run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["study", "bounds", *args])
    out, err = capsys.readouterr()
    return code, out, err


def issue_network() -> Network:
    """The issue's example: one message, 500 kbit/s, T = D = 1 ms, J = 0.9 ms, 8 zero bytes (its
    exact length given to the analysis)."""
    return Network(
        500_000, [NetNode("a")], [NetMsg("m", "a", 0x100, False, bytes(8), 1 * MS, 900_000, 1 * MS)], exact=True
    )


def broken(monkeypatch, schedulable: bool | None = None, **less: float) -> None:
    """Make the study's analysis return each figure in ``less`` that much smaller (ns), and
    ``schedulable`` as given."""
    real = bounds.analyse

    def analyse(*a, **k):
        out = real(*a, **k)
        fixed = {} if schedulable is None else {"schedulable": schedulable}
        return {
            n: dataclasses.replace(
                r, **{f: getattr(r, f) - d for f, d in less.items() if getattr(r, f) is not None}, **fixed
            )
            for n, r in out.items()
        }

    monkeypatch.setattr(bounds, "analyse", analyse)


def test_a_small_campaign_exceeds_no_bound_and_reports_every_method(tmp_path, capsys):
    out = tmp_path / "messages.csv"
    code, stdout, err = run(capsys, "--networks", "10", "--seed", "3", "--json", "--out", str(out))
    assert code == 0, err
    data = json.loads(stdout)
    assert set(data) >= {"study", "settings", "messages", "methods", "defects", "networks", "done", "failed"}
    assert data["networks"] == data["done"] == 10 and data["failed"] == 0 and data["defects"] == []
    assert list(data["methods"]) == ["davis2007", "fifo", "mailbox", "all"]
    for method, f in data["methods"].items():
        assert f["messages"] > 0, method
        assert f["exceeded"] == 0 and f["unpredicted_misses"] == 0, (method, f)
        assert set(f["queuing"]) == set(f["nominal"]) == {"max", "median", "p10"}
        assert 0 < f["queuing"]["p10"] <= f["queuing"]["median"] <= f["queuing"]["max"] <= 1
    # the figures are those of the rows written, recomputed with the standard library
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == data["messages"] == data["methods"]["all"]["messages"]
    for method in ("davis2007", "fifo", "mailbox"):
        mine = [r for r in rows if r["method"] == method]
        assert len(mine) == data["methods"][method]["messages"]
        for col, key in (("queued_ratio", "queuing"), ("nominal_ratio", "nominal")):
            v = [float(r[col]) for r in mine if r[col]]
            got = data["methods"][method][key]
            assert got["max"] == pytest.approx(max(v)) and got["median"] == pytest.approx(statistics.median(v))
            assert got["p10"] == pytest.approx(statistics.quantiles(v, n=10, method="inclusive")[0])
        for r in mine:  # a row's ratio is its worst measured time over its bound
            if r["bound_ns"]:
                assert float(r["queued_ns"]) <= float(r["bound_ns"])
                assert float(r["queued_ratio"]) == pytest.approx(float(r["queued_ns"]) / float(r["bound_ns"]))


def test_the_table_names_the_three_methods_and_no_exceedance(capsys):
    code, stdout, err = run(capsys, "--networks", "4", "--patterns", "critical,random")
    assert code == 0, err
    lines = stdout.splitlines()
    assert lines[0].startswith("4 networks, ") and "releases critical, random" in lines[1]
    table = {ln.split()[0]: ln.split() for ln in lines[4:8]}
    assert list(table) == ["davis2007", "fifo", "mailbox", "all"]
    assert all(row[3] == "0" for row in table.values())  # the exceeded column
    assert "4 networks; sequential" in err


def test_the_same_seed_gives_the_same_report_and_network_i_is_the_same_whatever_n(capsys):
    code, first, _ = run(capsys, "--networks", "3", "--seed", "9", "--json")
    code2, second, _ = run(capsys, "--networks", "3", "--seed", "9", "--json")
    assert code == code2 == 0 and first == second
    _, other, _ = run(capsys, "--networks", "3", "--seed", "10", "--json")
    assert json.loads(other)["methods"] != json.loads(first)["methods"]
    three = bounds_study(3, seed=9, patterns=("random",))
    five = bounds_study(5, seed=9, patterns=("random",))
    assert five.rows[:3] == three.rows


@pytest.mark.subprocess
def test_a_process_pool_gives_the_same_report():
    one = bounds.bounds_json(bounds_study(4, seed=2, patterns=("critical", "extremes")))
    two = bounds.bounds_json(bounds_study(4, seed=2, patterns=("critical", "extremes"), workers=2))
    assert one.pop("engine") == "sequential" and two.pop("engine") == "processes"
    assert one == two


def test_the_issue_network_reaches_its_bound_up_to_the_intermission():
    # hand-worked (tests/profiles/test_rta_sim.py): C = 135 bits with the intermission; instance
    # 0 queued 0.9 ms late, instance 1 on time waits for it: bound = 2 C - 0.1 ms, and the
    # simulation reaches it but for the second frame's 3-bit intermission
    net = issue_network()
    c = (net.messages[0].frame.wire_bits + 3) * TAU
    rows, defects = measure(net, ("critical",), 1)
    assert defects == []
    assert rows[0]["bound_ns"] == 2 * c - 100_000
    assert rows[0]["queued_ns"] == 2 * c - 100_000 - 3 * TAU and rows[0]["queued_pattern"] == "critical"


def test_a_bound_one_bit_below_what_the_simulation_reaches_is_a_defect(monkeypatch):
    net = issue_network()
    broken(monkeypatch, bound_ns=3 * TAU)  # the bound is now exactly what the simulation reaches
    assert measure(net, ("critical",), 1)[1] == []
    broken(monkeypatch, bound_ns=TAU)  # on top: one bit less
    rows, defects = measure(net, ("critical",), 1, network=7)
    assert len(defects) == 1
    d = defects[0]
    assert (d["network"], d["message"], d["method"], d["what"], d["pattern"]) == (
        7,
        "m",
        "davis2007",
        "queuing",
        "critical",
    )
    assert d["measured"] - d["bound"] == TAU
    assert "node a: priority queue" in d["description"] and "T 1000000 ns, J 900000 ns" in d["description"]
    assert summarise(rows)["davis2007"]["exceeded"] == 1


def test_a_response_time_too_small_and_an_unpredicted_miss_are_defects(monkeypatch):
    net = issue_network()
    rows, _ = measure(net, ("critical",), 1)
    assert rows[0]["misses"] > 0 and not rows[0]["schedulable"]  # R = J + ... > D: predicted
    broken(monkeypatch, response_ns=1_000_000, schedulable=True)  # R well below the measured time, <= D
    _, defects = measure(net, ("critical",), 1)
    assert [d["what"] for d in defects] == ["nominal", "miss"]


def test_a_broken_analysis_fails_the_command_loudly(monkeypatch, capsys):
    broken(monkeypatch, bound_ns=100 * TAU)
    code, stdout, err = run(capsys, "--networks", "2", "--patterns", "critical")
    assert code == 3
    exceeded = [int(ln.split()[3]) for ln in stdout.splitlines()[4:8]]
    assert exceeded[-1] > 0
    assert "DEFECT" in err and "a bound the simulated bus exceeds is a defect" in err
    assert re.search(r"^network \d+: message m\d+ \(\w+\): from queuing to the end of EOF \d+ ns > bound_ns", err, re.M)
    assert re.search(r"^network \d+ \(seed \d+\): \d+ bit/s", err, re.M) and "\n  node n0: " in err


@pytest.mark.skipif(importlib.util.find_spec("matplotlib") is None, reason="needs the plot extra")
def test_plot_file(tmp_path, capsys):
    path = tmp_path / "bounds.png"
    code, _, err = run(capsys, "--networks", "3", "--patterns", "critical", "--plot", str(path))
    assert code == 0, err
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and f"plot: {path}" in err


@pytest.mark.parametrize(
    "args,message",
    [
        (["--networks", "0"], "at least 1"),
        (["--networks", "many"], "'many'"),
        (["--utilisation", "2"], "a utilisation is from 0.01 to 1.5"),
        (["--utilisation", "half"], "is not a utilisation"),
        (["--nodes", "33"], "nodes a network is at most 32"),
        (["--per-node", "0"], "at least 1"),
        (["--queues", "lifo"], "'lifo': a queue kind is one of priority, fifo, mailbox"),
        (["--queues", "fifo=0"], "the weight of fifo is from 1 to 1000"),
        (["--queues", "fifo,fifo"], "fifo is given twice"),
        (["--patterns", "burst"], "'burst': a release pattern is one of random, critical, alternate, extremes"),
        (["--seed", "x"], "'x' is not an integer"),
        (["--plot", "b.txt"], "unknown image suffix '.txt'"),
        (["--out", "m.json"], "write .csv or .parquet"),
        (["--engine", "sequential", "--workers", "2"], "--engine sequential runs in this process"),
        (["--fd", "hybrid"], "argument --fd: invalid choice: 'hybrid' (choose from 'mixed', 'all')"),
        (["--fd", "all", "--networks", "0"], "at least 1"),
    ],
)
def test_bad_arguments_are_one_line_and_exit_2(capsys, args, message):
    code, stdout, err = run(capsys, *args)
    assert code == 2 and stdout == ""
    assert len(err.strip().splitlines()) == 1 and message in err, err


def table_rows(stdout: str) -> dict[str, list[str]]:
    """The method rows of the text table, by method."""
    lines = stdout.splitlines()
    start = next(i for i, ln in enumerate(lines) if ln.startswith("method ")) + 1
    return {ln.split()[0]: ln.split() for ln in lines[start : start + 4]}


def test_fd_networks_exceed_no_bound_and_carry_fd_frames_with_and_without_brs(tmp_path, capsys):
    out = tmp_path / "messages.csv"
    code, stdout, err = run(capsys, "--fd", "--networks", "8", "--seed", "4", "--out", str(out))
    assert code == 0, err
    table = table_rows(stdout)
    assert list(table) == ["davis2007", "fifo", "mailbox", "all"]
    assert all(row[3] == "0" for row in table.values())  # the exceeded column
    assert "DEFECT" not in err and "failed" not in err
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    fd = [r for r in rows if r["fd"] == "True"]
    brs = [r for r in fd if r["brs"] == "True"]
    classical = [r for r in rows if r["fd"] == "False"]
    # FD frames with and without BRS, classical frames, and classical frames from tolerant nodes
    assert brs and len(brs) < len(fd) and classical
    assert any(r["controller"] == "tolerant" for r in classical)
    for r in rows:  # the standard's rules on what each message sends
        if r["fd"] == "True":
            assert int(r["bytes"]) in FD_LENGTHS and r["controller"] == "fd", r
        else:
            assert 0 <= int(r["bytes"]) <= 8 and r["brs"] == "False", r
        if r["bound_ns"]:
            assert float(r["queued_ns"]) <= float(r["bound_ns"]) and float(r["nominal_ns"]) <= float(r["response_ns"])
    # the table says what the networks carried
    line = stdout.splitlines()[1]
    assert line.startswith(
        f"CAN FD, mixed: data phase 1..8 times the nominal bit rate; {len(fd)} FD frames ({len(brs)} with BRS), "
        f"{len(classical)} classical; "
    )
    assert int(line.split("; ")[-1].split()[0]) >= 1 and line.endswith(" tolerant nodes")


def test_fd_all_sends_every_message_as_an_fd_frame(tmp_path, capsys):
    out = tmp_path / "messages.csv"
    code, stdout, err = run(capsys, "--fd", "all", "--networks", "3", "--patterns", "critical", "--out", str(out))
    assert code == 0, err
    with open(out, newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert rows and all(r["fd"] == "True" and r["controller"] == "fd" for r in rows)
    assert "CAN FD, all: " in stdout and "0 classical; 0 tolerant nodes" in stdout


def test_fd_studies_are_deterministic_and_differ_from_classical_ones(capsys):
    code, first, _ = run(capsys, "--fd", "--networks", "3", "--seed", "9", "--json", "--patterns", "random,critical")
    code2, second, _ = run(capsys, "--fd", "--networks", "3", "--seed", "9", "--json", "--patterns", "random,critical")
    assert code == code2 == 0 and first == second
    data = json.loads(first)
    assert data["settings"]["fd"] == "mixed" and data["defects"] == [] and data["methods"]["all"]["exceeded"] == 0
    frames = data["frames"]
    assert frames["fd"] > 0 and frames["fd"] + frames["classical"] == data["messages"]
    _, classical, _ = run(capsys, "--networks", "3", "--seed", "9", "--json", "--patterns", "random,critical")
    assert json.loads(classical)["frames"] == {
        "classical": json.loads(classical)["messages"],
        "fd": 0,
        "brs": 0,
        "tolerant_nodes": 0,
    }
    three = bounds_study(3, seed=9, patterns=("random",), fd="all")
    four = bounds_study(4, seed=9, patterns=("random",), fd="all")
    assert four.rows[:3] == three.rows
    assert all(r["data_bitrate"] in {r["bitrate"] * k for k in (1, 2, 4, 5, 8)} for r in four.rows)


def fd_issue_network() -> Network:
    """The issue's example as a CAN FD frame: 64 zero bytes with BRS at 500 kbit/s / 2 Mbit/s."""
    m = NetMsg("m", "a", 0x100, False, bytes(64), 1 * MS, 900_000, 1 * MS, fd=True, brs=True)
    return Network(500_000, [NetNode("a", fd="fd")], [m], exact=True, data_bitrate=2_000_000)


def test_an_fd_frame_reaches_its_bound_up_to_the_intermission():
    # as the classical case: bound = 2 C - 0.1 ms, C the frame at both rates with its 3-bit
    # intermission (nominal bits); the simulation reaches it but for that intermission
    net = fd_issue_network()
    f = net.messages[0].frame
    c = f.bits.duration_ns(500_000, 2_000_000) + 3 * TAU
    assert f.bits.data_bits > 0 and c < (f.bits.length + 3) * TAU  # the data phase is faster
    rows, defects = measure(net, ("critical",), 1)
    assert defects == []
    assert rows[0]["bound_ns"] == 2 * c - 100_000
    assert rows[0]["queued_ns"] == 2 * c - 100_000 - 3 * TAU


def test_an_fd_defect_report_names_each_message_format(monkeypatch, capsys):
    broken(monkeypatch, bound_ns=10 * MS)  # every bound below what is measured
    code, _, err = run(capsys, "--fd", "--networks", "2", "--patterns", "critical")
    assert code == 3 and "DEFECT" in err
    assert re.search(r"^network \d+ \(seed \d+\): \d+ bit/s, CAN FD data phase \d+ bit/s, ", err, re.M)
    assert re.search(r"^  node n\d+: .*, (fd|tolerant) controller", err, re.M)
    kinds = set(
        re.findall(r"^    m\d+: id 0x[0-9A-F]+(?: \(29-bit\))?, (classical|FD|FD with BRS) \(\d+ bytes\), ", err, re.M)
    )
    assert kinds >= {"FD", "FD with BRS"}, kinds


def test_an_error_frame_without_an_error_model_fails_the_network():
    # a CAN 2.0 controller ("classic") on an FD bus destroys every FD frame with an error frame
    # (ISO 11898-1:2015, 10.4.2.3's protocol exception is what a tolerant one has instead): the
    # run is no measurement of an error-free bus
    net = fd_issue_network()
    net.nodes.append(NetNode("legacy", fd="classic"))
    with pytest.raises(ModelAssumptionError, match=r"error frames in pattern random .* without an error model"):
        measure(net, ("random",), 1)
    net.nodes[-1].fd = "tolerant"
    assert measure(net, ("random",), 1)[1] == []
