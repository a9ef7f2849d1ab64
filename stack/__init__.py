"""canstack's software CAN controller and bus, in layers (see the README's architecture section):

- `stack.wire` — identifiers, the `Frame` type, CRC-15 and bit stuffing, the bit decoder;
- `stack.controller` — fault confinement, queues, filters, the node and its events, the node API;
- `stack.bus` — the simulated bus, bit-level attempts, fault injection, traces;
- `stack.phy` — bit timing, synchronisation, waveforms;
- `stack.io` — the python-can driver and interface, the real-time runner, `canstack serve`;
- `stack.cli` — the `canstack` command and the benchmark.

The names most programs need are importable from here (``from stack import SimBus, Frame``); they
load on first use, so ``import stack`` stays cheap. Modules that moved when the package was
split into layers keep working under their old names (``stack.sim``, ``stack.node``, …) with a
DeprecationWarning naming the new place.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings
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
}

# modules of the flat layout (before the layers) -> where they live now
MOVED = {
    "stack.frame": "stack.wire.frame",
    "stack.bits": "stack.wire.coding",
    "stack.events": "stack.controller.events",
    "stack.filters": "stack.controller.filters",
    "stack.queues": "stack.controller.queues",
    "stack.node": "stack.controller.node",
    "stack.sim": "stack.bus.sim",
    "stack.errors": "stack.bus.attempt",
    "stack.faults": "stack.bus.faults",
    "stack.trace": "stack.bus.trace",
    "stack.bittiming": "stack.phy.bittiming",
    "stack.sync": "stack.phy.sync",
    "stack.waveform": "stack.phy.waveform",
    "stack.driver": "stack.io.driver",
    "stack.pycan": "stack.io.pycan",
    "stack.serve": "stack.io.serve",
    "stack.commands": "stack.cli.demo",
}

# what else a flat module held: the modules its other names live in now (command registration and
# benchmarks moved to `stack.cli`) ...
ALSO = {
    "stack.bits": ("stack.wire.decoder",),
    "stack.bittiming": ("stack.cli.bittiming",),
    "stack.sync": ("stack.cli.sync",),
    "stack.waveform": ("stack.cli.waveform",),
    "stack.serve": ("stack.cli.serve",),
}
# ... and the names that changed on the way ("module:name")
RENAMED = {
    "stack.errors": {
        "ACTIVE_FLAG_DOMINANT_LIMIT": "stack.controller.confinement:DOMINANT_BITS_TOLERATED",
        "PASSIVE_FLAG_DOMINANT_LIMIT": "stack.controller.confinement:DOMINANT_BITS_TOLERATED",
    },
    "stack.pycan": {"benchmark": "stack.cli.bench_io:benchmark", "wire_limit_fps": "stack.cli.bench_io:wire_limit_fps"},
    "stack.serve": {"benchmark": "stack.cli.bench_io:serve_benchmark"},
    "stack.waveform": {"benchmark": "stack.cli.bench_io:decode_benchmark"},
    "stack.driver": {"run_demo_on_bus": "stack.cli.demo:run_demo_on_bus"},
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


class _MovedModules(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Import an old flat-layout module name as a stand-in that reads every attribute from the
    module's new place, with a DeprecationWarning (``stack.bits`` reads the decoder as well)."""

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> Any:
        if fullname in MOVED:
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec: Any) -> Any:
        return None  # a plain module, filled in by exec_module

    def exec_module(self, module: Any) -> None:
        name = module.__name__
        new = MOVED[name]
        warnings.warn(f"{name} moved to {new}; import it from there", DeprecationWarning, stacklevel=2)
        sources = [importlib.import_module(m) for m in (new, *ALSO.get(name, ()))]
        renamed = RENAMED.get(name, {})

        def __getattr__(attr: str) -> Any:
            if attr in renamed:
                where, real = renamed[attr].split(":")
                return getattr(importlib.import_module(where), real)
            for src in sources:
                if hasattr(src, attr):
                    return getattr(src, attr)
            raise AttributeError(f"module {name!r} (now {new}) has no attribute {attr!r}")

        module.__getattr__ = __getattr__
        module.__all__ = [n for src in sources for n in getattr(src, "__all__", ())] + list(renamed)


if not any(isinstance(f, _MovedModules) for f in sys.meta_path):
    sys.meta_path.insert(0, _MovedModules())  # before path finders: an old checkout's files never shadow it
