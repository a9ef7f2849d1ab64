"""canstack's software CAN controller and bus, in layers (see the architecture page of the docs):

- `stack.wire` — identifiers, the `Frame` type, CRC-15 and bit stuffing, the bit decoder;
- `stack.controller` — fault confinement, queues, filters, the node and its events, the node API;
- `stack.bus` — the simulated bus, bit-level attempts, fault injection, traces;
- `stack.phy` — bit timing, synchronisation, waveforms;
- `stack.io` — python-can: the driver and interface, messages and trace files, the real-time
  runner, `canstack serve`;
- `stack.cli` — the `canstack` command and the benchmark.

The names most programs need are importable from here (``from stack import SimBus, Frame``): they
are the public API (`__all__`, listed in the API reference), and they load on first use, so
``import stack`` stays cheap. Everything else is imported from the module that defines it.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = [
    "Frame",
    "arbitration_key",
    "data_length",
    "Node",
    "NodeAPI",
    "NodeError",
    "QueueFull",
    "TxRequest",
    "RequestState",
    "Timer",
    "Subscription",
    "PeriodicTask",
    "LocalClock",
    "ErrorState",
    "Received",
    "TxDone",
    "TxFailed",
    "ArbitrationLost",
    "ErrorStateChanged",
    "SimBus",
    "TraceRecord",
    "FaultInjector",
    "PyCanDriver",
    "to_message",
    "save_trace",
]

# public name -> module that defines it
_EXPORTS = {
    "Frame": "stack.wire.frame",
    "arbitration_key": "stack.wire.frame",
    "data_length": "stack.wire.frame",
    "Node": "stack.controller.node",
    "NodeError": "stack.controller.exceptions",
    "Timer": "stack.controller.contract",
    "Subscription": "stack.controller.node",
    "PeriodicTask": "stack.controller.periodic",
    "ErrorState": "stack.controller.confinement",
    "LocalClock": "stack.controller.clock",
    "NodeAPI": "stack.controller.api",
    "QueueFull": "stack.controller.exceptions",
    "TxRequest": "stack.controller.queues",
    "RequestState": "stack.controller.queues",
    "Received": "stack.controller.events",
    "TxDone": "stack.controller.events",
    "TxFailed": "stack.controller.events",
    "ArbitrationLost": "stack.controller.events",
    "ErrorStateChanged": "stack.controller.events",
    "SimBus": "stack.bus.sim",
    "TraceRecord": "stack.bus.trace",
    "FaultInjector": "stack.bus.faults",
    "PyCanDriver": "stack.io.driver",
    "to_message": "stack.io.message",
    "save_trace": "stack.io.tracefile",
}


def __getattr__(name: str) -> Any:
    """Load a public name from its layer on first use (PEP 562)."""
    mod = _EXPORTS.get(name)
    if mod is None:
        raise AttributeError(f"module 'stack' has no attribute {name!r}")
    value = getattr(importlib.import_module(mod), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
