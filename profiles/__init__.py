"""Scheduling layers above a `stack` node, and the experiments that compare them.

- `profiles.base` — the profile contract: base class, context, message sources, the recorder;
- `profiles.csma` — native CSMA/CR (plain CAN arbitration);
- `profiles.pipeline.scenario` — scenario files (TOML), checked; `profiles.schema` — their typed tables;
- `profiles.registry` — the profiles scenario files can name;
- `profiles.pipeline.runner` — run a scenario on the simulated bus or a python-can bus;
- `profiles.pipeline.metrics` — the metrics and the response-time analysis beside them;
- `profiles.analysis.rta` — CAN schedulability analysis (Davis, Burns, Bril, Lukkien 2007);
- `profiles.pipeline.plots` — timeline, response times, bus load (the ``plot`` extra).

Profiles act only through the node API (`stack.NodeAPI`), so they run unchanged on the
simulated bus and on any python-can bus. `profiles` imports `stack`, never `dbc`.
"""
