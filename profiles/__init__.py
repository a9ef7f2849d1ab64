"""Scheduling layers that plug in above a `stack` node.

Planned (each in its own module, driven only through the node API: send, timers, subscriptions):
native CSMA/CR, master/slave polling, TDMA (TTCAN-like, basic cycle and system matrix) and a
CANopen-like layer (NMT, heartbeat, SYNC, PDO, SDO, EMCY). Imports `stack`, never `dbc`.
"""
