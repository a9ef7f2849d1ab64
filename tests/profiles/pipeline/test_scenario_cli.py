"""`canstack scenario assign-ids`: the scenario written back with identifiers in an optimal
priority order, everything else kept; bad input as one line with exit status 2; the
``canstack.scenario`` entry point group extends the command."""

from __future__ import annotations

import sys
from pathlib import Path

import pytest

from profiles.pipeline.metrics import analyse_scenario
from profiles.pipeline.scenario import load_scenario
from stack.cli import main

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

ROOT = Path(__file__).resolve().parents[3]
EXAMPLES = ROOT / "examples"

# The set of tests/profiles/test_rta_priority.py (hand-worked there): deadline monotonic leaves
# B unschedulable (R_B = 1210 us > 1200 us), Audsley's order B > A > X schedules all three.
JITTER_SET = """\
# three 8-byte messages; B's jitter defeats deadline-monotonic order
[bus]
bitrate = 500000
duration = 0.05

[[nodes]]
name = "n1"
messages = [
  {name = "A", id = 0x100, dlc = 8, period_ms = 1, deadline_ms = 1.2},   # most urgent
  {name = "B", id = 0x101, dlc = 8, period_ms = 4, deadline_ms = 1.2, jitter_ms = 0.4},
]

[[nodes]]
name = "n2"

[[nodes.messages]]
name = "X"
id = 258  # decimal on purpose
dlc = 8
period_ms = 1
deadline_ms = 1.5
jitter_ms = 0.4

[[nodes]]
name = "rx"
"""


def _run(capsys, *args: str) -> tuple[int, str, str]:
    code = main(["scenario", *args])
    out = capsys.readouterr()
    return code, out.out, out.err


def _ids(path: Path) -> dict[str, int]:
    raw = tomllib.loads(path.read_text())
    return {m["name"]: m["id"] for n in raw["nodes"] for m in n.get("messages", [])}


def test_opa_reassigns_the_files_own_identifiers_and_keeps_the_rest(tmp_path, capsys):
    src = tmp_path / "in.toml"
    src.write_text(JITTER_SET)
    out = tmp_path / "out.toml"
    code, stdout, _ = _run(capsys, "assign-ids", str(src), "--out", str(out))
    assert code == 0 and "every message schedulable" in stdout
    assert _ids(out) == {"B": 0x100, "A": 0x101, "X": 0x102}
    # only the identifiers changed: each in its own format (hex keeps its width, decimal stays)
    text = out.read_text()
    assert '{name = "B", id = 0x100, dlc = 8' in text and '{name = "A", id = 0x101,' in text
    assert "id = 258  # decimal on purpose" in text
    changed = [(a, b) for a, b in zip(JITTER_SET.splitlines(), text.splitlines()) if a != b]
    assert len(changed) == 2 and len(text.splitlines()) == len(JITTER_SET.splitlines())
    # independently: the experiments' analysis of the file written schedules every message
    results = analyse_scenario(load_scenario(out))["results"]
    assert all(r.schedulable for r in results.values()) and len(results) == 3


def test_dm_order_that_fails_exits_1_and_still_writes(tmp_path, capsys):
    src = tmp_path / "in.toml"
    src.write_text(JITTER_SET)
    out = tmp_path / "dm.toml"
    code, _, err = _run(capsys, "assign-ids", str(src), "--out", str(out), "--order", "dm")
    assert code == 1 and "deadline-monotonic" in err
    assert _ids(out) == {"A": 0x100, "B": 0x101, "X": 0x102}  # DM: A and B (D = 1.2 ms) above X
    results = analyse_scenario(load_scenario(out))["results"]
    assert not results["B"].schedulable


def test_dm_with_fifo_nodes_gives_the_fifo_analysis_verdict(tmp_path, capsys):
    # D07's priority-queue test accepts the example in DM order; its engine and gateway use FIFO
    # queues, where the experiment's analysis bounds EngineSpeed (D = 2 ms) beyond 5 ms
    out = tmp_path / "dm.toml"
    code, stdout, err = _run(
        capsys, "assign-ids", str(EXAMPLES / "powertrain_90_fifo.toml"), "--out", str(out), "--order", "dm"
    )
    assert code == 1 and "every message schedulable" not in stdout
    results = analyse_scenario(load_scenario(out))["results"]
    missed = sorted(n for n, r in results.items() if not r.schedulable)
    assert missed and "EngineSpeed" in missed
    assert err.strip().endswith(": " + ", ".join(n for n in results if not results[n].schedulable))


def test_rpa_on_an_example(tmp_path, capsys):
    out = tmp_path / "p.toml"
    code, stdout, _ = _run(
        capsys, "assign-ids", str(EXAMPLES / "powertrain_90.toml"), "--out", str(out), "--order", "rpa"
    )
    assert code == 0, stdout
    before, after = _ids(EXAMPLES / "powertrain_90.toml"), _ids(out)
    assert sorted(before.values()) == sorted(after.values()) and before != after
    # the example's Diagnostics message misses its deadline in the file's order, not in this one
    assert not analyse_scenario(load_scenario(EXAMPLES / "powertrain_90.toml"))["results"]["Diagnostics"].schedulable
    assert all(r.schedulable for r in analyse_scenario(load_scenario(out))["results"].values())


@pytest.mark.parametrize(
    "args, words",
    [
        (["assign-ids", "missing.toml", "--out", "o.toml"], ["missing.toml", "no such scenario file"]),
        (["assign-ids", str(EXAMPLES / "master_slave.toml"), "--out", "o.toml"], ["profile", "CSMA/CR"]),
        (["assign-ids", str(EXAMPLES / "powertrain_90_fifo.toml"), "--out", "o.toml"], ["fifo queue", "--order dm"]),
        (["assign-ids", str(EXAMPLES / "powertrain_90.toml"), "--out", "o.toml", "--order", "xyz"], ["xyz"]),
        (["assign-ids", str(EXAMPLES / "powertrain_90.toml"), "--out", "."], ["--out", "directory"]),
        (["assign-ids", str(EXAMPLES / "powertrain_90.toml")], ["--out"]),
        (["nothing-such"], ["nothing-such"]),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, words, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    code, _, err = _run(capsys, *args)
    assert code == 2
    assert len(err.strip().splitlines()) == 1, err
    for w in words:
        assert w in err


def test_mixed_identifier_formats_are_refused(tmp_path, capsys):
    src = tmp_path / "mixed.toml"
    src.write_text(JITTER_SET.replace("id = 258", "id = 0x1000\nextended = true"))
    code, _, err = _run(capsys, "assign-ids", str(src), "--out", str(tmp_path / "o.toml"))
    assert code == 2 and "'X' (extended)" in err and not (tmp_path / "o.toml").exists()


def test_the_scenario_group_takes_tools_from_entry_points(monkeypatch, capsys):
    # another package registers a tool under "canstack.scenario" (say, from-dbc): the command
    # finds it by entry point, with no change here
    import importlib.metadata

    calls = []

    class FakeEntryPoint:
        name = "from-nothing"

        @staticmethod
        def load():
            def register(tools):
                p = tools.add_parser("from-nothing", help="a tool of another package")
                p.set_defaults(func=lambda args: calls.append("ran") or 0)

            return register

    real = importlib.metadata.entry_points

    def entry_points(**kw):
        eps = list(real(**kw))
        return eps + [FakeEntryPoint()] if kw.get("group") == "canstack.scenario" else eps

    monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)
    assert main(["scenario", "from-nothing"]) == 0 and calls == ["ran"]
    with pytest.raises(SystemExit):  # argparse's help exits
        main(["scenario", "--help"])
    help_text = capsys.readouterr().out
    assert "assign-ids" in help_text and "from-nothing" in help_text
