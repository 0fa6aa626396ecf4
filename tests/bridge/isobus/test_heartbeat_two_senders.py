"""The heartbeat monitor's hint for two nodes sending with one source address (a new user's second ``hitch
ecu-sim`` joined the hub while the first still ran: "ECU heartbeat sequence error; last counter 17", no hint).

The expected words are written here by hand: the hint names the cause (two nodes, one source address, 169 =
0xA9) and is given only for interleaved counters, never for a single jump or a single repeat."""

import itertools

import pytest

from bridge.isobus.codec import Heartbeat, encode
from bridge.isobus.heartbeat import HeartbeatMonitor, HeartbeatState

ECU = 169


def _feed(monitor: HeartbeatMonitor, sequences, t0: float = 0.0, dt: float = 0.05) -> float:
    """Hand ``sequences`` to ``monitor`` as frames, ``dt`` apart; return the time of the last."""
    t = t0
    for q in sequences:
        assert monitor.handle(encode(Heartbeat(q), source=ECU), t)
        t += dt
    return t - dt


def _interleave(a, b):
    return [q for pair in zip(a, b, strict=True) for q in pair]


@pytest.mark.parametrize(
    "sequences",
    [
        _interleave(range(10, 20), range(200, 210)),  # two ECUs out of phase: 10, 200, 11, 201, ...
        _interleave(range(0, 10), range(0, 10)),  # in phase (started together): 0, 0, 1, 1, ...
        [15, 16, 17, 251] + _interleave(range(18, 28), range(0, 10)),  # the second one starts (251) and joins
        _interleave([k % 251 for k in range(245, 255)], range(100, 110)),  # one across the wrap 250 -> 0
    ],
    ids=["out-of-phase", "in-phase", "second-joins", "wrap"],
)
def test_two_interleaved_counters_from_one_address_say_two_nodes_may_share_it(sequences):
    m = HeartbeatMonitor(ECU)
    t = _feed(m, sequences)
    st = m.status(t)
    assert st.state is HeartbeatState.SEQUENCE_ERROR
    assert st.interleaved
    hint = st.sequence_error_hint()
    assert hint is not None
    assert hint == (
        "the counter interleaves two sequences, possibly two nodes sending with source address 169 = 0xA9 "
        "(e.g. a second hitch ecu-sim on the bus)"
    )


@pytest.mark.parametrize(
    "sequences",
    [
        [10, 11, 12, 13, 50, 51, 52],  # one jump forward
        [10, 11, 12, 13, 5, 6, 7],  # one jump back
        [10, 11, 12, 12, 13, 14],  # one repeat
        [10, 11, 12, 12, 12, 12, 12],  # a hung sender repeating its last counter
        [10, 11, 12, 100, 200, 40, 140],  # random jumps, no sequence continued
    ],
    ids=["jump-forward", "jump-back", "one-repeat", "hung", "random"],
)
def test_a_single_jump_or_repeat_is_a_sequence_error_without_the_two_nodes_hint(sequences):
    m = HeartbeatMonitor(ECU)
    t = _feed(m, sequences)
    st = m.status(t)
    assert st.state is HeartbeatState.SEQUENCE_ERROR
    assert not st.interleaved
    assert st.sequence_error_hint() is None


def test_the_hint_goes_once_the_second_sender_is_gone_and_the_counter_runs_clean_again():
    m = HeartbeatMonitor(ECU)
    t = _feed(m, _interleave(range(10, 20), range(200, 210)))
    assert m.status(t).sequence_error_hint() is not None
    t = _feed(m, range(20, 30), t0=t + 0.05)  # the first ECU alone: 8 correct in a row
    st = m.status(t)
    assert st.state is HeartbeatState.OPERATIONAL and not st.interleaved and st.sequence_error_hint() is None
    t = _feed(m, [30, 31, 90, 91], t0=t + 0.05)  # then a single jump: no hint
    assert m.status(t).state is HeartbeatState.SEQUENCE_ERROR and m.status(t).sequence_error_hint() is None


def test_no_hint_in_states_other_than_a_sequence_error():
    m = HeartbeatMonitor(ECU)
    t = _feed(m, _interleave(range(10, 20), range(200, 210)))
    assert m.status(t + 1.0).state is HeartbeatState.TIMEOUT
    assert m.status(t + 1.0).sequence_error_hint() is None
    m2 = HeartbeatMonitor(ECU)
    t2 = _feed(m2, itertools.islice(itertools.cycle(range(251)), 30))
    assert m2.status(t2).healthy and m2.status(t2).sequence_error_hint() is None
