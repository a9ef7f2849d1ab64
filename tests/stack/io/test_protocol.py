"""The `canstack serve` protocol on its own (no sockets): framing, every message's encoding
against its documented byte layout, round trips, and HELLO checks naming the broken rule."""

import json
import struct

import pytest
from hypothesis import given
from hypothesis import strategies as st

from stack.controller.confinement import ErrorState
from stack.io.serve import protocol as P
from stack.wire.frame import Frame


def test_send_and_rx_have_the_documented_layout():
    f = Frame(0x1ABCDE, b"\x01\x02", extended=True)
    # SEND: uint32 can_id, uint8 flags (1 extended, 2 remote), uint8 dlc, data
    assert P.encode_send(f) == struct.pack("!IB", 1 + 6 + 2, 0x10) + struct.pack("!IBB", 0x1ABCDE, 1, 2) + b"\x01\x02"
    # RX: uint64 t_ns, uint32 can_id, uint8 flags (4: own), uint8 dlc, data
    r = Frame(0x7FF, remote=True, dlc=3)
    assert P.encode_rx(123, r, own=True) == struct.pack("!IB", 1 + 14, 0x11) + struct.pack(
        "!QIBB", 123, 0x7FF, 2 | 4, 3
    )
    assert P.encode_state(ErrorState.PASSIVE, 130, 7) == struct.pack("!IBBHH", 6, 0x13, 2, 130, 7)
    assert P.encode_txend(None) == struct.pack("!IB", 2, 0x12) + b"\x01"
    assert P.encode_txend("aborted") == struct.pack("!IB", 9, 0x12) + b"\x00aborted"
    assert (
        P.encode_tx_error(5, "ack error (one-shot)", 8, 0)
        == struct.pack("!IBQHH", 1 + 12 + 20, 0x16, 5, 8, 0) + b"ack error (one-shot)"
    )
    assert P.encode_mode(True) == struct.pack("!IBB", 2, 0x17, 1)


frames = st.builds(
    lambda ext, rtr, cid, data, dlc: Frame(
        cid & (0x1FFFFFFF if ext else 0x7FF),
        b"" if rtr else data,
        extended=ext,
        remote=rtr,
        dlc=dlc if rtr else len(data),
    ),
    st.booleans(),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.binary(max_size=8),
    st.integers(0, 8),
)


@given(frames, st.integers(0, 2**64 - 1), st.booleans())
def test_rx_round_trip(frame, t, own):
    [(mtype, payload)] = P.Reader().feed(P.encode_rx(t, frame, own))
    assert mtype == P.RX
    t2, f2, is_rx = P.RxDecoder().decode(payload)
    assert (t2, f2.key, f2.dlc, f2.data, is_rx) == (t, frame.key, frame.dlc, frame.data, not own)


@given(frames)
def test_send_round_trip(frame):
    [(mtype, payload)] = P.Reader().feed(P.encode_send(frame))
    f2 = P.decode_send(payload)
    assert (mtype, f2.key, f2.dlc, f2.data) == (P.SEND, frame.key, frame.dlc, frame.data)


@given(st.lists(st.tuples(st.integers(0, 255), st.binary(max_size=40)), max_size=20), st.data())
def test_reader_reassembles_messages_split_anywhere(msgs, data):
    stream = b"".join(P.encode_message(t, p) for t, p in msgs)
    cuts = sorted(data.draw(st.lists(st.integers(0, len(stream)), max_size=10)))
    reader = P.Reader()
    out = []
    for a, b in zip([0, *cuts], [*cuts, len(stream)]):
        out += reader.feed(stream[a:b])
    assert out == msgs


def test_reader_refuses_an_absurd_length():
    with pytest.raises(ValueError, match=r"message length 1073741824 outside 1\.\.4096"):
        P.Reader().feed(struct.pack("!IB", 1 << 30, P.SEND))


def test_status_messages_round_trip():
    assert P.decode_state(P.encode_state(ErrorState.BUS_OFF, 256, 3)[5:]) == (ErrorState.BUS_OFF, 256, 3)
    assert P.decode_txend(P.encode_txend(None)[5:]) is None
    assert P.decode_txend(P.encode_txend("bit error (one-shot)")[5:]) == "bit error (one-shot)"
    assert P.decode_tx_error(P.encode_tx_error(99, "crc error (one-shot)", 16, 2)[5:]) == (
        99,
        "crc error (one-shot)",
        16,
        2,
    )
    assert P.decode_mode(P.encode_mode(False)[5:]) is False
    with pytest.raises(ValueError, match="MODE payload"):
        P.decode_mode(b"\x02")


def _hello(**kw):
    return json.dumps({"v": 2, "bus": "bus0", "bitrate": None, "node_name": None, "config": {}, **kw}).encode()


def test_hello_is_parsed_and_checked():
    h = P.parse_hello(
        _hello(node_name="ecu", config={"queue": "fifo", "one_shot": True}, receive_own_messages=True), "bus0", 500_000
    )
    assert h == P.Hello("bus0", None, "ecu", {"queue": "fifo", "one_shot": True}, True)
    assert P.parse_hello(
        P.encode_hello("bus0", 500_000, None, {"abort": True, "colour": 1}, False)[5:], "bus0", 500_000
    ).config == {"abort": True}  # unknown options never leave the client


@pytest.mark.parametrize(
    "payload,needle",
    [
        (b"{not json", "not JSON"),
        (b"[" * 5000, "nested too deeply"),
        (b"[]", "JSON object"),
        (_hello(v=1), "the client speaks canstack serve protocol 1, this server speaks 2: upgrade canstack"),
        (_hello(v=3), "protocol version 3 not supported"),
        (_hello(client="x" * 65), "client must be a printable string of at most 64"),
        (_hello(client="a\nb"), "client must be a printable string"),
        (_hello(fd="yes"), "fd 'yes' must be true or false"),
        (_hello(data_bitrate=-1), "data_bitrate -1 must be a positive integer"),
        (_hello(bus="other"), "serves bus 'bus0', not 'other'"),
        (_hello(bitrate=250_000), "runs at 500000 bit/s"),
        (_hello(node_name=""), "node_name must be a string of 1..64"),
        (_hello(config={"evil": 1}), "unknown node option 'evil'"),
        (_hello(config={"tx_queue_size": True}), "tx_queue_size=True has the wrong type"),
        (_hello(config={"tx_queue_size": 0}), "tx_queue_size must be 1..65536"),
        (_hello(config={"mailboxes": 65}), "mailboxes must be 1..64"),
    ],
)
def test_bad_hello_names_the_rule(payload, needle):
    with pytest.raises(ValueError, match=needle.replace(".", r"\.").replace("(", r"\(")):
        P.parse_hello(payload, "bus0", 500_000)


@pytest.mark.parametrize(
    "payload,needle",
    [
        (b"\x01", "too short"),
        (struct.pack("!IBB", 0x800, 0, 0), "0x800"),
        (struct.pack("!IBB", 0x10, 0, 3) + b"\x01", "DLC"),
    ],
)
def test_bad_send_names_what_is_wrong(payload, needle):
    with pytest.raises(ValueError, match=needle):
        P.decode_send(payload)


# ------------------------------------------------------------------------- version 2: CAN FD, TIME
FD_LENGTHS = (0, 1, 2, 3, 4, 5, 6, 7, 8, 12, 16, 20, 24, 32, 48, 64)  # ISO 11898-1:2015 table 5

fd_frames = st.builds(
    lambda ext, cid, n, fill, brs, esi: Frame(
        cid & (0x1FFFFFFF if ext else 0x7FF), bytes([fill]) * n, extended=ext, fd=True, brs=brs, esi=esi
    ),
    st.booleans(),
    st.integers(0, 0x1FFFFFFF),
    st.sampled_from(FD_LENGTHS),
    st.integers(0, 255),
    st.booleans(),
    st.booleans(),
)


def test_fd_flags_have_the_documented_layout():
    f = Frame(0x123, bytes(range(64)), fd=True, brs=True, esi=False)
    # SEND: flags 8 CAN FD + 16 bit rate switch; the dlc byte is the DLC code (15 for 64 bytes)
    assert P.encode_send(f) == struct.pack("!IB", 1 + 6 + 64, 0x10) + struct.pack("!IBB", 0x123, 8 | 16, 15) + bytes(
        range(64)
    )
    g = Frame(0x1ABCDEF0, bytes(12), extended=True, fd=True, esi=True)
    assert P.encode_rx(7, g, own=True) == struct.pack("!IB", 1 + 14 + 12, 0x11) + struct.pack(
        "!QIBB", 7, 0x1ABCDEF0, 1 | 4 | 8 | 32, 9
    ) + bytes(12)
    assert P.encode_time(42) == struct.pack("!IBQ", 9, 0x18, 42)
    assert P.encode_now(42, 5, 6) == struct.pack("!IBQQQ", 25, 0x19, 42, 5, 6)


@given(fd_frames, st.integers(0, 2**64 - 1), st.booleans())
def test_fd_frames_round_trip(frame, t, own):
    [(_, payload)] = P.Reader().feed(P.encode_send(frame))
    f2 = P.decode_send(payload)
    assert (f2, f2.fd, f2.brs, f2.esi) == (frame, True, frame.brs, frame.esi)
    [(_, payload)] = P.Reader().feed(P.encode_rx(t, frame, own))
    t2, f2, is_rx = P.RxDecoder().decode(payload)
    assert (t2, f2, f2.brs, f2.esi, is_rx) == (t, frame, frame.brs, frame.esi, not own)


@pytest.mark.parametrize(
    "payload,needle",
    [
        (struct.pack("!IBB", 0x10, 16, 0), "need the CAN FD flag"),  # BRS without FD
        (struct.pack("!IBB", 0x10, 64, 0), "unknown frame flags 0x40"),
        (struct.pack("!IBB", 0x10, 4, 0), "own-frame flag"),
        (struct.pack("!IBB", 0x10, 8 | 2, 0), "CAN FD has no remote frames"),
        (struct.pack("!IBB", 0x10, 8, 9) + bytes(10), "not a CAN FD length"),
    ],
)
def test_bad_fd_send_names_what_is_wrong(payload, needle):
    with pytest.raises(ValueError, match=needle):
        P.decode_send(payload)


def test_time_and_now_round_trip():
    assert P.decode_time(P.encode_time(2**63)[5:]) == 2**63
    assert P.decode_now(P.encode_now(1, 2, 3)[5:]) == (1, 2, 3)
    with pytest.raises(ValueError, match="TIME payload of 3 bytes"):
        P.decode_time(b"abc")


def test_hello_and_welcome_carry_the_client_and_fd():
    h = P.parse_hello(
        P.encode_hello("bus0", None, None, {}, False, client="candump[42]", fd=True, data_bitrate=2_000_000)[5:],
        "bus0",
        500_000,
    )
    assert (h.client, h.fd, h.data_bitrate) == ("candump[42]", True, 2_000_000)
    w = P.parse_welcome(P.encode_welcome(500_000, "n", 1.5, behind_ms=12.5, fd=True, data_bitrate=2_000_000)[5:])
    assert w == P.Welcome(500_000, "n", 1.5, 12.5, True, 2_000_000)
