"""DBC-driven applications: ECUs and rest-bus simulation built from a database (cantools).

- `Ecu` (``dbc.ecu``): a DBC node on a stack node — transmits its messages following the
  interaction layer, decodes what it receives, signal-level API with range checks;
- ``dbc.interaction``: the DBC attributes (GenMsgSendType, GenMsgCycleTime, ...) and what they
  mean here;
- ``dbc.checks``: alive counters, checksums (XOR, additive, CRC-8 SAE J1850, CRC-8H2F) and
  AUTOSAR E2E (through cantools) as pluggable hooks;
- `RestBus` (``dbc.restbus``): every node but the device under test, plus a decoding monitor;
  ``canstack restbus`` (``dbc.cli``);
- ``dbc.bench``: the ECU's transmit overhead against cantools' encode.

- ``dbc.scenario``: ``canstack scenario from-dbc``, a scheduling scenario from a DBC;

Sample databases live in ``dbc/databases/``. `dbc` builds on `stack` and on `profiles` (the
scenario format); `profiles` never imports `dbc` (an import-linter contract keeps it so).
"""

from pathlib import Path

from .checks import E2E, AliveCounter, Checksum
from .ecu import CheckFailed, Ecu, MessageReceived, SignalChanged
from .errors import ChoiceError, DbcError, DbcLoadError, SignalRangeError, UnknownNameError, load_database
from .interaction import MessageTiming, SendType
from .restbus import BusRecord, RestBus

DATABASES = Path(__file__).resolve().parent / "databases"
"""Folder of the sample databases (``powertrain_body.dbc``)."""

__all__ = [
    "Ecu",
    "RestBus",
    "BusRecord",
    "MessageReceived",
    "SignalChanged",
    "CheckFailed",
    "AliveCounter",
    "Checksum",
    "E2E",
    "MessageTiming",
    "SendType",
    "load_database",
    "DbcError",
    "DbcLoadError",
    "UnknownNameError",
    "SignalRangeError",
    "ChoiceError",
    "DATABASES",
]
