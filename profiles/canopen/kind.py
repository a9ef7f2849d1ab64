"""CANopen devices and masters in scenario files: ``profile = "canopen"`` (a `CanopenDevice`)
and ``profile = "canopen-master"`` (a `CanopenMaster`).

    [[nodes]]
    name = "io1"
    profile = "canopen"
    node_id = 1
    eds = "my_device.eds"        # optional: the default device when absent
    [nodes.canopen]              # device options (profiles.canopen.options.DeviceOptions)
    heartbeat_ms = 100
    sync_window_us = 600
    [nodes.canopen.tpdo.1]
    transmission_type = 1

    [[nodes]]
    name = "plc"
    profile = "canopen-master"
    [nodes.canopen]              # master options (MasterOptions)
    nodes = [1, 2, 3]
    sync_period_us = 1000
    heartbeat_consumer_ms = 250

The options are checked when the scenario is read (one line naming the file, the node and the
rule), the EDS loaded then too; the JSON result gains ``canopen``: per node the NMT state at
the end, heartbeats sent and missed, and per PDO the SYNC-to-reception latency (min/mean/p99/max)
and the PDOs not sent inside the synchronous window.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from profiles.base import Profile
from profiles.canopen.device import CanopenDevice
from profiles.canopen.master import CanopenMaster
from profiles.canopen.options import DeviceOptions, MasterOptions
from profiles.canopen.text import canopen_lines
from profiles.registry import ProfileKind
from profiles.schema import Key, ScenarioError, in_range, where

if TYPE_CHECKING:  # pragma: no cover
    from profiles.base import Context
    from profiles.declarations import NodeDecl, Scenario
    from stack import NodeAPI

__all__ = ["CanopenDeviceProfile", "CanopenMasterProfile", "DEVICE", "MASTER", "KINDS"]


class CanopenDeviceProfile(Profile):
    """A `CanopenDevice` as a scenario profile: built from the node's table, started with the
    others, summarised by its metrics."""

    kind = "canopen"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        super().__init__(node, decl, context)
        self.device = CanopenDevice(node, decl.options["node_id"], decl.options["eds"], **decl.options["canopen"])

    def start(self) -> None:
        """Boot the device (boot-up message, pre-operational)."""
        self.device.start()

    def summary(self) -> dict[str, Any]:
        """The device's metrics."""
        return self.device.metrics()


class CanopenMasterProfile(Profile):
    """A `CanopenMaster` as a scenario profile (NMT master, SYNC producer, heartbeat consumer)."""

    kind = "canopen-master"

    def __init__(self, node: NodeAPI, decl: NodeDecl, context: Context) -> None:
        super().__init__(node, decl, context)
        self.master = CanopenMaster(node, **decl.options["canopen"])

    def start(self) -> None:
        """Start the master: wait for boot-ups, configure, start the nodes, produce SYNC."""
        self.master.start()

    def summary(self) -> dict[str, Any]:
        """The master's metrics."""
        return self.master.metrics()


def _check(scenario: Scenario, tables: dict[str, Any]) -> None:
    """Check every CANopen node's options now, so that a bad one is a one-line error before the
    run; node-IDs are unique on a bus."""
    seen: dict[int, str] = {}
    for i, d in enumerate(scenario.nodes, 1):
        if d.profile not in ("canopen", "canopen-master"):
            continue
        loc = where(scenario.source, f"[[nodes]] #{i} {d.name!r}")
        if d.messages:
            raise ScenarioError(
                f"{loc}: messages: a {d.profile} node sends what CiA 301 says (PDOs, SDO, NMT, "
                "heartbeat): configure its PDOs in [nodes.canopen] instead"
            )
        try:
            if d.profile == "canopen":
                nid = d.options["node_id"]
                if nid in seen:
                    raise ScenarioError(
                        f"{loc}: node_id: {nid} is already node {seen[nid]!r}'s (node-IDs are "
                        "unique on a CANopen network)"
                    )
                seen[nid] = d.name
                DeviceOptions.parse(d.options["canopen"])
                if d.options["eds"] is not None:
                    from profiles.canopen.dictionary import load_od

                    def warn(w: str, loc: str = loc) -> None:
                        scenario.warnings.append(f"{loc}: eds: {w}")

                    load_od(d.options["eds"], nid, warn=warn)
            else:
                MasterOptions.parse(d.options["canopen"])
        except ScenarioError:
            raise
        except (ValueError, OSError) as exc:
            raise ScenarioError(f"{loc}: canopen: {exc}") from None


def _summarize(profiles: list[Profile], context: Context) -> dict[str, Any]:
    return {p.decl.name: p.summary() for p in profiles}


def _text(figures: dict[str, Any]) -> list[str]:
    """Every figure of the ``canopen`` result as tables (`profiles.canopen.text.canopen_lines`)."""
    return canopen_lines(figures)


_DEVICE_KEYS = {
    "node_id": Key(int, doc="CiA 301 node-ID 1..127", rule=in_range(1, 127, "CiA 301 node-ID")),
    "eds": Key(str, None, doc="EDS/DCF file (default: the shipped default device)"),
    "canopen": Key(dict, {}, doc="device options (heartbeat_ms, sync_window_us, tpdo, rpdo, values, ...)"),
}

_FD_NOTE = (
    "CANopen FD (CiA 1301) is out of scope: canopen nodes send classical CAN frames (CiA 301); an FD-enabled "
    "controller is fd = 'fd'"
)

DEVICE = ProfileKind(
    name="canopen",
    build=CanopenDeviceProfile,
    node_keys=_DEVICE_KEYS,
    timed_messages=False,
    parse=_check,
    result_key="canopen",
    summarize=_summarize,
    text=_text,
    description="CiA 301 device (NMT, heartbeat, SYNC, PDO, SDO, EMCY)",
    fd_note=_FD_NOTE,
)
"""``profile = "canopen"``: a `CanopenDevice` on the node."""

MASTER = ProfileKind(
    name="canopen-master",
    build=CanopenMasterProfile,
    node_keys={"canopen": Key(dict, {}, doc="master options (nodes, sync_period_us, heartbeat_consumer_ms, ...)")},
    timed_messages=False,
    result_key="canopen",
    summarize=_summarize,
    description="CiA 301 NMT master, SYNC producer, heartbeat consumer",
    fd_note=_FD_NOTE,
)
"""``profile = "canopen-master"``: a `CanopenMaster` on the node."""

KINDS = (DEVICE, MASTER)
"""The kinds this package adds (the registry reads them: see `profiles.registry`)."""
