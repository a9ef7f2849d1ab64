"""Identifiers in `canstack sync`'s text as in every other output: ``0x`` and upper-case hex, 3
digits for an 11-bit identifier and 8 for a 29-bit one (issue 23)."""

from __future__ import annotations

import re

from stack.cli import main
from stack.phy.sync import worst_case_frames
from stack.phy.tdc import TDC_FRAMES


def _spec(can_id: int, extended: bool) -> str:
    width = 8 if extended else 3  # 29 bits take 8 hex digits, 11 bits take 3
    return "0x" + format(can_id, "X").rjust(width, "0")


def _frames_line(out: str) -> list[str]:
    line = next(x for x in out.splitlines() if x.startswith("frames: "))
    return re.findall(r"(0x\S+) \[", line)


def test_sync_prints_its_frames_identifiers_in_upper_case(capsys):
    assert main(["sync", "--bitrate", "500000", "--clock", "16000000", "--drift-ppm", "0..20000"]) == 0
    out = capsys.readouterr().out
    assert _frames_line(out) == [_spec(f.can_id, f.extended) for f in worst_case_frames()]
    assert "0x7FF" in _frames_line(out)  # the all-recessive identifier is among them
    failure = next(x for x in out.splitlines() if x.startswith("first failure at"))
    assert re.search(r"frame 0x[0-9A-F]{3}: ", failure), failure


def test_sync_with_tdc_prints_a_29_bit_identifier_with_8_digits(capsys):
    argv = ["sync", "--clock", "40000000", "--bitrate", "500000", "--data-bitrate", "5000000", "--loop-delay", "255"]
    assert main(argv) == 0
    ids = _frames_line(capsys.readouterr().out)
    assert ids == [_spec(f.can_id, f.extended) for f in TDC_FRAMES]
    assert any(f.extended for f in TDC_FRAMES) and any(len(i) == 10 for i in ids)
