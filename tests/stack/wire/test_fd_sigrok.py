"""CAN FD frames as sigrok's CAN decoder reads them: a peer implementation of the FD field layout
and of dynamic (de)stuffing (sigrok-cli 0.7.2; it does not check the CRC, so the CRC field is the
second encoder's business in test_fd.py). Skipped when sigrok-cli is not installed.

Frames without BRS only: sigrok-cli 0.7.2 samples the bits after a bit rate switch late (it puts
the first data-phase sample point at BRS's sample point + one data bit + the sample point again),
so with BRS it reads ESI from the first DLC bit; the data-phase timing is checked in test_fd.py.
"""

import random
import re
import shutil
import subprocess

import pytest

from stack.wire.frame import FD_LENGTHS, Frame

SIGROK = shutil.which("sigrok-cli")
pytestmark = [pytest.mark.skipif(SIGROK is None, reason="sigrok-cli not installed"), pytest.mark.subprocess]


def _frames() -> list[Frame]:
    rng = random.Random(11)
    out = []
    for i, n in enumerate(FD_LENGTHS):
        ext = i % 2 == 1
        data = bytes(rng.choice([0x00, 0xFF, 0xF0, rng.getrandbits(8)]) for _ in range(n))
        out.append(Frame(rng.getrandbits(29 if ext else 11), data, extended=ext, fd=True, esi=i % 3 == 0))
    return out


def test_sigrok_reads_our_fd_frames(tmp_path):
    frames = _frames()
    spb = 16  # samples per bit at 500 kbit/s and 8 MHz
    samples = bytearray()
    for f in frames:
        samples += b"\x01" * (spb * 20)  # bus idle between frames
        samples += bytes(int(c) for c in f.bits.bits for _ in range(spb))
    samples += b"\x01" * (spb * 20)
    path = tmp_path / "fd.bin"
    path.write_bytes(bytes(samples))
    proc = subprocess.run(
        [
            SIGROK,
            "-I",
            "binary:numchannels=1:samplerate=8000000",
            "-i",
            str(path),
            "-P",
            "can:nominal_bitrate=500000:fast_bitrate=500000:sample_point=75",
            "-A",
            "can=sof:id:full-id:reserved-bit:dlc:data",
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert proc.returncode == 0, proc.stderr
    chunks = proc.stdout.split("Start of frame")[1:]
    assert len(chunks) == len(frames)
    for f, text in zip(frames, chunks):
        key = "Full Identifier" if f.extended else "Identifier"
        can_id = int(re.search(rf"{key}: \d+ \(0x([0-9a-f]+)\)", text).group(1), 16)
        dlc = int(re.search(r"Data length code: (\d+)", text).group(1))
        data = bytes(int(x, 16) for x in re.findall(r"Data byte \d+: 0x([0-9a-f]+)", text))
        assert "FDF: 1" in text or "Flexible data format: 1" in text
        assert (can_id, dlc, data) == (f.can_id, f.dlc, f.data), f
        assert f"Error state indicator: {int(f.esi)}" in text
