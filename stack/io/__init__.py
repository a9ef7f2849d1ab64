"""Nodes and buses outside the process: the python-can driver (`driver`), the python-can
interface plugin (`pycan`; messages and frames in `pycan_frames`, channels in `pycan_channel`, the
receive side in `pycan_inbox`) and `canstack serve` (`serve`: protocol, server, client), both
built on a client's node on a real-time simulated bus (`port`, `runner`); `discovery` lets a
process see the buses served on its machine."""
