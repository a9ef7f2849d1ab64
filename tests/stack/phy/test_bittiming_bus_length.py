"""The longest bus a bit timing covers (rule Prop_Seg >= 2 x (bus + transceiver + comparator
delays)), stated when the requested bus is longer, and sample points given as fractions."""

from __future__ import annotations

import pytest

import stack.phy.bittiming as bt
from stack.cli import main
from stack.phy.bittiming import BitTimingError, BusDelays, longest_bus, solve


def test_longest_bus_hand_value_500k_16mhz() -> None:
    # 16 MHz / 500 kbit/s: brp 2 gives 16 tq of 125 ns, the kernel's split for 87.5 % is
    # tseg1 13 / tseg2 2. Phase_Seg1 needs 1 tq (the default SJW drops to 1), so Prop_Seg can
    # take 12 tq = 1500 ns round trip = 750 ns one way = 150 m at 5 ns/m. brp 4 (8 tq of 250 ns,
    # tseg1 6) reaches only 5 x 250 / 2 / 5 = 125 m; brp 3 (11 tq of 187.5 ns, 3 % off, tseg1 8)
    # 7 x 187.5 / 2 / 5 = 131.25 m.
    sol = longest_bus(16_000_000, 500_000)
    assert sol is not None
    assert (sol.brp, sol.prop_seg, sol.phase_seg1, sol.phase_seg2, sol.sjw) == (2, 12, 1, 2, 1)
    assert sol.max_bus_length == pytest.approx(150.0)
    solve(16_000_000, 500_000, delays=BusDelays(150.0))  # exactly at the limit: still a timing


def test_too_long_a_bus_states_the_longest(capsys) -> None:
    with pytest.raises(BitTimingError) as ei:
        solve(16_000_000, 500_000, delays=BusDelays(10_000.0))
    assert ei.value.rule == bt.RULE_PROP_SEG
    assert "covers a 10000 m bus: the longest is 150.0 m" in str(ei.value)
    assert "phase_seg1=-" not in str(ei.value)
    rc = main(["bittiming", "--clock", "16000000", "--bitrate", "500000", "--bus-length", "10000"])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "the longest is 150.0 m" in err


def test_node_delays_alone_too_long() -> None:
    # 2 x 2000 ns = 4000 ns round trip: 32 tq of 125 ns, more than any 8..25 tq bit has
    with pytest.raises(BitTimingError, match=r"node delays alone \(2000 ns one way, 4000 ns round trip\)"):
        solve(16_000_000, 500_000, delays=BusDelays(0.0, transceiver_delay_ns=2000.0))


def test_1mbit_longest_bus() -> None:
    # 1 Mbit/s at 16 MHz: brp 1, 16 tq of 62.5 ns, CiA 75 %: tseg1 11, tseg2 4; Prop_Seg up to
    # 10 tq = 625 ns round trip -> 62.5 m
    with pytest.raises(BitTimingError, match=r"the longest is 62\.5 m"):
        bt.all_timings(16_000_000, 1_000_000, delays=BusDelays(100.0))


@pytest.mark.parametrize("given", ["0.875", "87.5"])
def test_sample_point_fraction_or_percent(capsys, given) -> None:
    assert main(["bittiming", "--clock", "16000000", "--bitrate", "500000", "--sample-point", given, "--json"]) == 0
    out = capsys.readouterr().out
    assert '"sample_point": 87.5' in out
