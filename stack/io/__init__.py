"""Nodes and buses outside the process: the python-can driver, the python-can interface plugin
with its real-time runner, and `canstack serve` (one simulated bus shared by processes)."""
