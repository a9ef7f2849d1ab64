"""ISO-TP (ISO 15765-2) on a stack node: can-isotp's transport logic, driven sans-IO.

`IsoTpChannel` runs ``isotp.TransportLayerLogic`` (the can-isotp package: segmentation, flow
control, block size, STmin, timeouts — not written again here) on a node of the node API: frames
it receives come from a subscription filtered on the receive identifier, frames it sends go out
through ``node.send``, and its ``process()`` runs when something happens (a frame arrives, a frame
was sent, a timer of the logic expires) — never in a loop or a thread.

can-isotp measures its timers with the process's performance counter. Here they run on the
node's clock instead (`NodeClockTimer`), so that on the simulated bus STmin and the N_Bs/N_Cr
timeouts are simulated time, and the same channel runs on a python-can bus on the wall clock.
The separation time runs from the end of a consecutive frame on the bus (its `TxDone`), as ISO
15765-2 defines STmin, not from the moment it was queued.
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable
from typing import Any

import isotp
from isotp.tools import Timer

from stack import Frame, NodeAPI, Received, TxDone, TxFailed

__all__ = ["IsoTpChannel", "NodeClockTimer"]


class NodeClockTimer(Timer):
    """A can-isotp `Timer` on a node's clock (ns), held while ``hold()`` says so (the frame it
    times from has not left the controller yet)."""

    def __init__(self, timeout: float, clock: Callable[[], int], hold: Callable[[], bool] = lambda: False) -> None:
        self._clock = clock
        self._hold = hold
        super().__init__(timeout)

    def start(self, timeout: float | None = None) -> None:
        """Start (or restart) the timer now, optionally with a new timeout in seconds."""
        if timeout is not None:
            self.set_timeout(timeout)
        self.start_time = self._clock()

    def elapsed_ns(self) -> int:
        """Nanoseconds of the node's clock since `start` (0 when stopped)."""
        if self.start_time is None:
            return 0
        return self._clock() - self.start_time

    def elapsed(self) -> float:
        """Seconds of the node's clock since `start`."""
        return self.elapsed_ns() / 1e9

    def is_timed_out(self) -> bool:
        """Expired (never while held)."""
        if self.is_stopped() or self._hold():
            return False
        return self.elapsed_ns() > self.timeout or self.timeout == 0


class IsoTpChannel:
    """One ISO-TP connection on ``node``: receives on ``rx_id``, sends on ``tx_id`` (11-bit
    unless ``extended``), normal addressing, classical CAN frames padded to 8 bytes with
    ``padding`` (None: no padding). ``on_pdu(data)`` is called with each complete PDU received.

    ``stmin_ms`` and ``block_size`` are what this side asks its peer for in its flow-control
    frames (STmin in ms, 0..127; block size 0 = no limit); other can-isotp parameters go in
    ``params``. `send` queues a PDU; its frames go out as the peer's flow control allows.
    """

    def __init__(
        self,
        node: NodeAPI,
        rx_id: int,
        tx_id: int,
        on_pdu: Callable[[bytes], Any],
        *,
        extended: bool = False,
        stmin_ms: int = 0,
        block_size: int = 0,
        padding: int | None = 0xCC,
        params: dict[str, Any] | None = None,
    ) -> None:
        self.node = node
        self.rx_id = rx_id
        self.tx_id = tx_id
        self.extended = extended
        self.on_pdu = on_pdu
        self.errors: list[str] = []
        self._rx: deque[isotp.CanMessage] = deque()
        self._inflight: set[int] = set()
        self._requests: list[Any] = []  # kept until done, so that their ids stay unique
        self._wake: Any = None
        self._running = False
        self._again = False
        p: dict[str, Any] = {
            "stmin": stmin_ms,
            "blocksize": block_size,
            "tx_padding": padding,
            "tx_data_min_length": 8 if padding is not None else None,
            "blocking_send": False,
        }
        p.update(params or {})
        mode = isotp.AddressingMode.Normal_29bits if extended else isotp.AddressingMode.Normal_11bits
        self.logic = isotp.TransportLayerLogic(
            rxfn=self._rxfn,
            txfn=self._txfn,
            address=isotp.Address(mode, txid=tx_id, rxid=rx_id),
            error_handler=self._error,
            params=p,
        )
        self._retime()
        mask = 0x1FFFFFFF if extended else 0x7FF
        self._sub = node.subscribe(self._on_frame, [{"can_id": rx_id, "can_mask": mask, "extended": extended}])
        node.listen(TxDone, self._on_done)
        node.listen(TxFailed, self._on_done)

    # ------------------------------------------------------------------ the logic's I/O
    def _rxfn(self, timeout: float) -> isotp.CanMessage | None:
        return self._rx.popleft() if self._rx else None

    def _txfn(self, msg: isotp.CanMessage) -> None:
        req = self.node.send(Frame(msg.arbitration_id, bytes(msg.data), extended=msg.is_extended_id))
        self._inflight.add(id(req))
        self._requests.append(req)

    def _error(self, exc: Exception) -> None:
        self.errors.append(f"{type(exc).__name__}: {exc}")

    def _retime(self) -> None:
        """Put every timer of the logic on the node's clock: can-isotp makes new ones as it
        goes (a new flow-control or consecutive-frame timer per block), started at this instant
        of the node's clock when made inside `process`."""
        logic = self.logic
        now = self.node.now
        for name in ("timer_rx_fc", "timer_rx_cf", "timer_tx_stmin"):
            old = getattr(logic, name)
            if isinstance(old, NodeClockTimer):
                continue
            hold = self._held if name == "timer_tx_stmin" else (lambda: False)
            new = NodeClockTimer(old.timeout / 1e9, now, hold)
            if old.start_time is not None:
                new.start_time = now()
            setattr(logic, name, new)

    def _held(self) -> bool:
        return bool(self._inflight)

    # ------------------------------------------------------------------ events
    def _on_frame(self, ev: Received) -> None:
        f = ev.frame
        if f.remote:
            return
        self._rx.append(
            isotp.CanMessage(arbitration_id=f.can_id, data=bytes(f.data), extended_id=f.extended, dlc=len(f.data))
        )
        self.process()

    def _on_done(self, ev: TxDone | TxFailed) -> None:
        key = id(ev.request)
        if key not in self._inflight:
            return
        self._inflight.discard(key)
        self._requests = [r for r in self._requests if id(r) != key]
        stmin = self.logic.timer_tx_stmin
        if not self._inflight and stmin.start_time is not None:
            stmin.start_time = self.node.now()  # STmin counts from the end of the frame on the bus
        self.process()

    # ------------------------------------------------------------------ driving
    def send(self, data: bytes) -> None:
        """Queue one PDU (up to 4095 bytes) for transmission."""
        self.logic.send(bytes(data))
        self.process()

    def process(self) -> None:
        """Run the transport logic now, hand every complete PDU to ``on_pdu``, and wake again
        when a timer of the logic needs it."""
        if self._running:  # a frame sent from inside process() completes synchronously on some drivers
            self._again = True
            return
        self._running = True
        try:
            self._again = True
            while self._again:
                self._again = False
                self.logic.process()
                self._retime()
                while True:
                    pdu = self.logic.recv()
                    if pdu is None:
                        break
                    self.on_pdu(bytes(pdu))
        finally:
            self._running = False
        self._schedule()

    def _schedule(self) -> None:
        """A timer at the next instant the logic has something to do by itself: the end of
        STmin before the next consecutive frame, or a flow-control / consecutive-frame
        timeout."""
        if self._wake is not None:
            self._wake.cancel()
            self._wake = None
        logic = self.logic
        due: list[int] = []
        if logic.is_tx_transmitting_cf() and not self._inflight:
            due.append(logic.timer_tx_stmin.remaining_ns() + 1)  # is_timed_out: strictly after
        for t in (logic.timer_rx_fc, logic.timer_rx_cf):
            if not t.is_stopped():
                due.append(t.remaining_ns() + 1)
        if due:
            self._wake = self.node.call_later(max(0, min(due)), self._woken)

    def _woken(self) -> None:
        self._wake = None
        self.process()

    def close(self) -> None:
        """Stop receiving and cancel the channel's timer."""
        self._sub.unsubscribe()
        self.node.unlisten(TxDone, self._on_done)
        self.node.unlisten(TxFailed, self._on_done)
        if self._wake is not None:
            self._wake.cancel()
            self._wake = None
