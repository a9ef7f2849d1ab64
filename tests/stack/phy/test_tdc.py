"""Transmitter delay compensation in the synchronisation simulation: a loop delay longer than a
data bit breaks a CAN FD transmitter without TDC and not with it (what ISO 11898-1:2015 has TDC
for), the limits worked out here from the bit timing, and the CAN FD receiver in time quanta."""

from __future__ import annotations

import math

import can
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from stack.cli import main
from stack.phy.bittiming_fd import solve_fd
from stack.phy.receiver import SyncReceiver
from stack.phy.tdc import TDC_FRAMES, bit_starts, max_loop_delay, transmit_fd
from stack.wire.coding import Field
from stack.wire.fd import FD_LENGTHS
from stack.wire.frame import Frame

# 40 MHz, 500 kbit/s / 5 Mbit/s on M_CAN as the kernel sets it: the data bit is 8 clock periods
# of 25 ns = 200 ns, sampled after 6 (150 ns); TDCO = 6
FD = solve_fd(40_000_000, 500_000, 5_000_000, limits="m_can")
TIMING = FD.timing
PERIOD = 25.0


def test_the_timing_is_what_the_comments_say() -> None:
    assert (TIMING.data_brp, TIMING.dbt, TIMING.data_tseg1, FD.tdc.tdco) == (1, 8, 5, 6)
    assert (TIMING.nom_brp, TIMING.nbt, TIMING.nom_tseg1) == (1, 80, 69)


@pytest.mark.parametrize("frame", TDC_FRAMES, ids=["std", "ext"])
def test_a_loop_delay_longer_than_a_data_bit_needs_tdc(frame: Frame) -> None:
    """255 ns of loop delay, longer than the 200 ns data bit: at its sample point the transmitter
    reads back an earlier bit of its own and sees a bit error in the data phase; with TDC it
    measures the delay (ceil(255 / 25) = 11 clock periods at the FDF/res edge) and checks each
    data bit at SSP = 11 + 6 periods after sending it, 425 - 255 = 170 ns into the bit as it
    comes back. The receiver decodes the frame either way: it needs no TDC."""
    without = transmit_fd(frame, TIMING, 255.0)
    assert not without.ok and without.kind == "bit" and "at its sample point" in without.detail
    fb = frame.bits
    assert fb.fields[Field.BRS][0] < without.position <= fb.crc_delim  # in the data phase
    with_tdc = transmit_fd(frame, TIMING, 255.0, FD.tdc.tdco)
    assert with_tdc.ok and (with_tdc.tdcv, with_tdc.ssp) == (11, 17)
    for r in (without, with_tdc):
        assert r.received is not None and r.received.ok and r.received.frame == frame


def test_without_tdc_the_loop_delay_must_end_before_the_data_sample_point() -> None:
    """At its data sample point, 6 periods = 150 ns after sending a bit, the transmitter reads its
    RX pin: the bit is back there if the loop delay is at most 150 ns."""
    for delay in (0.0, 60.0, 149.0):
        assert all(transmit_fd(f, TIMING, delay).ok for f in TDC_FRAMES)
    for delay in (151.0, 199.0, 420.0):
        assert not transmit_fd(TDC_FRAMES[0], TIMING, delay).ok
    longest, first = max_loop_delay(TIMING)
    assert longest == pytest.approx(150.0, abs=1.0) and first is not None and first.kind == "bit"


def test_with_tdc_the_nominal_sample_point_or_tdcv_is_the_limit() -> None:
    """With TDC every data bit is checked TDCO periods into its delayed copy, whatever the delay;
    what limits the delay then is the nominal phase (its bit back before the sample point after
    70 periods = 1750 ns) or TDCV's range (at most 20 periods: 500 ns)."""
    longest, first = max_loop_delay(TIMING, FD.tdc.tdco, limit_ns=4000)
    assert longest == pytest.approx(1750.0, abs=1.0)
    assert first is not None and first.kind == "bit" and first.position is not None
    assert first.position <= FD.nominal.timing.nbt  # a nominal-phase bit, not a data bit
    longest, first = max_loop_delay(TIMING, FD.tdc.tdco, tdcv_max=20, limit_ns=4000)
    assert longest == pytest.approx(20 * PERIOD, abs=1.0) and first is not None and first.kind == "tdcv"


@pytest.mark.parametrize(
    "timing,tdco,delay",
    [
        # 80 MHz, 1 Mbit/s / 8 Mbit/s: data bit 125 ns, sample point after 7 of 10 periods
        (
            can.BitTimingFd(80_000_000, 1, 59, 20, 10, 1, 6, 3, 1),
            7,
            300.0,
        ),
        # 80 MHz with prescaler 2 in both phases (CiA 601-1): 500 kbit/s / 2 Mbit/s, data bit
        # 20 tq of 25 ns = 500 ns, sample point after 15 tq = 30 clock periods
        (
            can.BitTimingFd(80_000_000, 2, 63, 16, 8, 2, 14, 5, 2),
            30,
            620.0,
        ),
    ],
)
def test_tdc_at_other_bit_rates_and_prescalers(timing: can.BitTimingFd, tdco: int, delay: float) -> None:
    period = 1e9 / timing.f_clock
    assert delay > timing.data_brp * timing.dbt * period  # longer than a data bit
    frame = TDC_FRAMES[1]
    assert not transmit_fd(frame, timing, delay).ok
    r = transmit_fd(frame, timing, delay, tdco)
    assert r.ok and r.tdcv == math.ceil(delay / period)


def test_bit_starts_follow_iso_at_the_switches() -> None:
    """BRS lasts the nominal sample point (70 periods) plus the data Phase_Seg2 (2), the CRC
    delimiter the data sample point (6) plus the nominal Phase_Seg2 (10); the total is the frame's
    nominal bits at 80 periods and its data bits at 8 (FrameBits.duration_ns)."""
    frame = TDC_FRAMES[0]
    fb = frame.bits
    starts, samples = bit_starts(frame, TIMING)
    brs, delim = fb.fields[Field.BRS][0], fb.crc_delim
    assert starts[brs + 1] - starts[brs] == 72 and starts[delim + 1] - starts[delim] == 16
    assert samples[brs] == 70 and samples[brs + 1] == 6 and samples[delim] == 6 and samples[delim + 1] == 70
    assert starts[-1] * PERIOD == fb.duration_ns(500_000, 5_000_000)


def test_the_fd_receiver_switches_at_brs_and_back_at_the_crc_delimiter() -> None:
    """Fed a frame one bit time at a time, the receiver is in the data phase exactly from the
    sample point of BRS to that of the CRC delimiter."""
    frame = Frame(0x2AB, bytes([0x12, 0x34, 0x56]), fd=True, brs=True)
    fb = frame.bits
    starts, _ = bit_starts(frame, TIMING)
    rx = SyncReceiver.from_timing_fd(TIMING)
    phase_at_sample: list[bool] = []
    res = None
    for tick in range(-5, starts[-1] + 5):
        k = max(0, min(len(starts) - 1, next(i for i, s in enumerate(starts) if s > tick) - 1)) if tick >= 0 else -1
        sampled = len(rx.sampled)
        res = rx.tick(int(fb.bits[k]) if 0 <= k < fb.length else 1)
        if len(rx.sampled) > sampled:
            phase_at_sample.append(rx.in_data_phase)
        if res is not None:
            break
    assert res is not None and res.ok and res.frame == frame
    brs, delim = fb.fields[Field.BRS][0], fb.crc_delim
    assert phase_at_sample == [brs <= i < delim for i in range(len(phase_at_sample))]


fd_frames = st.builds(
    lambda ext, ident, n, seed: Frame(
        ident & (0x1FFFFFFF if ext else 0x7FF),
        bytes((seed * (i + 7)) & 0xFF for i in range(n)),
        extended=ext,
        fd=True,
        brs=True,
    ),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.sampled_from(FD_LENGTHS),
    st.integers(0, 255),
)


@settings(max_examples=25, deadline=None)
@given(fd_frames, st.floats(-2000, 2000), st.floats(0.05, 0.95), st.floats(0, 2000))
def test_the_fd_receiver_resynchronises_in_the_data_phase(frame, drift_ppm, phase, delay_ns):
    """A receiver 0.2 % off, anywhere on the bus: the data SJW (1 tq of 8) corrects the 10-bit
    phase drift of 0.2 % (2 % of a bit) at every edge. The transmitter has no loop delay."""
    r = transmit_fd(frame, TIMING, 0.0, rx_delay_ns=delay_ns, rx_drift_ppm=drift_ppm, phase=phase)
    assert r.ok, r.describe()


def test_cli_sync_loop_delay(capsys: pytest.CaptureFixture[str]) -> None:
    rc = main(
        [
            "sync",
            "--clock",
            "40000000",
            "--bitrate",
            "500000",
            "--data-bitrate",
            "5000000",
            "--loop-delay",
            "255",
        ]
    )
    out = capsys.readouterr().out
    assert rc == 0
    assert "without TDC: fails" in out and "with TDC (TDCO 6): ok, TDCV 11" in out
    assert "largest loop delay without TDC: 150 ns" in out


@pytest.mark.parametrize(
    "argv,needle",
    [
        (["--loop-delay", "100"], "--loop-delay needs --data-bitrate"),
        (["--data-bitrate", "5000000", "--controller", "sja1000"], "no CAN FD data phase"),
        (["--data-bitrate", "5000000", "--loop-delay", "-1"], "-1"),
    ],
)
def test_cli_sync_fd_errors(capsys: pytest.CaptureFixture[str], argv: list[str], needle: str) -> None:
    rc = main(["sync", "--clock", "40000000", "--bitrate", "500000", *argv])
    out, err = capsys.readouterr()
    assert rc == 2 and out == "" and err.count("\n") == 1 and needle in err
