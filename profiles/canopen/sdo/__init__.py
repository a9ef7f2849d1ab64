"""SDO: the service data object (CiA 301 7.2.4) — the server of a device (`server`, with block
transfer in `block`), a sans-IO client for the master (`client`) and the abort codes (`abort`)."""
