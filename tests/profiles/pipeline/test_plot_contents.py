"""What the plots show (issue 23, "Complete and honest output"): each figure is built from a short
simulated run and looked at on its way to the file (matplotlib cannot read a PNG back), against
the rules the issue states: the error colour is not a node colour, frames carry their identifier
where they have room, legends cover no data, bus-load bins are readable and capped, zeros stay
visible on a logarithmic axis, and the CANopen response-time plot is not empty."""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import Any

import pytest

pytest.importorskip("matplotlib")

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.collections import LineCollection, PolyCollection
from matplotlib.colors import to_rgba
from matplotlib.figure import Figure
from matplotlib.transforms import Bbox

from profiles.pipeline import plots
from profiles.pipeline.recording import MAX_BINS
from profiles.pipeline.runner import run_scenario
from profiles.pipeline.scenario import parse_scenario, read_toml

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"
BODY = EXAMPLES / "body_network.toml"
CANOPEN = EXAMPLES / "canopen.toml"


def _run(path: Path, duration: float, **changes: Any) -> Any:
    raw = copy.deepcopy(read_toml(path))
    raw["bus"]["duration"] = duration
    raw.update(changes)
    return run_scenario(parse_scenario(raw, str(path)), plot=True)


@pytest.fixture(scope="module")
def body() -> Any:
    """The body network (125 kbit/s, low load) for 0.2 s with every bcm DoorStatus (0x2A0) frame
    corrupted once (a data bit flipped: an error frame, then the retransmission), the timeline
    over the first 10 ms so that the frames are wide."""
    fault = {"kind": "flip", "id": 0x2A0, "field": "data", "bit": 0}
    return _run(BODY, 0.2, faults=[fault], plot={"window_ms": [0.0, 10.0], "bin_ms": 0.1})


@pytest.fixture
def figures(monkeypatch: pytest.MonkeyPatch) -> list[Figure]:
    """The figures saved while the test runs, drawn (their text has a size only once drawn)."""
    seen: list[Figure] = []
    save = Figure.savefig

    def looking(fig: Figure, *a: Any, **k: Any) -> Any:
        out = save(fig, *a, **k)
        seen.append(fig)
        return out

    monkeypatch.setattr(Figure, "savefig", looking)
    return seen


def _renderer(fig: Figure) -> Any:
    """The figure drawn on an Agg canvas of its own (pyplot closed it after saving)."""
    canvas = FigureCanvasAgg(fig)
    canvas.draw()
    return canvas.get_renderer()


def _one(figures: list[Figure]) -> Figure:
    assert len(figures) == 1
    return figures[0]


def _bars(ax: Any) -> list[tuple[PolyCollection, tuple[float, float, float, float]]]:
    """The timeline's bars: each collection with its (x0, x1, y0, y1) in data units."""
    out = []
    for c in ax.collections:
        if isinstance(c, PolyCollection) and c.get_paths():
            v = c.get_paths()[0].vertices
            out.append((c, (v[:, 0].min(), v[:, 0].max(), v[:, 1].min(), v[:, 1].max())))
    return out


def _distance(a: Any, b: Any) -> float:
    return math.dist(to_rgba(a)[:3], to_rgba(b)[:3])


# -- 1. the error colour is not a node colour ------------------------------------------------------


def test_timeline_error_colour_is_no_node_colour(body, figures, tmp_path):
    kinds = {r.kind for r in body.trace if r.start <= 10_000_000}
    assert {"frame", "error"} <= kinds, "the run needs frames and error frames in the window"
    plots.timeline(body, tmp_path / "t.png")
    ax = _one(figures).axes[0]
    node_fill = {tuple(c.get_facecolor()[0]) for c, _ in _bars(ax) if _distance(c.get_facecolor()[0], "white") > 0.01}
    assert len(node_fill) >= 3  # several nodes sent in the window
    error_edges = [
        tuple(c.get_edgecolor()[0]) for c, _ in _bars(ax) if _distance(c.get_facecolor()[0], "white") <= 0.01
    ]
    crosses = [tuple(to_rgba(ln.get_color())) for ln in ax.lines if ln.get_marker() == "x"]
    assert error_edges and crosses
    # every node's colour, also for a network of more nodes than the palette has colours
    palette = plots.node_colours([f"n{i}" for i in range(25)]).values()
    for err in set(error_edges) | set(crosses):
        for c in list(node_fill) + list(palette):
            assert _distance(err, c) > 0.15, (err, c)  # told apart at a glance, not only by RGBA


# -- 2. frames carry their identifiers where they have room ----------------------------------------


def _identifier_texts(fig: Figure, result: Any) -> int:
    """Every frame bar at least twice as wide as its identifier's rendered text carries that
    identifier (in hex) inside it, and no identifier text overflows its bar."""
    ax = fig.axes[0]
    renderer = _renderer(fig)
    frames = [r for r in result.trace if r.kind == "frame"]
    texts = [t for t in ax.texts if t.get_text()]
    labelled = 0
    for _c, (x0, x1, y0, y1) in _bars(ax):
        rec = next((r for r in frames if math.isclose(r.start / 1e6, x0, abs_tol=1e-9)), None)
        if rec is None:
            continue  # an error frame
        (px0, py0), (px1, _py1) = ax.transData.transform([(x0, y0), (x1, y1)])
        inside = [t for t in texts if x0 <= t.get_position()[0] <= x1 and y0 <= t.get_position()[1] <= y1]
        for t in inside:
            assert int(t.get_text().removeprefix("0x"), 16) == rec.frame.can_id, t.get_text()
            ext = t.get_window_extent(renderer)
            assert min(px0, px1) <= ext.x0 and ext.x1 <= max(px0, px1), f"{t.get_text()} overflows its frame"
        need = len(f"{rec.frame.can_id:03X}")
        probe = ax.text(0, 0, "D" * need, fontsize=6)  # hex's widest glyphs
        room = abs(px1 - px0) >= 2 * probe.get_window_extent(renderer).width
        probe.remove()
        if room:
            assert inside, f"frame 0x{rec.frame.can_id:X} at {x0:g} ms has room and no identifier"
            labelled += 1
    return labelled


def test_timeline_frames_carry_their_identifiers(body, figures, tmp_path):
    plots.timeline(body, tmp_path / "t.png")
    fig = _one(figures)
    labelled = _identifier_texts(fig, body)
    ids = {r.frame.can_id for r in body.trace if r.kind == "frame" and r.end <= 10_000_000}
    assert labelled >= len(ids) >= 5  # a low-load window of 10 ms: every frame has room


def test_timeline_identifiers_never_overflow_a_narrow_frame(body, figures, tmp_path):
    """The default 50 ms window makes the 125 kbit/s frames narrow: labels only where they fit."""
    plots.timeline(body, tmp_path / "t.png", window=(0, 50_000_000))
    _identifier_texts(_one(figures), body)


# -- 3. legends cover no data ----------------------------------------------------------------------


def _covered(fig: Figure) -> list[str]:
    """What of each axes' data a legend's box covers: the vertices of its lines (segments
    sampled), line collections and bars, as far as they are drawn (inside their axes)."""
    renderer = _renderer(fig)
    legends = [lg for ax in fig.axes for lg in [ax.get_legend()] if lg is not None] + list(fig.legends)
    hits = []
    for lg in legends:
        box = lg.get_window_extent(renderer)
        for ax in fig.axes:
            for ln in ax.lines:
                pts = ln.get_transform().transform(ln.get_xydata())
                for (xa, ya), (xb, yb) in zip(pts, pts[1:] if len(pts) > 1 else pts):
                    for k in range(21):
                        x, y = xa + (xb - xa) * k / 20, ya + (yb - ya) * k / 20
                        if box.contains(x, y) and ax.bbox.contains(x, y):  # drawn: clipped to the axes
                            hits.append(f"line {ln.get_label()!r}")
                            break
            for c in ax.collections:
                if isinstance(c, LineCollection):
                    for seg in c.get_segments():
                        pts = c.get_transform().transform(seg)
                        if any(box.contains(x, y) for x, y in pts) or (
                            box.x0 <= pts[0][0] <= box.x1 and min(pts[:, 1]) <= box.y1 and max(pts[:, 1]) >= box.y0
                        ):
                            hits.append("vertical bar")
            for p in ax.patches:
                drawn = Bbox.intersection(p.get_window_extent(renderer), ax.bbox)  # clipped to the axes
                if p.get_visible() and drawn is not None and drawn.overlaps(box) and p is not ax.patch:
                    hits.append(f"patch {type(p).__name__}")
    return hits


def test_pipeline_legends_cover_no_data(body, figures, tmp_path):
    plots.response_times(body, tmp_path / "r.png")
    plots.response_cdf(body, tmp_path / "c.png")
    plots.bus_load(body, tmp_path / "b.png")
    assert len(figures) == 3
    assert all(f.legends or any(ax.get_legend() for ax in f.axes) for f in figures), "each has a legend"
    for f in figures:
        assert _covered(f) == []


# -- 4. bus load: readable bins, at most MAX_BINS --------------------------------------------------


def _readable(ms: float) -> bool:
    """1, 2 or 5 times a power of ten (the steps of a plot's axis)."""
    e = math.floor(math.log10(ms))
    return any(math.isclose(ms, m * 10.0**e, rel_tol=1e-9) for m in (1, 2, 5, 10))


def test_bus_load_bins_are_readable_and_capped(body, figures, tmp_path):
    """0.2 s in bins of 0.1 ms would be 2000 bins: widened to a readable width with at most
    MAX_BINS of them, and the figure says it was widened."""
    plots.bus_load(body, tmp_path / "b.png")
    ax = _one(figures).axes[0]
    (stairs,) = [p for p in ax.patches if type(p).__name__ == "StepPatch"]
    edges = stairs.get_data().edges
    widths = [b - a for a, b in zip(edges, edges[1:])]
    assert len(widths) <= MAX_BINS
    assert math.isclose(edges[-1], 200.0)
    assert all(math.isclose(w, widths[0]) for w in widths[:-1])  # the last may be cut short
    assert widths[0] > 0.1 and _readable(widths[0]), widths[0]
    assert "widened" in ax.get_title()


@pytest.mark.parametrize("end_s", [0.2, 1.234, 7.0, 3600.0])
def test_widened_bin_width_is_readable(end_s):
    from profiles.pipeline.recording import PlotRecords

    load = PlotRecords((0, 0), 100_000, round(end_s * 1e9), 500_000)
    assert len(load.busy) <= MAX_BINS
    assert load.widened and _readable(load.bin_ns / 1e6), load.bin_ns


# -- 5. zeros on a logarithmic axis ----------------------------------------------------------------


def test_profiles_plot_marks_a_zero_on_its_log_axis(figures, tmp_path):
    from profiles.message_set import MessageSet, StudyMessage
    from profiles.sweeps.comparison import profiles_study
    from profiles.sweeps.plots import profiles_plot

    mset = MessageSet(
        500_000,
        (
            StudyMessage("fast", "a", 0x10, 8, 2_000_000, 2_000_000),
            StudyMessage("slow", "b", 0x30, 8, 10_000_000, 10_000_000),
        ),
        duration_s=0.05,
        seed=3,
    )
    study = profiles_study(mset)
    assert study.rows
    row = study.rows[0]
    row["slow.max_ms"] = 0.0  # a worst response of 0: a bar of no height on a log axis
    profiles_plot(study, tmp_path / "p.png")
    ax = _one(figures).axes[0]
    assert ax.get_yscale() == "log"
    bottom = ax.get_ylim()[0]
    x = 1 - 0.4 + 0.8 / len(study.rows) * 0.5  # the first profile's bar of the second message
    marks = [t for t in ax.texts if t.get_text() == "0"]
    assert len(marks) == 1
    mx, my = marks[0].xy
    assert math.isclose(mx, x) and math.isclose(my, bottom)
    # and the mark is drawn inside the axes
    renderer = _renderer(ax.figure)
    assert ax.get_window_extent(renderer).overlaps(marks[0].get_window_extent(renderer))
    # its legend, below the axes, covers neither the bars nor the message names
    fig = ax.figure
    assert _covered(fig) == []
    box = ax.get_legend().get_window_extent(renderer)
    for t in ax.get_xticklabels():
        assert not t.get_window_extent(renderer).overlaps(box), t.get_text()


def test_sweep_plot_keeps_a_zero_off_the_log_axis(figures, tmp_path):
    """A logarithmic axis has no place for 0: asked for one over values with a 0, the sweep plot
    stays linear and draws the point at 0."""
    from profiles.sweeps.plots import sweep_plot

    rows = [{"k": k, "bus_load": 0.1 + 0.001 * k} for k in (0, 10, 1000)]
    sweep_plot(rows, ["k"], "bus_load", tmp_path / "s.png", log_x=True)
    ax = _one(figures).axes[0]
    assert ax.get_xscale() == "linear"
    xs = [x for ln in ax.lines for x in ln.get_xdata()]
    assert 0 in xs


# -- 6. the CANopen response-time plot has data ----------------------------------------------------


def test_canopen_response_time_plot_is_not_empty(figures, tmp_path):
    result = _run(CANOPEN, 0.1)
    assert not [m for m in result.messages if m["response_ms"]]  # no declared message: latency per id
    plots.response_times(result, tmp_path / "r.png")
    ax = _one(figures).axes[0]
    sent = {r.frame.can_id for r in result.trace if r.kind == "frame"}
    assert len(sent) >= 10  # NMT, SYNC, heartbeats and PDOs of five devices
    bars = [seg for c in ax.collections if isinstance(c, LineCollection) for seg in c.get_segments()]
    means = [ln for ln in ax.lines if ln.get_marker() == "o"]
    assert len(bars) == len(means) == len(sent)
    labels = [int(t.get_text(), 16) for t in ax.get_xticklabels()]
    assert set(labels) == sent
    shortest = {
        i: min(r.end - r.start for r in result.trace if r.kind == "frame" and r.frame.can_id == i) for i in sent
    }
    for (x, lo), (_x, hi) in bars:
        can_id = labels[round(x) - 1]
        # a latency from queuing to the end of EOF is at least the frame's own time on the bus
        assert lo >= shortest[can_id] / 1e6 * 0.999 and hi >= lo
    _lo, top = ax.get_ylim()
    assert top >= max(hi for (_x, _l), (_x2, hi) in bars)
