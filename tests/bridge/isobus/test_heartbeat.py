"""Heartbeat sender sequence/timing and monitor rules (ISO 11783-7 B.33), simulated time."""

import random

import can
import pytest

from bridge.isobus.codec import Heartbeat, decode, encode
from bridge.isobus.heartbeat import HeartbeatMonitor, HeartbeatSender, HeartbeatState

DT = 0.001  # simulated poll step, s


def run_sender(sender: HeartbeatSender, t0: float, t1: float):
    """Poll every DT from t0 to t1; return [(time, sequence)]."""
    out = []
    for k in range(round((t1 - t0) / DT) + 1):
        t = t0 + k * DT
        out += [(t, decode(f).sequence) for f in sender.poll(t)]
    return out


def test_sender_sequence_is_251_then_0_to_250_wrapping_every_100_ms():
    s = HeartbeatSender(source=169)
    first = s.start(0.0)
    assert [decode(f).sequence for f in first] == [251]
    assert first[0].arbitration_id == 0x0CF0E4A9  # priority 3, PGN 0xF0E4, source 169
    assert bytes(first[0].data) == b"\xfb" + b"\xff" * 7
    sent = run_sender(s, DT, 60.0)
    seqs = [q for _, q in sent]
    assert len(seqs) == 600
    assert seqs == [k % 251 for k in range(600)]  # 0..250, 0..250, 0..97
    times = [t for t, _ in sent]
    gaps = [b - a for a, b in zip([0.0] + times, times, strict=False)]  # each gap to the one before
    assert max(gaps) == pytest.approx(0.1, abs=DT) and min(gaps) == pytest.approx(0.1, abs=DT)


def test_sender_is_silent_before_start_and_does_not_burst_after_a_late_poll():
    s = HeartbeatSender()
    assert s.poll(5.0) == [] and not s.started
    s.start(0.0)
    assert [decode(f).sequence for f in s.poll(0.35)] == [0]  # one frame, not three
    assert s.poll(0.40) == []
    assert [decode(f).sequence for f in s.poll(0.45)] == [1]


def test_sender_fault_and_shutdown_values():
    s = HeartbeatSender()
    s.start(0.0)
    s.poll(0.1)
    s.fault = True
    assert [decode(f).sequence for f in s.poll(0.2)] == [254]
    s.fault = False
    assert [decode(f).sequence for f in s.poll(0.3)] == [1]
    assert [decode(f).sequence for f in s.shutdown()] == [255]
    assert s.poll(0.4) == [] and not s.started
    assert [decode(f).sequence for f in s.start(1.0)] == [251]


def feed(monitor: HeartbeatMonitor, sequences, t0=0.0, period=0.1):
    t = t0
    for q in sequences:
        monitor.handle_sequence(q, t)
        t += period
    return t - period  # time of the last heartbeat


def test_monitor_error_after_300_ms_of_silence():
    m = HeartbeatMonitor(source=169)
    assert m.status(0.0).state is HeartbeatState.WAITING and not m.healthy(0.0)
    last = feed(m, [251, 0, 1, 2])
    assert m.healthy(last + 0.29)
    status = m.status(last + 0.31)
    assert status.state is HeartbeatState.TIMEOUT and status.age_s == pytest.approx(0.31)
    # The late heartbeat starts a recovery: eight correct ones in a row (3..10) are needed.
    t = last + 0.5
    m.handle_sequence(3, t)
    assert m.status(t).state is HeartbeatState.TIMEOUT and m.status(t).timeouts == 1
    for k in range(4, 10):
        t += 0.1
        m.handle_sequence(k, t)
        assert not m.healthy(t)
    m.handle_sequence(10, t + 0.1)
    assert m.healthy(t + 0.1)


def test_monitor_sequence_rules():
    m = HeartbeatMonitor(source=169)
    t = feed(m, [251, 0, 1, 2])
    assert m.healthy(t)
    m.handle_sequence(4, t + 0.1)  # one heartbeat lost: tolerated
    m.handle_sequence(7, t + 0.2)  # two lost: tolerated
    assert m.healthy(t + 0.2)
    m.handle_sequence(7, t + 0.3)  # repeat
    st = m.status(t + 0.3)
    assert st.state is HeartbeatState.SEQUENCE_ERROR and st.sequence_errors == 1
    t = feed(m, range(8, 15), t + 0.4)  # seven correct: still in error
    assert m.status(t).state is HeartbeatState.SEQUENCE_ERROR
    m.handle_sequence(15, t + 0.1)  # the eighth
    assert m.healthy(t + 0.1)
    m.handle_sequence(19, t + 0.2)  # jump of 4 (three lost)
    assert m.status(t + 0.2).state is HeartbeatState.SEQUENCE_ERROR


def test_monitor_wraps_after_250_and_ignores_reserved_values():
    m = HeartbeatMonitor(source=169)
    t = feed(m, [248, 249, 250, 0, 1])
    assert m.healthy(t) and m.status(t).last_sequence == 1
    m.handle_sequence(252, t + 0.1)  # reserved: ignored, does not refresh the timestamp
    assert m.status(t + 0.1).last_sequence == 1 and m.status(t + 0.1).age_s == pytest.approx(0.1)
    m.handle_sequence(2, t + 0.2)
    assert m.healthy(t + 0.2)


def test_monitor_restart_error_and_shutdown():
    m = HeartbeatMonitor(source=169)
    t = feed(m, [251, 0, 1, 2, 3])
    m.handle_sequence(251, t + 0.1)  # the sender restarted
    st = m.status(t + 0.1)
    assert st.restarts == 1 and st.healthy
    m.handle_sequence(0, t + 0.2)
    m.handle_sequence(254, t + 0.3)
    assert m.status(t + 0.3).state is HeartbeatState.SENDER_ERROR
    m.handle_sequence(255, t + 0.4)
    assert m.status(t + 0.4).state is HeartbeatState.SHUTDOWN
    m.handle_sequence(5, t + 0.5)  # counting again without the initial 251
    assert m.status(t + 0.5).state is HeartbeatState.SEQUENCE_ERROR
    m.handle_sequence(251, t + 0.6)
    assert m.healthy(t + 0.6) and m.status(t + 0.6).restarts == 2


def test_monitor_handles_frames_only_from_its_sender():
    m = HeartbeatMonitor(source=169)
    assert m.handle(encode(Heartbeat(251), source=169), 0.0)
    assert not m.handle(encode(Heartbeat(0), source=166), 0.1)  # another sender
    one_byte = can.Message(arbitration_id=0x0CF0E4A9, is_extended_id=True, data=b"\x00")
    assert m.handle(one_byte, 0.1)  # DLC 1, as ISO 11783-7 defines the message
    reserved = can.Message(arbitration_id=0x0CF0E4A9, is_extended_id=True, data=b"\xfd")
    assert not m.handle(reserved, 0.2)
    other = can.Message(arbitration_id=0x0CFF22A9, is_extended_id=True, data=bytes(8))
    assert not m.handle(other, 0.2)
    assert m.healthy(0.2) and m.status(0.2).last_sequence == 0


def test_sender_and_monitor_with_five_percent_frame_loss():
    rnd = random.Random(5)
    sender, monitor = HeartbeatSender(source=169), HeartbeatMonitor(source=169)
    for f in sender.start(0.0):
        monitor.handle(f, 0.0)
    lost_in_a_row, worst, unhealthy_polls = 0, 0, 0
    for k in range(1, 20_001):
        t = k * 0.01
        for f in sender.poll(t):
            if rnd.random() < 0.05:
                lost_in_a_row += 1
                continue
            worst, lost_in_a_row = max(worst, lost_in_a_row), 0
            monitor.handle(f, t)
        unhealthy_polls += not monitor.healthy(t)
    # With this seed up to two heartbeats in a row are lost (300 ms gap, advance 3): tolerated.
    assert worst == 2
    assert unhealthy_polls == 0 and monitor.status(t).sequence_errors == 0
    assert monitor.status(t).timeouts == 0


@pytest.mark.parametrize("bad", [-1, 256, 1.0, None])
def test_monitor_rejects_impossible_sequence_numbers(bad):
    with pytest.raises(ValueError, match=r"sequence must be an integer in 0\.\.255"):
        HeartbeatMonitor(source=1).handle_sequence(bad, 0.0)


def test_bad_configuration_is_rejected():
    with pytest.raises(ValueError, match="period_s"):
        HeartbeatSender(period_s=0.0)
    with pytest.raises(ValueError, match="timeout_s"):
        HeartbeatMonitor(source=1, timeout_s=-1.0)


def test_monitor_judges_the_gap_by_the_frames_timestamps_when_given():
    """Heartbeats sent 100 ms apart but read 400 ms apart (the reader stalled, they waited in the bus)
    are on time; heartbeats whose own timestamps are 400 ms apart are late however they are read."""
    m = HeartbeatMonitor(source=169)
    for k, q in enumerate([251, 0, 1, 2]):
        m.handle_sequence(q, 0.1 * k, stamp_s=100.0 + 0.1 * k)
    for k, q in enumerate([3, 4, 5]):  # sent at 100.4, 100.5, 100.6; all read at 0.75 after a stall
        m.handle_sequence(q, 0.75, stamp_s=100.4 + 0.1 * k)
    assert m.status(0.75).state is HeartbeatState.OPERATIONAL and m.status(0.75).timeouts == 0
    m.handle_sequence(6, 1.2, stamp_s=101.0)  # its own timestamp: 400 ms after the last one
    assert m.status(1.2).state is HeartbeatState.TIMEOUT and m.status(1.2).timeouts == 1
    # the smaller of the two gaps counts: a wall clock stepped forward (stamps 500 ms apart, read 100 ms
    # apart) raises no timeout; a heartbeat without a timestamp is judged by its read time alone
    n = HeartbeatMonitor(source=169)
    n.handle_sequence(251, 0.0, stamp_s=5.0)
    n.handle_sequence(0, 0.1, stamp_s=5.5)
    assert n.status(0.1).state is HeartbeatState.OPERATIONAL
    n.handle_sequence(1, 0.5)
    assert n.status(0.5).state is HeartbeatState.TIMEOUT


def test_the_gap_that_counted_as_a_silence_is_kept():
    m = HeartbeatMonitor(0xA9)
    for k, t in enumerate((0.0, 0.1, 0.2, 0.75, 0.85)):
        m.handle_sequence(k, t)
    st = m.status(0.86)
    assert st.state is HeartbeatState.TIMEOUT and st.age_s == pytest.approx(0.01)
    assert st.last_gap_s == pytest.approx(0.55) and st.timeouts == 1
    assert HeartbeatMonitor(0xA9).status(0.0).last_gap_s is None
