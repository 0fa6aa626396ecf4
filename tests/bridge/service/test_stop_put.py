"""A put on ``<prefix>/stop`` stops as the query does, in both control-core arrangements.

A fleet trial: fleet software broadcasting an emergency stop as a Zenoh put (the obvious way to reach many
services at once) was ignored and the hitch moved on; api.md says "whatever is sent to stop, stops".
"""

from __future__ import annotations

import time

import pytest

from bridge.service.client import HitchClient
from bridge.service.config import ServiceConfig
from bridge.service.server import HitchService
from tests.helpers import loopback_client_session
from tests.integration.service_process import free_port

pytestmark = pytest.mark.slow  # a service with its twin (and, for "process", its control core's process)


@pytest.fixture(params=["thread", "process"])
def service(tmp_path, request):
    port = free_port()
    cfg = ServiceConfig(listen=[f"tcp/127.0.0.1:{port}"], data_dir=tmp_path, control_core=request.param)
    svc = HitchService(cfg).start()
    try:
        yield svc, f"tcp/127.0.0.1:{port}"
    finally:
        svc.close()


def _online(c: HitchClient) -> None:
    end = time.monotonic() + 15
    while not c.state(timeout_s=5.0)["ecu"]["online"]:
        assert time.monotonic() < end, "the ECU did not come online"
        time.sleep(0.1)


def _put_during_a_goto(ep: str, c: HitchClient, *puts: tuple[str, bytes | None]) -> dict:
    """A slow goto (several seconds), then ``puts`` from another session (None: a delete); the goto's reply."""
    r = _slow_goto(c)
    s = loopback_client_session(ep)
    try:
        time.sleep(0.3)  # the put's route to the subscriber
        for key, payload in puts:
            if payload is None:
                s.delete(key)
            else:
                s.put(key, payload)
        time.sleep(0.5)
    finally:
        s.close()
    return r


def _slow_goto(c: HitchClient) -> dict:
    r = c.goto({"z": 0.3}, speed_scale=0.2)  # several seconds of motion
    assert r["accepted"], r
    time.sleep(0.5)
    assert c.state()["moving"]
    return r


@pytest.mark.parametrize(
    ("key", "payload"),
    [
        ("hitch/stop", b"{}"),
        ("hitch/stop", b""),
        ("hitch/stop", b"\xff not json"),
        ("*/stop", b""),  # a fleet's broadcast: a wildcard that includes this service's stop key (a review)
        ("hitch/stop", None),  # a delete: whatever is sent to stop, stops
    ],
)
def test_a_put_on_stop_stops_the_motion(service, key, payload):
    svc, ep = service
    with HitchClient([ep], timeout_s=10.0) as c:
        _online(c)
        r = _put_during_a_goto(ep, c, (key, payload))
        end = time.monotonic() + 3.0
        while c.state()["motion"] == "goto" and time.monotonic() < end:
            time.sleep(0.05)
        st = c.state()
        recent = c.request("events/recent", {})
    assert st["motion"] in (None, "stop"), st["motion"]
    ended = [e for e in recent["events"] if e.get("motion_id") == r["motion_id"] and e["event"] == "motion_aborted"]
    assert ended and "stop" in ended[-1]["reason"]


def test_a_put_on_another_key_under_the_prefix_does_not_stop(service):
    svc, ep = service
    with HitchClient([ep], timeout_s=10.0) as c:
        _online(c)
        r = _put_during_a_goto(ep, c, ("hitch/stopx", b"{}"), ("hitch/user/alice/stop", b"{}"))
        st = c.state()
        c.stop()
    assert st["moving"] and st["motion"] == "goto" and st["motion_id"] == r["motion_id"]
