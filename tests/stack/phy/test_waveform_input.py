"""`canstack decode` on hostile or damaged input: every case is one line on stderr, exit status
2, naming the value and the rule, and nothing is allocated beyond what the file can hold."""

from __future__ import annotations

import json
import re
import zipfile

import pytest

from stack.cli import main
from stack.phy.waveform import read_vcd, render_edges, render_samples, write_raw
from stack.wire.frame import Frame

VCD_HEAD = (
    "$timescale 1 {unit} $end\n$scope module top $end\n$var wire 1 ! CAN_RX $end\n$upscope $end\n$enddefinitions $end\n"
)


def _cli(args, capsys):
    rc = main(args)
    cap = capsys.readouterr()
    return rc, cap.out, cap.err


def _one_line(rc, err):
    assert rc == 2, err
    assert err.startswith("canstack: error: ") and err.count("\n") == 1, err


def test_vcd_change_beyond_the_float_range_is_refused(tmp_path, capsys):
    # one change at #10^309 with a 1 s timescale: the exact sample period is 10^309 s, whose
    # rate (10^-309 Hz) is below the smallest normal float; 16 samples a bit at 125 kbit/s
    # would need 2e6 x 10^309 samples
    vcd = tmp_path / "far.vcd"
    vcd.write_text(VCD_HEAD.format(unit="s") + f"#{10**309}\n0!\n")
    rc, _, err = _cli(["decode", str(vcd), "--bitrate", "125000"], capsys)
    _one_line(rc, err)
    assert "#100000... (310 digits)" in err and "about 1e315 samples" in err and "400,000,000" in err
    # without a bit rate nothing subdivides the period: the rate itself is what cannot be used
    far = tmp_path / "farther.vcd"
    far.write_text(VCD_HEAD.format(unit="s") + f"#{10**400}\n0!\n")
    with pytest.raises(ValueError, match=r"sample period of about 1e400 s.*no usable rate"):
        read_vcd(far)


def test_vcd_time_going_backwards_is_refused_naming_the_line(tmp_path, capsys):
    vcd = tmp_path / "back.vcd"
    # lines 6..11: #0, 1!, #1000, 0!, #500, 1!
    vcd.write_text(VCD_HEAD.format(unit="ns") + "#0\n1!\n#1000\n0!\n#500\n1!\n")
    rc, _, err = _cli(["decode", str(vcd), "--bitrate", "125000"], capsys)
    _one_line(rc, err)
    assert f"{vcd} line 10: time #500 is earlier than #1000 (line 8): VCD times must not decrease" in err


def test_equal_vcd_times_are_accepted(tmp_path):
    vcd = tmp_path / "same.vcd"
    vcd.write_text(VCD_HEAD.format(unit="us") + "#0\n1!\n#8\n0!\n#8\n0!\n#16\n1!\n")
    assert read_vcd(vcd, bitrate=125_000).samples.count(0) == 16 * 1  # 8 us = 1 bit, 16 samples


def _session(path, samples: bytes, *, compression=zipfile.ZIP_STORED, metadata=None):
    meta = metadata or "[device 1]\ncapturefile=logic-1\nunitsize=1\nsamplerate=1 MHz\nprobe1=CAN_RX\n"
    with zipfile.ZipFile(path, "w", compression=compression) as zf:
        zf.writestr("version", "2")
        zf.writestr("metadata", meta)
        zf.writestr("logic-1", samples)


def _damage_member(path, member: str, offset: int, value: int) -> None:
    """Overwrite one byte of a member's stored data; the central directory stays intact."""
    with zipfile.ZipFile(path) as zf:
        info = zf.getinfo(member)
    raw = bytearray(path.read_bytes())
    # local file header: 30 bytes, then the name and the extra field (lengths at 26 and 28)
    start = info.header_offset
    data = (
        start
        + 30
        + int.from_bytes(raw[start + 26 : start + 28], "little")
        + int.from_bytes(raw[start + 28 : start + 30], "little")
    )
    raw[data + offset] = value
    path.write_bytes(bytes(raw))


@pytest.mark.parametrize(
    "compression,needle",
    [
        (zipfile.ZIP_STORED, "Bad CRC-32"),  # the data reads, but not what was stored
        (zipfile.ZIP_DEFLATED, "damaged"),  # the deflate stream itself is broken
    ],
)
def test_sigrok_session_with_damaged_sample_data(tmp_path, capsys, compression, needle):
    sr = tmp_path / "damaged.sr"
    samples = render_samples([Frame(0x123, b"\x11\x22")], 125_000, 1_000_000)
    _session(sr, samples, compression=compression)
    with zipfile.ZipFile(sr) as zf:  # the archive opens and lists its members
        assert "logic-1" in zf.namelist()
    # stored: a 1 (recessive) sample becomes 0; deflated: the first block header becomes the
    # reserved block type 3, which no inflater accepts
    _damage_member(sr, "logic-1", 0, 0x00 if compression == zipfile.ZIP_STORED else 0x07)
    rc, _, err = _cli(["decode", str(sr), "--bitrate", "125000"], capsys)
    _one_line(rc, err)
    assert str(sr) in err and "member 'logic-1' is damaged" in err and needle in err


@pytest.mark.parametrize("probe", ["probe99999999", "probe999999999", "probe9", "probe0"])
def test_sigrok_probe_beyond_the_sample_width_is_refused(tmp_path, capsys, probe):
    # unitsize 1: one byte a sample holds channels probe1..probe8, nothing else
    sr = tmp_path / "probes.sr"
    _session(
        sr,
        b"\x01" * 64,
        metadata=f"[device 1]\ncapturefile=logic-1\nunitsize=1\nsamplerate=1 MHz\nprobe1=CAN_RX\n{probe}=X\n",
    )
    rc, _, err = _cli(["decode", str(sr), "--bitrate", "125000"], capsys)
    _one_line(rc, err)
    assert f"names '{probe}', but a sample of unitsize 1 holds 8 channels (probe1..probe8)" in err


def test_total_probes_beyond_the_sample_width_allocates_nothing(tmp_path):
    # 'total probes' counts channels the device has; only 8 x unitsize of them can be in the data
    sr = tmp_path / "total.sr"
    frame = Frame(0x123, b"\x11\x22")
    _session(
        sr,
        render_samples([frame], 125_000, 1_000_000),
        metadata="[device 1]\ncapturefile=logic-1\nunitsize=1\ntotal probes=999999999\nsamplerate=1 MHz\nprobe1=CAN_RX\n",
    )
    from stack.phy.waveform import decode_file

    assert [r.to_frame() for r in decode_file(sr, 125_000)] == [frame]


@pytest.mark.parametrize(
    "bitrate,samplerate,shown", [("1e-10", "1e300", "inf"), ("1e-10", "1e200", "1e+210"), ("1", "2e9", "2e+09")]
)
def test_extreme_rates_are_checked_as_a_ratio(tmp_path, capsys, bitrate, samplerate, shown):
    # each value alone is a positive finite number; their ratio, the samples in a bit, is not usable
    raw = tmp_path / "idle.bin"
    write_raw(raw, b"\x01" * 100)
    rc, _, err = _cli(["decode", str(raw), "--bitrate", bitrate, "--samplerate", samplerate], capsys)
    _one_line(rc, err)
    assert f"gives {shown} samples per bit: at most 1e+09" in err
    with pytest.raises(ValueError, match=r"at most 1e\+09 can be rendered"):
        render_edges([Frame(1, b"")], float(bitrate), float(samplerate))


def test_sample_point_as_a_fraction(tmp_path, capsys):
    raw = tmp_path / "one.bin"
    frame = Frame(0x0C1, bytes.fromhex("4001087500000000"))
    write_raw(raw, render_samples([frame], 500_000, 8_000_000))
    rc, out, _ = _cli(
        [
            "decode",
            str(raw),
            "--bitrate",
            "500000",
            "--samplerate",
            "8e6",
            "--sample-point",
            "0.75",
            "--json",
            "--no-retry",
        ],
        capsys,
    )
    assert rc == 0 and '"crc_ok": true' in out
    rc, _, err = _cli(["decode", str(raw), "--bitrate", "500000", "--samplerate", "8e6", "--sample-point", "1"], capsys)
    _one_line(rc, err)
    assert "sample point 1 %: must be 50 <= sample point < 100" in err


def test_decode_shows_ids_as_0x_hex_in_text_and_integers_in_json(tmp_path, capsys):
    raw = tmp_path / "two.bin"
    frames = [Frame(0x0C1, b"\x01"), Frame(0x18FEF100, b"", extended=True), Frame(0x700, remote=True, dlc=2)]
    write_raw(raw, render_samples(frames, 500_000, 8_000_000))
    rc, out, _ = _cli(["decode", str(raw), "--bitrate", "500000", "--samplerate", "8e6"], capsys)
    assert rc == 0
    assert re.findall(r"^ +[0-9.]+ +(0x[0-9A-F]+) +(std|ext|stdR) ", out, re.M) == [
        ("0x0C1", "std"),
        ("0x18FEF100", "ext"),
        ("0x700", "stdR"),
    ]
    assert out.rstrip().endswith("3 frames, 0 error records")
    rc, out, _ = _cli(["decode", str(raw), "--bitrate", "500000", "--samplerate", "8e6", "--json"], capsys)
    assert [json.loads(line)["id"] for line in out.splitlines()] == [0x0C1, 0x18FEF100, 0x700]


@pytest.mark.parametrize(
    "make,needle",
    [
        (lambda t: t, "is a directory, not a capture file"),
        (lambda t: t / "afile" / "x.sr", "'{t}/afile' is a file, not a directory"),
        (lambda t: t / "none.sr", "none.sr: no such capture file"),
    ],
)
def test_missing_inputs_say_what_is_wrong(tmp_path, capsys, make, needle):
    (tmp_path / "afile").write_text("x")
    rc, _, err = _cli(["decode", str(make(tmp_path)), "--bitrate", "125000"], capsys)
    _one_line(rc, err)
    assert needle.format(t=tmp_path) in err


def test_render_checks_its_output_first_and_says_what_it_wrote(tmp_path, capsys):
    src = tmp_path / "f.jsonl"
    src.write_text('{"id": 291, "data": "1122"}\n')
    rc, _, err = _cli(
        ["render", "--bitrate", "500000", "--samplerate", "8e6", "--vcd", str(tmp_path / "no" / "o.vcd"), str(src)],
        capsys,
    )
    _one_line(rc, err)
    assert "--vcd" in err and "does not exist" in err
    out_path = tmp_path / "o.raw"
    rc, out, _ = _cli(
        ["render", "--bitrate", "500000", "--samplerate", "8e6", "--raw", str(out_path), str(src)], capsys
    )
    n = out_path.stat().st_size  # one byte a sample
    assert (
        rc == 0
        and out == f"render: 1 frame, {n:,} samples ({n / 8e6:.6g} s at 8e+06 samples/s) written to {out_path}\n"
    )
