"""Diagnostics: UDS (ISO 14229-1) over ISO-TP (ISO 15765-2) on any stack node.

- ``dbc.diag.isotp``: `IsoTpChannel`, can-isotp's transport logic driven sans-IO by a node;
- ``dbc.diag.uds``: `UdsServer`, session control, tester present, read/write data by
  identifier, read and clear DTCs, ECU reset;
- ``dbc.diag.ecu``: `attach_uds`, a server whose DIDs are a DBC ECU's signals, with the active
  session (0xF186) and the VIN (0xF190);
- ``dbc.diag.client``: `SimConnection`, udsoncan's client on the simulated bus (imports
  udsoncan, which the server does not need).
"""

from .ecu import DEFAULT_VIN, DID_ACTIVE_SESSION, DID_VIN, attach_uds, signal_dids
from .isotp import IsoTpChannel
from .uds import NRC, DataIdentifier, Session, UdsServer

__all__ = [
    "IsoTpChannel",
    "UdsServer",
    "DataIdentifier",
    "Session",
    "NRC",
    "attach_uds",
    "signal_dids",
    "DID_ACTIVE_SESSION",
    "DID_VIN",
    "DEFAULT_VIN",
]
