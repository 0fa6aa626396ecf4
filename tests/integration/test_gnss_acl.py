"""The tractor's GNSS (``hitch/tractor/gnss``, a sensor input timing maneuver line triggers) under the
access-control list of :mod:`bridge.service.security`, on the real service in its own process: an
operator's fixes reach the control core, a viewer's are denied by Zenoh (the viewer still observes)."""

from __future__ import annotations

import json
import time

import pytest

from bridge.service.client import HitchClient
from bridge.service.gnss import LocalTangentPlane
from bridge.service.security import AccessPolicy, Credentials, SecuritySettings, security_json5, write_users_file
from tests.integration.service_process import ServiceProcess, free_port, wait_online

pytestmark = pytest.mark.slow


def _client_file(d, user: str, password: str):
    p = d / f"{user}.json5"
    p.write_text(security_json5(SecuritySettings(credentials=Credentials(user, password))))
    return p


def _crossings(c: HitchClient) -> int:
    return int(c.request("lines/list", {})["lines"][0]["crossings"])


def _outliers(c: HitchClient) -> int:
    """Fixes the core received and refused as outliers (a 5 km jump from the twin's track)."""
    gnss = c.request("lines/list", {})["gnss"]
    return int(gnss["rejected"]) if "an outlier" in str(gnss["last_rejection"]) else 0


def test_only_an_operator_may_publish_gnss_fixes(tmp_path):
    users = write_users_file(tmp_path / "users.txt", {"alice": "alice-pw", "bob": "bob-pw"})
    server = tmp_path / "server.json5"
    server.write_text(
        security_json5(SecuritySettings(users_file=users, access=AccessPolicy(operators=("alice",), viewers=("bob",))))
    )
    port = free_port()
    ep = f"tcp/127.0.0.1:{port}"
    svc = ServiceProcess(["--listen", ep, "--data-dir", str(tmp_path / "data"), "--security", str(server)])
    try:
        alice, bob = _client_file(tmp_path, "alice", "alice-pw"), _client_file(tmp_path, "bob", "bob-pw")
        with HitchClient([ep], security=alice, timeout_s=10) as c, HitchClient([ep], security=bob, timeout_s=2) as v:
            wait_online(c)
            # a line 5 km east: the twin's own fixes (near the origin) never reach it. A fix beyond it is a 5 km
            # jump from the twin's track: the core refuses it as an outlier (never a crossing) and counts it, which
            # shows that it arrived
            plane = LocalTangentPlane(48.0, 11.0)
            a, b = plane.to_geodetic(5000.0, -100.0), plane.to_geodetic(5000.0, 100.0)
            c.request(
                "lines/save",
                {"name": "far", "geojson": {"type": "LineString", "coordinates": [[a[1], a[0]], [b[1], b[0]]]}},
            )
            seen: list[dict] = []
            v.session.declare_subscriber("hitch/tractor/gnss", lambda m: seen.append(json.loads(m.payload.to_bytes())))
            beyond = json.dumps({"east": 5010.0, "north": 0.0})
            for _ in range(10):
                v.session.put("hitch/tractor/gnss", beyond)
                time.sleep(0.05)
            time.sleep(0.3)
            assert _crossings(c) == 0 and _outliers(c) == 0  # denied: never reached the core
            assert seen, "the viewer observes the twin's fixes"
            for _ in range(10):
                c.session.put("hitch/tractor/gnss", beyond)
                time.sleep(0.05)
            end = time.monotonic() + 5.0
            while _outliers(c) == 0 and time.monotonic() < end:
                time.sleep(0.05)
            assert _outliers(c) > 0 and _crossings(c) == 0  # the operator's fixes arrived; an outlier crosses nothing
    finally:
        svc.kill()
