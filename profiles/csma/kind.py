"""What CSMA/CR adds to scenario files: ``profile = "csma"`` (the default), its one node key
(``tdma_gated``) and its worst-case traffic for the response-time analysis."""

from __future__ import annotations

from typing import TYPE_CHECKING

from profiles.csma.profile import CsmaProfile, message_specs
from profiles.registry import ProfileKind
from profiles.schema import Key

if TYPE_CHECKING:  # pragma: no cover
    from profiles.analysis.rta import MessageSpec
    from profiles.base import Context
    from profiles.declarations import NodeDecl, Scenario
    from stack import NodeAPI

__all__ = ["CSMA", "KINDS"]


def _build(node: NodeAPI, decl: NodeDecl, context: Context) -> CsmaProfile:
    return CsmaProfile(node, decl, context)


def _traffic(decl: NodeDecl, scenario: Scenario) -> list[MessageSpec]:
    return message_specs(decl, exact=scenario.analysis.get("stuffing") == "exact")


CSMA = ProfileKind(
    name="csma",
    build=_build,
    traffic=_traffic,
    node_keys={
        "tdma_gated": Key(
            bool,
            True,
            doc="on a bus with a TDMA schedule: send only inside its arbitrating windows (false: ungated)",
        )
    },
    description="native CSMA/CR (plain CAN arbitration)",
    fd_messages=True,
)
"""``profile = "csma"``: plain CAN arbitration."""

KINDS = (CSMA,)
"""The kinds this package adds (the registry reads them: see `profiles.registry`)."""
