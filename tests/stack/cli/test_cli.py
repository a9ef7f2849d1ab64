"""`canstack demo` and `canstack frame`, and the CLI's bad-input contract (one line, status 2)."""

import json
import subprocess
import sys

import pytest

from stack.cli import main
from stack.wire.decoder import decode


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "stack.cli", *args], capture_output=True, text=True)


def test_demo_prints_summary_and_writes_nothing(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["demo"]) == 0
    out = capsys.readouterr().out
    assert "bus load" in out and "0x0C1" in out and "arb. losses" in out
    assert list(tmp_path.iterdir()) == []


def test_demo_writes_trace_when_asked(tmp_path, capsys):
    path = tmp_path / "out.asc"
    assert main(["demo", "--duration", "0.1", "--trace", str(path)]) == 0
    assert path.read_text().count("Rx") > 50


def test_frame_json_golden_crc_and_bits(capsys):
    assert main(["frame", "--id", "0x0C1", "--data", "4001087500000000", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["crc"] == 0x5B40 and out["stuff_bits"] == 10 and out["length"] == 118 == len(out["bits"])
    d = decode(out["bits"])
    assert d.ok and d.frame.can_id == 0x0C1 and d.frame.data.hex() == "4001087500000000"


def test_frame_remote_extended(capsys):
    assert main(["frame", "--id", "0x18FEF100", "--extended", "--remote", "--dlc", "8", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    d = decode(out["bits"])
    assert d.frame.remote and d.frame.extended and d.frame.dlc == 8


@pytest.mark.parametrize(
    "args,needle",
    [
        (["frame", "--id", "0x800"], "0x800 out of range"),
        (["frame", "--id", "0x1", "--data", "zz"], "not hex"),
        (["frame", "--id", "0x1", "--remote", "--dlc", "16"], "DLC 16"),
        (["frame", "--id", "0x1", "--data", "112233445566778899"], "at most 8"),
        (["frame", "--id", "abc"], "not an integer"),
        (["demo", "--bitrate", "5000000"], "1000..1000000"),
        (["demo", "--trace", "x.unknown"], "unknown suffix"),
        (["demo", "--duration", "-1"], "--duration"),
        (["demo", "--plot", "x.png"], "use it with --faults"),
        (["nosuchcommand"], "invalid choice"),
        (["frame", "--id", "-1"], "identifier -0x1 out of range"),
        (["demo", "--trace", "/nonexistent-dir/x.asc"], "'/nonexistent-dir' does not exist"),
        (["demo", "--trace", ""], "--trace needs a file name"),
        (["demo", "--vcd", "/"], "is a directory"),
        (["demo", "--interface", "virtual", "--trace", "x.asc"], "--trace needs the simulated bus"),
        (["demo", "--interface", "virtual", "--json"], "--json needs the simulated bus"),
    ],
)
def test_bad_input_is_one_line_and_status_2(args, needle, capsys, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)  # a relative file a bad command would write lands here
    assert main(args) == 2  # an exception escaping main (a traceback) fails the test
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert out == "" and len(lines) == 1 and needle in lines[0]


@pytest.mark.subprocess
def test_bad_input_to_the_command_is_one_line_on_stderr_and_status_2():
    """The same contract as a shell sees it: the process's status and all of its stderr, whatever
    else a fresh interpreter might print there (a warning, a log line)."""
    p = run_cli("frame", "--id", "0x800")
    assert p.returncode == 2 and p.stdout == ""
    assert p.stderr.strip().splitlines() == [p.stderr.strip()] and "0x800 out of range" in p.stderr


def test_fault_demo_goes_passive_bus_off_and_recovers(capsys, tmp_path):
    pytest.importorskip("matplotlib")
    png = tmp_path / "tec.png"
    assert main(["demo", "--faults", "--plot", str(png)]) == 0
    out = capsys.readouterr().out
    import re

    assert re.search(r"ecu2 +error-warning -> error-passive", out)
    # the disconnected transmitter: warning at TEC 96 and passive at 128 within its first
    # attempt (rules 3, 4, 9), then bus off at 256 (rule 10) after 16 passive attempts
    assert re.search(
        r"ecu2 +error-active -> error-warning TEC +96.*\n.*ecu2 +error-warning -> error-passive TEC 128"
        r".*\n.*ecu2 +error-passive -> bus-off +TEC 256",
        out,
    )
    assert re.search(r"ecu2 +bus-off -> error-active +TEC +0 REC +0", out)
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"


def test_demo_waveform_decodes_back_to_the_trace(tmp_path, capsys):
    from stack.bus.sim import SimBus
    from stack.cli.demo import build_demo, write_trace_vcd
    from stack.phy.waveform import decode_file

    bus = SimBus(500_000)
    build_demo(bus)
    bus.run(until=30_000_000)
    path = tmp_path / "demo.vcd"
    n = write_trace_vcd(bus, str(path))
    recs = decode_file(str(path), 500_000)
    frames = [r.to_frame() for r in recs if r.ok]
    assert n == len(bus.trace) == len(frames) and frames == [r.frame for r in bus.trace]
    lead = 11 * 2000  # the waveform starts with 11 idle bits
    assert [round(r.t * 1e9) - lead for r in recs] == [r.start for r in bus.trace]


@pytest.mark.subprocess
def test_a_plugin_command_loads_its_own_module_only():
    """`canstack experiment` registers the experiment command and imports neither the DBC nor the
    CANopen command modules (their imports cost every command start-up time); a name that is
    no command still lists every command."""
    script = (
        "import sys; from stack.cli import CliError, build_parser; p = build_parser('experiment');"
        "print(p.parse_args(['experiment', 'x.toml']).scenario);"
        "print([m for m in ('dbc.cli', 'profiles.canopen.cli', 'profiles.sweeps.cli') if m in sys.modules])\n"
        "try:\n    p.parse_args(['restbus', 'x.dbc'])\nexcept CliError as exc:\n    print(exc)"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    scenario, loaded, restbus = out.stdout.splitlines()
    assert scenario == "x.toml" and loaded == "[]" and "invalid choice: 'restbus'" in restbus
    out = run_cli("restbuss")
    assert out.returncode == 2 and "invalid choice: 'restbuss'" in out.stderr
    assert "'restbus'" in out.stderr and "'canopen'" in out.stderr and "'demo'" in out.stderr
