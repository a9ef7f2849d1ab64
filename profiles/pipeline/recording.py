"""What a run records beside its metrics, each in bounded memory however long the run: the
receptions of a faulted run, what the plots draw, every instance of every message
(``--samples``), all fed as the bus runs (`stack.SimBus.on_trace` on a bus that keeps no trace,
`profiles.base.Track.sink`).

- `ReceptionCounter` — per message, the instances that reached at least one other node, from
  the attempts each receiver accepted (faults make some attempts reach only some nodes, and one
  instance may be received twice: it counts once);
- `PlotRecords` — the trace records of the timeline's window (with a margin for the layers a
  profile draws behind it) and the busy time of each bus-load bin;
- `SampleWriter` — every instance as a row of a CSV or Parquet file, written in batches.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path
from typing import TYPE_CHECKING, Any

from profiles.base import Instance, frame_of

if TYPE_CHECKING:  # pragma: no cover
    from profiles.base import Track
    from stack import TraceRecord

__all__ = [
    "ReceptionCounter",
    "PlotRecords",
    "SampleWriter",
    "SAMPLE_COLUMNS",
    "MAX_BINS",
    "plot_window",
    "readable_bin_ns",
]

SAMPLE_COLUMNS = ("message", "node", "outcome", "nominal_ns", "queued_ns", "sof_ns", "eof_ns", "response_ns", "missed")
"""The columns of a ``--samples`` file (`profiles.base.Instance`; times in bus ns)."""

MAX_BINS = 500
"""Most bus-load bins a plot draws: a finer ``[plot] bin_ms`` over a long run is widened (bins
narrower than a few pixels make a grey band, and each costs memory)."""


def readable_bin_ns(at_least_ns: int) -> int:
    """The narrowest bin of 1, 2 or 5 times a power of ten nanoseconds that is at least
    ``at_least_ns`` wide: a widened bus-load bin reads as 2 ms or 50 ms, never as 2.468 ms."""
    step = 1
    while True:
        for m in (1, 2, 5):
            if m * step >= at_least_ns:
                return m * step
        step *= 10


TIMELINE_MARGIN_NS = 1_000_000_000
"""Trace kept on each side of the timeline's window: a profile's layer (a TDMA cycle) may start
before the window or end after it."""


class ReceptionCounter:
    """Counts, per tracked message, the instances that reached at least one other node: an
    attempt that completed cleanly (every node received it), or one that some receivers
    accepted before an error (inconsistent omission, the double-reception case). Attempts of one
    instance share its queuing time, and instances of a message leave in order, so an instance
    counts once however many of its attempts were accepted."""

    def __init__(self, tracks: dict[str, Track]) -> None:
        self._name = {frame_of(tr.decl).key: name for name, tr in tracks.items()}
        self.received = dict.fromkeys(tracks, 0)
        self._last: dict[int, int] = {}

    def __call__(self, rec: TraceRecord) -> None:
        """One trace record of the bus (`stack.SimBus.on_trace`)."""
        key = rec.frame.key
        name = self._name.get(key)
        if name is None:
            return
        d = rec.detail or {}
        if d.get("accepted_by") or (rec.kind == "frame" and "error" not in d):
            if self._last.get(key) != rec.queued:
                self._last[key] = rec.queued
                self.received[name] += 1


def plot_window(plot: dict[str, Any], end_ns: int) -> tuple[int, int]:
    """The timeline's window in bus ns: ``[plot] window_ms``, else the first 50 ms (a timeline of
    seconds is a grey band)."""
    w = plot.get("window_ms")
    if w:
        return round(w[0] * 1e6), round(w[1] * 1e6)
    return 0, min(end_ns, 50_000_000)


class PlotRecords:
    """The trace records of the timeline's window, and the busy time of each bus-load bin (frames
    and error frames with their intermission, as `stack.SimBus.bus_load` counts them), kept as
    the bus runs. ``bin_ns`` is ``[plot] bin_ms``, widened to a readable width
    (`readable_bin_ns`) so that the run has at most `MAX_BINS` bins (``widened`` then says so)."""

    def __init__(self, window: tuple[int, int], bin_ns: int, end_ns: int, bitrate: int) -> None:
        self.window = window
        self.records: list[Any] = []
        self.requested_bin_ns = bin_ns
        fewest = math.ceil(end_ns / MAX_BINS)
        self.bin_ns = bin_ns if bin_ns >= fewest else readable_bin_ns(fewest)
        self.widened = self.bin_ns != bin_ns
        self.end_ns = end_ns
        self.busy = [0] * max(1, -(-end_ns // self.bin_ns))
        self._ifs = round(3 * 1e9 / bitrate)
        self._lo = window[0] - TIMELINE_MARGIN_NS
        self._hi = window[1] + TIMELINE_MARGIN_NS

    def __call__(self, rec: TraceRecord) -> None:
        """One trace record of the bus (`stack.SimBus.on_trace`)."""
        if rec.end >= self._lo and rec.start <= self._hi:
            self.records.append(rec)
        a, b = rec.start, min(self.end_ns, rec.end + self._ifs)
        busy, size = self.busy, self.bin_ns
        while a < b:
            i = a // size
            if i >= len(busy):
                break
            edge = min(b, (i + 1) * size)
            busy[i] += edge - a
            a = edge


class SampleWriter:
    """Every instance of every message (`profiles.base.Instance`) as one row of a CSV file or,
    for a ``.parquet`` path, a Parquet file (pyarrow, the ``parquet`` extra) written in row
    groups of `BATCH` rows; nothing is held beyond one batch."""

    BATCH = 65_536

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self.rows = 0
        self.error: OSError | None = None
        self._batch: list[Instance] = []
        self._parquet = self.path.suffix.lower() == ".parquet"
        self._pq: Any = None
        self._file: Any = None
        self._csv: Any = None
        if self._parquet:
            import pyarrow as pa
            import pyarrow.parquet as pq

            self._schema = pa.schema(
                [
                    ("message", pa.string()),
                    ("node", pa.string()),
                    ("outcome", pa.string()),
                    *((c, pa.int64()) for c in SAMPLE_COLUMNS[3:8]),
                    ("missed", pa.bool_()),
                ]
            )
            self._pq = pq.ParquetWriter(str(self.path), self._schema)
        else:
            self._file = open(self.path, "w", newline="", encoding="utf-8")  # noqa: SIM115 (closed in close())
            self._csv = csv.writer(self._file)
            self._csv.writerow(SAMPLE_COLUMNS)

    def __call__(self, inst: Instance) -> None:
        """One instance (a `profiles.base.Track` sink)."""
        self._batch.append(inst)
        if len(self._batch) >= self.BATCH:
            self.flush()

    def flush(self) -> None:
        """Write the rows held so far; a failed write (a full disk) is kept in ``error`` and
        stops the writing, not the run."""
        rows, self._batch = self._batch, []
        if not rows or self.error is not None:
            return
        try:
            self._write(rows)
        except OSError as exc:
            self.error = exc

    def _write(self, rows: list[Instance]) -> None:
        if self._parquet:
            import pyarrow as pa

            cols = list(zip(*rows))
            self._pq.write_table(
                pa.table({c: pa.array(v, type=self._schema.field(c).type) for c, v in zip(SAMPLE_COLUMNS, cols)})
            )
        else:
            self._csv.writerows(["" if v is None else v for v in r] for r in rows)
        self.rows += len(rows)

    def close(self) -> None:
        """Write what is left and close the file (idempotent; a failure is kept in ``error``)."""
        self.flush()
        try:
            if self._pq is not None:
                pq, self._pq = self._pq, None
                pq.close()
            if self._file is not None:
                f, self._file = self._file, None
                f.close()
        except OSError as exc:
            self.error = self.error or exc
