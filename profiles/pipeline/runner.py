"""Run a scenario: build its nodes and profiles on the simulated bus (or on a python-can bus),
inject its faults, run it, and collect the metrics and the analysis into a `Result`.

On the simulated bus time is virtual and the run is deterministic (the same scenario and seed
give the same trace and the same result). On a python-can bus (``interface``/``channel``) the
same profiles run on the wall clock through `stack.PyCanDriver`; the end of each frame is taken
from the receive timestamps of a monitor connection on that bus, so the metrics mean the same.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from profiles.base import Context, Profile, Recorder, frame_of
from profiles.declarations import NodeDecl, Scenario
from profiles.pipeline.faults import inject_faults
from profiles.pipeline.metrics import analyse_scenario, message_rows, summary_of
from profiles.pipeline.recording import PlotRecords, ReceptionCounter, SampleWriter, plot_window
from profiles.registry import profile_kind
from profiles.schema import ScenarioError
from stack import LocalClock, SimBus
from stack.bus.trace import DiscardedTrace
from stack.io.progress import run_sliced

if TYPE_CHECKING:  # pragma: no cover
    from stack.io.tracefile import TraceWriter

__all__ = ["Result", "run_scenario", "run_on_pycan", "build", "Built"]


@dataclass
class Built:
    """A scenario made ready to run: the driver (a SimBus, or a PyCanDriver), the nodes and
    profiles by name, the context they share."""

    scenario: Scenario
    driver: Any
    nodes: dict[str, Any]
    profiles: dict[str, Profile]
    context: Context


@dataclass
class Result:
    """What a run measured, with the analysis beside it (see `to_json` for the keys)."""

    scenario: Scenario
    duration_s: float
    bus_load: float
    frames: int
    error_frames: int
    messages: list[dict[str, Any]]
    profiles: dict[str, Any]
    nodes: dict[str, dict[str, int]]
    analysis: dict[str, Any]
    interrupted: bool = False
    driver: str = "simulated"
    wall_s: float = 0.0
    trace: list[Any] = field(default_factory=list)
    tracks: dict[str, Any] = field(default_factory=dict)
    load: Any = None  # what the plots draw of a long run (`profiles.pipeline.recording.PlotRecords`)
    files: dict[str, Any] = field(default_factory=dict)  # trace/samples: path, how much, the error that stopped it
    id_latency: dict[str, Any] = field(default_factory=dict)
    lost: Any = None  # a python-can bus that went away mid-run (`stack.io.driver.BusGone`)

    def responses_ms(self, name: str) -> list[float]:
        """The response times of message ``name`` that were kept (ms, in release order): every
        one of a short run or of one that kept them all (``samples``), else those of the last
        batch (`profiles.base.Track`)."""
        tr = self.tracks.get(name)
        return [] if tr is None else [v / 1e6 for v in tr.responses]

    def to_json(self) -> dict[str, Any]:
        """One JSON object: bus_load (0..1), duration (s), frames, error_frames, messages (one
        object per declared message), each profile's own figures under its key, the nodes'
        counters, the analysis' assumptions."""
        out: dict[str, Any] = {
            "scenario": self.scenario.source,
            "driver": self.driver,
            "seed": self.scenario.seed,
            "bitrate": self.scenario.bitrate,
            "data_bitrate": self.scenario.data_bitrate,
            "duration": self.duration_s,
            "bus_load": self.bus_load,
            "frames": self.frames,
            "error_frames": self.error_frames,
            "messages": self.messages,
        }
        out.update(self.profiles)
        out["nodes"] = self.nodes
        out["analysis"] = self.analysis
        if self.interrupted:
            out["interrupted"] = True
        if self.lost is not None:
            out["bus_lost"] = {
                "bus": self.lost.bus,
                "at_s": round(self.lost.t_ns / 1e9, 6),
                "wall_time": self.lost.wall,
                "reason": self.lost.reason,
            }
        return out


def _node_config(d: NodeDecl) -> dict[str, Any]:
    cfg: dict[str, Any] = {
        "queue": d.policy,
        "tx_queue_size": d.tx_queue_size,
        "rx_fifo_size": d.rx_fifo_size,
        "listen_only": d.listen_only,
    }
    if d.policy == "mailbox":
        cfg.update(mailboxes=d.mailboxes, abort=d.abort)
    if d.fd is not None:
        cfg["fd"] = d.fd
    if d.drift_ppm or d.clock_offset_ns:
        cfg["clock"] = LocalClock(offset_ns=d.clock_offset_ns, drift_ppm=d.drift_ppm)
    return cfg


def build(scenario: Scenario, driver: Any, *, bus: Any = None, recorder: Recorder | None = None) -> Built:
    """Make the scenario's nodes on ``driver`` (a SimBus or a PyCanDriver) and their profiles,
    call the application hooks (``app = "module:function"``), and return them unstarted."""
    ctx = Context(scenario, recorder or Recorder(), bus=bus)
    nodes = {}
    for d in scenario.nodes:
        nodes[d.name] = driver.node(d.name, **_node_config(d))
    ctx.nodes = dict(nodes)
    profiles: dict[str, Profile] = {}
    for d in scenario.nodes:
        try:
            profiles[d.name] = profile_kind(d.profile).build(nodes[d.name], d, ctx)
        except ScenarioError:
            raise
        except ValueError as exc:  # a rule the profile keeps when it builds (a PDO mapping, ...)
            raise ScenarioError(f"{scenario.source}: [[nodes]] {d.name!r} ({d.profile}): {exc}") from None
        ctx.profiles[d.name] = profiles[d.name]
    for d in scenario.nodes:
        if d.app:
            fn = _app(d.app, scenario.source, d.name)
            try:
                fn(nodes[d.name], profiles[d.name], ctx)
            except Exception as exc:
                raise ScenarioError(
                    f"{_app_loc(scenario.source, d.name)}: {d.app} failed: {_where_raised(exc)}"
                ) from exc
    return Built(scenario, driver, nodes, profiles, ctx)


def _app_loc(source: str, node: str) -> str:
    return f"{source}: [[nodes]] {node!r}: app"


def _where_raised(exc: BaseException) -> str:
    """An exception of application code on one line: its type, message and the innermost place
    in the traceback (file:line), since the CLI prints no traceback."""
    import traceback

    frames = traceback.extract_tb(exc.__traceback__)
    at = f" (at {frames[-1].filename}:{frames[-1].lineno})" if frames else ""
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}{at}"


def _app(spec: str, source: str, node: str) -> Callable[..., Any]:
    """The function ``module:function`` names, checked to take (node, profile, context)."""
    import inspect

    mod_name, _, fn_name = spec.partition(":")
    loc = _app_loc(source, node)
    try:
        mod = importlib.import_module(mod_name)
    except ImportError as exc:
        raise ScenarioError(f"{loc}: cannot import module {mod_name!r} ({exc})") from None
    except Exception as exc:  # the module's own code failed while it was imported
        raise ScenarioError(f"{loc}: importing module {mod_name!r} failed: {_where_raised(exc)}") from None
    fn: Any = mod
    for part in fn_name.split("."):
        fn = getattr(fn, part, None)
    if not callable(fn):
        raise ScenarioError(f"{loc}: module {mod_name!r} has no function {fn_name!r}")
    try:
        inspect.signature(fn).bind(None, None, None)
    except TypeError:
        raise ScenarioError(
            f"{loc}: {spec} does not take the arguments an app is called with: (node, profile, context)"
        ) from None
    except ValueError:
        pass  # a builtin without a signature: it is called and says itself what it takes
    return fn


def _desc(scenario: Scenario) -> str:
    return f"simulating {scenario.source}"


def run_scenario(
    scenario: Scenario,
    *,
    record: bool | None = None,
    progress: bool | None = None,
    setup: Callable[[Built], Any] | None = None,
    plot: bool = False,
    trace: str | None = None,
    samples: str | None = None,
    time_limit: float | None = None,
) -> Result:
    """Run ``scenario`` on the simulated bus for its duration and return the `Result`.

    Memory stays bounded however long the run unless ``record`` asks to keep every trace record
    in ``Result.trace``. ``plot`` keeps what the plots draw (the timeline window's records, the
    bus-load bins: `profiles.pipeline.recording.PlotRecords`); ``trace`` streams the trace to
    that file as the bus runs (python-can's writer for its suffix, timestamps in bus time);
    ``samples`` writes every instance of every message to that .csv or .parquet file and keeps
    every response time, so that the p99 is exact; a scenario with faults counts receptions from
    the attempts each receiver accepted, without keeping them. ``progress`` shows a progress bar
    (None: on a terminal, for runs longer than 2 s); ``setup(built)`` runs after the nodes and
    profiles are built and before they start (application code). Ctrl-C (or SIGTERM) ends the
    run early: the result covers the time simulated so far and says ``interrupted``, and the
    files hold what was recorded. ``time_limit`` (wall-clock seconds) raises
    `stack.io.progress.TimeLimitExceeded` past it.
    """
    records = bool(record) or plot or trace is not None or bool(scenario.faults)
    bus = SimBus(
        scenario.bitrate,
        data_bitrate=scenario.data_bitrate,
        seed=scenario.seed,
        name="bus0",
        record=records,
        keep=bool(record),
    )
    built = build(scenario, bus, bus=bus, recorder=Recorder(keep_all=samples is not None))
    inject_faults(bus, scenario.faults, scenario.source)
    tracks = built.context.recorder.tracks
    rec = Recording()
    if scenario.faults:
        rec.receptions = ReceptionCounter(tracks)
        bus.on_trace(rec.receptions)
    if plot:
        window = plot_window(scenario.plot, scenario.duration_ns)
        bin_ns = round(scenario.plot.get("bin_ms", 10.0) * 1e6)
        rec.plots = PlotRecords(window, bin_ns, scenario.duration_ns, scenario.bitrate)
        bus.on_trace(rec.plots)
    try:
        if trace is not None:
            from stack.io.tracefile import TraceWriter

            rec.trace = TraceWriter(trace, channel=bus.name)
            bus.on_trace(rec.trace.write)
        if samples is not None:
            rec.samples = SampleWriter(samples)
            for tr in tracks.values():
                tr.sink = rec.samples
                tr.clock = bus.now
        if setup is not None:
            setup(built)
        for p in built.profiles.values():
            p.start()
        wall0 = time.perf_counter()
        # the run covers [0, duration): a release at the end would have no time to go out
        done = run_sliced(bus, scenario.duration_ns - 1, progress=progress, desc=_desc(scenario), time_limit=time_limit)
        result = collect(
            built,
            time.perf_counter() - wall0,
            interrupted=not done,
            t_end=scenario.duration_ns if done else bus.now(),
            recording=rec,
        )
    finally:
        rec.close()
    result.files = _files(rec)
    return result


@dataclass
class Recording:
    """What a run recorded beside its metrics (`profiles.pipeline.recording`): receptions of a
    faulted run, what the plots draw, the trace and samples files as they were written."""

    receptions: ReceptionCounter | None = None
    plots: PlotRecords | None = None
    trace: TraceWriter | None = None
    samples: SampleWriter | None = None

    def close(self) -> None:
        """Finish the files (what was recorded so far, on an interrupted or failed run too)."""
        if self.trace is not None:
            self.trace.close()
        if self.samples is not None:
            self.samples.close()


def collect(
    built: Built,
    wall_s: float,
    *,
    interrupted: bool = False,
    driver: str = "simulated",
    t_end: int | None = None,
    bus_load: float | None = None,
    recording: Recording | None = None,
) -> Result:
    """Read the recorder, the bus and the profiles into a `Result` (analysis included)."""
    sc = built.scenario
    bus = built.context.bus
    rec = recording or Recording()
    t_end = bus.now() if t_end is None else t_end
    for tr in built.context.recorder.tracks.values():
        tr.finish(t_end)
    if bus is not None:
        for name, tr in built.context.recorder.tracks.items():
            tr.received = rec.receptions.received[name] if rec.receptions is not None else tr.sent
    analysis = analyse_scenario(sc)
    rows = message_rows(sc, built.context.recorder, analysis)
    profiles_json: dict[str, Any] = {}
    by_kind: dict[str, list[Profile]] = {}
    for d in sc.nodes:
        by_kind.setdefault(d.profile, []).append(built.profiles[d.name])
    for kind_name, profs in by_kind.items():
        kind = profile_kind(kind_name)
        if kind.result_key and kind.summarize:
            # profiles that share a key (a CANopen master and its devices) share the object
            profiles_json.setdefault(kind.result_key, {}).update(kind.summarize(profs, built.context))
    nodes = {name: n.counters() for name, n in built.nodes.items()}
    s = summary_of(bus, t_end)
    trace: list[Any] = []
    if bus is not None and bus.record and not isinstance(bus.trace, DiscardedTrace):
        trace = list(bus.trace)
    elif rec.plots is not None:
        trace = rec.plots.records
    return Result(
        scenario=sc,
        duration_s=t_end / 1e9,
        bus_load=s["bus_load"] if bus_load is None else bus_load,
        frames=s["frames"],
        error_frames=s["error_frames"],
        messages=rows,
        profiles=profiles_json,
        nodes=nodes,
        analysis=analysis["assumptions"],
        interrupted=interrupted,
        driver=driver,
        wall_s=wall_s,
        trace=trace,
        tracks=dict(built.context.recorder.tracks),
        load=rec.plots,
        id_latency=bus.summary()["ids"] if bus is not None else {},
    )


def _files(rec: Recording) -> dict[str, Any]:
    """What went into each file: its path, how much, and the error that stopped the writing."""
    out: dict[str, Any] = {}
    if rec.trace is not None:
        out["trace"] = {"path": rec.trace.path, "records": rec.trace.written, "left_out": rec.trace.left_out}
        if rec.trace.error is not None:
            out["trace"]["error"] = rec.trace.error.strerror or str(rec.trace.error)
    if rec.samples is not None:
        out["samples"] = {"path": str(rec.samples.path), "rows": rec.samples.rows}
        if rec.samples.error is not None:
            out["samples"]["error"] = rec.samples.error.strerror or str(rec.samples.error)
    return out


def run_on_pycan(
    scenario: Scenario,
    interface: str,
    channel: Any,
    *,
    duration_s: float | None = None,
    progress: bool = False,
    trace: str | None = None,
    plot: bool = False,
    **bus_kwargs: Any,
) -> Result:
    """Run ``scenario`` on a python-can bus (``interface``/``channel``, any python-can options in
    ``bus_kwargs``) on the wall clock, for its duration (or ``duration_s``).

    Every scenario node gets its own connection through `stack.PyCanDriver`; a monitor
    connection receives every frame (`profiles.pipeline.monitor.BusMonitor`): it counts them,
    and its receive timestamps give the end of each frame on the driver's clock, the one the
    releases are stamped on, so response times mean what they mean in simulation (release to
    end of EOF; on a served bus the server's bus time mapped onto this process's clock, so that a
    loaded machine shows as lateness). ``trace`` streams what the monitor receives to that file
    (python-can's writer for its suffix, timestamps in seconds of bus time from the start);
    ``plot`` keeps the frames as timeline records for `profiles.pipeline.plots`. Faults are a
    simulation feature: a scenario with ``[[faults]]`` is refused here.

    When the bus goes away mid-run (a served bus's server stops, an interface is closed) the run
    stops at once: the result covers the time until then, says ``interrupted`` and, in ``lost``,
    which bus and when (`stack.io.driver.BusGone`). Ctrl-C ends it early the same way.
    """
    from profiles.pipeline.monitor import BusMonitor
    from stack import PyCanDriver
    from stack.io.tracefile import TraceWriter

    if scenario.faults:
        raise ScenarioError(
            f"{scenario.source}: [[faults]] need the simulated bus (fault injection is a simulation "
            "feature); remove them to run on a python-can bus"
        )
    bus_kwargs.setdefault("bitrate", scenario.bitrate)
    if scenario.data_bitrate is not None:  # a CAN FD bus: python-can's fd=True with its data phase
        bus_kwargs.setdefault("fd", True)
        bus_kwargs.setdefault("data_bitrate", scenario.data_bitrate)
    try:
        drv = PyCanDriver(interface=interface, channel=channel, **bus_kwargs)
        built = build(scenario, drv)
        monitor_node = drv.node("__monitor__", listen_only=True)
    except Exception as exc:
        raise ScenarioError(f"cannot open {interface} channel {channel!r}: {exc}") from None
    recorder = built.context.recorder
    for tr in recorder.tracks.values():
        tr.monitor = True  # ends come from the monitor's timestamps
    by_key = {frame_of(tr.decl).key: tr for tr in recorder.tracks.values()}
    senders = {frame_of(m).key: d.name for d in scenario.nodes for m in d.messages}
    total = scenario.duration_ns / 1e9 if duration_s is None else duration_s
    wall0 = time.perf_counter()
    interrupted = False
    sink = None
    try:
        # the channel as a trace names it: one word (a candump .log line splits at spaces)
        sink = TraceWriter(trace, channel="_".join(str(channel).split()) or interface) if trace is not None else None
        with drv.lock:
            for p in built.profiles.values():
                p.start()
            t0 = drv.now()
            monitor = BusMonitor(
                by_key, senders, scenario.bitrate, t0, trace=sink, plot=plot, data_bitrate=scenario.data_bitrate
            )
            monitor_node.subscribe(monitor)
        drv.start()
        try:
            end = time.monotonic() + total
            # short waits: the main thread comes back to Python for Ctrl-C and SIGTERM
            while time.monotonic() < end and not drv.gone.wait(min(0.2, max(0.0, end - time.monotonic()))):
                pass
        except KeyboardInterrupt:
            interrupted = True
        finally:
            drv.stop()
            t_end = drv.now() if drv.lost is None else drv.lost.t_ns
            drv.close()
    finally:
        if sink is not None:
            sink.close()
    elapsed = max(1, t_end - t0)
    with drv.lock:
        res = collect(
            built,
            time.perf_counter() - wall0,
            interrupted=interrupted or drv.lost is not None,
            driver=f"{interface} {channel}",
            t_end=t_end,
            bus_load=min(1.0, monitor.busy_ns / elapsed),
        )
    res.duration_s = elapsed / 1e9
    res.frames = monitor.frames
    res.error_frames = drv.rx_error_frames.get(monitor_node.name, 0)
    res.trace = monitor.records
    res.lost = None if drv.lost is None else drv.lost._replace(t_ns=drv.lost.t_ns - t0)  # time into the run
    res.files = _files(Recording(trace=sink))
    if drv.errors:
        res.analysis["driver_errors"] = drv.errors[:5]
    return res
