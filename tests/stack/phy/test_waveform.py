"""CAN_RX waveforms: render -> decode round trips, the receiver's synchronisation rules, real
captures (golden values from the capture READMEs, CRC-15 from the spec, sigrok's decoder), and
bad input."""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import zipfile
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from stack.cli import main
from stack.phy.waveform import (
    BitReceiver,
    decode_file,
    decode_samples,
    read_capture,
    record_to_json,
    render_edges,
    render_samples,
    write_raw,
    write_vcd,
)
from stack.wire.coding import Field, crc15
from stack.wire.decoder import decode
from stack.wire.frame import Frame

CAPTURES = Path(__file__).resolve().parents[4] / "shared" / "corpus" / "captures"
MSG_222 = CAPTURES / "mcp2515dm-bm-125kbits_msg_222_5bytes.sr"
EXTMSG = CAPTURES / "mcp2515dm-bm-125kbits_extmsg_11223344_7bytes.sr"
NMEA = CAPTURES / "nmea2000_fuel_flow_gps_snippet.sr"
needs_corpus = pytest.mark.skipif(not MSG_222.is_file(), reason="../shared/corpus not present")
SIGROK = shutil.which("sigrok-cli")
needs_sigrok = pytest.mark.skipif(SIGROK is None, reason="sigrok-cli not installed")


def _frames_of(recs):
    return [r.to_frame() for r in recs]


# ---------------------------------------------------------------------------------------------
# Round trips on the project's own frames

frames_st = st.builds(
    lambda ext, ident, data, remote, dlc: Frame(
        ident & (0x1FFFFFFF if ext else 0x7FF),
        b"" if remote else data,
        extended=ext,
        remote=remote,
        dlc=dlc if remote else None,
    ),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=8),
    st.booleans(),
    st.integers(0, 8),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.lists(frames_st, min_size=1, max_size=4),
    st.sampled_from([(500_000, 8_000_000), (125_000, 4_000_000), (250_000, 2_500_000)]),
)
def test_render_decode_round_trip(frames, rates):
    bitrate, samplerate = rates
    samples = render_samples(frames, bitrate, samplerate)
    recs = decode_samples(samples, samplerate, bitrate, retry=False)
    assert _frames_of(recs) == frames
    # the CRC reported is CRC-15 over the unstuffed SOF..data bits, recomputed independently
    for rec, frame in zip(recs, frames):
        bits = [int(b) for i, b in enumerate(frame.bits.bits) if i not in frame.bits.stuff_positions]
        n_before_crc = (64 if frame.extended else 44) + 8 * len(frame.data) - 25
        assert rec.crc == crc15(bits[:n_before_crc])
        assert rec.crc_ok and rec.ack


@settings(max_examples=40, deadline=None)
@given(
    st.lists(frames_st, min_size=1, max_size=3),
    st.floats(-0.005, 0.005),
    st.floats(0.0, 0.03),
    st.integers(0, 2**16),
)
def test_round_trip_with_drift_and_jitter_needs_resynchronisation(frames, drift, jitter, seed):
    """Up to ±0.5 % clock error and ±3 % edge jitter. Without resynchronisation 0.5 % drift moves
    the sample point by 0.5 bit over a 100-bit frame; with it the phase error stays within
    2 x jitter + 10 bits x drift = 11 % < the 12.5 % after an 87.5 % sample point."""
    samples = render_samples(frames, 500_000, 16_000_000, drift=drift, jitter=jitter, seed=seed)
    recs = decode_samples(samples, 16_000_000, 500_000, retry=False)
    assert _frames_of(recs) == frames


def _long_run_frame() -> Frame:
    # runs of 5 equal bits + stuff bits: 10 bits between rec->dom edges, the worst case
    return Frame(0x7F0, bytes([0x00, 0xF8, 0x3E, 0x0F, 0x83, 0xE0, 0xF8, 0x3E]))


def test_resynchronisation_is_what_tolerates_drift():
    """Transmitter 1 % fast, runs of 10 bits between rec->dom edges: the phase error grows to
    0.1 bit between edges. SJW = 2 of 16 tq (12.5 %) corrects it at every edge (CAN's tolerance
    df <= SJW / (20 NBT) is for the worst case of both nodes); SJW = 1 of 25 tq (4 %) cannot, and
    the sample point walks out of the bit."""
    frame = _long_run_frame()
    samples = render_samples([frame], 500_000, 16_000_000, drift=-0.01)
    good = decode_samples(samples, 16_000_000, 500_000, retry=False, sjw=2)
    assert _frames_of(good) == [frame]
    bad = decode_samples(samples, 16_000_000, 500_000, retry=False, sjw=1, tq_per_bit=25, sample_point=88)
    assert bad and not bad[0].ok
    # and without drift the narrow SJW is enough
    clean = render_samples([frame], 500_000, 16_000_000)
    assert _frames_of(
        decode_samples(clean, 16_000_000, 500_000, retry=False, sjw=1, tq_per_bit=25, sample_point=88)
    ) == [frame]


def test_phase_correction_follows_the_can_rule():
    rx = BitReceiver(500_000, 16_000_000, sample_point=87.5, sjw=2)  # 32 samples, tq = 2 samples
    assert rx.sjw_samples == 4
    # e > 0 before the sample point: Phase_Seg1 lengthened by min(e, SJW)
    assert rx.phase_correction(100, 103) == (3, 0)
    assert rx.phase_correction(100, 110) == (4, 0)
    # edge after the sample point: e < 0 for the next bit, Phase_Seg2 shortened by min(|e|, SJW)
    assert rx.phase_correction(100, 130) == (0, 2)
    assert rx.phase_correction(100, 129) == (0, 3)
    assert rx.phase_correction(100, 129.5) == (0, 2.5)
    assert rx.phase_correction(100, 100) == (0, 0)


def test_hard_sync_only_after_bus_idle():
    """Hard synchronisation needs bus idle: 11 recessive bits, or 10 when the SOF comes in the
    third intermission bit after an error/overload delimiter; 9 is still inside traffic."""
    frame = Frame(0x123, b"\x55")
    samples = render_samples([frame], 500_000, 8_000_000)  # 11 idle bits of 16 samples first
    traffic = bytes(16)  # one dominant bit: the bus was busy before the recessive run
    assert decode_samples(traffic + samples[2 * 16 :], 8_000_000, 500_000) == []
    assert _frames_of(decode_samples(traffic + samples[1 * 16 :], 8_000_000, 500_000)) == [frame]
    assert _frames_of(decode_samples(traffic + samples, 8_000_000, 500_000)) == [frame]


@pytest.mark.parametrize("idle_bits", [1, 3, 9])
def test_a_frame_right_after_the_capture_starts_is_decoded(idle_bits):
    """What came before a capture is unknown: a capture triggered on a SOF with a short
    pre-trigger still gets its first frame (as sigrok does), when it decodes cleanly."""
    frames = [Frame(0x123, b"\x01\x02"), Frame(0x456, b"\x03")]
    samples = render_samples(frames, 125_000, 4_000_000, idle_bits=idle_bits)
    recs = decode_samples(samples, 4_000_000, 125_000)
    assert _frames_of(recs) == frames and recs[0].t == idle_bits * 32 / 4_000_000


def test_a_capture_that_starts_inside_a_frame_gives_no_false_record():
    frame = Frame(0x2AA, b"\x11\x22\x33")
    samples = render_samples([frame, frame], 125_000, 4_000_000)
    cut = samples[(11 + 20) * 32 :]  # from bit 20 of the first frame
    recs = decode_samples(cut, 4_000_000, 125_000)
    assert _frames_of(recs) == [frame] and all(r.ok for r in recs)


def test_back_to_back_frames_start_in_the_intermission():
    frames = [Frame(0x100, b"\x01"), Frame(0x1ABCDEF, b"", extended=True), Frame(0x7FF, remote=True, dlc=3)]
    runs, total, sofs = render_edges(frames, 250_000, 2_000_000)
    # frame k+1 starts exactly 3 bits (intermission) after frame k's EOF
    for k in range(2):
        assert sofs[k + 1] - sofs[k] == (frames[k].wire_bits + 3) * 8
    samples = b"".join((b"\x01" if lvl else b"\x00") * n for lvl, n in runs)
    assert len(samples) == total
    recs = decode_samples(samples, 2_000_000, 250_000)
    assert _frames_of(recs) == frames
    assert [r.sample for r in recs] == sofs


def test_timestamps_round_trip_and_overlap_is_refused():
    frames = [Frame(0x10, b"\xaa"), Frame(0x20, b"\xbb")]
    samples = render_samples(frames, 500_000, 8_000_000, times=[0.001, 0.0025])
    recs = decode_samples(samples, 8_000_000, 500_000)
    assert [r.t for r in recs] == [0.001, 0.0025]
    with pytest.raises(ValueError, match=r"frame 1 at t=0\.00101 s starts before"):
        render_samples(frames, 500_000, 8_000_000, times=[0.001, 0.00101])


def test_error_flag_is_an_error_record_and_decoding_resumes():
    f1, f2 = Frame(0x155, b"\x12\x34"), Frame(0x2AA, b"\x56")
    runs, _, sofs = render_edges([f1, f2], 500_000, 8_000_000, times=[0.0005, 0.001])
    samples = bytearray(b"".join((b"\x01" if lvl else b"\x00") * n for lvl, n in runs))
    # an error flag (6 dominant bits) over f1's data field
    start = sofs[0] + 25 * 16
    samples[start : start + 6 * 16] = b"\x00" * (6 * 16)
    recs = decode_samples(bytes(samples), 8_000_000, 500_000)
    assert len(recs) == 2
    err, ok = recs
    assert err.error is not None and err.error.kind == "stuff" and err.error_flag
    assert err.can_id == 0x155
    assert ok.to_frame() == f2
    j = record_to_json(err)
    assert j["error"]["kind"] == "stuff" and j["error"]["field"] in {"DLC", "DATA"} and j["error"]["flag"]


def test_truncated_frame_at_end_of_capture_is_an_error_record():
    frame = Frame(0x321, b"\x01\x02\x03\x04")
    samples = render_samples([frame, frame], 500_000, 8_000_000)
    cut = samples[: len(samples) - 16 * 11 - 16 * 40]  # second frame loses its last 40 bits
    recs = decode_samples(cut, 8_000_000, 500_000)
    assert recs[0].to_frame() == frame
    assert recs[1].error is not None and recs[1].error.kind == "truncated"
    assert recs[1].can_id == 0x321 and not recs[1].ok


def test_crc_error_is_reported_with_the_received_crc():
    frame = Frame(0x0C1, bytes([0x40, 0x01, 0x08, 0x75, 0, 0, 0, 0]))
    assert frame.bits.crc == 0x5B40  # the DESIGN example
    bits = frame.bits.bits

    # a data bit whose flip keeps the stuffing valid: the bit-level decoder says CRC error
    def flipped(p: int) -> str:
        return bits[:p] + ("1" if bits[p] == "0" else "0") + bits[p + 1 :]

    pos = next(p for p in frame.bits.fields[Field.DATA] if (e := decode(flipped(p)).error) and e.kind == "crc")
    samples = bytearray(render_samples([frame], 500_000, 8_000_000))
    sof = 11 * 16
    level = b"\x01" if bits[pos] == "0" else b"\x00"
    samples[sof + pos * 16 : sof + (pos + 1) * 16] = level * 16
    recs = decode_samples(bytes(samples), 8_000_000, 500_000)
    assert len(recs) == 1
    rec = recs[0]
    assert rec.error is not None and rec.error.kind == "crc" and not rec.crc_ok
    assert rec.crc == 0x5B40  # the CRC as sent, which no longer matches the corrupted data
    assert rec.data != frame.data and record_to_json(rec)["error"]["kind"] == "crc"


def test_vcd_and_raw_files_round_trip(tmp_path):
    frames = [Frame(0x222, bytes.fromhex("0011223344")), Frame(0x11223344, bytes(range(7)), extended=True)]
    runs, _, _ = render_edges(frames, 500_000, 8_000_000)
    vcd = tmp_path / "w.vcd"
    write_vcd(vcd, runs, 8_000_000)
    assert "$timescale 1 ns $end" in vcd.read_text()
    assert _frames_of(decode_file(vcd, 500_000)) == frames
    raw = tmp_path / "w.bin"
    write_raw(raw, render_samples(frames, 500_000, 8_000_000, bit=5))
    assert set(raw.read_bytes()) == {0, 32}
    assert _frames_of(decode_file(raw, 500_000, samplerate=8_000_000)) == frames


def test_sigrok_session_with_chunks_and_unitsize_2(tmp_path):
    """A newer-style .sr: samples split over logic-1-1, logic-1-2, 2 bytes a sample, CAN_RX on
    bit 9 (probe10)."""
    frame = Frame(0x5A5, b"\xde\xad")
    one = render_samples([frame], 125_000, 1_000_000)
    data = b"".join(bytes([0xFF, 0xFD | (v << 1)]) for v in one)  # bit 9 = byte 1, bit 1
    path = tmp_path / "chunks.sr"
    meta = "[global]\nsigrok version=0.5.1\n[device 1]\ncapturefile=logic-1\nunitsize=2\ntotal probes=16\nsamplerate=1 MHz\n"
    meta += "".join(f"probe{i + 1}=D{i}\n" for i in range(16) if i != 9) + "probe10=CAN_RX\n"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("version", "2")
        zf.writestr("metadata", meta)
        half = len(data) // 2 & ~1
        zf.writestr("logic-1-2", data[half:])
        zf.writestr("logic-1-1", data[:half])
    assert _frames_of(decode_file(path, 125_000)) == [frame]
    assert _frames_of(decode_file(path, 125_000, channel=9)) == [frame]
    with pytest.raises(ValueError, match=r"channel 'CAN_TX' not found .*9='CAN_RX'"):
        decode_file(path, 125_000, channel="CAN_TX")


# ---------------------------------------------------------------------------------------------
# Bad input, through the CLI (one line, exit 2, no traceback)


def _cli(args, capsys):
    rc = main(args)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def test_cli_not_a_capture(tmp_path, capsys):
    p = tmp_path / "notes.txt"
    p.write_text("hello, not a waveform\n")
    rc, _, err = _cli(["decode", str(p), "--bitrate", "125000"], capsys)
    assert rc == 2 and "not a capture" in err and "--samplerate" in err and err.count("\n") == 1
    fake = tmp_path / "fake.sr"
    fake.write_bytes(b"\x00\x01" * 100)
    rc, _, err = _cli(["decode", str(fake), "--bitrate", "125000"], capsys)
    assert rc == 2 and "not a capture" in err
    z = tmp_path / "other.sr"
    with zipfile.ZipFile(z, "w") as zf:
        zf.writestr("readme", "x")
    rc, _, err = _cli(["decode", str(z), "--bitrate", "125000"], capsys)
    assert rc == 2 and "zip without 'metadata'" in err


def test_cli_missing_channel_lists_the_available_ones(tmp_path, capsys):
    vcd = tmp_path / "w.vcd"
    write_vcd(vcd, render_samples([Frame(1, b"")], 500_000, 8_000_000), 8_000_000, name="RXD")
    rc, _, err = _cli(["decode", str(vcd), "--bitrate", "500000", "--channel", "CAN_RX"], capsys)
    assert rc == 2 and "channel 'CAN_RX' not found" in err and "0='RXD'" in err


@needs_corpus
def test_nmea2000_decodes_the_same_from_vcd_as_from_the_session_file(tmp_path):
    # 2 samples a bit: the VCD reader subdivides the edge grid for the receiver, and the
    # decoder must still treat it as the coarse capture it is (run-length rescue)
    cap = read_capture(NMEA)  # its only channel
    vcd = tmp_path / "nmea.vcd"
    write_vcd(vcd, cap.samples, cap.samplerate, name="CAN_RX")
    from_sr = decode_file(NMEA, 250_000)
    from_vcd = decode_file(vcd, 250_000, channel="CAN_RX")
    assert sum(r.ok for r in from_sr) == 113
    assert [(r.t, r.to_frame()) for r in from_vcd if r.ok] == [(r.t, r.to_frame()) for r in from_sr if r.ok]


@needs_corpus
def test_channel_number_that_is_a_name_and_an_index_is_ambiguous(capsys):
    # the MCP2515 captures name their channels '1', '2', 'CAN_RX', '4'...: '2' is the name of
    # index 1 and the index of CAN_RX
    rc, _, err = _cli(["decode", str(MSG_222), "--bitrate", "125000", "--channel", "2"], capsys)
    assert rc == 2 and "ambiguous" in err and "--channel '#2'" in err
    rc, out, _ = _cli(["decode", str(MSG_222), "--bitrate", "125000", "--channel", "#2", "--json"], capsys)
    ids = {json.loads(line)["id"] for line in out.splitlines() if line.startswith("{")}
    assert rc == 0 and ids == {0x222}  # the file's name says: message 0x222, 5 bytes


def test_cli_too_few_samples_per_bit(tmp_path, capsys):
    raw = tmp_path / "w.bin"
    write_raw(raw, render_samples([Frame(1, b"")], 500_000, 8_000_000))
    rc, _, err = _cli(["decode", str(raw), "--bitrate", "5000000", "--samplerate", "8000000"], capsys)
    assert rc == 2 and "1.6 samples per bit" in err and "at least 2" in err
    rc, _, err = _cli(["render", "--bitrate", "500000", "--samplerate", "600000", "--raw", str(raw), str(raw)], capsys)
    assert rc == 2


def test_cli_render_then_decode_json(tmp_path, capsys):
    frames = [
        {"id": 0x123, "extended": False, "remote": False, "dlc": 2, "data": "abcd"},
        {"t": 0.002, "id": 0x1FFFFFFF, "extended": True, "remote": False, "dlc": 0, "data": ""},
        {"id": 0x7FF, "remote": True, "dlc": 4, "data": ""},
    ]
    src = tmp_path / "in.jsonl"
    src.write_text("\n".join(json.dumps(f) for f in frames) + "\n")
    vcd = tmp_path / "out.vcd"
    rc, _, err = _cli(["render", "--bitrate", "500000", "--samplerate", "8000000", "--vcd", str(vcd), str(src)], capsys)
    assert rc == 0, err
    rc, out, err = _cli(["decode", str(vcd), "--bitrate", "500000", "--json"], capsys)
    assert rc == 0, err
    got = [json.loads(line) for line in out.splitlines()]
    assert [(g["id"], g["extended"], g["remote"], g["dlc"], g["data"]) for g in got] == [
        (0x123, False, False, 2, "abcd"),
        (0x1FFFFFFF, True, False, 0, ""),
        (0x7FF, False, True, 4, ""),
    ]
    assert got[1]["t"] == 0.002
    assert all(set(g) == {"t", "id", "extended", "remote", "dlc", "data", "crc", "crc_ok", "ack"} for g in got)
    assert all(g["crc_ok"] and g["ack"] for g in got)
    # decode's output renders again (crc is checked against the frame)
    again = tmp_path / "again.jsonl"
    again.write_text(out)
    rc, _, err = _cli(
        ["render", "--bitrate", "500000", "--samplerate", "8000000", "--raw", str(tmp_path / "r.bin"), str(again)],
        capsys,
    )
    assert rc == 0, err
    bad = tmp_path / "bad.jsonl"
    bad.write_text(json.dumps({**got[0], "crc": got[0]["crc"] ^ 1}) + "\n")
    rc, _, err = _cli(
        ["render", "--bitrate", "500000", "--samplerate", "8000000", "--raw", str(tmp_path / "x.bin"), str(bad)], capsys
    )
    assert rc == 2 and "line 1" in err and "does not match" in err


def test_cli_table(tmp_path, capsys):
    raw = tmp_path / "w.bin"
    write_raw(raw, render_samples([Frame(0x222, bytes.fromhex("0011223344"))], 125_000, 1_000_000))
    rc, out, _ = _cli(["decode", str(raw), "--bitrate", "125000", "--samplerate", "1e6"], capsys)
    assert rc == 0
    assert re.search(r"222\s+std\s+5\s+00 11 22 33 44\s+0x66DA\s+ok\s+ok\s+ok\s+yes", out)


# ---------------------------------------------------------------------------------------------
# Real captures (../shared/corpus)


@needs_corpus
def test_mcp2515_golden_standard_frame():
    recs = decode_file(MSG_222, 125_000, channel="CAN_RX")
    assert len(recs) == 3
    for r in recs:
        assert (r.can_id, r.extended, r.dlc, r.data, r.crc) == (0x222, False, 5, bytes.fromhex("0011223344"), 0x66DA)
        assert r.crc_ok and r.ack and r.ok and r.via == "receiver"
    # this session names bit 1 "2" (no traffic there) and "CAN_RX" is bit 2: "2" is ambiguous,
    # "#1" is the quiet channel by index
    with pytest.raises(ValueError, match="ambiguous"):
        decode_file(MSG_222, 125_000, channel="2")
    assert decode_file(MSG_222, 125_000, channel="#1") == []
    with pytest.raises(ValueError, match=r"channel '9' not found .* 2='CAN_RX'"):
        decode_file(MSG_222, 125_000, channel="9")


@needs_corpus
def test_mcp2515_golden_extended_frame():
    recs = decode_file(EXTMSG, 125_000)
    assert len(recs) == 5
    for r in recs:
        assert r.ok and r.extended and r.can_id == 0x11223344 and r.dlc == 7
        assert r.data == bytes.fromhex("00112233445566")


@needs_corpus
@pytest.mark.parametrize("load", [25, 50, 75])
def test_mcp2515_bus_load_all_frames_valid(load):
    recs = decode_file(CAPTURES / f"mcp2515dm-bm-125kbits_bus_load_{load}percent.sr", 125_000)
    assert recs and all(r.ok and r.crc_ok and r.via == "receiver" for r in recs)
    # every CRC was independently recomputed by the frame encoder (CRC-15 of the spec)
    assert all(r.to_frame().bits.crc == r.crc for r in recs)


def _sigrok_frames(path: Path, channel: str, bitrate: int) -> list[dict]:
    out = subprocess.run(
        [
            SIGROK,
            "-i",
            str(path),
            "-P",
            f"can:can_rx={channel}:nominal_bitrate={bitrate}",
            "-A",
            "can=fields",
            "--protocol-decoder-samplenum",
        ],
        capture_output=True,
        text=True,
        check=True,
    ).stdout
    frames: list[dict] = []
    for line in out.splitlines():
        m = re.match(r"(\d+)-\d+ can-1: (.*)", line)
        if not m:
            continue
        start, text = int(m.group(1)), m.group(2)
        if text == "Start of frame":
            frames.append({"sample": start, "data": [], "ext": False, "rtr": False})
        elif not frames:
            continue
        elif text.startswith(("Identifier:", "Full Identifier:")):
            frames[-1]["id"] = int(re.search(r"\((0x[0-9a-f]+)\)", text).group(1), 16)
            frames[-1]["ext"] = text.startswith("Full")
        elif text.startswith("Remote transmission request:"):
            frames[-1]["rtr"] = "remote" in text
        elif text.startswith("Data length code:"):
            frames[-1]["dlc"] = int(text.split(":")[1])
        elif text.startswith("Data byte"):
            frames[-1]["data"].append(int(text.split(":")[1], 16))
        elif text.startswith("CRC-15 sequence:"):
            frames[-1]["crc"] = int(text.split(":")[1], 16)
    for f in frames:
        f["crc_valid"] = False
        if "crc" in f and "dlc" in f:
            try:
                fr = Frame(
                    f["id"], b"" if f["rtr"] else bytes(f["data"]), extended=f["ext"], remote=f["rtr"], dlc=f["dlc"]
                )
            except ValueError:
                continue
            f["crc_valid"] = fr.bits.crc == f["crc"]
            f["frame"] = fr
    return frames


@pytest.mark.subprocess
@needs_corpus
@needs_sigrok
def test_bus_load_100_matches_sigrok():
    path = CAPTURES / "mcp2515dm-bm-125kbits_bus_load_100percent.sr"
    ours = decode_file(path, 125_000)
    theirs = _sigrok_frames(path, "CAN_RX", 125_000)
    assert len(ours) == len(theirs) == 286
    assert all(r.ok for r in ours)
    assert [r.to_frame() for r in ours] == [f["frame"] for f in theirs]
    assert all(abs(r.sample - f["sample"]) <= 1 for r, f in zip(ours, theirs))


@pytest.mark.subprocess
@needs_corpus
@needs_sigrok
def test_nmea2000_hard_case_beats_sigrok():
    """2 samples a bit: we get every frame of the capture CRC-valid; sigrok reports more 'frames'
    (some start inside other frames) of which far fewer have a valid CRC."""
    ours = decode_file(NMEA, 250_000, channel="0")
    theirs = _sigrok_frames(NMEA, "0", 250_000)
    valid = [r for r in ours if r.ok]
    assert all(r.crc_ok for r in valid)
    sigrok_valid = [f for f in theirs if f["crc_valid"]]
    assert len(valid) > len(sigrok_valid)
    # every frame sigrok got right, we got too, at the same place
    by_sample = {r.sample: r.to_frame() for r in valid}
    for f in sigrok_valid:
        assert any(by_sample.get(f["sample"] + d) == f["frame"] for d in (-1, 0, 1))
    # sigrok's SOFs that do not follow bus idle are not frames: none of them has a valid CRC
    starts = {r.sample for r in ours}
    extra = [f for f in theirs if not any(f["sample"] + d in starts for d in (-1, 0, 1))]
    assert not any(f["crc_valid"] for f in extra)
    assert len(valid) >= len(theirs) - len(extra)


@needs_corpus
def test_nmea2000_every_frame_after_bus_idle_is_recovered():
    ours = decode_file(NMEA, 250_000, channel=0)
    assert len(ours) == 113 and all(r.ok for r in ours)
    # the plain CAN bit receiver alone gets fewer: quantisation of 1/2 bit defeats it on some
    plain = decode_file(NMEA, 250_000, channel=0, retry=False)
    assert sum(r.ok for r in plain) < 113


@pytest.mark.subprocess
@needs_corpus
@needs_sigrok
def test_sigrok_exported_vcd_decodes_like_the_session(tmp_path):
    vcd = tmp_path / "m.vcd"
    subprocess.run([SIGROK, "-i", str(MSG_222), "-O", "vcd", "-o", str(vcd)], check=True, capture_output=True)
    a = decode_file(vcd, 125_000)
    b = decode_file(MSG_222, 125_000)
    assert [(r.t, r.to_frame()) for r in a] == [(r.t, r.to_frame()) for r in b]


@pytest.mark.subprocess
@needs_sigrok
def test_sigrok_decodes_our_rendered_vcd(tmp_path):
    """An independent receiver (sigrok's CAN decoder) reads our waveform."""
    frames = [Frame(0x0C1, bytes([0x40, 0x01, 0x08, 0x75, 0, 0, 0, 0])), Frame(0x1234567, b"\x99", extended=True)]
    vcd = tmp_path / "r.vcd"
    write_vcd(vcd, render_samples(frames, 500_000, 8_000_000), 8_000_000)
    theirs = _sigrok_frames(vcd, "CAN_RX", 500_000)
    assert [f["frame"] for f in theirs] == frames
    assert [f["crc"] for f in theirs] == [0x5B40, frames[1].bits.crc]


def _session(path, metadata: bytes, samples: bytes = b"\x01" * 64):
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("version", "2")
        zf.writestr("metadata", metadata)
        zf.writestr("logic-1-1", samples)


@pytest.mark.parametrize(
    "metadata,needle",
    [
        (b"\xff\x00[x", "metadata is not an ini file (File contains no section headers.)"),
        (b"[device 1]\ncapturefile=logic-1\nunitsize=two\nsamplerate=1 MHz\nprobe1=CAN_RX\n", "invalid literal"),
        (b"[device 1]\ncapturefile=logic-1\nunitsize=0\nsamplerate=1 MHz\nprobe1=CAN_RX\n", "unitsize 0 outside 1..8"),
    ],
)
def test_cli_bad_session_metadata_is_one_line_naming_the_file(tmp_path, capsys, metadata, needle):
    sr = tmp_path / "bad.sr"
    _session(sr, metadata)
    rc, _, err = _cli(["decode", str(sr), "--bitrate", "125000"], capsys)
    assert rc == 2 and needle in err and str(sr) in err and err.count("\n") == 1


def test_cli_render_refuses_a_waveform_too_long_to_build(tmp_path, capsys):
    src = tmp_path / "far.jsonl"
    for t, needle in (("1e300", "span 1e+300 s"), ("1000", "span 1000 s"), ("Infinity", "'t' inf must be")):
        src.write_text(f'{{"id": 291, "t": {t}}}\n')
        rc, _, err = _cli(
            ["render", "--bitrate", "500000", "--samplerate", "8000000", "--raw", str(tmp_path / "o.raw"), str(src)],
            capsys,
        )
        assert rc == 2 and needle in err and err.count("\n") == 1
    src.write_bytes(b"\xff\xfe{}")
    rc, _, err = _cli(
        ["render", "--bitrate", "500000", "--samplerate", "8000000", "--raw", str(tmp_path / "o.raw"), str(src)], capsys
    )
    assert rc == 2 and "not a text file of JSON lines" in err


def test_samples_per_bit_message_is_not_rounded(tmp_path, capsys):
    raw = tmp_path / "w.bin"
    write_raw(raw, bytes([1]) * 1000)
    rc, _, err = _cli(["decode", str(raw), "--bitrate", "2000001", "--samplerate", "4000000"], capsys)
    assert rc == 2 and "1.999999 samples per bit" in err


def test_a_frame_cut_off_by_the_end_of_the_capture_keeps_what_was_received():
    f = Frame(0x222, bytes.fromhex("0011223344"))
    samples = render_samples([f], 125_000, 4_000_000)
    recs = decode_samples(samples[: (11 + 80) * 32], 4_000_000, 125_000)
    (r,) = recs
    assert r.error.kind == "truncated" and r.error.position == 80
    assert (r.can_id, r.dlc, r.data, r.crc) == (0x222, 5, f.data, f.bits.crc)  # 0x66DA, the golden CRC


def test_capture_receiver_agrees_with_the_time_quantum_receiver_on_drift():
    """Two implementations of the same synchronisation rules: the decoder's sample-domain
    receiver and `stack.phy.sync.SyncReceiver` (one tick a time quantum). At 16 samples a bit, with
    one sample a quantum, they receive the same worst-case frames as the transmitter's bit time
    drifts, and their limits of drift (both ways) agree to 0.2 % of the bit time."""
    from stack.phy.sync import SyncReceiver, worst_case_frames

    frames = list(worst_case_frames())

    def both(drift: float) -> tuple[bool, bool]:
        s = render_samples(frames, 500_000, 8_000_000, drift=drift)
        rx = SyncReceiver(13, 2, 2)  # 16 tq: sample point 87.5 %, SJW 2 as given to the decoder
        got = [r.frame for r in map(rx.tick, s) if r is not None and r.frame is not None]
        dec = [r.to_frame() for r in decode_samples(s, 8_000_000, 500_000, sjw=2, retry=False) if r.ok]
        return got == frames, dec == frames

    def limit(sign: int, which: int) -> float:
        d = 0.0
        while d < 0.05 and both(sign * (d + 0.001))[which]:
            d += 0.001
        return d

    assert both(0.0) == (True, True)
    for sign in (1, -1):
        tq, sample = limit(sign, 0), limit(sign, 1)
        assert tq > 0.003 and abs(tq - sample) <= 0.002 + 1e-9, (sign, tq, sample)
