"""SIGINT / SIGTERM as a flag (bridge.service.signals): a handler that took the lock of an Event the main
thread was waiting on hung `hitch serve` for good; the handler now takes no lock, a real signal ends the
wait within a poll, a storm of signals too, and the old handlers come back."""

from __future__ import annotations

import os
import signal
import threading
import time

from bridge.service.signals import POLL_S, StopSignals


def _send(signum: int, after_s: float, count: int = 1) -> threading.Thread:
    def run() -> None:
        time.sleep(after_s)
        for _ in range(count):
            os.kill(os.getpid(), signum)

    t = threading.Thread(target=run, daemon=True)
    t.start()
    return t


def test_a_real_sigterm_ends_the_wait_within_one_poll_and_the_old_handler_comes_back():
    before = signal.getsignal(signal.SIGTERM)
    with StopSignals() as stop:
        assert not stop.wait(0.0)
        t0 = time.monotonic()
        _send(signal.SIGTERM, 0.2)
        assert stop.wait(5.0)
        assert time.monotonic() - t0 < 0.2 + POLL_S + 0.5
    assert signal.getsignal(signal.SIGTERM) is before


def test_a_storm_of_signals_while_waiting_never_blocks_the_handler():
    """Hundreds of SIGINTs land while the main thread is inside wait (the old handler, Event.set, could
    find the event's lock held by its own thread there): the wait still ends."""
    with StopSignals() as stop:
        sender = _send(signal.SIGINT, 0.05, count=300)
        t0 = time.monotonic()
        assert stop.wait(10.0)
        sender.join(10.0)
        assert time.monotonic() - t0 < 10.0


def test_the_handler_only_sets_the_flag_even_with_a_lock_held_around_it():
    lock = threading.Lock()
    with StopSignals() as stop:
        handler = signal.getsignal(signal.SIGINT)
        assert callable(handler)
        with lock:  # whatever the main thread holds, the handler needs nothing
            handler(signal.SIGINT, None)
        assert stop.received and stop.wait(0.0)
