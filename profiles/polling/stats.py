"""What a poll-list master measures, apart from what it does: the cycles (`CycleStats`) and its
view of each slave (`SlaveLink`), with their figures for the results (``master_slave``).

Times are the master's clock (ns) unless said otherwise; the windows of the poll-cycle plot are
bus times.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.responses import ResponseStats

if TYPE_CHECKING:  # pragma: no cover
    from profiles.polling.config import MasterConfig

__all__ = ["SlaveLink", "CycleStats"]


class SlaveLink:
    """The master's view of one slave: polls sent (requests that reached the bus), answers and
    their response times (request SOF to response end, master's clock) and period jitter (max −
    min distance between the ends of answers to consecutive polls), timeouts (attempts
    without an answer in time), missed polls (all attempts of a transaction), the lost state with
    its periods, late answers (after the timeout, or from a lost slave between its slow polls),
    COS/cyclic messages consumed and acknowledged, and the COS/cyclic connection's time-outs (its
    watchdog, 4 × EPR) with their periods."""

    __slots__ = (
        "name",
        "polls",
        "responses",
        "timeouts",
        "missed",
        "in_a_row",
        "lost",
        "lost_cycle",
        "lost_periods",
        "response",
        "late",
        "cos",
        "acks",
        "last_end",
        "gap_min",
        "gap_max",
        "cos_lost",
        "cos_lost_periods",
    )

    def __init__(self, name: str) -> None:
        self.name = name
        self.polls = 0
        self.responses = 0
        self.timeouts = 0
        self.missed = 0
        self.in_a_row = 0
        self.lost = False
        self.lost_cycle = 0
        self.lost_periods: list[list[int | None]] = []
        self.response = ResponseStats()  # request SOF to answer end, bounded in memory
        self.late = 0
        self.cos = 0
        self.acks = 0
        self.last_end: int | None = None  # end of the last answer, if the poll before it was answered
        self.gap_min: int | None = None
        self.gap_max: int | None = None
        self.cos_lost = False
        self.cos_lost_periods: list[list[int | None]] = []

    def cos_lost_at(self, t: int) -> None:
        """The COS/cyclic connection timed out at ``t``."""
        self.cos_lost = True
        self.cos_lost_periods.append([t, None])

    def cos_back(self, t: int) -> None:
        """A message of the timed-out COS/cyclic connection came at ``t``."""
        self.cos_lost = False
        if self.cos_lost_periods and self.cos_lost_periods[-1][1] is None:
            self.cos_lost_periods[-1][1] = t

    def answered(self, t_end: int) -> None:
        """An answer ended at ``t_end``: the distance from the previous one (when that one answered
        the previous poll) makes the answers' period jitter."""
        if self.last_end is not None:
            gap = t_end - self.last_end
            self.gap_min = gap if self.gap_min is None else min(self.gap_min, gap)
            self.gap_max = gap if self.gap_max is None else max(self.gap_max, gap)
        self.last_end = t_end

    def due(self, cycle: int, every: int) -> bool:
        """Polled in this cycle: always, or every ``every`` cycles from the one it was lost in."""
        return not self.lost or (cycle - self.lost_cycle) % every == 0

    def figures(self) -> dict[str, Any]:
        """The link as JSON (ms)."""
        jitter = None if self.gap_min is None or self.gap_max is None else (self.gap_max - self.gap_min) / 1e6
        return {
            "polls": self.polls,
            "responses": self.responses,
            "timeouts": self.timeouts,
            "missed": self.missed,
            "lost": self.lost,
            "lost_ms": [
                [a / 1e6 if a is not None else None, b / 1e6 if b is not None else None] for a, b in self.lost_periods
            ],
            "late": self.late,
            "response_ms": self.response.stats_ms(),
            "jitter_ms": jitter,
            "cos": self.cos,
            "acks": self.acks,
            "cos_lost": self.cos_lost,
            "cos_lost_ms": [
                [a / 1e6 if a is not None else None, b / 1e6 if b is not None else None]
                for a, b in self.cos_lost_periods
            ],
        }


class CycleStats:
    """A master's cycles: the measured length of each (first request's SOF to the end of the last
    transaction) — of every cycle, and of the *clean* ones, in which every slave due answered in
    time (no timeout, no request the bus could not take), as `ResponseStats` (bounded in memory)
    — overruns, requests the bus could not take (``unsent``), the bus-time windows of the cycles
    that fall in ``plot_window`` (bus ns: what the poll-cycle plot draws), when bus off stopped
    the master, and per transaction the latest end of its request and of its last answer after
    the cycle's start (``offsets``)."""

    __slots__ = ("cycle_ns", "clean_ns", "overruns", "windows", "unsent", "offsets", "stopped_at", "plot_window")

    def __init__(self, config: MasterConfig, plot_window: tuple[int, int] | None = None) -> None:
        self.cycle_ns = ResponseStats()
        self.clean_ns = ResponseStats()
        self.plot_window = plot_window
        self.overruns = 0
        self.windows: list[tuple[int, int, bool]] = []  # (first SOF, end) bus ns, overrun
        self.unsent = 0
        self.offsets: dict[str, list[int]] = {t.request.name: [0, 0] for t in config.transactions}
        self.stopped_at: list[int] = []

    def request_end(self, name: str, after_start: int) -> None:
        """Transaction ``name``'s request ended ``after_start`` ns after its cycle started."""
        off = self.offsets[name]
        off[0] = max(off[0], after_start)

    def answers_end(self, name: str, after_start: int) -> None:
        """Transaction ``name``'s last answer ended ``after_start`` ns after its cycle started."""
        off = self.offsets[name]
        off[1] = max(off[1], after_start)

    def cycle(self, length: int, clean: bool, first_sof_bus: int | None, overrun: bool) -> None:
        """A cycle that ran at least one transaction ended, ``length`` ns after its first SOF."""
        self.cycle_ns.add(length)
        if clean:
            self.clean_ns.add(length)
        if first_sof_bus is not None:
            w = self.plot_window
            if w is None or (first_sof_bus + length >= w[0] and first_sof_bus <= w[1]):
                self.windows.append((first_sof_bus, first_sof_bus + length, overrun))

    def figures(self, cycles: int, state: str, events: list[Any]) -> dict[str, Any]:
        """cycles started, the measured cycle (min/mean/p99/max ms) of every cycle and of the clean
        ones, overruns, requests the bus could not take, the master's state, bus-off stops, and how
        many times each event happened."""
        counts: dict[str, int] = {}
        for e in events:
            counts[type(e).__name__] = counts.get(type(e).__name__, 0) + 1
        return {
            "cycles": cycles,
            "cycle_ms": self.cycle_ns.stats_ms(),
            "clean_cycle_ms": self.clean_ns.stats_ms(),
            "overruns": self.overruns,
            "unsent": self.unsent,
            "state": state,
            "stopped_ms": [t / 1e6 for t in self.stopped_at],
            "events": counts,
        }
