"""`canstack canopen`: one-line errors with exit status 2, and a device run from the command
line that the ``canopen`` library (in this process) drives over a `canstack serve` bus."""

import importlib.metadata
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import canopen
import pytest

import stack.cli as cli
from profiles.canopen.dictionary import DEFAULT_EDS
from stack.io.serve import BusServer

ROOT = Path(__file__).resolve().parents[3]
EP = importlib.metadata.EntryPoint(name="canopen", value="profiles.canopen.cli:register", group="canstack.commands")


def _installed() -> bool:
    return any(ep.name == "canopen" for ep in importlib.metadata.entry_points(group="canstack.commands"))


@pytest.fixture
def registered(monkeypatch):
    """The entry point as pyproject.toml declares it, also before the checkout is re-installed."""
    if not _installed():
        real = importlib.metadata.entry_points

        def entry_points(**kw):
            eps = real(**kw)
            return importlib.metadata.EntryPoints([*eps, EP]) if kw.get("group") == "canstack.commands" else eps

        monkeypatch.setattr(importlib.metadata, "entry_points", entry_points)


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_pyproject_registers_the_command():
    import tomllib

    py = tomllib.loads((ROOT / "pyproject.toml").read_text())
    assert py["project"]["entry-points"]["canstack.commands"]["canopen"] == EP.value


@pytest.mark.parametrize(
    "argv, message",
    [
        (["--node-id", "0", "--interface", "virtual"], r"0: a CANopen node-ID is 1\.\.127"),
        (["--node-id", "128", "--interface", "virtual"], r"128: a CANopen node-ID is 1\.\.127"),
        (["--node-id", "x", "--interface", "virtual"], r"'x' is not an integer"),
        (["--node-id", "5"], r"the following arguments are required: --interface"),
        (["--node-id", "5", "--interface", "virtual", "--heartbeat", "70000"], r"70000: the producer heartbeat time"),
        (["--node-id", "5", "--interface", "no-such-interface"], r"cannot open no-such-interface channel None"),
    ],
)
def test_bad_input_is_one_line_and_exit_status_2(capsys, registered, argv, message):
    import re

    code, out, err = run(capsys, "canopen", *argv)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and re.search(message, err)


def test_a_malformed_eds_names_the_file(capsys, registered, tmp_path):
    bad = tmp_path / "broken.eds"
    bad.write_text(DEFAULT_EDS.read_text().replace("[1001]", "[1001"))
    code, out, err = run(capsys, "canopen", str(bad), "--node-id", "5", "--interface", "virtual")
    assert code == 2 and str(bad) in err and "not a valid EDS" in err and len(err.strip().splitlines()) == 1
    code, out, err = run(capsys, "canopen", str(tmp_path / "none.eds"), "--node-id", "5", "--interface", "virtual")
    assert code == 2 and "none.eds: no such file" in err


@pytest.mark.wallclock
def test_a_short_run_on_the_virtual_bus_prints_the_summary(capsys, registered):
    code, out, err = run(
        capsys,
        "canopen",
        "--node-id",
        "9",
        "--interface",
        "virtual",
        "--channel",
        "co-cli",
        "--heartbeat",
        "50",
        "--duration",
        "0.3",
        "--start",
    )
    assert code == 0, err
    assert "NMT INITIALISING -> OPERATIONAL" in out
    assert "node 9: OPERATIONAL, 1 boot-up," in out
    code, out, err = run(
        capsys,
        "canopen",
        "--node-id",
        "9",
        "--interface",
        "virtual",
        "--channel",
        "co-cli",
        "--duration",
        "0.1",
        "--json",
    )
    import json

    m = json.loads(out)
    assert code == 0 and m["node_id"] == 9 and m["nmt_state"] == "PRE_OPERATIONAL" and m["boot_ups"] == 1


@pytest.mark.wallclock
@pytest.mark.socket
@pytest.mark.subprocess
def test_the_canopen_library_drives_a_device_run_by_the_command(tmp_path, interruptible_python):
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    if not _installed():  # the entry point of pyproject.toml, for a checkout not re-installed yet
        dist = tmp_path / "canstack_canopen_entry-0.dist-info"
        dist.mkdir()
        (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: canstack-canopen-entry\nVersion: 0\n")
        (dist / "entry_points.txt").write_text(f"[canstack.commands]\ncanopen = {EP.value}\n")
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        proc = subprocess.Popen(
            interruptible_python(  # Ctrl-C stops it even when the suite runs with SIGINT ignored
                "-m",
                "stack.cli",
                "canopen",
                "--node-id",
                "12",
                "--interface",
                "canstack",
                "--channel",
                srv.url,
                "--heartbeat",
                "100",
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
        )
        net = canopen.Network()
        try:
            assert "Ctrl-C stops it" in proc.stdout.readline()
            net.connect(interface="canstack", channel=srv.url)
            node = net.add_node(12, str(DEFAULT_EDS))
            node.sdo.RESPONSE_TIMEOUT = 2.0  # a loaded CI machine is slow, not wrong
            node.nmt.wait_for_heartbeat(5.0)  # its first heartbeat, 100 ms after boot-up
            assert node.sdo[0x1018][2].raw == 1 and node.sdo[0x1008].raw == "canstack CANopen device"
            node.nmt.state = "OPERATIONAL"
            deadline = time.monotonic() + 3
            while node.nmt.state != "OPERATIONAL" and time.monotonic() < deadline:
                node.nmt.wait_for_heartbeat(1.0)
            assert node.nmt.state == "OPERATIONAL"
        finally:
            net.disconnect()
            proc.send_signal(signal.SIGINT)
            try:
                out, err = proc.communicate(timeout=30)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate()
    assert proc.returncode == 130, err
    assert "NMT PRE_OPERATIONAL -> OPERATIONAL" in out and "node 12: OPERATIONAL" in out


@pytest.mark.parametrize(
    "app, message",
    [
        ("no_colon_here", r"--app 'no_colon_here': not module:function"),
        ("nosuchmodule_xyz:setup", r"--app 'nosuchmodule_xyz:setup': no module named 'nosuchmodule_xyz'"),
        ("app_mod:missing", r"--app 'app_mod:missing': module 'app_mod' has no 'missing'"),
        ("app_mod:VALUE", r"--app 'app_mod:VALUE': 'VALUE' is a int, not a function to call with the device"),
        ("app_mod:two", r"--app 'app_mod:two': two\(a, b\) cannot be called with one argument \(the device\)"),
        ("app_broken:setup", r"--app 'app_broken:setup': cannot import 'app_broken': ZeroDivisionError"),
    ],
)
def test_a_bad_app_is_one_line_and_exit_status_2(capsys, registered, tmp_path, monkeypatch, app, message):
    import re

    (tmp_path / "app_mod.py").write_text("VALUE = 3\n\ndef two(a, b):\n    pass\n")
    (tmp_path / "app_broken.py").write_text("1 / 0\n")
    monkeypatch.chdir(tmp_path)  # the app is found in the current directory, as python -m finds it
    monkeypatch.setattr(sys, "path", list(sys.path))
    code, out, err = run(capsys, "canopen", "--node-id", "5", "--interface", "virtual", "--app", app)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and re.search(message, err), err


APP = r"""
# the application of a CANopen device run by `canstack canopen --app app_demo:setup`
def setup(device):
    device.write(0x1012, 0, 0x80000100)  # consume TIME on 0x100
    device.write(0x2003, 0, 1234)  # an object of its own
    device.node.call_later(50_000_000, device.report_error, 0x5000, b"\x01")  # an EMCY, 50 ms in

    def on_time(unix_ms):
        device.write(0x2002, 0, unix_ms // 1000 % 2**32)  # react to TIME: seconds into 0x2002

    device.on_time(on_time)
"""


@pytest.mark.socket
@pytest.mark.subprocess
@pytest.mark.wallclock
def test_the_app_of_a_device_in_another_process_raises_emcy_writes_objects_and_reacts_to_time(
    tmp_path, interruptible_python
):
    (tmp_path / "app_demo.py").write_text(APP)
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(ROOT), str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    if not _installed():
        dist = tmp_path / "canstack_canopen_entry-0.dist-info"
        dist.mkdir()
        (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: canstack-canopen-entry\nVersion: 0\n")
        (dist / "entry_points.txt").write_text(f"[canstack.commands]\ncanopen = {EP.value}\n")
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        net = canopen.Network()
        net.connect(interface="canstack", channel=srv.url)
        node = net.add_node(13, str(DEFAULT_EDS))
        node.sdo.RESPONSE_TIMEOUT = 10.0  # a loaded machine is slow, not wrong
        proc = subprocess.Popen(
            interruptible_python(  # Ctrl-C stops it even when the suite runs with SIGINT ignored
                "-m",
                "stack.cli",
                "canopen",
                "--node-id",
                "13",
                "--interface",
                "canstack",
                "--channel",
                srv.url,
                "--app",
                "app_demo:setup",
            ),
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            env=env,
            cwd=tmp_path,
        )
        try:
            assert "Ctrl-C stops it" in proc.stdout.readline()
            emcy = node.emcy.wait(0x5000, timeout=30.0)
            assert emcy is not None and emcy.code == 0x5000 and emcy.data[:1] == b"\x01"
            assert node.sdo[0x2003].raw == 1234
            net.time.transmit(1_700_000_000.0)  # TIME_OF_DAY: 2023-11-14 22:13:20 UTC
            deadline = time.monotonic() + 30
            while node.sdo[0x2002].raw != 1_700_000_000 and time.monotonic() < deadline:
                time.sleep(0.05)
            assert node.sdo[0x2002].raw == 1_700_000_000
        finally:
            net.disconnect()
            proc.send_signal(signal.SIGINT)
            try:
                out, err = proc.communicate(timeout=30)
            finally:
                if proc.poll() is None:
                    proc.kill()
                    proc.communicate()
    assert proc.returncode == 130, err
    assert "canstack canopen:" not in err  # no callback failed on the driver's thread


@pytest.mark.wallclock
@pytest.mark.subprocess
def test_an_eds_without_device_info_is_one_warning_naming_the_file(tmp_path):
    """CiA 306 makes [DeviceInfo] mandatory; the canopen library logs its absence. Through the
    command that is exactly one warning line on stderr, naming the file, and the device runs."""
    import re

    text = DEFAULT_EDS.read_text()
    eds = tmp_path / "no_info.eds"
    eds.write_text(re.sub(r"(?ms)^\[DeviceInfo\]\n.*?(?=^\[)", "", text))
    assert "[DeviceInfo]" in text and "DeviceInfo" not in eds.read_text()
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    argv = ["canopen", str(eds), "--node-id", "5", "--interface", "virtual", "--channel", "noinfo", "--duration", "0.2"]
    proc = subprocess.run(
        [sys.executable, "-m", "stack.cli", *argv], capture_output=True, text=True, env=env, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith(f"canstack: warning: {eds}: ") and "DeviceInfo" in lines[0]
    assert "node 5: PRE_OPERATIONAL, 1 boot-up" in proc.stdout
