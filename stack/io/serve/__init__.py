"""`canstack serve`: one simulated bus in real time shared by several processes.

The server runs a `SimBus` paced to the wall clock (`stack.io.runner.RealTimeRunner`) and accepts
clients over TCP (loopback only unless ``allow_remote``) or a unix socket. Each client is a
node with its own controller on that bus; arbitration, ACK and timing are done by the server, so
ECU prototypes in several processes contend as on a real bus. A client joins with
``can.Bus(interface="canstack", channel="tcp://127.0.0.1:PORT/bus0")`` or
``channel="unix:///path/to/socket/bus0"``.

- `stack.io.serve.protocol` — message types, framing, encoding and decoding (pure, no sockets);
- `stack.io.serve.server` — `BusServer` and its per-client sessions;
- `stack.io.serve.client` — `RemotePort`, the python-can interface's side of a connection.
"""

from stack.io.serve.client import RemotePort
from stack.io.serve.protocol import (
    BYE,
    ERROR,
    FILTERS,
    HELLO,
    MAX_MESSAGE,
    MODE,
    PROTOCOL_VERSION,
    RX,
    SEND,
    STATE,
    TXEND,
    TXERROR,
    WELCOME,
    encode_message,
)
from stack.io.serve.server import HELLO_TIMEOUT_S, MAX_BACKLOG, BusServer

__all__ = [
    "BusServer",
    "RemotePort",
    "MAX_MESSAGE",
    "MAX_BACKLOG",
    "HELLO_TIMEOUT_S",
    "encode_message",
    "PROTOCOL_VERSION",
    "HELLO",
    "WELCOME",
    "ERROR",
    "SEND",
    "RX",
    "TXEND",
    "STATE",
    "FILTERS",
    "BYE",
    "TXERROR",
    "MODE",
]
