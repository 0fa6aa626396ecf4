"""``hitch fleet ls`` as a viewer and with a live token whose service does not answer, run as a user would (the
CLI in its own process, loopback Zenoh only).

A fleet trial's report: for a viewer (bob) every row read ``no reply from fleet/t01/hitch/user/bob/mode: nothing
answered that key …`` — ``mode`` is an operator's key, the ACL denies it to a viewer — and the command exited 0.
The mode is now read from ``config``, which a viewer may ask; a service that does not answer is shown as such
and the exit status is not 0.

Truth: the service's own configuration (its mode ``auto`` at start, the default profile); the token the test
declares itself (no queryable behind it).
"""

from __future__ import annotations

import json

import pytest
import zenoh

from bridge.service.security import AccessPolicy, Credentials, SecuritySettings, security_json5, write_users_file
from tests.helpers import loopback_zenoh_config
from tests.integration.service_process import ServiceProcess, free_port, hitch

pytestmark = pytest.mark.slow  # the service runs in its own process


@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    """A service with access control (alice operator, bob viewer) on its own loopback port; bob's client file."""
    d = tmp_path_factory.mktemp("fleet-roles")
    users = write_users_file(d / "users.txt", {"alice": "alice-pw", "bob": "bob-pw"})
    server = d / "server.json5"
    server.write_text(
        security_json5(SecuritySettings(users_file=users, access=AccessPolicy(operators=("alice",), viewers=("bob",))))
    )
    bob = d / "bob.json5"
    bob.write_text(security_json5(SecuritySettings(credentials=Credentials("bob", "bob-pw"))))
    port = free_port()
    svc = ServiceProcess(
        ["--listen", f"tcp/127.0.0.1:{port}", "--data-dir", str(d / "data"), "--security", str(server)]
    )
    try:
        yield f"tcp/127.0.0.1:{port}", bob
    finally:
        svc.kill()


def test_a_viewer_lists_the_fleet_with_each_mode(secured):
    ep, bob = secured
    p = hitch(ep, "fleet", "ls", "--security", str(bob), "--json", "--timeout", "5")
    assert p.returncode == 0, p.stdout + p.stderr
    rows = json.loads(p.stdout)["fleet"]
    assert rows == [
        {
            "prefix": "hitch",
            "profile": "thesis-t132",
            "category": rows[0]["category"],
            "implement": None,
            "mode": "auto",
            # its machine now, from one state (a viewer may read it): the simulated ECU online, at rest
            "state": {"ecu_online": True, "faults": [], "ack_required": [], "moving": False, "motion": None},
        }
    ], rows
    p = hitch(ep, "fleet", "ls", "--security", str(bob), "--timeout", "5")
    assert p.returncode == 0 and p.stderr == "", p.stderr
    assert p.stdout.startswith("hitch: thesis-t132 cat "), p.stdout
    assert p.stdout.rstrip().endswith("mode auto; ECU online, at rest"), p.stdout


def test_a_live_token_without_a_service_is_shown_as_not_answering():
    """A token whose holder answers nothing (a hung service, another program on the prefix): shown as NO ANSWER,
    exit status 2 (nothing answered); before: listed with its error, exit status 0."""
    ep = f"tcp/127.0.0.1:{free_port()}"
    s = zenoh.open(loopback_zenoh_config("router", ep))
    try:
        token = s.liveliness().declare_token("fleet/t09/hitch/alive")
        p = hitch(ep, "fleet", "ls", "--json", "--timeout", "2")
        assert p.returncode == 2, p.stdout + p.stderr
        rows = json.loads(p.stdout)["fleet"]
        assert [(r["prefix"], r["code"]) for r in rows] == [("fleet/t09/hitch", "timeout")], rows
        assert "no reply from fleet/t09/hitch/config" in rows[0]["error"]
        p = hitch(ep, "fleet", "ls", "--timeout", "2")
        assert p.returncode == 2
        assert p.stdout.startswith("fleet/t09/hitch: NO ANSWER: no reply from fleet/t09/hitch/config"), p.stdout
        assert p.stdout.rstrip().endswith("; no state within 1 s"), p.stdout  # nothing publishes its state
        assert "1 of 1 services gave no configuration: fleet/t09/hitch" in p.stderr
        token.undeclare()
    finally:
        s.close()
