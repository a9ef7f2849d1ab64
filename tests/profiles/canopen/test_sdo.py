"""The SDO server (CiA 301 7.2.4) driven by the ``canopen`` library's SDO client — a second
implementation — in all three transfer modes, and by hand-made frames for each refusal, with
the abort codes of CiA 301."""

import struct

import pytest
from canopen.sdo import SdoAbortedError
from canopen.sdo import constants as lib

from profiles.canopen.sdo import abort
from profiles.canopen.sdo.abort import ABORT_TEXT
from profiles.canopen.sdo.block import crc16
from stack import Frame

MS = 1_000_000


def test_abort_codes_are_the_canopen_librarys():
    ours = {k: v for k, v in vars(abort).items() if k.isupper() and isinstance(v, int)}
    assert len(ours) == len(ABORT_TEXT) == 31
    theirs = {v for k, v in vars(lib).items() if k.startswith("ABORT_")}
    assert set(ours.values()) - {abort.DEVICE_STATE, abort.CANNOT_STORE} <= theirs | {0x0800_0020}
    for code in ours.values():
        assert code in SdoAbortedError.CODES  # the library knows every code we send


def test_crc_is_the_canopen_librarys_xmodem():
    from canopen.sdo.base import CrcXmodem

    c = CrcXmodem()
    c.process(b"123456789")
    assert crc16(b"123456789") == c.final() == 0x31C3  # CRC-16/XMODEM check value


def test_expedited_upload_and_download(remote):
    dev, node = remote
    assert node.sdo[0x1018][1].raw == 0
    assert node.sdo[0x1017].raw == 1000
    node.sdo[0x1017].raw = 250
    assert dev.read(0x1017) == 250
    node.sdo[0x2003].raw = -123
    assert dev.read(0x2003) == -123
    assert dev.sdo.completed["expedited download"] == 2 and dev.sdo.completed["expedited upload"] >= 2


def test_segmented_upload_and_download(remote):
    dev, node = remote
    assert node.sdo[0x1008].raw == "canstack CANopen device"  # 23 bytes: 4 segments
    node.sdo[0x2200].raw = "a label longer than seven bytes"
    assert dev.read(0x2200) == "a label longer than seven bytes"
    assert node.sdo.upload(0x2200, 0) == b"a label longer than seven bytes"
    assert dev.sdo.completed["segmented download"] == 1 and dev.sdo.completed["segmented upload"] == 2


@pytest.mark.parametrize("size", [1, 6, 7, 8, 127 * 7, 127 * 7 + 1, 3000])
def test_block_download_and_upload(remote, size):
    dev, node = remote
    blob = bytes((i * 7 + 3) & 0xFF for i in range(size))
    with node.sdo[0x2201].open("wb", size=len(blob), block_transfer=True) as f:
        f.write(blob)
    assert dev.store.read(0x2201) == blob
    with node.sdo[0x2201].open("rb", block_transfer=True) as f:
        assert f.read() == blob
    assert dev.sdo.completed["block download"] == 1 and dev.sdo.completed["block upload"] == 1
    assert dev.sdo.aborts_sent == 0


def test_block_upload_below_the_protocol_switch_threshold_goes_expedited(remote, lib, master_node, spy):
    dev, _ = remote
    # initiate block upload of 0x1017 (2 bytes) with pst 10: the server answers as a normal upload
    master_node.send(Frame(0x605, struct.pack("<BHBBB", 0xA4, 0x1017, 0, 16, 10) + b"\x00\x00"))
    lib.run(2 * MS)
    resp = [f for _, f in spy if f.can_id == 0x585][-1]
    assert resp.data[0] == 0x4B and resp.data[4:6] == (1000).to_bytes(2, "little")  # expedited, 2 bytes


@pytest.mark.parametrize(
    "access, code",
    [
        (lambda n: n.sdo.upload(0x3000, 0), lib.ABORT_NOT_IN_OD),
        (lambda n: n.sdo.upload(0x1018, 7), lib.ABORT_NO_SUBINDEX),
        (lambda n: n.sdo.download(0x1000, 0, b"\x01\x00\x00\x00"), lib.ABORT_WRITE_READONLY),
        (lambda n: n.sdo.upload(0x2203, 0), lib.ABORT_READ_WRITEONLY),
        (lambda n: n.sdo.download(0x1017, 0, b"\x01\x02\x03"), lib.ABORT_LENGTH_TOO_HIGH),
        (lambda n: n.sdo.download(0x1017, 0, b"\x01"), lib.ABORT_LENGTH_TOO_LOW),
        (lambda n: n.sdo.download(0x2003, 0, (2000).to_bytes(2, "little")), lib.ABORT_VALUE_TOO_HIGH),
        (lambda n: n.sdo.download(0x2003, 0, (-1000).to_bytes(2, "little", signed=True)), lib.ABORT_VALUE_TOO_LOW),
        (lambda n: n.sdo.download(0x1008, 0, b"renamed device"), lib.ABORT_WRITE_READONLY),  # segmented, const
        (lambda n: n.sdo.download(0x1003, 0, b"\x02"), lib.ABORT_INVALID_VALUE),  # only 0 clears 0x1003
        (lambda n: n.sdo.upload(0x1003, 1), lib.ABORT_NO_DATA_AVAILABLE),  # no error in the history
    ],
)
def test_refusals_reach_the_client_with_cia_301_abort_codes(remote, access, code):
    _, node = remote
    with pytest.raises(SdoAbortedError) as exc:
        access(node)
    assert exc.value.code == code


def request(master_node, lib, spy, data, *, can_id=0x605):
    """Send one raw request, return the server's answers."""
    n = len(spy)
    master_node.send(Frame(can_id, bytes(data).ljust(8, b"\x00")))
    lib.run(2 * MS)
    return [f.data for _, f in spy[n:] if f.can_id == 0x585]


def aborted(resp, code):
    return resp and resp[-1][0] == 0x80 and struct.unpack_from("<L", resp[-1], 4)[0] == code


def test_toggle_bit_not_alternated(remote, lib, master_node, spy):
    assert request(master_node, lib, spy, struct.pack("<BHBL", 0x21, 0x2200, 0, 14))[0][0] == 0x60
    assert request(master_node, lib, spy, b"\x00abcdefg")[0][0] == 0x20  # toggle 0
    assert aborted(request(master_node, lib, spy, b"\x00hijklmn"), abort.TOGGLE_BIT)  # toggle 0 again


def test_unknown_command_specifier(remote, lib, master_node, spy):
    assert aborted(request(master_node, lib, spy, b"\xe0\x17\x10\x00"), abort.COMMAND)  # ccs 7
    assert aborted(request(master_node, lib, spy, b"\x60\x00\x00\x00"), abort.COMMAND)  # segment without transfer


def test_invalid_block_size_and_crc_error(remote, lib, master_node, spy):
    assert aborted(request(master_node, lib, spy, struct.pack("<BHBBB", 0xA4, 0x2200, 0, 0, 0)), abort.BLOCK_SIZE)
    resp = request(master_node, lib, spy, struct.pack("<BHBL", 0xC6, 0x2200, 0, 3))  # block download, 3 bytes, CRC
    assert resp[0][0] == 0xA4 and resp[0][4] == 127
    assert request(master_node, lib, spy, b"\x81abc")[0][:2] == b"\xa2\x01"  # last segment acknowledged
    bad = crc16(b"abc") ^ 0xFFFF
    assert aborted(request(master_node, lib, spy, bytes([0xC1 | (4 << 2)]) + struct.pack("<H", bad)), abort.CRC)


def test_block_download_resends_after_a_lost_segment(remote, lib, master_node, spy):
    dev, _ = remote
    request(master_node, lib, spy, struct.pack("<BHBL", 0xC2, 0x2201, 0, 21))  # 21 bytes, no CRC
    request(master_node, lib, spy, b"\x01" + b"A" * 7)
    resp = request(master_node, lib, spy, b"\x03" + b"C" * 7)  # segment 2 lost
    assert resp[0][:3] == b"\xa2\x01\x7f"  # ackseq 1: send again from segment 2
    request(master_node, lib, spy, b"\x01" + b"B" * 7)
    assert request(master_node, lib, spy, b"\x82" + b"C" * 7)[0][:2] == b"\xa2\x02"
    assert request(master_node, lib, spy, b"\xc1\x00\x00")[0][0] == 0xA1
    assert dev.store.read(0x2201) == b"A" * 7 + b"B" * 7 + b"C" * 7


def test_server_times_out_a_transfer_the_client_left(remote, lib, bus, master_node, spy):
    dev, _ = remote
    request(master_node, lib, spy, struct.pack("<BHBL", 0x21, 0x2200, 0, 14))
    t_request = [t for t, f in spy if f.can_id == 0x605][-1]
    n = len(spy)
    bus.run(until=t_request + 999 * MS)
    assert not [f for _, f in spy[n:] if f.can_id == 0x585]
    bus.run(until=t_request + 1001 * MS)  # CANopenNode's default: 1000 ms
    assert aborted([f.data for _, f in spy[n:] if f.can_id == 0x585], abort.TIMEOUT)
    assert dev.sdo.transfer is None


def test_client_abort_ends_the_transfer_without_answer(remote, lib, master_node, spy):
    dev, _ = remote
    request(master_node, lib, spy, struct.pack("<BHBL", 0x21, 0x2200, 0, 14))
    assert request(master_node, lib, spy, struct.pack("<BHBL", 0x80, 0x2200, 0, abort.GENERAL)) == []
    assert dev.sdo.transfer is None and dev.sdo.aborts_received == 1


def test_frames_shorter_than_8_bytes_are_ignored(remote, lib, master_node, spy):
    dev, _ = remote
    n = len(spy)
    master_node.send(Frame(0x605, b"\x40\x17\x10\x00"))
    lib.run(2 * MS)
    assert not [f for _, f in spy[n:] if f.can_id == 0x585] and dev.sdo.ignored == 1
