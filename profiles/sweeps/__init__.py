"""Many runs: parameter sweeps over a scenario's keys and the classic studies, on one process,
a process pool or a Dask cluster.

- `profiles.sweeps.sweep` — varied keys, the runs they make, one row of metrics per run;
- `profiles.sweeps.execute` — where the runs go (sequential, processes, Dask);
- `profiles.sweeps.random_sets` — random message sets (UUniFast, log-uniform periods);
- `profiles.sweeps.converters` — a message set in each profile's terms;
- `profiles.sweeps.schedulability` — the schedulability study;
- `profiles.sweeps.comparison` — the profiles study (one set under every profile);
- `profiles.sweeps.bounds` — the bounds study: the analysis against simulation on random
  networks (`profiles.sweeps.networks`) released in several patterns (`profiles.sweeps.releases`);
- `profiles.sweeps.plots`, `profiles.sweeps.cli` — their plots and ``canstack sweep`` /
  ``canstack study`` (``study bounds`` in `profiles.sweeps.bounds_cli`, the options both share in
  `profiles.sweeps.options_cli`);
  `profiles.sweeps.bench` — the speed figures of the runner and the sweeps.

The sweeps build on the experiment pipeline (`profiles.pipeline`), never the reverse.
"""
