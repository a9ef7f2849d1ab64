"""`canstack frame --fd`: the FD keys, the duration at two bit rates, and bad input (one line,
status 2)."""

import json

import pytest

from stack.cli import main
from stack.wire.coding import Field
from stack.wire.decoder import decode
from stack.wire.frame import Frame


def test_frame_fd_json_decodes_to_the_frame(capsys):
    data = bytes(range(20))
    assert (
        main(["frame", "--fd", "--brs", "--esi", "--id", "0x1ABCDEF", "--extended", "--data", data.hex(), "--json"])
        == 0
    )
    out = json.loads(capsys.readouterr().out)
    d = decode(out["bits"], mode="fd")
    assert d.ok and d.frame == Frame(0x1ABCDEF, data, extended=True, fd=True, brs=True, esi=True)
    assert out["length"] == len(out["bits"]) == out["nominal_bits"] + out["data_bits"]
    assert out["crc"] == d.crc and out["crc_bits"] == 21 and out["fixed_stuff_bits"] == 7
    assert out["stuff_count"] == out["stuff_bits"] % 8 == d.stuff_count % 8
    assert int(out["stuff_count_bits"], 2) == d.stuff_count_bits
    # the data phase: after BRS up to and including the CRC delimiter
    brs = d.frame.bits.position(Field.BRS)
    assert out["data_bits"] == d.frame.bits.crc_delim - brs and "duration_ns" not in out


def test_frame_duration_at_two_bit_rates(capsys):
    args = ["frame", "--fd", "--brs", "--id", "0x123", "--data", "00" * 64, "--json"]
    assert main([*args, "--bitrate", "500000", "--data-bitrate", "2000000"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["duration_ns"] == out["nominal_bits"] * 2000 + out["data_bits"] * 500
    assert main(["frame", "--id", "0x0C1", "--data", "4001087500000000", "--bitrate", "500000", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["duration_ns"] == 118 * 2000


def test_frame_fd_text_marks_fixed_stuff_bits(capsys):
    assert main(["frame", "--fd", "--brs", "--id", "0x123", "--data", "00" * 12, "--bitrate", "1000000",
                 "--data-bitrate", "4000000"]) == 0  # fmt: skip
    out = capsys.readouterr().out
    fb = Frame(0x123, bytes(12), fd=True, brs=True).bits
    assert "CRC-17" in out and f"sent as {fb.stuff_count_bits:04b}" in out and "duration" in out
    field_lines = "".join(line for line in out.splitlines() if line.startswith("  "))
    assert field_lines.count("{") == len(fb.fixed_stuff_positions) == 6
    stuffed = next(line for line in out.splitlines() if line.startswith("stuffed")).split()[1]
    assert stuffed == fb.bits


@pytest.mark.parametrize(
    "args,needle",
    [
        (["--fd", "--id", "0x1", "--data", "00" * 9], "data of 9 bytes is not a CAN FD length"),
        (["--fd", "--id", "0x1", "--data", "00" * 65], "data of 65 bytes is not a CAN FD length"),
        (["--brs", "--id", "0x1"], "--brs needs --fd"),
        (["--esi", "--id", "0x1"], "--esi needs --fd"),
        (["--id", "0x1", "--data", "00" * 12], "a CAN 2.0 frame carries at most 8 (up to 64 with --fd)"),
        (["--fd", "--remote", "--id", "0x1"], "CAN FD has no remote frames"),
        (["--fd", "--brs", "--id", "0x1", "--bitrate", "500000"], "needs --data-bitrate"),
        (["--fd", "--id", "0x1", "--data-bitrate", "2000000"], "--data-bitrate needs --bitrate"),
        (["--fd", "--id", "0x1", "--bitrate", "500000", "--data-bitrate", "250000"], "below --bitrate 500000"),
        (["--fd", "--id", "0x1", "--bitrate", "500000", "--data-bitrate", "x"], "not a whole number of bit/s"),
    ],
)
def test_frame_fd_bad_input_is_one_line_and_status_2(args, needle, capsys):
    # in-process (an exception escaping main fails the test); the whole process's view of the
    # same contract is tests/stack/cli/test_cli.py's test_bad_input_to_the_command_...
    assert main(["frame", *args]) == 2
    out, err = capsys.readouterr()
    lines = err.strip().splitlines()
    assert out == "" and len(lines) == 1 and needle in lines[0]
