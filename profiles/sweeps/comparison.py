"""The profiles study: one message set under each registered profile that can express it.

The converters that express the set in each profile's terms are in `profiles.sweeps.converters`.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from profiles.message_set import MessageSet
from profiles.registry import profile_kind, profile_kinds
from profiles.sweeps.converters import Converter, converter_for
from profiles.sweeps.execute import execute

__all__ = ["ProfileTask", "profile_run", "ProfilesStudy", "profiles_study"]


@dataclass(frozen=True)
class ProfileTask:
    """One profile's run of the profiles study."""

    index: int
    profile: str
    raw: Mapping[str, Any]

    def head(self) -> dict[str, Any]:
        """run, profile."""
        return {"run": self.index, "profile": self.profile}


def profile_run(task: ProfileTask) -> dict[str, Any]:
    """Run one profile's scenario; the row holds the bus load, per message ``<name>.max_ms``,
    ``.jitter_ms``, ``.misses``, and the profile's own figures (`profiles.sweeps.sweep.summary_row`)."""
    from profiles.pipeline.runner import run_scenario
    from profiles.pipeline.scenario import parse_scenario
    from profiles.sweeps.sweep import summary_row

    res = run_scenario(parse_scenario(task.raw, f"study profiles ({task.profile})"), progress=False)
    if res.interrupted:
        raise KeyboardInterrupt
    row = task.head()
    row.update(summary_row(res))
    return row


@dataclass
class ProfilesStudy:
    """One row per compared profile (canonical order: by name; profiles that share a converter
    share a row, labelled ``master/slave``), the message set, and the profiles left out with the
    reason."""

    mset: MessageSet
    rows: list[dict[str, Any]]
    skipped: dict[str, str]
    interrupted: bool
    engine: str
    wall_s: float


def profiles_study(
    mset: MessageSet,
    *,
    workers: int = 1,
    scheduler: str | None = None,
    engine: str = "auto",
    progress: bool | None = None,
    time_limit: float | None = None,
) -> ProfilesStudy:
    """Run ``mset`` under every registered profile that has a converter (see the module
    docstring) and return their rows side by side. A converter that refuses the set (ValueError:
    its profile cannot express it) puts the profile in ``skipped`` with the reason; one that
    fails otherwise, or a scenario its profile refuses, is that profile's row with an ``error``."""
    tasks: list[ProfileTask] = []
    skipped: dict[str, str] = {}
    failed: list[dict[str, Any]] = []
    # profiles of one module (master and slave, canopen and canopen-master) share its converter:
    # one run, labelled with all their names
    groups: dict[Converter, list[str]] = {}
    for name in sorted(profile_kinds()):
        fn = converter_for(name)
        if fn is None:
            mod = profile_kind(name).build.__module__
            skipped[name] = f"no converter ({mod} has no express_message_set)"
            continue
        groups.setdefault(fn, []).append(name)
    for fn, names in groups.items():
        label = "/".join(names)
        try:
            raw = fn(mset)
        except ValueError as exc:  # the converter's word that its profile cannot express this set
            skipped[label] = " ".join(str(exc).split())
            continue
        except Exception as exc:
            from profiles.sweeps.execute import error_text

            failed.append({"run": None, "profile": label, "error": f"converter: {error_text(exc)}"})
            continue
        tasks.append(ProfileTask(len(tasks), label, raw))
    ex = execute(
        profile_run,
        tasks,
        workers=workers,
        scheduler=scheduler,
        engine=engine,
        progress=progress,
        desc="profiles",
        time_limit=time_limit,
    )
    rows = ex.rows + failed
    return ProfilesStudy(mset, rows, skipped, ex.interrupted, ex.engine, ex.wall_s)
