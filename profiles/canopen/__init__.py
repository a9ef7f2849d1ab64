"""A CANopen-like profile (CiA 301): devices with CANopenNode's behaviour and a master, sans-IO
on a `stack` node, which the ``canopen`` library can drive.

- `CanopenDevice` (`profiles.canopen.device`): an NMT slave with its object dictionary from an
  EDS/DCF (through ``canopen.objectdictionary.import_od``), NMT, heartbeat and node guarding,
  SYNC, TPDOs of every transmission type, RPDOs, SDO server with block transfer, EMCY, TIME.
- `CanopenMaster` (`profiles.canopen.master`): boots a network (boot-up, SDO configuration,
  start), produces SYNC, consumes heartbeats, measures SYNC-to-PDO latency.

One module per service, as the ``canopen`` library does: `nmt` (with the transition table in
`_state`), `heartbeat`, `guarding`, `sync`, `emcy`, `timestamp`, `pdo` (`mapping`, `common`,
`tpdo`, `rpdo`), `sdo` (`server`, `block`, `client`, `abort`); `dictionary` holds the values,
`cob` the pre-defined connection set, `options` the constructor options, `cli` the
``canstack canopen`` command, `kind` the profiles scenario files name (``profile = "canopen"``,
``"canopen-master"``).
"""

from profiles.canopen.device import CanopenDevice, RpdoUpdate
from profiles.canopen.dictionary import DEFAULT_EDS, EdsError
from profiles.canopen.master import CanopenMaster
from profiles.canopen.sdo.abort import SdoAbort

__all__ = ["CanopenDevice", "CanopenMaster", "RpdoUpdate", "EdsError", "SdoAbort", "DEFAULT_EDS"]
