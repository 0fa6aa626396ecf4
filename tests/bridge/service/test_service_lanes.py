"""The running service over Zenoh (in process, loopback): slow planning requests fill the workers,
an operator's goto times out at its client, a stop is answered — and the goto never starts later.

The old defect: the goto waited in the worker pool behind four slow ``plan`` requests and started
long after its client had given up and after the stop. Now motion requests have their own lane,
wait for the planner no longer than their deadline, and a stop cancels what arrived before it.
"""

from __future__ import annotations

import threading
import time

import pytest

from bridge.service.client import HitchClient, ServiceError
from bridge.service.config import ServiceConfig
from bridge.service.server import HitchService
from tests.integration.service_process import free_port

PLAN_S = 1.5  # each slow plan holds the planner this long


@pytest.fixture
def service(tmp_path):
    port = free_port()
    # the controller in this process (its planning guard is slowed below) and planning on its threads:
    # the arrangement in which the old defect showed
    cfg = ServiceConfig(
        listen=[f"tcp/127.0.0.1:{port}"], data_dir=tmp_path, control_core="thread", planning_processes=0
    )
    svc = HitchService(cfg).start()
    try:
        yield svc, f"tcp/127.0.0.1:{port}"
    finally:
        svc.close()


def test_an_abandoned_goto_never_starts_after_the_stop(service):
    svc, ep = service
    events: list[dict] = []
    svc.add_listener("event", events.append)
    real = svc.motion.plan_guard.plan

    def slow(*a, **k):
        time.sleep(PLAN_S)
        return real(*a, **k)

    svc.motion.plan_guard.plan = slow
    with HitchClient([ep], timeout_s=10.0) as c:
        end = time.monotonic() + 10
        while not c.state(timeout_s=5.0)["ecu"]["online"] and time.monotonic() < end:
            pass
        viewers = [
            threading.Thread(target=_quiet, args=(c.plan, {"z": 0.05 + 0.01 * i}), daemon=True) for i in range(4)
        ]
        for t in viewers:
            t.start()
        time.sleep(0.3)  # the plans hold the workers and the planner
        with pytest.raises(ServiceError):  # the operator's goto: refused busy or timed out at the client
            c.request("goto", {"goal": {"z": 0.2}}, timeout_s=1.0)
        assert c.stop()["stopped"]
        t_stop = time.monotonic()
        for t in viewers:
            t.join(4 * PLAN_S + 5)
        time.sleep(PLAN_S + 0.5)  # the old code started the goto once the planner was free
    svc.motion.plan_guard.plan = real
    late = [e for e in events if e["event"] == "motion_started" and e.get("kind") == "goto"]
    assert not late, f"a goto started {time.monotonic() - t_stop:.1f} s after the stop: {late}"


def _quiet(fn, *args):
    try:
        fn(*args)
    except ServiceError:
        pass
