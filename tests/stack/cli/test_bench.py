"""`python -m stack.bench` on a plain clone: a figure whose data is missing is skipped with a note,
one that fails is noted, and neither loses the others (the figures themselves are measured by
the benchmark, never timed here)."""

from __future__ import annotations

import json

import pytest

from stack.cli.bench import Figure, Settings, main, run_figures
from stack.cli.bench_io import BENCH_CAPTURE_NAME


def test_without_the_corpus_the_decode_figure_is_skipped_with_a_note(tmp_path, capsys):
    assert main(["--only", "decode", "--corpus", str(tmp_path), "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    missing = tmp_path / "captures" / BENCH_CAPTURE_NAME
    assert set(out) == {"skipped"}  # nothing was measured, nothing failed
    assert str(missing) in out["skipped"]["decode"] and "../shared/corpus" in out["skipped"]["decode"]


def test_the_report_says_which_figure_was_skipped_and_why(tmp_path, capsys):
    assert main(["--only", "decode", "--corpus", str(tmp_path)]) == 0
    captured = capsys.readouterr()
    assert captured.out.splitlines() == [
        f"decode: skipped ({tmp_path / 'captures' / BENCH_CAPTURE_NAME}: the benchmark capture is not there "
        "(it comes with ../shared/corpus))"
    ]
    assert "Traceback" not in captured.err


def test_a_failing_figure_loses_none_of_the_others():
    def measured(value):
        return lambda s: {"value_" + str(value): value * s.scale}

    def broken(s):
        raise ZeroDivisionError("the reference ran in no time")

    def no_data(s):
        raise FileNotFoundError("capture.sr: not there")

    chosen = [
        Figure("first", "", measured(1), lambda r: [f"first {r['value_1']}"]),
        Figure("broken", "", broken, lambda r: ["never"]),
        Figure("no_data", "", no_data, lambda r: ["never"]),
        Figure("last", "", measured(2), lambda r: [f"last {r['value_2']}"]),
    ]
    res, lines = run_figures(chosen, Settings(scale=0.5))
    assert res == {
        "value_1": 0.5,
        "value_2": 1.0,
        "failed": {"broken": "ZeroDivisionError: the reference ran in no time"},
        "skipped": {"no_data": "capture.sr: not there"},
    }
    assert lines == [
        "first 0.5",
        "broken: failed (ZeroDivisionError: the reference ran in no time)",
        "no_data: skipped (capture.sr: not there)",
        "last 1.0",
    ]


def test_ctrl_c_keeps_the_figures_measured_so_far():
    def interrupted(s):
        raise KeyboardInterrupt

    chosen = [
        Figure("first", "", lambda s: {"first": 1}, lambda r: ["first"]),
        Figure("stopped", "", interrupted, lambda r: ["never"]),
        Figure("after", "", lambda s: pytest.fail("measured after Ctrl-C"), lambda r: ["never"]),
    ]
    res, lines = run_figures(chosen, Settings())
    assert res == {"first": 1, "interrupted": ["stopped", "after"]}
    assert lines == ["first", "interrupted: not measured: stopped, after"]


def test_an_unknown_figure_name_is_one_line_and_exit_2(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--only", "decode,warp"])
    assert exc.value.code == 2
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--only 'decode,warp'" in err and "engine" in err and "decode" in err


def test_the_unacknowledged_frame_figure_measures_both_paths_of_the_same_bus(monkeypatch, capsys):
    """The fast path's figure times both ways of carrying the same traffic: the bus each builds
    reaches error passive and sends nothing (a lone node: every attempt an ACK error), and the
    ratio is the bit-level CPU time over the fast path's."""
    from stack.bus.sim import SimBus
    from stack.cli import bench

    built = []
    real = SimBus

    def spy(*a, **k):
        b = real(*a, **k)
        built.append(b)
        return b

    monkeypatch.setattr(bench, "SimBus", spy)
    assert main(["--only", "unacked", "--quick", "--repeat", "1", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert [b.reuse_unacked for b in built] == [True, False]
    for b in built:
        (node,) = b.nodes
        assert node.state.value == "error-passive" and node.tec == 128 and node.tx_frames == 0 and b.frames_ok == 0
    assert out["unacked_fast_vs_bitlevel"] == pytest.approx(
        out["unacked_cpu_per_sim_s_bitlevel"] / out["unacked_cpu_per_sim_s_fast"]
    )
