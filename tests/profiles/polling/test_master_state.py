"""The poll-list master as a state machine: its transition table against the one its module
documents, and a `PollMaster` built from its `MasterConfig` alone on a simulated bus."""

from __future__ import annotations

from profiles.pipeline.scenario import parse_scenario
from profiles.polling._state import TRANSITIONS, MasterEvent, MasterState, next_state
from profiles.polling.config import NETWORK_TABLE
from profiles.polling.events import SlaveLost
from profiles.polling.master import PollMaster
from stack import Frame, SimBus

S, E = MasterState, MasterEvent


def test_the_transition_table_is_the_documented_one():
    """Written out again from the module docstring's table."""
    running = (S.IDLE, S.SENDING, S.WAITING)
    expected = {(S.IDLE, E.CYCLE_START): S.IDLE, (S.SENDING, E.SENT): S.WAITING}
    expected[(S.SENDING, E.UNSENT)] = S.SENDING
    expected[(S.WAITING, E.ANSWER)] = S.WAITING
    expected[(S.SENDING, E.TIMEOUT)] = S.SENDING
    expected[(S.WAITING, E.TIMEOUT)] = S.WAITING
    expected[(S.STOPPED, E.RECOVERED)] = S.IDLE
    for s in running:
        expected[(s, E.REQUEST)] = S.SENDING
        expected[(s, E.COS)] = s
        expected[(s, E.CYCLE_END)] = S.IDLE
        expected[(s, E.BUS_OFF)] = S.STOPPED
        expected[(s, E.COMM_FAULT)] = S.FAULTED
    assert expected == TRANSITIONS
    assert not [e for e in MasterEvent if next_state(S.FAULTED, e) is not None]


def test_a_stopped_master_ignores_everything_but_its_recovery():
    for event in MasterEvent:
        assert next_state(S.STOPPED, event) == (S.IDLE if event is E.RECOVERED else None)


def test_an_answer_counts_only_while_waiting_and_a_request_goes_out_only_while_sending():
    assert [s for s in MasterState if next_state(s, E.ANSWER) is not None] == [S.WAITING]
    assert [s for s in MasterState if next_state(s, E.SENT) is not None] == [S.SENDING]


def test_a_poll_master_built_from_its_config_alone_loses_a_silent_slave():
    """One master polling s1, which is not on the bus (a second node only acknowledges). On the
    idle bus each request starts the moment it is queued, and its timeout runs 1 ms from that SOF:
    the request at 0 times out at 1 ms, its one retry at 2 ms — s1 missed the poll, and the cycle
    ends exactly when the next is due (no overrun). Cycles at 0, 2 and 4 ms; the third miss, at
    6 ms, makes s1 lost (lost_after 3)."""
    raw = {
        "bus": {"bitrate": 500000, "duration": 0.01},
        "nodes": [
            {
                "name": "m",
                "profile": "master",
                "cycle_ms": 2,
                "timeout_ms": 1,
                "retries": 1,
                "lost_after": 3,
                "poll": [{"slave": "s1"}],
            },
            {"name": "s1", "profile": "slave", "mac_id": 1, "messages": [{"name": "s1_in", "id": 0x3C1, "dlc": 1}]},
        ],
    }
    config = parse_scenario(raw).tables[NETWORK_TABLE].masters["m"]
    bus = SimBus(500_000)
    node = bus.node("m")
    bus.node("ack")  # acknowledges; s1 itself is absent
    sent = []

    def send(message, not_after):
        sent.append((message.name, not_after))
        return node.send(Frame(message.can_id, bytes(message.dlc)), not_after=not_after)

    master = PollMaster(node, config, send=send)
    states = {}
    for t in (0, 100_000, 500_000):  # before the first request, queued on the bus, in its timeout
        bus.call_at(t + 1, lambda t=t: states.__setitem__(t, master.state))
    master.start()
    bus.run(until=7_000_000)
    assert states == {0: S.SENDING, 100_000: S.WAITING, 500_000: S.WAITING}
    link = master.links["s1"]
    (lost,) = [e for e in master.events if isinstance(e, SlaveLost)]
    assert (lost.time, lost.master, lost.slave, lost.missed) == (6_000_000, "m", "s1", 3)
    # the fourth cycle (6 ms) polls s1 no more: it is lost, polled every 10th cycle
    assert link.polls == 6 and link.timeouts == 6 and link.missed == 3 and link.lost
    assert sent == [("poll_s1", t + 1_000_000) for t in range(0, 6_000_000, 1_000_000)]
    assert master.figures()["cycles"] == 4 and master.stats.overruns == 0
