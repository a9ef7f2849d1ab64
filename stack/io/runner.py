"""The simulated bus in real time on its own thread, and the registry of such buses in this
process (shared by the python-can interface `stack.io.pycan` and the server `stack.io.serve`)."""

from __future__ import annotations

import logging
import re
import threading
import time
from collections import deque
from collections.abc import Callable
from typing import Any

import can

from stack.bus.sim import SimBus
from stack.io.clock import clock_pair

__all__ = [
    "RealTimeRunner",
    "acquire_runner",
    "release_runner",
    "running_buses",
    "get_runner",
    "BUS_NAME_RE",
    "DEFAULT_BITRATE",
    "DEFAULT_DATA_BITRATE",
    "fd_capable_bus",
    "SLICE_NS",
    "BUDGET_NS",
]

LOG = logging.getLogger("stack.io.runner")

DEFAULT_BITRATE = 500_000
DEFAULT_DATA_BITRATE = 2_000_000
"""The data bit rate of a CAN FD bus opened with fd=True and none given (a common 500 k/2 M bus)."""
SLICE_NS = 5_000_000
"""Bus time the runner simulates in one step while it catches up with the wall clock."""
BUDGET_NS = 20_000_000
"""Most wall time the runner spends catching up before it runs the commands waiting (joins,
sends, time requests): a bus that cannot keep up with real time still answers, and says how far
behind it is. A bus that is only late because its thread did not run for a while (a loaded
machine) catches up within it, so its commands still happen at the time they were posted."""
BUS_NAME_RE = re.compile(r"^[A-Za-z0-9_.\-]{1,64}$")
"""A bus or node name: 1..64 letters, digits, '_', '.' or '-' (it appears in channel URLs)."""


class RealTimeRunner:
    """A `SimBus` paced to the wall clock on its own thread.

    The loop advances the engine to the wall clock (``bus.run(until=wall_ns)``, in steps of
    `SLICE_NS` for at most `BUDGET_NS` of wall time), runs the commands posted by other threads before that clock was read, lets
    arbitration that became due start, lets each attached port mirror its node's error state,
    and sleeps until the engine's next event (``bus.next_event_time()``) or until a command
    wakes it. ``behind_ns`` says how far the bus is behind real time after the last step.

    A port (`stack.io.port.Port`) is anything with ``mirror_state()`` (called on the runner
    thread after each step) and ``closed_by_runner(reason)`` (called if the engine fails).
    """

    def __init__(self, name: str, bitrate: int, data_bitrate: int | None = None) -> None:
        self.name = name
        self.sim = fd_capable_bus(bitrate, data_bitrate, name)
        self.bitrate = bitrate
        self.data_bitrate = data_bitrate  # None: a classical bus (no CAN FD frames)
        self._cmds: deque[Callable[[], Any]] = deque()
        self._wake = threading.Event()
        self._stop = False
        self._ports: list[Any] = []
        self.t0_ns, self.epoch0 = clock_pair()
        self.max_lag_ns = 0
        self.behind_ns = 0  # how far the bus is behind real time (0 when it keeps up)
        self._thread = threading.Thread(target=self._loop, name=f"canstack-{name}", daemon=True)
        self._thread.start()

    def now_ns(self) -> int:
        """Wall-clock ns since the bus started (the virtual clock it is paced to)."""
        return time.monotonic_ns() - self.t0_ns

    def post(self, fn: Callable[[], Any]) -> None:
        """Run ``fn()`` on the runner thread soon (thread-safe)."""
        self._cmds.append(fn)
        self._wake.set()

    def call(self, fn: Callable[[], Any], timeout: float = 5.0) -> Any:
        """Run ``fn()`` on the runner thread and return its result (or raise its exception)."""
        if threading.current_thread() is self._thread:
            return fn()
        done = threading.Event()
        box: list[Any] = [None, None]

        def run() -> None:
            try:
                box[0] = fn()
            except BaseException as exc:  # handed to the caller
                box[1] = exc
            done.set()

        self.post(run)
        if not done.wait(timeout):
            raise can.CanOperationError(f"canstack bus {self.name!r} did not answer within {timeout} s")
        if box[1] is not None:
            raise box[1]
        return box[0]

    def add_port(self, port: Any) -> None:
        """Have ``port`` mirror its node's state after each step (runner thread only)."""
        # the list is replaced, never changed in place: a port may leave from inside the loop
        # that walks it (a session closed from its own state callback)
        self._ports = [*self._ports, port]

    def remove_port(self, port: Any) -> None:
        """Stop mirroring ``port`` (runner thread only; a port not attached is ignored)."""
        self._ports = [p for p in self._ports if p is not port]

    def stop(self) -> None:
        """End the loop after the commands already posted."""
        self._stop = True
        self._wake.set()

    def join(self, timeout: float | None = None) -> None:
        """Wait for the runner thread to end."""
        self._thread.join(timeout)

    def _loop(self) -> None:
        sim = self.sim
        cmds = self._cmds
        wake = self._wake
        mono = time.monotonic_ns
        t0 = self.t0_ns
        try:
            while True:
                # the commands posted before the clock is read run after the bus reached that
                # time: a frame is never queued at a bus time before it was sent (a thread
                # preempted in the middle of `sim.run` would otherwise queue it in the past)
                waiting = len(cmds)
                now = mono() - t0
                if now > sim.now():
                    nxt = sim.next_event_time()
                    if nxt < now and now - nxt > self.max_lag_ns:
                        self.max_lag_ns = int(now - nxt)
                    spent = mono()
                    while sim.now() < now:
                        sim.run(until=min(now, sim.now() + SLICE_NS))
                        if mono() - spent > BUDGET_NS:
                            break  # behind real time for good: answer the commands first
                self.behind_ns = max(0, now - sim.now())
                if waiting:
                    for _ in range(waiting):
                        try:
                            cmds.popleft()()
                        except Exception:  # a command must never stop the bus
                            LOG.exception("canstack bus %r: command failed", self.name)
                    sim.run(until=sim.now())  # arbitration that became due now
                for p in self._ports:
                    p.mirror_state()
                if self._stop and not cmds:
                    break
                if cmds or self.behind_ns:
                    continue
                nxt = sim.next_event_time()
                delay = (nxt - (mono() - t0)) / 1e9 if nxt != float("inf") else 0.5
                if delay > 0:
                    wake.wait(min(delay, 0.5))
                wake.clear()
        except Exception:  # pragma: no cover - an engine failure is logged, the buses see shutdown
            LOG.exception("canstack bus %r: engine failure, the bus stops", self.name)
            for p in list(self._ports):
                p.closed_by_runner("engine failure (see log)")


def fd_capable_bus(bitrate: int, data_bitrate: int | None, name: str) -> SimBus:
    """The simulated bus of a runner: classical, or CAN FD with ``data_bitrate`` when the engine
    carries FD frames (`SimBus` takes a data bit rate); ValueError saying why not otherwise."""
    if data_bitrate is None:
        return SimBus(bitrate, name=name, record=False)
    try:
        return SimBus(bitrate, name=name, record=False, data_bitrate=data_bitrate)  # type: ignore[call-arg]
    except TypeError:
        raise ValueError(
            f"data_bitrate {data_bitrate}: this canstack's simulated bus carries CAN 2.0 frames only (no CAN FD "
            "data phase yet); open the bus without fd=True"
        ) from None


_REGISTRY: dict[str, tuple[RealTimeRunner, int]] = {}
_REGISTRY_LOCK = threading.Lock()


def running_buses() -> dict[str, int]:
    """Buses running in this process: name -> bitrate."""
    with _REGISTRY_LOCK:
        return {name: r.bitrate for name, (r, _) in _REGISTRY.items()}


def get_runner(name: str) -> RealTimeRunner | None:
    """The runner of the in-process bus ``name``, or None when no such bus runs."""
    with _REGISTRY_LOCK:
        entry = _REGISTRY.get(name)
        return entry[0] if entry is not None else None


def acquire_runner(name: str, bitrate: int | None, data_bitrate: int | None = None, fd: bool = False) -> RealTimeRunner:
    """The in-process bus ``name``, started at ``bitrate`` (default 500000) by its first user,
    a CAN FD bus with ``data_bitrate`` when that user asks for ``fd`` (default
    `DEFAULT_DATA_BITRATE`).

    Each call takes a reference that `release_runner` gives back; the bus stops when the last
    one is released. `can.CanInitializationError` when the bus runs at another bit rate, or
    without the data phase an ``fd`` user needs. A user without ``fd`` may join an FD bus (its
    interface shows it no FD frames, as SocketCAN without CAN_RAW_FD_FRAMES).
    """
    with _REGISTRY_LOCK:
        entry = _REGISTRY.get(name)
        if entry is not None:
            runner, refs = entry
            if fd and data_bitrate is None:
                data_bitrate = runner.data_bitrate  # joins at the bus's rate, whatever it is
            if bitrate is not None and bitrate != runner.bitrate:
                raise can.CanInitializationError(
                    f"canstack bus {name!r} runs at {runner.bitrate} bit/s; a node cannot join it at "
                    f"{bitrate} bit/s (every node on a CAN bus uses the same bitrate)"
                )
            if fd and runner.data_bitrate is None:
                raise can.CanInitializationError(
                    f"canstack bus {name!r} was opened without fd=True: it carries no CAN FD frames"
                )
            if fd and data_bitrate != runner.data_bitrate:
                raise can.CanInitializationError(
                    f"canstack bus {name!r} runs its data phase at {runner.data_bitrate} bit/s; a node cannot join "
                    f"it at {data_bitrate} bit/s"
                )
            _REGISTRY[name] = (runner, refs + 1)
            return runner
        if fd and data_bitrate is None:
            data_bitrate = DEFAULT_DATA_BITRATE
        try:
            runner = RealTimeRunner(name, bitrate or DEFAULT_BITRATE, data_bitrate if fd else None)
        except ValueError as exc:
            raise can.CanInitializationError(str(exc)) from None
        _REGISTRY[name] = (runner, 1)
        return runner


def release_runner(runner: RealTimeRunner) -> None:
    """Give back a reference taken by `acquire_runner`; the last one stops the bus."""
    with _REGISTRY_LOCK:
        entry = _REGISTRY.get(runner.name)
        if entry is None or entry[0] is not runner:
            return
        refs = entry[1] - 1
        if refs > 0:
            _REGISTRY[runner.name] = (runner, refs)
            return
        del _REGISTRY[runner.name]
    runner.stop()
