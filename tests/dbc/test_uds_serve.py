"""`canstack restbus --uds` over a served bus: the rest bus runs in its own process on
``canstack serve``'s bus (python-can interface ``canstack``); udsoncan, over can-isotp's own
threaded stack on another connection, reads the VIN and a signal; a third connection watches the
frames with their bus timestamps and sees the tester's STmin and block size kept."""

from __future__ import annotations

import subprocess
import sys
import threading
from pathlib import Path

import pytest

udsoncan = pytest.importorskip("udsoncan")
isotp = pytest.importorskip("isotp")
can = pytest.importorskip("can")

SAMPLE = Path(__file__).resolve().parents[2] / "dbc" / "databases" / "powertrain_body.dbc"
VIN = "WVWZZZ1JZXW000001"
STMIN_MS = 5


@pytest.mark.wallclock
@pytest.mark.socket
@pytest.mark.subprocess
def test_udsoncan_reads_vin_and_signal_from_restbus_over_serve():
    from udsoncan.client import Client
    from udsoncan.connections import PythonIsoTpConnection

    from stack.io.serve import BusServer

    server = BusServer(500_000, listen=("127.0.0.1", 0))
    proc = None
    tester = watcher = None
    try:
        proc = subprocess.Popen(
            [
                sys.executable, "-m", "stack.cli", "restbus", str(SAMPLE), "--interface", "canstack",
                "--channel", server.url, "--duration", "120", "--uds", "ECM:0x7E0:0x7E8", "--vin", VIN,
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )  # fmt: skip
        assert proc.stdout is not None
        listed = []
        for line in proc.stdout:  # the DIDs are printed when it starts
            listed.append(line.strip())
            if line.strip().startswith("0xF190"):
                break
        assert listed[0].startswith("UDS: ECM answers requests on 0x7E0, responds on 0x7E8")
        assert "0x1000  EngineData.EngineSpeed" in listed and "0xF190  VIN" in listed

        watcher = can.Bus(interface="canstack", channel=server.url, receive_own_messages=False)
        seen: list[can.Message] = []
        stop = threading.Event()

        def watch() -> None:
            while not stop.is_set():
                m = watcher.recv(0.05)
                if m is not None and m.arbitration_id in (0x7E0, 0x7E8):
                    seen.append(m)

        thread = threading.Thread(target=watch)
        thread.start()
        tester = can.Bus(interface="canstack", channel=server.url)
        stack_ = isotp.CanStack(
            tester,
            address=isotp.Address(isotp.AddressingMode.Normal_11bits, txid=0x7E0, rxid=0x7E8),
            params={"stmin": STMIN_MS, "blocksize": 2, "tx_padding": 0xCC, "tx_data_min_length": 8},
        )
        conn = PythonIsoTpConnection(stack_)
        cfg = dict(udsoncan.configs.default_client_config)
        cfg["data_identifiers"] = {0xF190: udsoncan.AsciiCodec(17), 0x1000: ">H", 0xF186: "B"}
        cfg["request_timeout"] = 10
        cfg["p2_timeout"] = 5
        try:
            with Client(conn, config=cfg) as client:
                assert client.read_data_by_identifier(0xF190).service_data.values[0xF190] == VIN
                assert client.read_data_by_identifier(0x1000).service_data.values[0x1000] == (3200,)  # 800 rpm
                client.change_session(3)
                assert client.read_data_by_identifier(0xF186).service_data.values[0xF186] == (3,)
        finally:
            stop.set()
            thread.join()
        # the VIN response: first frame, the tester's flow control (BS 2, STmin 5 ms), two consecutive frames
        kinds = [(m.arbitration_id, m.data[0] >> 4) for m in seen]
        first = kinds.index((0x7E8, 1))
        assert kinds[first : first + 4] == [(0x7E8, 1), (0x7E0, 3), (0x7E8, 2), (0x7E8, 2)]
        fc, cf1, cf2 = seen[first + 1], seen[first + 2], seen[first + 3]
        assert fc.data[1:3] == bytes((2, STMIN_MS))
        # bus timestamps mark the end of each frame. The sender (can-isotp) times STmin from
        # handing CF1 over, and CF1 may then wait for the bus or the server's pace, which
        # shortens the gap seen between the ends by that wait (4.75 ms seen on a loaded machine).
        # A sender that ignored STmin would put CF2 about 216 us (108 bits at 500 kbit/s) after
        # CF1; the STmin shows as a gap of most of 5 ms
        assert cf2.timestamp - cf1.timestamp >= 0.8 * STMIN_MS / 1000
    finally:
        for bus in (tester, watcher):
            if bus is not None:
                bus.shutdown()
        if proc is not None:
            proc.terminate()
            try:
                proc.communicate(timeout=60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.communicate()
        server.close()
