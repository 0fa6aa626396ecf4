"""A service behind a router that loses it: the fleet can neither see nor stop the hitch any more.

A fleet trial: a 103 s goto ran on after the router was killed, with no event and nothing in the black box.
Now the service watches the nodes of ``connect``: losing the last one is a ``link_lost`` event and, by
``on_link_loss`` (default ``stop``), the hitch brakes to rest; ``link_restored`` when the router is back, and
nothing resumes. Truth: the service's own state (moving or not) and its events.
"""

from __future__ import annotations

import json
import time

import pytest

from bridge.service.config import ServiceConfig
from bridge.service.server import HitchService
from tests.helpers import wait_until
from tests.integration.service_process import free_port, start_hitch_router, start_router

pytestmark = pytest.mark.slow


@pytest.mark.parametrize(("policy", "mode"), [("stop", "client"), ("continue", "client"), ("stop", "peer")])
def test_losing_the_router_brakes_the_hitch_says_so_and_nothing_resumes(tmp_path, policy, mode):
    """A peer that connects to a router is watched too, from the first router it reaches (a review: the watch
    ran for clients only, and on_link_loss was ignored for peers without a word)."""
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    router = start_router(endpoint)
    svc = None
    try:
        cfg = ServiceConfig(
            mode=mode,
            connect=[endpoint],
            listen=[] if mode == "client" else [f"tcp/127.0.0.1:{free_port()}"],
            prefix=f"linkloss{port}/hitch",
            data_dir=tmp_path,
            planning_processes=0,
            can_channel=f"link-loss-{port}",
            on_link_loss=policy,
        )
        svc = HitchService(cfg).start()
        assert svc.api is not None
        events: list[dict] = []
        svc.add_listener("event", events.append)
        assert wait_until(lambda: svc.latest_state is not None and svc.latest_state["ecu"]["online"], 10.0)
        if mode == "peer":  # watched from the first router it reaches
            time.sleep(0.5)
        z0 = svc.latest_state["pose"]["z"]
        ok, reply = svc.api.handle("goto", json.dumps({"goal": {"z": z0 + 0.12}, "speed_scale": 0.05}), None)
        assert ok and reply["duration"] > 20.0, reply
        assert wait_until(lambda: svc.latest_state["moving"], 5.0)

        router.kill()  # SIGKILL, as in the trial
        router.wait(10)
        assert wait_until(lambda: any(e.get("event") == "link_lost" for e in events), 5.0), events
        lost = next(e for e in events if e.get("event") == "link_lost")
        assert lost["action"] == policy and endpoint in lost["message"], lost
        if policy == "stop":  # the state reaches the service over the core's own socket, not through the router
            assert wait_until(lambda: not svc.latest_state["moving"], 5.0), svc.latest_state["motion"]
            aborted = [e for e in events if e.get("event") == "motion_aborted"]
            assert any("link lost" in str(e.get("reason")) for e in aborted), aborted
        else:
            time.sleep(1.0)
            assert svc.latest_state["moving"] and time.time() - svc.latest_state["t"] < 1.0  # fresh, and it runs on

        router = start_router(endpoint)  # back: the client reconnects
        assert wait_until(lambda: any(e.get("event") == "link_restored" for e in events), 15.0), events
        if policy == "stop":
            time.sleep(1.0)
            assert not svc.latest_state["moving"]  # nothing resumed
            started = [e.get("kind") for e in events if e.get("event") == "motion_started"]
            assert started == ["goto", "stop"], started  # the goto, its stop, and nothing since
    finally:
        if svc is not None:
            svc.close()
        router.terminate()
        router.wait(10)


def test_a_frozen_router_is_noticed_within_the_lease_and_the_hitch_brakes(tmp_path):
    """A fleet trial: a router stopped with SIGSTOP (a hung host, a half-open TCP link) was noticed only after
    8.9 s, Zenoh's default 10 s lease, while nobody in the fleet could stop the hitch. `hitch router` and the
    service now announce a lease of DEFAULT_LEASE_S: link_lost and the brake come within it (plus the 0.1 s watch)."""
    import os
    import signal

    from bridge.service.config import DEFAULT_LEASE_S

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = start_hitch_router(endpoint)
    svc = None
    try:
        cfg = ServiceConfig(
            mode="client",
            connect=[endpoint],
            prefix="frozen/hitch",
            data_dir=tmp_path,
            planning_processes=0,
            can_channel=f"frozen-{endpoint[-5:]}",
        )
        svc = HitchService(cfg).start()
        assert svc.api is not None
        events: list[dict] = []
        svc.add_listener("event", events.append)
        assert wait_until(lambda: svc.latest_state is not None and svc.latest_state["ecu"]["online"], 10.0)
        z0 = svc.latest_state["pose"]["z"]
        ok, reply = svc.api.handle("goto", json.dumps({"goal": {"z": z0 + 0.12}, "speed_scale": 0.05}), None)
        assert ok, reply
        assert wait_until(lambda: svc.latest_state["moving"], 5.0)
        os.kill(router.pid, signal.SIGSTOP)
        frozen = time.monotonic()
        assert wait_until(lambda: any(e.get("event") == "link_lost" for e in events), 8.0), events
        took = time.monotonic() - frozen
        assert took < DEFAULT_LEASE_S + 1.0, took  # before: 8.9 s
        assert wait_until(lambda: not svc.latest_state["moving"], 5.0)
    finally:
        if svc is not None:
            svc.close()
        os.kill(router.pid, signal.SIGKILL)
        router.wait(10)


def test_a_peer_whose_router_is_down_at_start_says_it_is_not_reached(tmp_path):
    """A new user's trial: `hitch serve --listen … --connect <a router that is down>` said "ready … connected to
    …", and its started record had no warning."""
    from bridge.service.blackbox import event_log_path, read_events
    from tests.integration.service_process import ServiceProcess

    down = f"tcp/127.0.0.1:{free_port()}"  # nothing listens there
    svc = ServiceProcess(["--listen", f"tcp/127.0.0.1:{free_port()}", "--connect", down, "--data-dir", str(tmp_path)])
    try:
        out = "".join(svc.output)
        assert f"connecting to {down}" in out and f"connected to {down}" not in out, out
        assert f"warning: connect {down}: not reached yet" in out, out
    finally:
        svc.proc.send_signal(2)
        svc.proc.wait(30)
    started = next(r for r in read_events(event_log_path(tmp_path)) if r.get("what") == "started")
    assert any("not reached yet" in w for w in started["warnings"]), started
