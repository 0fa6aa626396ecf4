"""``hitch serve --security FILE``: Zenoh user/password authentication and the access-control list
of :mod:`bridge.service.security` on the real service, in its own process. An operator moves the
hitch; a viewer reads state and uses IK but the motion keys do not answer him (denied by Zenoh);
an unknown user cannot even open a session."""

from __future__ import annotations

import json
import signal
import time
from pathlib import Path

import pytest

from bridge.service.client import HitchClient, ServiceError
from bridge.service.security import AccessPolicy, Credentials, SecuritySettings, security_json5, write_users_file
from tests.integration.service_process import ServiceProcess, free_port, hitch, wait_online

pytestmark = pytest.mark.slow  # the service runs in its own process


def client_file(tmp_path, user: str, password: str):
    p = tmp_path / f"{user}.json5"
    p.write_text(security_json5(SecuritySettings(credentials=Credentials(user, password))))
    return p


@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    d = tmp_path_factory.mktemp("acl")
    users = write_users_file(d / "users.txt", {"alice": "alice-pw", "bob": "bob-pw"})
    server = d / "server.json5"
    server.write_text(
        security_json5(SecuritySettings(users_file=users, access=AccessPolicy(operators=("alice",), viewers=("bob",))))
    )
    port = free_port()
    svc = ServiceProcess(
        ["--listen", f"tcp/127.0.0.1:{port}", "--data-dir", str(d / "data"), "--security", str(server)]
    )
    try:
        yield f"tcp/127.0.0.1:{port}", client_file(d, "alice", "alice-pw"), client_file(d, "bob", "bob-pw"), d
    finally:
        svc.kill()


def test_operator_moves_viewer_reads(secured):
    ep, alice, bob, _ = secured
    with HitchClient([ep], security=alice, timeout_s=10) as c:
        wait_online(c)
        r = c.goto({"z": 0.2})
        assert r["accepted"]
    with HitchClient([ep], security=bob, timeout_s=1.5) as c:
        assert c.state()["motion_id"] == r["motion_id"]  # state is readable
        assert c.ik(0.0, 0.1, 0.0, 0.0)["status"] == "ok"  # a non-motion query is answered
        for key, body in (("goto", {"goal": {"z": 0.1}}), ("jog", {"vz": 0.01}), ("mode", {"mode": "manual"})):
            with pytest.raises(ServiceError) as ei:
                c.request(key, body)
            assert ei.value.code == "timeout", key  # denied by the ACL: no queryable answers


def test_cli_with_credentials(secured):
    ep, alice, bob, _ = secured
    p = hitch(ep, "mode", "--security", str(alice), "--json")
    assert p.returncode == 0 and json.loads(p.stdout)["mode"] == "auto"
    p = hitch(ep, "goto", "--to", "z=0.15", "--security", str(bob), "--timeout", "1.5")
    assert p.returncode == 2 and "no reply" in p.stderr
    # a viewer reads the mode and the configuration (before: `hitch mode` asked the mode key, an operator's:
    # no reply for a viewer; and there was no `hitch config`)
    p = hitch(ep, "mode", "--security", str(bob), "--json", "--timeout", "3")
    assert p.returncode == 0 and json.loads(p.stdout)["mode"] == "auto", p.stderr
    p = hitch(ep, "config", "--security", str(bob), "--json", "--timeout", "3")
    assert p.returncode == 0 and json.loads(p.stdout)["user_keys"] is True, p.stderr
    p = hitch(ep, "config", "--security", str(bob), "--timeout", "3")
    assert "prefix: hitch" in p.stdout and "user_keys: True" in p.stdout


def test_unknown_user_cannot_connect(secured):
    ep, _, _, d = secured
    with pytest.raises(ServiceError) as ei:
        with HitchClient([ep], security=client_file(d, "mallory", "guess"), timeout_s=1.0) as c:
            c.state(timeout_s=1.0)
    assert ei.value.code in ("connect", "timeout")
    time.sleep(0.1)


def test_only_an_operator_can_stream_track_setpoints(secured):
    # the setpoint stream is Zenoh puts: without an ACL rule for them an operator's stream was denied
    ep, alice, bob, _ = secured
    with HitchClient([ep], security=alice, timeout_s=10) as c, HitchClient([ep], security=bob, timeout_s=2) as v:
        wait_online(c)
        z0 = c.state()["pose"]["z"]
        session = c.track_start("tractor", ["z"], 500)["session"]
        for i in range(1, 30):  # the viewer's puts are denied by Zenoh: they never reach the service
            v.track_setpoint(session, 1000 + i, {"z": z0 - 0.05})
            time.sleep(0.01)
        for i in range(1, 60):
            c.track_setpoint(session, i, {"z": z0 + 0.03})
            time.sleep(0.02)
        st = c.state()
        assert st["track"]["session"] == session
        assert st["track"]["setpoints"] >= 50 and st["track"]["ignored_seq"] == 0, st["track"]
        assert st["track"]["target"]["z"] > z0
        c.track_stop(session)


def test_each_user_is_known_to_the_service_by_name(secured):
    """Zenoh gives a service no querier's name: every Zenoh request counted against one shared admission
    allowance and was recorded by '-'. A client logged in as a user now sends on that user's own keys,
    which the ACL lets only that user send: the black box records who asked."""
    ep, alice, bob, d = secured
    with HitchClient([ep], security=alice, timeout_s=10) as a, HitchClient([ep], security=bob, timeout_s=1.5) as b:
        assert (a.user, b.user) == ("alice", "bob")  # from each security file's login
        wait_online(a)
        assert a.config()["user_keys"] is True
        assert a.goto({"z": 0.15})["accepted"]
        assert b.ik(0.0, 0.1, 0.0, 0.0)["status"] == "ok"  # a viewer's reading key, on his own keys
        with pytest.raises(ServiceError) as ei:
            b.request("goto", {"goal": {"z": 0.1}})  # his own motion key is not his to use either
        assert ei.value.code == "timeout"
    with HitchClient([ep], security=bob, timeout_s=1.5, user="alice") as posing:  # bob claims to be alice
        with pytest.raises(ServiceError) as ei:
            posing.config()
        assert ei.value.code == "timeout"  # Zenoh's ACL: not bob's key
    log = d / "data" / "log" / "events.jsonl"
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        asked = [json.loads(ln) for ln in log.read_text().splitlines() if '"request"' in ln]
        mine = {(r.get("key"), r.get("user")) for r in asked}
        if {("goto", "alice"), ("ik", "bob")} <= mine:
            break
        time.sleep(0.2)
    assert {("goto", "alice"), ("ik", "bob")} <= mine, sorted(mine, key=str)
    assert ("goto", "bob") not in mine and "config" not in {k for k, _ in mine}  # config is not recorded
    assert {k for k, u in mine if u is None} <= {"stop"}  # anonymous only: stop, on the plain key for all


def _children_cmdlines(pid: int) -> list[list[str]]:
    kids: list[int] = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids += [int(k) for k in (task / "children").read_text().split()]
    return [Path(f"/proc/{k}/cmdline").read_bytes().decode().split("\0")[:-1] for k in kids]


def test_a_secured_service_runs_its_control_core_in_its_own_process_logged_in_as_a_made_up_user(tmp_path, monkeypatch):
    # before: with a security file the control core ran in the service's threads (its link had no login)
    users = write_users_file(tmp_path / "users.txt", {"alice": "alice-pw", "bob": "bob-pw"})
    before = users.read_text()
    server = tmp_path / "server.json5"
    server.write_text(
        security_json5(SecuritySettings(users_file=users, access=AccessPolicy(operators=("alice",), viewers=("bob",))))
    )
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))  # where the service puts the core's users file
    ep = f"tcp/127.0.0.1:{free_port()}"
    svc = ServiceProcess(["--listen", ep, "--data-dir", str(tmp_path / "data"), "--security", str(server)])
    try:
        cores = [c for c in _children_cmdlines(svc.proc.pid) if "bridge.service.core.process" in c]
        assert len(cores) == 1 and cores[0][-1] == "login", cores
        assert "password" not in " ".join(cores[0])  # sent over the private socket, not the command line
        # Zenoh read the copy of the users file when the service's session opened: it is gone already
        assert list(tmp.glob("hitch-core-link-*")) == []
        assert users.read_text() == before
        assert not any("control core runs in the service's own process" in ln for ln in svc.output)
        with HitchClient([ep], security=client_file(tmp_path, "alice", "alice-pw"), timeout_s=10) as c:
            wait_online(c)  # users log in after the copy is gone
            assert c.goto({"z": 0.2})["accepted"]
            with HitchClient([ep], security=client_file(tmp_path, "bob", "bob-pw"), timeout_s=5) as v:
                stopped = v.stop()  # the viewer's stop, answered by the core's own queryable through the ACL
                assert stopped["stopped"] is True and isinstance(stopped["t"], float)
                assert v.state()["motion_id"] == stopped["motion_id"]
    finally:
        svc.proc.send_signal(signal.SIGTERM)
        svc.proc.wait(30)
    assert list(tmp.glob("hitch-core-link-*")) == []


def _stopped_by(c: HitchClient, ep: str, bob, motion_id: int, send) -> list[dict]:
    """``send(viewer_session)`` during motion ``motion_id``; the motion's ``motion_aborted`` events after it."""
    with HitchClient([ep], security=bob, timeout_s=5) as v:
        time.sleep(0.5)
        send(v.session)
        end = time.monotonic() + 3.0
        while c.state()["motion"] == "goto" and time.monotonic() < end:
            time.sleep(0.05)
    events = c.request("events/recent", {})["events"]
    return [e for e in events if e.get("motion_id") == motion_id and e["event"] == "motion_aborted"]


def test_a_viewers_put_on_stop_stops_through_the_acl(secured):
    """A put or delete on stop stops as the query does (a fleet trial: a put was ignored; a review: a delete was
    refused by the ACL); with access control every role may put on stop, as it may query it — no other key."""
    ep, alice, bob, _ = secured
    with HitchClient([ep], security=alice, timeout_s=10) as c:
        wait_online(c)
        r = c.goto({"z": 0.3}, speed_scale=0.2)
        assert r["accepted"]
        with HitchClient([ep], security=bob, timeout_s=5) as v:
            v.session.put("hitch/mode", b'{"mode": "manual"}')  # not a stop: denied, and ignored anyway
            time.sleep(0.5)
            assert c.state()["motion"] == "goto" and c.state()["mode"] != "manual"
        aborted = _stopped_by(c, ep, bob, r["motion_id"], lambda s: s.put("hitch/stop", b""))
        assert aborted and "stop" in aborted[-1]["reason"], aborted
        end = time.monotonic() + 5.0
        while c.state()["moving"] and time.monotonic() < end:  # the stop brakes to rest first
            time.sleep(0.05)
        r = c.goto({"z": -0.15}, speed_scale=0.2)  # several seconds
        assert r["accepted"]
        aborted = _stopped_by(c, ep, bob, r["motion_id"], lambda s: s.delete("hitch/stop"))
        assert aborted and "stop" in aborted[-1]["reason"], aborted
