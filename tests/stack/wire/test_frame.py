"""Frame value type: the CAN 2.0 rules on identifiers, DLC and data. (Its `can.Message`
boundary is tested with python-can in tests/stack/io/test_message.py.)"""

import pytest

from stack.wire.frame import Frame, arbitration_key, data_length


@pytest.mark.parametrize("can_id,extended", [(0x800, False), (-1, False), (0x20000000, True)])
def test_identifier_out_of_range_names_value_and_limit(can_id, extended):
    with pytest.raises(ValueError) as exc:
        Frame(can_id, extended=extended)
    msg = str(exc.value)
    assert (f"0x{can_id:X}" if can_id >= 0 else f"-0x{-can_id:X}") in msg
    assert ("0x7FF" if not extended else "0x1FFFFFFF") in msg


def test_identifier_limits_are_accepted():
    assert Frame(0x7FF).can_id == 0x7FF
    assert Frame(0x1FFFFFFF, extended=True).can_id == 0x1FFFFFFF


@pytest.mark.parametrize("dlc", [-1, 16, 99])
def test_dlc_outside_0_to_15_is_rejected(dlc):
    with pytest.raises(ValueError, match=r"DLC .* 0\.\.15"):
        Frame(0x10, remote=True, dlc=dlc)


def test_data_longer_than_8_bytes_is_rejected():
    with pytest.raises(ValueError, match="at most 8"):
        Frame(0x10, bytes(9))


def test_data_not_matching_dlc_is_rejected():
    with pytest.raises(ValueError, match="DLC 3 means 3 data bytes, but 2"):
        Frame(0x10, b"\x01\x02", dlc=3)


def test_remote_frame_with_data_is_rejected():
    with pytest.raises(ValueError, match="remote frame carries no data"):
        Frame(0x10, b"\x01", remote=True)


@pytest.mark.parametrize("dlc", range(9, 16))
def test_dlc_9_to_15_carries_8_bytes_and_is_kept(dlc):
    f = Frame(0x123, bytes(range(8)), dlc=dlc)
    assert f.dlc == dlc and len(f.data) == 8 == data_length(dlc)
    # the DLC goes on the wire as given
    assert f.bits.bits[15:19] == format(dlc, "04b")


def test_remote_frame_dlc_is_requested_length():
    f = Frame(0x321, remote=True, dlc=6)
    assert f.remote and f.data == b"" and f.dlc == 6


def test_frame_is_immutable_and_hashable():
    f = Frame(0x1, b"\x01")
    with pytest.raises(AttributeError):
        f.can_id = 2
    assert {f: 1}[Frame(0x1, b"\x01")] == 1
    assert Frame(0x1, b"\x01") != Frame(0x1, b"\x01", extended=True)


def test_arbitration_key_orders_as_on_the_wire():
    # data beats remote with the same ID; standard beats extended with the same base ID
    assert arbitration_key(0x100, False, False) < arbitration_key(0x100, False, True)
    assert arbitration_key(0x100, False, True) < arbitration_key(0x100 << 18, True, False)
    assert arbitration_key(0x100 << 18, True, False) < arbitration_key(0x101, False, False)
