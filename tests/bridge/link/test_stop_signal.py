"""StopSignal: the stop flag the real-time loops sleep on behaves as threading.Event's set / is_set / wait."""

from __future__ import annotations

import threading
import time

import pytest

from bridge.link import StopSignal
from bridge.link.realtime import RealtimeRunner
from bridge.service.periodic import PeriodicThread


def test_a_wait_before_set_times_out_false_and_takes_its_time():
    s = StopSignal()
    t0 = time.monotonic()
    assert s.wait(0.05) is False
    assert time.monotonic() - t0 >= 0.045
    assert not s.is_set()


@pytest.mark.parametrize("timeout", [0.0, -1.0, -1e-9])
def test_a_wait_of_zero_or_less_does_not_block(timeout):
    s = StopSignal()
    t0 = time.monotonic()
    assert s.wait(timeout) is False
    assert time.monotonic() - t0 < 0.5  # -1 would mean "forever" to Lock.acquire
    s.set()
    assert s.wait(timeout) is True


def test_set_wakes_every_blocked_waiter_at_once_and_every_later_wait_returns_true():
    s = StopSignal()
    woke: list[tuple[bool, float]] = []
    lock = threading.Lock()

    def waiter(timeout):
        r = s.wait(timeout)
        with lock:
            woke.append((r, time.monotonic()))

    threads = [threading.Thread(target=waiter, args=(t,)) for t in (10.0, 10.0, None, 5.0)]
    for t in threads:
        t.start()
    time.sleep(0.1)
    assert woke == []
    t_set = time.monotonic()
    s.set()
    for t in threads:
        t.join(2.0)
    assert len(woke) == 4 and all(r for r, _ in woke)
    assert max(t for _, t in woke) - t_set < 1.0  # not their 5-10 s timeouts
    assert s.is_set() and s.wait(0.0) and s.wait(None) and s.wait(1.0)


def test_set_is_idempotent_from_many_threads_at_once():
    s = StopSignal()
    errors: list[BaseException] = []
    go = threading.Barrier(8)

    def setter():
        go.wait()
        try:
            s.set()
            s.set()
        except BaseException as exc:  # noqa: BLE001 - a double release would raise RuntimeError
            errors.append(exc)

    threads = [threading.Thread(target=setter) for _ in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(2.0)
    assert errors == [] and s.is_set() and s.wait(0.0)


class _IdleNode:
    """A BusNode with nothing to do: due again in 10 s (the runner's wait is capped at max_wait_s)."""

    def __init__(self, bus):
        self.bus, self.polls = bus, 0

    def start(self, now_s):
        pass

    def poll(self, now_s):
        self.polls += 1

    def next_due_s(self):
        return 1e9

    def handle(self, frame, now_s):
        pass


def test_a_runner_and_a_periodic_thread_in_long_waits_stop_at_once():
    from bridge.link.virtual import InProcessBus

    bus = InProcessBus(channel="stop-signal-test")
    try:
        node = _IdleNode(bus)
        runner = RealtimeRunner(node, max_wait_s=1.0, prompt=lambda: False).start()
        periodic = PeriodicThread(10.0, lambda: None, name="stop-signal-test").start()
        time.sleep(0.2)
        t0 = time.monotonic()
        runner.stop(2.0)
        periodic.stop(2.0)
        assert time.monotonic() - t0 < 0.5  # not the 1 s / 10 s waits
        assert not periodic.alive
        assert runner.wait(0.0) is True  # ended
        assert node.polls >= 1
    finally:
        bus.shutdown()
