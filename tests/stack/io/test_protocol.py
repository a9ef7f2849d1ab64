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
    return json.dumps({"v": 1, "bus": "bus0", "bitrate": None, "node_name": None, "config": {}, **kw}).encode()


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
        (_hello(v=2), "protocol version 2 not supported"),
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
