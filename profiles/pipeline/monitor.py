"""What an experiment on a python-can bus sees of the bus: `BusMonitor`, the listen-only node's
subscription that counts the frames, ends each message's instances (`profiles.base.Track`), adds
up the bus time for the load, streams a trace file and keeps the timeline records the plots draw.

Everything is on one clock: the driver's (`stack.io.driver.PyCanDriver`: the bus's receive
timestamps mapped onto this process's monotonic clock; a served bus's time through
`stack.io.clock`), counted from ``t0``, the start of the run. A trace file and the plots show
that bus time in seconds from the start, as a simulated run shows its own.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import can

from stack.bus.trace import TraceRecord
from stack.controller.events import Received
from stack.io.message import to_message
from stack.io.tracefile import check_suffix
from stack.wire.coding import INTERMISSION_BITS

__all__ = ["BusMonitor", "BusTimeTrace", "PLOT_RECORDS"]

PLOT_RECORDS = 200_000
"""Timeline records a monitor keeps for the plots at most (the plots draw a window of the run)."""


class BusTimeTrace:
    """A trace file written as the run goes (python-can's writer for the suffix), with message
    timestamps in bus seconds from the start of the run: python-can's .asc writer counts from its
    first event and its .blf writer from its first message, so both are started at time 0. A .trc
    file holds no remote frames: they are counted in ``left_out``. A write that fails (a full
    disk) keeps its error in ``error`` and ends the writing, not the run."""

    def __init__(self, path: str, channel: Any = None) -> None:
        self.suffix = check_suffix(path)
        self.path = path
        self.channel = channel
        self.written = 0
        self.left_out = 0
        self.error: OSError | None = None
        self._writer: Any = can.Logger(path)  # type: ignore[abstract]
        if isinstance(self._writer, can.ASCWriter):
            self._writer.log_event(f"canstack: timestamps are bus time of {channel or 'the bus'}", timestamp=0.0)
        elif isinstance(self._writer, can.BLFWriter):
            self._writer.start_timestamp = 0.0

    def message(self, msg: can.Message) -> None:
        """Write one message (its timestamp in bus seconds)."""
        if self.suffix == ".trc" and msg.is_remote_frame:
            self.left_out += 1
            return
        if self.error is not None or self._writer is None:
            return
        try:
            self._writer.on_message_received(msg)
        except OSError as exc:
            self.error = exc
            return
        self.written += 1

    def close(self) -> None:
        """Finish the file (idempotent)."""
        if self._writer is not None:
            writer, self._writer = self._writer, None
            try:
                writer.stop()
            except OSError as exc:
                self.error = self.error or exc


class BusMonitor:
    """The subscription of the monitor node (see the module docstring). ``tracks`` by arbitration
    key, ``senders`` the node that sends each key; ``t0`` the driver time the run starts at."""

    def __init__(
        self,
        tracks: Mapping[int, Any],
        senders: Mapping[int, str],
        bitrate: int,
        t0: int,
        *,
        trace: BusTimeTrace | None = None,
        plot: bool = False,
    ) -> None:
        self.tracks = tracks
        self.senders = senders
        self.t0 = t0
        self.trace = trace
        self.plot = plot
        self.frames = 0
        self.busy_ns = 0
        self.records: list[TraceRecord] = []
        self._ifs_ns = round(INTERMISSION_BITS * 1e9 / bitrate)
        self._bit_ns = 1e9 / bitrate

    def __call__(self, ev: Received) -> None:
        """One frame on the bus (every frame: the monitor has no filters)."""
        self.frames += 1
        frame = ev.frame
        tr = self.tracks.get(frame.key)
        if tr is not None:
            tr.observed(ev.time, ev.sof)
        sof = ev.sof if ev.sof >= 0 else ev.time - round(frame.bits.length * self._bit_ns)
        self.busy_ns += ev.time - sof + self._ifs_ns
        end = ev.time - self.t0
        if self.trace is not None:
            self.trace.message(to_message(frame, timestamp=end / 1e9, channel=self.trace.channel))
        if self.plot and len(self.records) < PLOT_RECORDS:
            start = sof - self.t0
            sender = self.senders.get(frame.key, "")
            self.records.append(TraceRecord("frame", start, end, sender, frame, frame.bits.length, 0, start))
