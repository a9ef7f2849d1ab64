"""Scheduling layers above a `stack` node, and the experiments that compare them.

The package is laid out the way the work flows (DESIGN.md, "Profiles: the contract"):

- the profile contract — `profiles.base` (the `Profile` base class, its `Context`, message
  sources, the one `Recorder`), `profiles.registry` (`ProfileKind`: what a profile adds to
  scenario files), `profiles.declarations` (the node, message and scenario declarations a
  profile is built from), `profiles.schema` (typed scenario keys and their errors) and
  `profiles.message_set` (a plain message set);
- the protocols, each a package that imports the contract only: `profiles.csma` (native
  CSMA/CR), `profiles.polling` (master/slave), `profiles.tdma` (TTCAN-like), `profiles.canopen`
  (CiA 301 devices and master); `profiles.analysis` (CAN response-time analysis, Davis et al.
  2007, with FIFO and mailbox bounds; priority assignment);
- `profiles.pipeline` — the experiment pipeline: scenario files read, run on the simulated bus or
  a python-can bus, measured, analysed, plotted (``canstack experiment``);
- `profiles.sweeps` — many runs: parameter sweeps and the classic studies (``canstack sweep``,
  ``canstack study``).

Arrows go pipeline → contract ← protocols, and sweeps → pipeline; import-linter contracts in
pyproject.toml keep them. Profiles act only through the node API (`stack.NodeAPI`), so they run
unchanged on the simulated bus and on any python-can bus. `profiles` imports `stack`, never `dbc`.

The names users import are importable from here (``from profiles import load_scenario,
run_scenario``); they load on first use, so ``import profiles`` stays cheap.
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:  # pragma: no cover
    from profiles.analysis.priority import assign_priorities
    from profiles.analysis.rta import ErrorModel, MessageSpec, NodeQueue, RtaResult, analyse
    from profiles.base import Context, Profile, Recorder
    from profiles.canopen.device import CanopenDevice
    from profiles.canopen.master import CanopenMaster
    from profiles.csma.profile import CsmaProfile
    from profiles.declarations import MessageDecl, NodeDecl, Scenario
    from profiles.message_set import MessageSet, StudyMessage
    from profiles.pipeline.metrics import analyse_scenario, format_table
    from profiles.pipeline.plots import write_plots
    from profiles.pipeline.runner import Result, run_on_pycan, run_scenario
    from profiles.pipeline.scenario import load_scenario, parse_scenario
    from profiles.polling.master import Master
    from profiles.polling.slave import Slave
    from profiles.registry import ProfileKind, profile_kind, profile_kinds, register
    from profiles.schema import ScenarioError
    from profiles.sweeps.comparison import profiles_study
    from profiles.sweeps.schedulability import schedulability_study
    from profiles.sweeps.sweep import run_sweep
    from profiles.tdma.profile import TdmaProfile

__all__ = [
    # the profile contract
    "Profile",
    "Context",
    "Recorder",
    "ProfileKind",
    "register",
    "profile_kinds",
    "profile_kind",
    "Scenario",
    "NodeDecl",
    "MessageDecl",
    "ScenarioError",
    "MessageSet",
    "StudyMessage",
    # the profiles
    "CsmaProfile",
    "Master",
    "Slave",
    "TdmaProfile",
    "CanopenDevice",
    "CanopenMaster",
    # scenarios: loading, running, the results
    "load_scenario",
    "parse_scenario",
    "run_scenario",
    "run_on_pycan",
    "Result",
    "format_table",
    "write_plots",
    # the analysis
    "analyse",
    "MessageSpec",
    "ErrorModel",
    "RtaResult",
    "NodeQueue",
    "assign_priorities",
    "analyse_scenario",
    # many runs
    "run_sweep",
    "schedulability_study",
    "profiles_study",
]

# public name -> module that defines it
_EXPORTS = {
    "Profile": "profiles.base",
    "Context": "profiles.base",
    "Recorder": "profiles.base",
    "ProfileKind": "profiles.registry",
    "register": "profiles.registry",
    "profile_kinds": "profiles.registry",
    "profile_kind": "profiles.registry",
    "Scenario": "profiles.declarations",
    "NodeDecl": "profiles.declarations",
    "MessageDecl": "profiles.declarations",
    "ScenarioError": "profiles.schema",
    "MessageSet": "profiles.message_set",
    "StudyMessage": "profiles.message_set",
    "CsmaProfile": "profiles.csma.profile",
    "Master": "profiles.polling.master",
    "Slave": "profiles.polling.slave",
    "TdmaProfile": "profiles.tdma.profile",
    "CanopenDevice": "profiles.canopen.device",
    "CanopenMaster": "profiles.canopen.master",
    "load_scenario": "profiles.pipeline.scenario",
    "parse_scenario": "profiles.pipeline.scenario",
    "run_scenario": "profiles.pipeline.runner",
    "run_on_pycan": "profiles.pipeline.runner",
    "Result": "profiles.pipeline.runner",
    "format_table": "profiles.pipeline.metrics",
    "write_plots": "profiles.pipeline.plots",
    "analyse": "profiles.analysis.rta",
    "MessageSpec": "profiles.analysis.rta",
    "ErrorModel": "profiles.analysis.rta",
    "RtaResult": "profiles.analysis.rta",
    "NodeQueue": "profiles.analysis.rta",
    "assign_priorities": "profiles.analysis.priority",
    "analyse_scenario": "profiles.pipeline.metrics",
    "run_sweep": "profiles.sweeps.sweep",
    "schedulability_study": "profiles.sweeps.schedulability",
    "profiles_study": "profiles.sweeps.comparison",
}


def __getattr__(name: str) -> Any:
    """Load a public name from its module on first use (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'profiles' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
