"""CAN FD waveforms: frames with BRS rendered at two bit rates and decoded back, the timing of the
rate switches against ISO 11898-1:2015, sigrok's CAN FD decoder reading our waveforms frame by
frame, and the command line."""

from __future__ import annotations

import json
import random
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stack.cli import main
from stack.phy.waveform import decode_samples, render_edges, render_samples, write_vcd
from stack.wire.coding import Field
from stack.wire.fd import FD_LENGTHS
from stack.wire.frame import Frame

SIGROK = shutil.which("sigrok-cli")
needs_sigrok = pytest.mark.skipif(SIGROK is None, reason="sigrok-cli not installed")

fd_frames = st.builds(
    lambda ext, ident, n, fill, brs, esi: Frame(
        ident & (0x1FFFFFFF if ext else 0x7FF),
        bytes(fill[i % len(fill)] for i in range(n)),
        extended=ext,
        fd=True,
        brs=brs,
        esi=esi,
    ),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.sampled_from(FD_LENGTHS),
    st.binary(min_size=1, max_size=8),
    st.booleans(),
    st.booleans(),
)
classic_frames = st.builds(lambda ident, data: Frame(ident, data), st.integers(0, 0x7FF), st.binary(max_size=8))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(st.one_of(fd_frames, classic_frames), min_size=1, max_size=4),
    st.sampled_from(
        [(500_000, 2_000_000, 40_000_000), (1_000_000, 5_000_000, 80_000_000), (250_000, 1_000_000, 8_000_000)]
    ),
)
def test_fd_round_trip(frames, rates):
    bitrate, data_bitrate, samplerate = rates
    samples = render_samples(frames, bitrate, samplerate, data_bitrate=data_bitrate)
    recs = decode_samples(samples, samplerate, bitrate, data_bitrate=data_bitrate, retry=False)
    assert [r.to_frame() for r in recs] == frames
    # the CRC received is the frame's CRC-15/17/21 (the wire layer's, checked against the CRC
    # catalogue there), and the receiver checked it
    assert [r.crc for r in recs] == [f.bits.crc for f in frames]
    assert all(r.crc_ok and r.ack and r.via == "receiver" for r in recs)


@settings(max_examples=30, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(fd_frames, min_size=1, max_size=3), st.floats(-0.003, 0.003), st.floats(0.0, 0.03), st.integers(0, 2**16)
)
def test_fd_round_trip_with_drift_and_jitter(frames, drift, jitter, seed):
    """0.3 % clock error and 3 % edge jitter: a 64-byte data phase lasts ~600 data bits, so the
    receiver must resynchronise in the data phase too (10 data bits between edges at most)."""
    samples = render_samples(frames, 500_000, 40_000_000, data_bitrate=2_000_000, drift=drift, jitter=jitter, seed=seed)
    recs = decode_samples(samples, 40_000_000, 500_000, data_bitrate=2_000_000, retry=False)
    assert [r.to_frame() for r in recs] == frames


def test_the_rate_switches_where_iso_puts_them():
    """ISO 11898-1:2015: the data bit rate runs from the sample point of BRS to the sample point of
    the CRC delimiter. With the transmitter's sample points 80 % / 60 % at 500 kbit/s / 2 Mbit/s
    (100 samples / 25 samples a bit), BRS lasts 80 + 0.4 x 25 = 90 samples, the CRC delimiter
    0.6 x 25 + 20 = 35, each data bit 25 and each other bit 100."""
    frame = Frame(0x555, bytes([0x0F] * 8), fd=True, brs=True)
    runs, _, sofs = render_edges(
        [frame], 500_000, 50_000_000, data_bitrate=2_000_000, sample_point=80, data_sample_point=60, idle_bits=11
    )
    fb = frame.bits
    brs, delim = fb.fields[Field.BRS][0], fb.crc_delim
    lengths = [90 if i == brs else 35 if i == delim else 25 if brs < i < delim else 100 for i in range(fb.length)]
    starts = [sofs[0] + sum(lengths[:i]) for i in range(fb.length + 1)]
    edges, t = [], 0
    for _, n in runs:
        t += n
        edges.append(t)
    want = [starts[i] for i in range(1, fb.length) if fb.bits[i] != fb.bits[i - 1]]
    assert [e for e in edges if sofs[0] < e < starts[-1]] == want


def test_a_classical_receiver_does_not_take_fd_frames():
    """Decoded without a data bit rate (a CAN 2.0 receiver), an FD frame is not a frame: the
    FD-intolerant node of a mixed network sees errors."""
    frame = Frame(0x123, bytes(range(12)), fd=True, brs=True)
    samples = render_samples([frame], 500_000, 40_000_000, data_bitrate=2_000_000)
    recs = decode_samples(samples, 40_000_000, 500_000, retry=False)
    assert recs and not any(r.ok for r in recs)


def test_rendering_fd_needs_a_data_bit_rate():
    frame = Frame(0x1, b"\x01", fd=True, brs=True)
    with pytest.raises(ValueError, match=r"frame 0 .* switches bit rate .BRS.: it needs a data bit rate"):
        render_samples([frame], 500_000, 8_000_000)
    with pytest.raises(ValueError, match="at the data bit rate 5000000 bit/s: at least 2"):
        render_samples([frame], 500_000, 8_000_000, data_bitrate=5_000_000)
    with pytest.raises(ValueError, match="at least the nominal"):
        render_samples([frame], 500_000, 8_000_000, data_bitrate=250_000)
    # a frame without BRS needs none
    assert render_samples([Frame(0x1, b"\x01", fd=True)], 500_000, 8_000_000)


# ---------------------------------------------------------------------------------------------
# sigrok's CAN decoder (libsigrokdecode 'can', which reads CAN FD: nominal_bitrate, fast_bitrate)


def _sigrok_fd(path: Path, bitrate: int, data_bitrate: int) -> list[dict]:
    out = subprocess.run(
        [
            SIGROK,
            "-i",
            str(path),
            "-P",
            f"can:can_rx=CAN_RX:nominal_bitrate={bitrate}:fast_bitrate={data_bitrate}",
            "-A",
            "can=fields",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    frames: list[dict] = []
    for line in out.splitlines():
        text = line.split("can-1: ", 1)[-1]
        if text == "Start of frame":
            frames.append({"data": [], "ext": False, "fd": False, "brs": False, "esi": False})
        elif not frames:
            continue
        elif text.startswith(("Identifier:", "Full Identifier:")):
            frames[-1]["id"] = int(re.search(r"\((0x[0-9a-f]+)\)", text).group(1), 16)
            frames[-1]["ext"] = text.startswith("Full")
        elif text.startswith("Flexible data format:"):
            frames[-1]["fd"] = text.endswith("1")
        elif text.startswith("Bit rate switch:"):
            frames[-1]["brs"] = text.endswith("1")
        elif text.startswith("Error state indicator:"):
            frames[-1]["esi"] = text.endswith("1")
        elif text.startswith("Data length code:"):
            frames[-1]["dlc"] = int(text.split(":")[1])
        elif text.startswith("Data byte"):
            frames[-1]["data"].append(int(text.split(":")[1], 16))
        elif m := re.match(r"CRC-(\d+) sequence: 0x([0-9a-f]+)", text):
            frames[-1]["crc_width"], frames[-1]["crc_field"] = int(m.group(1)), int(m.group(2), 16)
        elif text.startswith("CRC delimiter:"):
            frames[-1]["crc_delimiter"] = int(text.split(":")[1])
    return frames


def _sigrok_misreads_crc_field(frame: Frame) -> bool:
    """sigrok's decoder (0.5.x) keeps removing stuff bits for 17 bits after the data field, where
    an FD frame has fixed stuff bits instead: when five equal bits end there (the last data bits
    included), it drops the next bit as a stuff bit and counts the CRC field one bit short."""
    fb = frame.bits
    raw, first = fb.bits, fb.fixed_stuff_positions[0]
    return any(
        len(set(raw[i - 5 : i])) == 1 and raw[i] != raw[i - 1] for i in range(first, min(first + 17, fb.crc_delim))
    )


def _fd_sample_frames() -> list[Frame]:
    rng = random.Random(2024)
    out = []
    for k in range(60):
        n = [0, 1, 3, 5, 8, 12, 20, 24, 32, 48, 64][k % 11]  # not 16: below
        ext = k % 3 == 0
        ident = rng.randrange(1 << (29 if ext else 11))
        out.append(Frame(ident, rng.randbytes(n), extended=ext, fd=True, brs=k % 4 != 0))
    return out


@pytest.mark.subprocess
@needs_sigrok
@pytest.mark.parametrize("rates", [(500_000, 2_000_000, 40_000_000), (1_000_000, 5_000_000, 50_000_000)])
def test_sigrok_reads_our_fd_waveform_frame_by_frame(tmp_path: Path, rates: tuple[int, int, int]) -> None:
    """sigrok's CAN decoder reads every frame of our FD waveform: identifier, FDF, BRS, ESI, DLC
    and data. Its CRC annotation is the CRC field as sent (stuff count, parity, fixed stuff
    bits and CRC, 27 or 32 bits): where its destuffing leaves that field alone it equals ours
    bit for bit, so the stuff count and the CRC-17/21 inside it are ours; where it drops a
    fixed stuff bit (see `_sigrok_misreads_crc_field`) its CRC delimiter lands one bit late, on
    a dominant bit. ESI is left dominant: sigrok resynchronises after BRS only on an edge and
    samples a recessive ESI a bit late. 16-byte frames are left out: sigrok takes CRC-21 for them
    (ISO 11898-1:2015 uses CRC-17 up to 16 bytes)."""
    bitrate, data_bitrate, samplerate = rates
    frames = _fd_sample_frames() + [Frame(0x0C1, bytes([0x40, 0x01, 0x08, 0x75, 0, 0, 0, 0]))]
    vcd = tmp_path / "fd.vcd"
    write_vcd(vcd, render_samples(frames, bitrate, samplerate, data_bitrate=data_bitrate), samplerate)
    theirs = _sigrok_fd(vcd, bitrate, data_bitrate)
    assert len(theirs) == len(frames)
    clean = 0
    for f, s in zip(frames, theirs):
        assert (s["id"], s["ext"], s["fd"], s["brs"], s["esi"]) == (f.can_id, f.extended, f.fd, f.brs, f.esi)
        assert (s["dlc"], bytes(s["data"])) == (f.dlc, f.data)
        if not f.fd:
            assert (s["crc_width"], s["crc_field"], s["crc_delimiter"]) == (15, f.bits.crc, 1)
            continue
        fb = f.bits
        assert s["crc_width"] == fb.crc_width
        field = fb.bits[fb.fixed_stuff_positions[0] : fb.crc_delim]
        if _sigrok_misreads_crc_field(f):
            assert s["crc_delimiter"] == 0
            continue
        clean += 1
        assert s["crc_field"] == int(field, 2) and s["crc_delimiter"] == 1
        # the field less its fixed stuff bits (every 5th from the first) is the stuff count (Gray
        # code + parity, 4 bits) and the CRC
        bits = "".join(b for i, b in enumerate(field) if i % 5)
        assert int(bits[:4], 2) == fb.stuff_count_bits and int(bits[4:], 2) == fb.crc
    assert clean >= len(frames) // 2


# ---------------------------------------------------------------------------------------------
# Command line


def test_cli_fd_render_decode_round_trip(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    frames = [
        Frame(0x123, bytes(range(20)), fd=True, brs=True),
        Frame(0x0C1, bytes([0x40, 0x01, 0x08, 0x75, 0, 0, 0, 0])),
        Frame(0x1ABCDE, b"\xa5" * 8, extended=True, fd=True, esi=True),
    ]
    src = tmp_path / "in.jsonl"
    src.write_text(
        "\n".join(
            json.dumps(
                {"id": f.can_id, "extended": f.extended, "fd": f.fd, "brs": f.brs, "esi": f.esi, "data": f.data.hex()}
            )
            for f in frames
        )
    )
    vcd = tmp_path / "fd.vcd"
    argv = ["--bitrate", "500000", "--data-bitrate", "4000000"]
    assert main(["render", str(src), *argv, "--samplerate", "40000000", "--vcd", str(vcd)]) == 0
    capsys.readouterr()
    assert main(["decode", str(vcd), *argv, "--json"]) == 0
    lines = [json.loads(x) for x in capsys.readouterr().out.splitlines()]
    assert [(d["id"], bytes.fromhex(d["data"]), d.get("fd"), d.get("brs"), d.get("esi")) for d in lines] == [
        (0x123, bytes(range(20)), True, True, False),
        (0x0C1, frames[1].data, None, None, None),  # classical records keep their keys
        (0x1ABCDE, b"\xa5" * 8, True, False, True),
    ]
    assert [d["crc"] for d in lines] == [f.bits.crc for f in frames]
    # the decoded JSON renders the same waveform again
    again = tmp_path / "again.jsonl"
    again.write_text("\n".join(json.dumps(d) for d in lines))
    vcd2 = tmp_path / "again.vcd"
    assert main(["render", str(again), *argv, "--samplerate", "40000000", "--vcd", str(vcd2)]) == 0
    assert vcd2.read_text() == vcd.read_text().replace(str(src.name), str(again.name))
    # the table marks FD frames and their bit rate switch
    main(["decode", str(vcd), *argv])
    table = capsys.readouterr().out
    assert "stdFB" in table and "extFE" in table and "3 frames, 0 error records" in table


def test_cli_fd_bad_input_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    src = tmp_path / "in.jsonl"
    src.write_text(json.dumps({"id": 1, "fd": True, "brs": True, "data": "01"}))
    rc = main(["render", str(src), "--bitrate", "500000", "--samplerate", "8000000", "--vcd", str(tmp_path / "x.vcd")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "needs a data bit rate" in err
    src.write_text(json.dumps({"id": 1, "fd": True, "remote": True}))
    rc = main(["render", str(src), "--bitrate", "500000", "--samplerate", "8000000", "--vcd", str(tmp_path / "x.vcd")])
    err = capsys.readouterr().err
    assert rc == 2 and err.count("\n") == 1 and "line 1" in err and "remote" in err
