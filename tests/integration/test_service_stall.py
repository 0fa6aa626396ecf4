"""A request sent while the service stalls is not taken as sent when the service runs again.

A fleet trial (service in client mode behind a router, its control core in its own process): ``hitch serve``
frozen 1.5 s; a goto sent 0.3 s into it timed out at its client; a stop 1.0 s later was answered by the core
(not frozen) — and after the thaw the goto started, 1.2 s after it was sent and after the acknowledged stop.
The service stamped the goto's arrival when its Python took it, after the thaw (``bridge.service.stall_watch``).
"""

from __future__ import annotations

import os
import signal
import threading
import time

import pytest

from bridge.service.client import HitchClient, ServiceError
from bridge.service.stall_watch import CHAIN_MAX_S, DRAIN_S, STALL_S, StallWatch
from tests.integration.service_process import ServiceProcess, free_port, start_hitch_router, wait_online


def test_the_arrival_during_and_just_after_a_stall_is_the_stalls_start():
    now = [100.0]
    w = StallWatch(clock=lambda: now[0])
    w.tick()
    now[0] = 100.0 + STALL_S * 0.9  # a gap within the stop's grace: now
    assert w.arrival() == pytest.approx(now[0])
    w.tick()
    t0 = now[0]
    now[0] = t0 + 1.5  # 1.5 s without a tick, not noticed yet: any time since the tick
    assert w.arrival() == t0
    w.tick()  # the tick notices the stall: taken within DRAIN_S after it, any time since its start
    assert w.arrival() == t0
    assert w.arrival(now[0] + STALL_S * 0.5) == t0
    end = now[0]
    while now[0] <= end + DRAIN_S:  # the process runs on, ticking
        now[0] += 0.02
        w.tick()
    assert w.arrival() == now[0]  # drained: now again


def test_two_stalls_close_together_count_from_the_first_ones_start():
    """A review: stall A 100.0-101.5 (a goto sent at 100.3, a stop at 101.0), 0.1 s of ticks, stall B 0.25 s: the
    goto taken after B was stamped with B's start (101.6), after the stop, and not refused."""
    now = [100.0]
    w = StallWatch(clock=lambda: now[0])
    w.tick()
    now[0] = 101.5
    w.tick()  # stall A noticed
    for _ in range(5):
        now[0] += 0.02
        w.tick()
    now[0] += 0.25
    w.tick()  # stall B, within DRAIN_S of A's end
    assert w.arrival() == 100.0


def test_stalls_every_half_second_do_not_push_the_stamps_back_without_end():
    """A review: 150 ms stalls every ~0.45 s for 10 s chained into one and stamped a request taken then 9.55 s old
    (every motion request refused as late while it lasts). A chain reaches back at most CHAIN_MAX_S."""
    now = [100.0]
    w = StallWatch(clock=lambda: now[0])
    w.tick()
    worst = 0.0
    while now[0] < 110.0:
        for _ in range(15):  # 0.3 s of ticks
            now[0] += 0.02
            w.tick()
        now[0] += 0.15  # a stall
        w.tick()
        worst = max(worst, now[0] - w.arrival())
    assert worst <= CHAIN_MAX_S + 0.5 + 0.15


@pytest.mark.slow
def test_a_goto_sent_while_the_service_is_frozen_never_starts_after_a_stop(tmp_path):
    router_ep = f"tcp/127.0.0.1:{free_port()}"
    router = start_hitch_router(router_ep)
    svc = None
    try:
        svc = ServiceProcess(["--mode", "client", "--connect", router_ep, "--data-dir", str(tmp_path / "data")])
        with HitchClient([router_ep], timeout_s=10.0) as c:
            wait_online(c)
            events: list[dict] = []
            c.subscribe("events", events.append)
            time.sleep(0.3)
            sent: dict = {}

            def goto() -> None:
                try:  # a deadline long enough that only the stop's ordering can refuse it
                    sent["reply"] = c.goto({"z": 0.25}, deadline_ms=10_000)
                except ServiceError as exc:
                    sent["error"] = exc.code

            os.kill(svc.proc.pid, signal.SIGSTOP)
            try:
                time.sleep(0.3)
                t = threading.Thread(target=goto)
                t.start()
                time.sleep(0.7)
                stopped = c.stop()  # the core's own queryable, through the router: not frozen
                assert stopped["stopped"] is True
                time.sleep(0.5)
            finally:
                os.kill(svc.proc.pid, signal.SIGCONT)
            t.join(15)
            time.sleep(1.5)
            state = c.state()
    finally:
        if svc is not None:
            svc.kill()
        router.kill()
        router.wait(10)
    started = [e for e in events if e.get("event") == "motion_started" and e.get("kind") == "goto"]
    assert started == [], started
    assert state["motion"] != "goto"
    # the goto's own reply (if its query was still open): refused busy, naming the stop
    if "reply" in sent:
        raise AssertionError(f"the goto was accepted: {sent['reply']}")
