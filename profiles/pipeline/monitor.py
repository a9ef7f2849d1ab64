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

from stack.bus.trace import TraceRecord
from stack.controller.events import Received
from stack.io.message import to_message
from stack.io.tracefile import TraceWriter
from stack.wire.coding import INTERMISSION_BITS

__all__ = ["BusMonitor", "PLOT_RECORDS"]

PLOT_RECORDS = 200_000
"""Timeline records a monitor keeps for the plots at most (the plots draw a window of the run)."""


class BusMonitor:
    """The subscription of the monitor node (see the module docstring). ``tracks`` by arbitration
    key, ``senders`` the node that sends each key; ``t0`` the driver time the run starts at;
    ``data_bitrate`` the CAN FD data phase's rate (frames with BRS)."""

    def __init__(
        self,
        tracks: Mapping[int, Any],
        senders: Mapping[int, str],
        bitrate: int,
        t0: int,
        *,
        trace: TraceWriter | None = None,
        plot: bool = False,
        data_bitrate: int | None = None,
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
        self._bitrate = bitrate
        self._data_bitrate = data_bitrate

    def __call__(self, ev: Received) -> None:
        """One frame on the bus (every frame: the monitor has no filters)."""
        self.frames += 1
        frame = ev.frame
        tr = self.tracks.get(frame.key)
        if tr is not None:
            tr.observed(ev.time, ev.sof)
        # no SOF time from the interface: the frame's own duration (a CAN FD frame's at both rates)
        sof = ev.sof if ev.sof >= 0 else ev.time - frame.bits.duration_ns(self._bitrate, self._data_bitrate)
        self.busy_ns += ev.time - sof + self._ifs_ns
        end = ev.time - self.t0
        if self.trace is not None:
            self.trace.message(to_message(frame, timestamp=end / 1e9, channel=self.trace.channel))
        if self.plot and len(self.records) < PLOT_RECORDS:
            start = sof - self.t0
            sender = self.senders.get(frame.key, "")
            self.records.append(TraceRecord("frame", start, end, sender, frame, frame.bits.length, 0, start))
