"""A service killed (SIGKILL) while its core moves the hitch: the core brakes and says why (a fleet trial: the
motion was aborted "service shutting down", as if the service had been closed on purpose)."""

from __future__ import annotations

import threading

import pytest
import zenoh

from bridge.service.client import HitchClient
from tests.helpers import loopback_zenoh_config, wait_until
from tests.integration.service_process import ServiceProcess, free_port, wait_online

pytestmark = pytest.mark.slow  # a service and its core in their own processes, behind a router

PREFIX = "fleet/t05/hitch"


def test_a_killed_service_has_its_core_brake_naming_the_kill(tmp_path):
    ep = f"tcp/127.0.0.1:{free_port()}"
    router = zenoh.open(loopback_zenoh_config("router", ep))
    svc = None
    try:
        svc = ServiceProcess(["--mode", "client", "--connect", ep, "--prefix", PREFIX, "--data-dir", str(tmp_path)])
        events: list[dict] = []
        lock = threading.Lock()
        with HitchClient([ep], prefix=PREFIX, timeout_s=10.0) as c:
            c.subscribe("events", lambda e: [lock.acquire(), events.append(e), lock.release()])
            s = wait_online(c)
            ws = c.config()["limits"]["workspace"]["z"]
            goal = ws[0] + 0.9 * (ws[1] - ws[0]) if s["pose"]["z"] < sum(ws) / 2 else ws[0] + 0.1 * (ws[1] - ws[0])
            mid = c.goto({"z": goal})["motion_id"]
            assert wait_until(lambda: c.state()["moving"], 5.0)
            svc.kill()  # SIGKILL: no close message reaches the core

            def aborted() -> list[dict]:
                with lock:
                    return [e for e in events if e.get("event") == "motion_aborted" and e.get("motion_id") == mid]

            assert wait_until(lambda: bool(aborted()), 10.0), events
            assert aborted()[0]["reason"] == "the service ended without closing the core (killed or crashed)"
    finally:
        if svc is not None:
            svc.kill()
        router.close()
