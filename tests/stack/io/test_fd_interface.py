"""CAN FD at the python-can boundary: the `canstack` interface's ``fd``/``data_bitrate``, FD
messages refused on a bus opened without ``fd=True`` (as python-can's udp_multicast refuses them),
the served protocol's version 2 and its FD flags, and `PyCanDriver` sending and receiving FD
frames on python-can's virtual bus."""

import json
import os
import socket
import time

import can
import pytest

from stack.controller.node import Node
from stack.io.driver import PyCanDriver
from stack.io.pycan import InvalidFrame
from stack.io.serve import ERROR, HELLO, BusServer, encode_message
from stack.io.serve.protocol import Reader
from stack.wire.frame import Frame

pytestmark = pytest.mark.wallclock


def _fd_msg(n=64, **kw):
    return can.Message(arbitration_id=0x123, data=bytes(range(n)), is_extended_id=False, is_fd=True, **kw)


def test_an_fd_message_on_a_bus_opened_without_fd_is_refused():
    with can.Bus(interface="canstack", channel=f"nofd{os.getpid()}") as bus:
        assert bus.protocol is can.CanProtocol.CAN_20
        with pytest.raises(can.CanOperationError, match="CAN FD message on a canstack bus opened without fd=True"):
            bus.send(_fd_msg(12))
        with pytest.raises(InvalidFrame):
            bus.send_periodic(_fd_msg(8), 0.01)


def test_timing_and_data_bitrate_need_fd():
    with pytest.raises(can.CanInitializationError, match="open the bus with fd=True"):
        can.Bus(interface="canstack", channel=f"dbr{os.getpid()}", data_bitrate=2_000_000)
    fd_timing = can.BitTimingFd.from_sample_point(
        f_clock=80_000_000, nom_bitrate=500_000, nom_sample_point=80.0, data_bitrate=2_000_000, data_sample_point=80.0
    )
    with pytest.raises(can.CanInitializationError, match=r"a can\.BitTimingFd on a bus opened with fd=True"):
        can.Bus(interface="canstack", channel=f"tim{os.getpid()}", timing=fd_timing)


def test_fd_messages_go_both_ways_in_process(drain):
    ch = f"fdbus{os.getpid()}"
    with (
        can.Bus(interface="canstack", channel=ch, fd=True, data_bitrate=4_000_000) as a,
        can.Bus(interface="canstack", channel=ch, fd=True) as b,
        can.Bus(interface="canstack", channel=ch) as classic,
    ):
        assert (a.protocol, b.data_bitrate) == (can.CanProtocol.CAN_FD, 4_000_000)
        a.send(_fd_msg(64, bitrate_switch=True))
        a.send(_fd_msg(12, error_state_indicator=True))
        got = drain(b, 2, timeout=30.0)
        # ESI is the transmitter's error state, set by its controller (ISO 11898-1:2015): an
        # error-active node sends it dominant whatever the message asked
        assert [(len(m.data), m.is_fd, m.bitrate_switch, m.error_state_indicator) for m in got] == [
            (64, True, True, False),
            (12, True, False, False),
        ]
        assert bytes(got[0].data) == bytes(range(64))
        a.send(can.Message(arbitration_id=0x7, data=b"\x01", is_extended_id=False))
        # a node opened without fd=True sees the classical frame only
        assert [(m.arbitration_id, m.is_fd) for m in drain(classic, 1, timeout=30.0)] == [(0x7, False)]


@pytest.mark.socket
def test_fd_messages_go_both_ways_through_serve(drain):
    with (
        BusServer(500_000, listen=("127.0.0.1", 0), data_bitrate=2_000_000) as srv,
        can.Bus(interface="canstack", channel=srv.url, fd=True) as a,
        can.Bus(interface="canstack", channel=srv.url, fd=True) as b,
    ):
        assert a.protocol is can.CanProtocol.CAN_FD and a.data_bitrate == 2_000_000
        a.send(_fd_msg(48, bitrate_switch=True, error_state_indicator=True))
        [m] = drain(b, 1, timeout=30.0)
        assert (len(m.data), m.is_fd, m.bitrate_switch, m.error_state_indicator) == (48, True, True, False)


@pytest.mark.socket
def test_a_served_classical_bus_refuses_an_fd_client():
    with (
        BusServer(500_000, listen=("127.0.0.1", 0)) as srv,
        pytest.raises(can.CanInitializationError, match="served without a data bit rate: it carries no CAN FD"),
    ):
        can.Bus(interface="canstack", channel=srv.url, fd=True, data_bitrate=2_000_000)


@pytest.mark.socket
def test_an_older_client_is_refused_with_a_message_that_says_to_upgrade():
    with BusServer(500_000, listen=("127.0.0.1", 0)) as srv:
        s = socket.create_connection(srv.address, timeout=10.0)
        with s:
            hello = {"v": 1, "bus": "bus0", "bitrate": None, "node_name": None, "config": {}}
            s.sendall(encode_message(HELLO, json.dumps(hello).encode()))
            reader, got = Reader(), []
            while (data := s.recv(65536)) != b"":
                got += reader.feed(data)
    assert got == [
        (
            ERROR,
            b"HELLO refused: the client speaks canstack serve protocol 1, this server speaks 2: upgrade canstack on "
            b"the client (pip install -U canstack)",
        )
    ]


def test_the_driver_sends_and_receives_fd_frames_on_a_virtual_bus():
    ch = f"drvfd{os.getpid()}"
    got = []
    with (
        can.Bus(interface="virtual", channel=ch, protocol=can.CanProtocol.CAN_FD) as peer,
        PyCanDriver(interface="virtual", channel=ch, protocol=can.CanProtocol.CAN_FD, data_bitrate=2_000_000) as drv,
    ):
        node = drv.add(Node("n"))
        node.subscribe(got.append)
        with drv.lock:
            node.send(Frame(0x321, bytes(range(32)), fd=True, brs=True))
        m = peer.recv(30.0)
        peer.send(_fd_msg(20, error_state_indicator=True))
        end = time.monotonic() + 30.0
        while not got and time.monotonic() < end:
            time.sleep(0.01)
    assert (m.arbitration_id, bytes(m.data), m.is_fd, m.bitrate_switch) == (0x321, bytes(range(32)), True, True)
    assert [(e.frame.fd, e.frame.esi, e.frame.data) for e in got] == [(True, True, bytes(range(20)))]


def test_a_driver_opened_with_fd_true_alone_has_fd_nodes():
    # python-can's fd=True is the bus's word that it carries CAN FD (SocketCAN's rates are set by
    # `ip link`, not by the program): the nodes on it are FD enabled, as the driver's docs say
    channel = f"fdalone{os.getpid()}"
    with (
        can.Bus(interface="virtual", channel=channel, fd=True) as peer,
        PyCanDriver(interface="virtual", channel=channel, fd=True) as driver,
    ):
        node = driver.node("a")
        assert node.fd == "fd" and driver.node("b", fd="classic").fd == "classic"
        node.send(Frame(0x10, bytes(range(12)), fd=True))
        m = peer.recv(5.0)
    assert m is not None and (m.arbitration_id, bytes(m.data), m.is_fd) == (0x10, bytes(range(12)), True)
