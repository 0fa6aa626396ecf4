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

from bridge.service.api import MAX_IN_FLIGHT_PER_USER
from bridge.service.client import HitchClient, ServiceError
from bridge.service.config import ServiceConfig
from bridge.service.server import HitchService
from tests.helpers import Gate
from tests.integration.service_process import free_port

PLAN_S = 1.5  # each slow plan holds the planner this long


@pytest.fixture(params=["auto"])
def service(tmp_path, request):
    port = free_port()
    # the controller in this process (its planning guard is slowed below) and planning on its threads:
    # the arrangement in which the old defect showed
    cfg = ServiceConfig(
        listen=[f"tcp/127.0.0.1:{port}"],
        data_dir=tmp_path,
        control_core="thread",
        planning_processes=0,
        user_keys=request.param,
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


@pytest.mark.parametrize("service", [True], indirect=True)  # as behind a router whose ACL checks the names
def test_expensive_requests_over_zenoh_are_admitted_per_user(service):
    """Before, every Zenoh request was admitted against one shared allowance (Zenoh names no user): one
    viewer's plans refused everybody's ``busy``. A client with a user sends on its own keys
    (``<prefix>/user/<name>/…``), and the service admits per name."""
    svc, ep = service
    real = svc.motion.preview_with_tail
    svc.motion.preview_with_tail = held = Gate(real)
    entered = held.entered
    results: list = []
    with (
        HitchClient([ep], timeout_s=10.0, user="victor") as victor,
        HitchClient([ep], timeout_s=10.0, user="vera") as vera,
    ):
        end = time.monotonic() + 10
        while not vera.state(timeout_s=5.0)["ecu"]["online"] and time.monotonic() < end:
            pass
        ts = [
            threading.Thread(target=lambda: results.append(victor.plan({"z": 0.2})), daemon=True)
            for _ in range(MAX_IN_FLIGHT_PER_USER)
        ]
        for t in ts:
            t.start()
        try:
            for _ in ts:
                assert entered.acquire(timeout=5.0)
            with pytest.raises(ServiceError) as ei:  # one more of victor's: at once busy
                victor.plan({"z": 0.2})
            assert ei.value.code == "busy" and "this user" in str(ei.value)
            other = threading.Thread(target=lambda: results.append(vera.plan({"z": 0.2})), daemon=True)
            other.start()
            ts.append(other)
            assert entered.acquire(timeout=5.0), "vera's plan was not admitted beside victor's"
        finally:
            held.open()
            for t in ts:
                t.join(15.0)
        assert len(results) == MAX_IN_FLIGHT_PER_USER + 1
        saved = vera.request("presets/save", {"name": "vera-made", "pose": {"z": 0.2}})
        assert saved["saved"] == "vera-made"
    svc.motion.preview_with_tail = real
    assert svc.store.get_preset("vera-made", implement=svc.api.implement).owner == "vera"  # stored as hers


def test_a_service_that_cannot_check_names_serves_no_user_keys_and_clients_use_the_plain_ones(service):
    """Without access control that gives each user their own keys anyone could claim any name (and so
    another user's admission allowance and store limits): such a service does not serve them."""
    svc, ep = service
    assert svc.user_keys is False
    with HitchClient([ep], timeout_s=5.0, user="victor") as c:
        assert c.config()["user_keys"] is False  # asked on the plain key, as the client does once
        assert [r for r in c.session.get("hitch/user/victor/config", payload=b"{}", timeout=1.0) if r.ok] == []
        assert c.ik(0.0, 0.1, 0.0, 0.0)["status"] == "ok"  # answered on the plain key
