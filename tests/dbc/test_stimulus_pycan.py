"""`canstack restbus --stimulus FILE` on a python-can ``virtual`` bus: a logger on the same
channel, decoding with cantools, sees each stimulated value from the time the file gives.

The bus runs on the wall clock, so the times are checked with tolerances the stimulus file itself
gives: half the shortest interval between two of its changes (a change that drifted that far
would be mistaken for its neighbour), never tighter than the message's own cycle time."""

from __future__ import annotations

import csv
from pathlib import Path

import can
import cantools
import pytest

import stack.cli as cli

ROOT = Path(__file__).resolve().parents[2]
DBC = ROOT / "dbc" / "databases" / "powertrain_body.dbc"
STIMULUS = ROOT / "examples" / "restbus_stimulus.csv"


@pytest.mark.wallclock
def test_a_logger_on_the_virtual_bus_decodes_the_stimulated_values_at_their_times(capsys, rerun_until):
    db = cantools.database.load_file(str(DBC))
    with open(STIMULUS, newline="") as f:
        changes = [(float(r["time"]), r["message"], r["signal"], r["value"]) for r in csv.DictReader(f)]
    times = sorted({t for t, *_ in changes})
    tolerance = min(b - a for a, b in zip(times, times[1:])) / 2  # 0.05 s for the shipped file
    duration = times[-1] + 3 * tolerance

    def run() -> list[can.Message]:
        logger = can.Bus(interface="virtual", channel="restbus-stimulus", receive_own_messages=False)
        try:
            code = cli.main(
                ["restbus", str(DBC), "--dut", "IPC", "--interface", "virtual", "--channel", "restbus-stimulus",
                 "--duration", str(duration), "--stimulus", str(STIMULUS)]
            )  # fmt: skip
            assert code == 0, capsys.readouterr().err
            received = []
            while (m := logger.recv(timeout=0)) is not None:
                received.append(m)
        finally:
            logger.shutdown()
        # whatever the machine's load: every message is sent and every stimulated value arrives
        assert received
        for _, name, signal, value in changes:
            msg = db.get_message_by_name(name)
            physical = _same(msg, signal, value)
            rows = _rows(db, msg, signal, received)
            assert rows and any(physical(v) for _, v in rows), (name, signal, value, rows)
        return received

    def late(received: list[can.Message]) -> list[tuple[str, str, str]]:
        """The changes whose value came more than the tolerance (or a cycle) off its time."""
        t0 = received[0].timestamp  # the rest bus sends every cyclic message at its start
        out = []
        for at, name, signal, value in changes:
            msg = db.get_message_by_name(name)
            tol = max(tolerance, (msg.cycle_time or 0) / 1000)
            physical = _same(msg, signal, value)
            rows = [(t - t0, v) for t, v in _rows(db, msg, signal, received)]
            after = [v for t, v in rows if t > at + tol]
            before = [v for t, v in rows if t < at - tol]
            first = next(t for t, v in rows if physical(v))
            if (
                not (after and all(physical(v) for v in after))
                or any(physical(v) for v in before)
                or abs(first - at) > tol
            ):
                out.append((name, signal, value))
        return out

    # on time on a machine that did not starve the sender's thread (a loaded one may, now and then)
    received = rerun_until(run, lambda r: not late(r))
    assert late(received) == []


def _rows(db, msg, signal: str, received: list[can.Message]) -> list[tuple[float, str]]:
    """(timestamp, decoded value of ``signal``) of every frame of ``msg`` in ``received``."""
    return [
        (m.timestamp, str(msg.decode(m.data, decode_choices=True)[signal]))
        for m in received
        if m.arbitration_id == msg.frame_id and m.is_extended_id == msg.is_extended_frame
    ]


def _same(msg, signal: str, value: str):
    """Whether a decoded value is the stimulus' ``value`` (a choice name, or a number)."""
    sig = msg.get_signal_by_name(signal)
    if sig.choices and not _is_number(value):
        return lambda decoded: decoded == value
    return lambda decoded: _is_number(decoded) and float(decoded) == pytest.approx(float(value))


def _is_number(text: str) -> bool:
    try:
        float(text)
    except ValueError:
        return False
    return True
