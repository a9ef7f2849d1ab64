"""What ``canopen.LocalNode`` (the canopen library's device) does not do — the right-hand column
of the README's comparison table. Each check drives LocalNode directly through a network stand-in
that records what it subscribes to and what it sends; the canstack device's side of every row
is tested in the other modules (named in the README table)."""

import struct

import canopen
import pytest

from profiles.canopen.dictionary import DEFAULT_EDS


class Recorder(canopen.Network):
    """A canopen Network without a bus: records subscriptions and sent frames."""

    def __init__(self):
        super().__init__()
        self.sent = []

    def send_message(self, can_id, data, remote=False):
        self.sent.append((can_id, bytes(data or b"")))

    def send_periodic(self, can_id, data, period, remote=False):
        self.sent.append((can_id, bytes(data or b"")))  # the first of a periodic message

        class Task:
            def stop(self):
                pass

            def update(self, data):
                pass

        return Task()


@pytest.fixture
def local():
    net = Recorder()
    net.before = set(net.subscribers)  # the network's own (LSS master)
    node = canopen.LocalNode(4, str(DEFAULT_EDS))
    net.add_node(node)
    return net, node


def test_it_listens_to_nothing_but_its_sdo_requests_and_nmt(local):
    net, node = local
    # no SYNC consumer (0x080), no RPDO (0x204..), no heartbeat consumer or node guarding (0x7xx)
    assert set(net.subscribers) - net.before == {0x604, 0x000}


def test_an_nmt_reset_from_the_network_sends_no_boot_up(local):
    net, node = local
    net.notify(0x000, bytearray([0x82, 4]), 0.0)
    net.notify(0x000, bytearray([0x81, 0]), 0.0)
    assert net.sent == [] and node.nmt.state == "INITIALISING"


def test_it_answers_sdo_while_stopped(local):
    net, node = local
    net.notify(0x000, bytearray([0x02, 4]), 0.0)
    assert node.nmt.state == "STOPPED"
    net.notify(0x604, bytearray(struct.pack("<BHB", 0x40, 0x1018, 1) + bytes(4)), 0.0)
    assert net.sent and net.sent[-1][0] == 0x584 and net.sent[-1][1][0] == 0x43  # an answer, not silence


def test_it_has_no_block_download(local):
    net, node = local
    net.notify(0x604, bytearray(struct.pack("<BHBL", 0xC6, 0x2201, 0, 100)), 0.0)
    cmd, index, sub, code = struct.unpack("<BHBL", net.sent[-1][1])
    assert (cmd, code) == (0x80, 0x0504_0001)


def test_it_takes_mapping_writes_while_the_pdo_is_valid(local):
    net, node = local
    net.notify(0x000, bytearray([0x01, 4]), 0.0)  # operational, TPDO1 valid
    net.notify(0x604, bytearray(struct.pack("<BHBB", 0x2F, 0x1A00, 0, 0) + bytes(3)), 0.0)
    assert net.sent[-1][1][0] == 0x60  # accepted: CiA 301 and the canstack device refuse it


def test_it_sends_no_pdo_by_itself(local):
    net, node = local
    net.notify(0x000, bytearray([0x01, 4]), 0.0)
    node.sdo[0x2002].raw = 5  # a mapped object changes; TPDO2/3 are event-driven in the EDS too
    net.notify(0x080, bytearray(), 0.0)  # a SYNC it does not even listen to
    assert [c for c, _ in net.sent if 0x180 <= c < 0x580] == []
