"""CRC-15, stuffing, the frame bit sequence and the decoder, against the specification's values."""

import pytest
from crccheck.crc import Crc15Can
from hypothesis import given
from hypothesis import strategies as st

from stack.wire.coding import Field, crc15, crc15_bytes, destuff, stuff, unstuffed_length, worst_case_length
from stack.wire.decoder import decode
from stack.wire.frame import Frame


def frames():
    std = st.builds(
        lambda i, d, r, dlc: Frame(i, remote=True, dlc=dlc) if r else Frame(i, d),
        st.integers(0, 0x7FF),
        st.binary(max_size=8),
        st.booleans(),
        st.integers(0, 15),
    )
    ext = st.builds(
        lambda i, d, r, dlc: Frame(i, extended=True, remote=True, dlc=dlc) if r else Frame(i, d, extended=True),
        st.integers(0, 0x1FFFFFFF),
        st.binary(max_size=8),
        st.booleans(),
        st.integers(0, 15),
    )
    dlc_hi = st.builds(
        lambda i, d, dlc: Frame(i, d, dlc=dlc),
        st.integers(0, 0x7FF),
        st.binary(min_size=8, max_size=8),
        st.integers(9, 15),
    )
    return st.one_of(std, ext, dlc_hi)


def test_crc15_check_value():
    assert crc15_bytes(b"123456789") == 0x059E


@given(st.binary(max_size=32))
def test_crc15_agrees_with_crccheck(data):
    assert crc15_bytes(data) == Crc15Can.calc(data)


def test_golden_crc_id_0c1():
    assert Frame(0x0C1, bytes.fromhex("4001087500000000")).bits.crc == 0x5B40


def test_golden_crc_recorded_from_mcp2515():
    assert Frame(0x222, bytes.fromhex("0011223344")).bits.crc == 0x66DA


@given(frames())
def test_decode_encode_round_trip(f):
    d = decode(f.bits.bits)
    assert d.ok and d.frame == f and d.crc_ok and d.crc == f.bits.crc and d.ack
    assert d.length == f.bits.length


@given(frames())
def test_no_run_of_six_equal_bits_before_crc_delimiter(f):
    b = f.bits.bits[: f.bits.crc_delim + 1]  # SOF .. CRC delimiter
    assert "000000" not in b and "111111" not in b[:-1]


@given(st.lists(st.integers(0, 1), max_size=200))
def test_destuff_inverts_stuff(bits):
    stuffed, _ = stuff(bits)
    assert destuff(stuffed) == bits


@given(frames())
def test_lengths_match_formula(f):
    n = len(f.data)
    fb = f.bits
    assert fb.length == unstuffed_length(n, f.extended) + fb.stuff_count
    assert fb.length <= worst_case_length(n, f.extended)


def test_unstuffed_and_worst_case_numbers_from_the_spec():
    assert unstuffed_length(8, False) == 108 and unstuffed_length(8, True) == 128
    assert worst_case_length(8, False) == 108 + (34 + 64 - 1) // 4 == 132
    assert worst_case_length(8, True) == 128 + (54 + 64 - 1) // 4 == 157
    assert worst_case_length(0, False) == 44 + 33 // 4


def test_field_layout_standard_and_extended():
    f = Frame(0x0C1, bytes(8))
    fb = f.bits
    assert [
        len(fb.fields[x])
        for x in (Field.SOF, Field.ID, Field.RTR, Field.IDE, Field.R0, Field.DLC, Field.DATA, Field.CRC)
    ] == [1, 11, 1, 1, 1, 4, 64, 15]
    e = Frame(0x11223344, bytes(7), extended=True).bits
    assert [
        len(e.fields[x]) for x in (Field.ID, Field.SRR, Field.IDE, Field.ID_EXT, Field.RTR, Field.R1, Field.R0)
    ] == [11, 1, 1, 18, 1, 1, 1]
    assert e.bits[e.position(Field.SRR)] == "1" and e.bits[e.position(Field.IDE)] == "1"
    assert fb.bits[fb.position(Field.ACK_SLOT)] == "0"
    assert fb.bits[-7:] == "1111111"


def test_stuff_bits_are_marked_and_opposite_to_the_five_before():
    fb = Frame(0x0C1, bytes.fromhex("4001087500000000")).bits
    assert fb.stuff_count == 10
    for p in fb.stuff_positions:
        prev = fb.bits[p - 5 : p]
        assert len(set(prev)) == 1 and fb.bits[p] != prev[0]


def _flip(bits: str, i: int) -> str:
    return bits[:i] + ("1" if bits[i] == "0" else "0") + bits[i + 1 :]


def test_decoder_reports_stuff_error_with_field_and_bit():
    fb = Frame(0x0C1, bytes.fromhex("4001087500000000")).bits
    p = fb.stuff_positions[0]  # stuff bit inside the identifier
    d = decode(_flip(fb.bits, p))
    assert not d.ok and d.error.kind == "stuff" and d.error.position == p
    assert d.error.field == Field.ID


def test_decoder_reports_crc_error_after_ack_delimiter():
    f = Frame(0x123, b"\x55")
    raw = [int(c) for c in f.bits.bits]
    # build the frame with a wrong CRC, stuffed correctly
    unstuffed = destuff(raw[: f.bits.crc_delim])
    bad = unstuffed[:-15] + [int(c) for c in format(f.bits.crc ^ 1, "015b")]
    stuffed, _ = stuff(bad)
    bits = "".join(map(str, stuffed)) + "1" + "0" + "1" + "1111111"
    d = decode(bits)
    assert d.error.kind == "crc" and not d.crc_ok and d.crc == f.bits.crc ^ 1
    # signalled at the ACK delimiter bit
    assert d.error.position == len(stuffed) + 2


@pytest.mark.parametrize("fld,idx", [(Field.CRC_DELIM, 0), (Field.ACK_DELIM, 0), (Field.EOF, 0), (Field.EOF, 5)])
def test_decoder_reports_form_error_in_fixed_fields(fld, idx):
    fb = Frame(0x7A, b"\x01\x02").bits
    p = fb.position(fld, idx)
    d = decode(_flip(fb.bits, p))
    assert d.error.kind == "form" and d.error.field == fld and d.error.index == idx and d.error.position == p


def test_dominant_last_eof_bit_is_overload_not_error():
    fb = Frame(0x7A, b"\x01").bits
    d = decode(fb.bits[:-1] + "0")
    assert d.ok and d.overload


def test_missing_ack_is_seen_by_decoder():
    fb = Frame(0x7A, b"\x01").bits
    d = decode(_flip(fb.bits, fb.position(Field.ACK_SLOT)))
    assert d.ok and not d.ack


def test_truncated_sequence_names_field():
    with pytest.raises(ValueError, match="inside field DATA"):
        decode(Frame(0x7A, b"\x01\x02").bits.bits[:25])


def test_position_rejects_unknown_field_and_index():
    fb = Frame(0x7A, b"\x01").bits
    with pytest.raises(ValueError, match="unknown field"):
        fb.position("BOGUS")
    with pytest.raises(ValueError, match="bit 11 outside field ID"):
        fb.position(Field.ID, 11)


def _reference_bits(f):
    """A second, bit-list encoder straight from the field layout in ISO 11898-1."""

    def ib(v, w):
        return [(v >> (w - 1 - i)) & 1 for i in range(w)]

    if f.extended:
        raw = [0] + ib(f.can_id >> 18, 11) + [1, 1] + ib(f.can_id & 0x3FFFF, 18) + [int(f.remote), 0, 0]
    else:
        raw = [0] + ib(f.can_id, 11) + [int(f.remote), 0, 0]
    raw += ib(f.dlc, 4) + [(b >> (7 - i)) & 1 for b in f.data for i in range(8)]
    raw += ib(crc15(raw), 15)
    stuffed, positions = stuff(raw)
    return "".join(map(str, stuffed)) + "1011111111", positions


@given(frames())
def test_encoder_matches_bitwise_reference(f):
    bits, positions = _reference_bits(f)
    assert f.bits.bits == bits and list(f.bits.stuff_positions) == positions


def test_decoder_reports_only_whole_data_bytes_received():
    # fed up to (not including) data bit 13 of 11 22 33 44: one whole byte (0x11) and 5 bits;
    # the received data is 11, never a right-aligned partial value
    from stack.wire.decoder import BitDecoder

    f = Frame(0x123, bytes.fromhex("11223344"))
    stop = f.bits.position(Field.DATA, 13)
    dec = BitDecoder()
    for c in f.bits.bits[:stop]:
        assert dec.feed(int(c)) is None
    assert dec.received_data == b"\x11" and dec.received_crc is None
    for c in f.bits.bits[stop:]:
        res = dec.feed(int(c))
    assert res.frame == f and res.crc == f.bits.crc
