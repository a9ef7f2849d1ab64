"""The experiment pipeline: a scenario file read into the declarations of the profile contract,
run on the simulated bus or a python-can bus, measured, analysed and plotted.

- `profiles.pipeline.scenario` — scenario files (TOML) read and checked into
  `profiles.declarations`;
- `profiles.pipeline.faults` — the ``[[faults]]`` kinds: their keys, checks and injection;
- `profiles.pipeline.runner` — run a scenario, collect a `Result`;
- `profiles.pipeline.metrics` — the metrics and the response-time analysis beside them;
- `profiles.pipeline.plots` — timeline, response times, bus load (the ``plot`` extra);
- `profiles.pipeline.cli` — ``canstack experiment``.

The pipeline imports the profile contract and finds the protocols through the registry; the
protocols never import it (an import-linter contract keeps it so).
"""
