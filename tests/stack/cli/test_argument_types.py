"""The argument types the subcommands share (`stack.cli`): each bad value is one line on stderr
naming the option, the value and the rule, and exit status 2 — before anything runs."""

from __future__ import annotations

import pytest

from stack.cli import main

BITRATE_RULE = "a CAN 2.0 bus runs at 1000..1000000 bit/s"  # ISO 11898-1: classical CAN up to 1 Mbit/s


@pytest.mark.parametrize(
    "argv,message",
    [
        (["demo", "--bitrate", "2000000"], f"argument --bitrate: 2000000: {BITRATE_RULE}"),
        (["demo", "--bitrate", "fast"], "argument --bitrate: 'fast' is not a whole number of bit/s"),
        (["demo", "--duration", "0"], "argument --duration: 0: a duration is > 0 and at most 3600 s"),
        (["demo", "--duration", "soon"], "argument --duration: 'soon' is not a number of seconds"),
        (["serve", "--bitrate", "999"], f"argument --bitrate: 999: {BITRATE_RULE}"),
        (["restbus", "x.dbc", "--bitrate", "0x10"], f"argument --bitrate: 16: {BITRATE_RULE}"),
        (
            ["canopen", "--node-id", "0", "--interface", "virtual"],
            "argument --node-id: 0: a CANopen node-ID is 1..127 (CiA 301; 0 addresses all nodes)",
        ),
        (
            ["canopen", "--node-id", "5", "--interface", "virtual", "--bitrate", "10"],
            f"argument --bitrate: 10: {BITRATE_RULE}",
        ),
        (
            ["canopen", "--node-id", "5", "--interface", "virtual", "--heartbeat", "70000"],
            "argument --heartbeat: 70000: the producer heartbeat time 0x1017 is 0..65535 ms (UNSIGNED16)",
        ),
        (
            ["canopen", "--node-id", "5", "--interface", "virtual", "--duration", "-2"],
            "argument --duration: -2: a duration is > 0 and at most 1e+07 s",
        ),
        (
            ["experiment", "x.toml", "--duration", "2e6"],
            "argument --duration: 2e6: a duration is > 0 and at most 1e+06 s",
        ),
        (
            ["sweep", "x.toml", "--vary", "bus.seed=1", "--seeds", "0"],
            "argument --seeds: '0': the number of seeds is at least 1",
        ),
        (
            ["sweep", "x.toml", "--vary", "bus.seed=1", "--workers", "two"],
            "argument --workers: 'two' is not a whole number (the number of worker processes)",
        ),
        (["study", "schedulability", "--sets", "0"], "argument --sets: '0': sets per point is at least 1"),
    ],
)
def test_a_bad_value_is_one_line_naming_the_rule(capsys, argv, message):
    assert main(argv) == 2
    out = capsys.readouterr()
    assert out.out == "" and len(out.err.strip().splitlines()) == 1
    assert message in out.err, out.err
