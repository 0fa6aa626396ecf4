"""Zenoh security: the generated config (ACL, usrpwd, TLS) and real sessions in separate processes on
loopback — permitted and refused users, wildcard queries, TLS, mTLS, wrong CA, plain TCP."""

import json
import os
import select
import shutil
import signal
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest
import zenoh

from bench._common import free_port
from bridge.service.security import (
    MOTION_KEYS,
    OPERATOR_KEYS,
    VIEWER_QUERIES,
    AccessPolicy,
    Credentials,
    SecurityError,
    SecuritySettings,
    TlsSettings,
    access_policy_from_file,
    acl_scopes_users,
    apply_security,
    build_acl,
    build_security_config,
    connect_sections,
    exposure_warnings,
    grant_internal_socket,
    grant_internal_user,
    motion_keys,
    scope_acl_users,
    security_json5,
    security_sections,
    write_users_file,
)
from tests.helpers import loopback_zenoh_config, wait_until

USERS = {"alice": "alice-pw", "bob": "bob-pw", "carol": "carol-pw"}


# ------------------------------------------------------------------------------------------ config
@pytest.fixture
def users_file(tmp_path):
    return write_users_file(tmp_path / "users.txt", USERS)


def test_users_file_is_private_and_in_zenoh_format(users_file):
    assert stat.S_IMODE(users_file.stat().st_mode) == 0o600
    assert users_file.read_text().splitlines() == ["alice:alice-pw", "bob:bob-pw", "carol:carol-pw"]
    for bad in ({"a:b": "pw"}, {"a b": "pw"}, {"a": "two\nlines"}, {"a": ""}, {}):
        with pytest.raises(SecurityError):
            write_users_file(users_file.parent / "x.txt", bad)


def test_acl_restricts_exactly_the_motion_keys(users_file):
    acl = build_acl(AccessPolicy("fleet/t07/hitch", operators=("alice",), viewers=("bob", "carol")))
    assert acl["enabled"] is True and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["no_motion"]["permission"] == "deny"
    assert rules["no_motion"]["key_exprs"] == [f"fleet/t07/hitch/{k}" for k in MOTION_KEYS]
    assert rules["no_motion"]["flows"] == ["ingress", "egress"]
    viewer_keys = set(rules["viewer_queries"]["key_exprs"])
    assert viewer_keys == {f"fleet/t07/hitch/{k}" for k in VIEWER_QUERIES}
    assert not viewer_keys & set(motion_keys("fleet/t07/hitch")) and not any("*" in k for k in viewer_keys)
    pol = {p["id"]: p for p in acl["policies"]}
    assert "no_motion" in pol["viewers"]["rules"] and "no_motion" not in pol["operators"]["rules"]
    subj = {s["id"]: s for s in acl["subjects"]}
    assert subj["operators_users"]["usernames"] == ["alice"]
    assert subj["viewers_users"]["usernames"] == ["bob", "carol"]
    # Zenoh itself accepts the section, and it round-trips through the config
    cfg = apply_security(
        zenoh.Config(),
        SecuritySettings(
            users_file=users_file,
            access=AccessPolicy("fleet/t07/hitch", operators=("alice",), viewers=("bob", "carol")),
        ),
    )
    assert json.loads(cfg.get_json("access_control"))["rules"][0]["id"] == "observe"
    assert json.loads(cfg.get_json("transport/auth/usrpwd"))["dictionary_file"] == str(users_file.resolve())


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"operators": ("alice",), "viewers": ("alice",)}, "access.viewers"),
        ({"operators": ("a:b",)}, "access.operators"),
        ({"operators": "alice"}, "access.operators"),
        ({}, "access"),
        ({"prefix": "hitch/", "operators": ("a",)}, "prefix"),
        ({"prefix": "hi tch//x", "operators": ("a",)}, "prefix"),
        ({"operators": ("a",), "viewer_queries": ("goto",)}, "access.viewer_queries"),
        ({"operators": ("a",), "viewer_queries": ("presets/*",)}, "access.viewer_queries"),
    ],
)
def test_bad_access_policies_name_the_field(kwargs, field):
    with pytest.raises(SecurityError) as exc:
        AccessPolicy(**kwargs)
    assert exc.value.field == field


def test_inconsistent_settings_are_refused(tmp_path, users_file):
    with pytest.raises(SecurityError) as exc:  # usernames but no authentication: nothing could match
        SecuritySettings(access=AccessPolicy(operators=("alice",)))
    assert exc.value.field == "users_file"
    with pytest.raises(SecurityError) as exc:
        SecuritySettings(users_file=users_file, access=AccessPolicy(operator_cert_names=("op",)))
    assert exc.value.field == "tls.mutual"
    with pytest.raises(SecurityError) as exc:
        SecuritySettings(users_file=tmp_path / "missing.txt")
    assert exc.value.field == "users_file"
    with pytest.raises(SecurityError) as exc:
        TlsSettings(certificate=users_file)
    assert exc.value.field == "tls.private_key"
    with pytest.raises(SecurityError) as exc:
        TlsSettings(root_ca=tmp_path / "nope.pem")
    assert exc.value.field == "tls.root_ca"
    with pytest.raises(SecurityError) as exc:
        TlsSettings(root_ca=users_file, mutual=True)
    assert exc.value.field == "tls.mutual"
    with pytest.raises(SecurityError) as exc:
        Credentials("alice", "")
    assert exc.value.field == "credentials.password"
    assert "alice-pw" not in repr(Credentials("alice", "alice-pw"))


def _service_security_file(tmp_path, users_file):
    """A service's settings (alice operator, bob viewer) and the security file written from them."""
    settings = SecuritySettings(
        credentials=Credentials("svc", "svc-pw"),
        users_file=users_file,
        access=AccessPolicy(operators=("alice",), viewers=("bob",)),
    )
    path = tmp_path / "security.json5"
    path.write_text(security_json5(settings))
    return settings, path


def test_security_file_round_trip_and_refusals(tmp_path, users_file):
    settings, path = _service_security_file(tmp_path, users_file)
    assert security_sections(path) == security_sections(settings)
    usrpwd = json.loads(security_sections(path)["transport/auth/usrpwd"])
    assert (usrpwd["user"], usrpwd["password"]) == ("svc", "svc-pw")
    # JSON5 with comments is read by Zenoh's own parser
    path.write_text("// hitch\n{ access_control: { enabled: false, }, }\n")
    assert json.loads(security_sections(path)["access_control"])["enabled"] is False
    for text, needle in (
        ('{mode: "client"}', "sets mode"),
        ('{listen: {endpoints: ["tcp/0.0.0.0:1"]}}', "listen"),
        ("{transport: {unicast: {max_links: 4}}}", "transport settings other"),
        ("{access_contrl: {}}", "not a valid Zenoh security config"),
        ("{access_control: {enabled: 1, bogus: 2}}", "not a valid Zenoh"),
    ):
        path.write_text(text)
        with pytest.raises(SecurityError, match=needle):
            security_sections(path)
    with pytest.raises(SecurityError, match="does not exist"):
        security_sections(tmp_path / "absent.json5")


def test_a_service_whose_users_file_is_missing_names_it_before_zenoh_does(tmp_path, users_file):
    """A security engineer's report: `hitch serve --security FILE` with the users file gone printed Zenoh's
    "Invalid user-password dictionary file: No such file or directory (os error 2). at …/usrpwd.rs:76" —
    no path, and a Rust source location."""
    from bridge.service.config import ServiceConfig
    from bridge.service.server import HitchService

    settings, path = _service_security_file(tmp_path, users_file)
    users_file.unlink()
    cfg = ServiceConfig(listen=[f"tcp/127.0.0.1:{free_port()}"], data_dir=tmp_path / "data", security=path)
    with pytest.raises(SecurityError) as e:
        HitchService(cfg).start()
    assert str(users_file.resolve()) in str(e.value) and ".rs:" not in str(e.value), str(e.value)


def test_the_core_user_is_added_to_a_copy_of_the_users_file_and_given_the_service_keys(tmp_path, users_file):
    settings, path = _service_security_file(tmp_path, users_file)
    z = apply_security(zenoh.Config(), path)
    acl_before = json.loads(z.get_json("access_control"))
    (tmp_path / "link").mkdir()
    link = grant_internal_user(z, "hitch", tmp_path / "link")
    assert link is not None and link.users_file.parent == tmp_path / "link"
    assert stat.S_IMODE(link.users_file.stat().st_mode) == 0o600
    user, password = link.credentials.user, link.credentials.password
    assert link.users_file.read_text() == users_file.read_text() + f"{user}:{password}\n"
    assert users_file.read_text().splitlines() == ["alice:alice-pw", "bob:bob-pw", "carol:carol-pw"]  # untouched
    usrpwd = json.loads(z.get_json("transport/auth/usrpwd"))
    assert usrpwd["dictionary_file"] == str(link.users_file) and usrpwd["user"] == "svc"
    acl = json.loads(z.get_json("access_control"))
    added = {k: [x for x in acl[k] if x not in acl_before[k]] for k in ("rules", "subjects", "policies")}
    assert [r["permission"] for r in added["rules"]] == ["allow"] and added["rules"][0]["key_exprs"] == ["hitch/**"]
    assert [(x["id"], x["usernames"]) for x in added["subjects"]] == [(added["rules"][0]["id"], [user])]
    assert len(added["policies"]) == 1 and added["policies"][0]["subjects"] == [added["subjects"][0]["id"]]
    assert all(x in acl[k] for k in ("rules", "subjects", "policies") for x in acl_before[k])  # nothing taken away
    assert access_policy_from_file(path, "hitch").role(user) is None  # no role of the operator's
    again = grant_internal_user(apply_security(zenoh.Config(), path), "hitch", tmp_path / "link")
    assert again is not None and again.credentials.user != user  # a new one at every start
    # a file that authenticates nobody by password gets no made-up user (the core links through a Unix socket)
    only_acl = tmp_path / "no-users.json5"
    only_acl.write_text(json.dumps({"access_control": {"enabled": False}}))
    assert grant_internal_user(apply_security(zenoh.Config(), only_acl), "hitch", tmp_path / "link") is None
    # nor does an empty users file: Zenoh checks no password against it, one user added would start the checks
    (tmp_path / "empty.txt").write_text("\n")
    empty = tmp_path / "empty-users.json5"
    empty.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"dictionary_file": str(tmp_path / "empty.txt")}}}}))
    assert grant_internal_user(apply_security(zenoh.Config(), empty), "hitch", tmp_path / "link") is None


def test_without_users_the_core_gets_a_unix_socket_and_an_id_only_the_acl_of_that_socket_allows(tmp_path, pki):
    # before: a service secured by certificates only (no users file) ran its core in its threads
    cert_only = SecuritySettings(
        tls=TlsSettings(**_tls(pki, cert="server", mutual=True)),
        access=AccessPolicy(operator_cert_names=("operator-1",)),
    )
    z = apply_security(zenoh.Config(), cert_only)
    acl_before = json.loads(z.get_json("access_control"))
    link = grant_internal_socket(z, "hitch", tmp_path)
    assert link.credentials is None and link.users_file is None
    assert link.endpoint == f"unixsock-stream/{tmp_path / 'core.sock'}"
    assert len(link.zid) == 32 and int(link.zid, 16) > 0
    acl = json.loads(z.get_json("access_control"))
    added = {k: [x for x in acl[k] if x not in acl_before[k]] for k in ("rules", "subjects", "policies")}
    assert [(r["permission"], r["key_exprs"]) for r in added["rules"]] == [("allow", ["hitch/**"])]
    (subject,) = added["subjects"]
    assert subject["link_protocols"] == ["unixsock-stream"] and subject["zids"] == [link.zid]  # both at once
    assert not subject.get("usernames") and not subject.get("cert_common_names")
    assert json.loads(z.get_json("transport/auth/usrpwd"))["dictionary_file"] is None  # no password checks started
    assert grant_internal_socket(apply_security(zenoh.Config(), cert_only), "hitch", tmp_path).zid != link.zid
    # the service reads the roles of such a file (before: TypeError, Zenoh writes null for its usernames)
    path = tmp_path / "cert-only.json5"
    path.write_text(security_json5(cert_only))
    policy = access_policy_from_file(path, "hitch")
    assert policy.operator_cert_names == ("operator-1",) and policy.operators == ()
    # without access control nothing is added: the socket's directory (0700) is the only door
    plain = apply_security(zenoh.Config(), SecuritySettings(tls=TlsSettings(**_tls(pki, cert="server"))))
    grant_internal_socket(plain, "hitch", tmp_path)
    assert json.loads(plain.get_json("access_control"))["enabled"] is False


@pytest.mark.slow  # the service in its own process
def test_a_service_secured_by_certificates_only_runs_its_core_in_its_own_process(tmp_path, pki, monkeypatch):
    from bridge.service.client import HitchClient, ServiceError
    from tests.integration.service_process import ServiceProcess, wait_online

    server = tmp_path / "server.json5"
    server.write_text(
        security_json5(
            SecuritySettings(
                tls=TlsSettings(**_tls(pki, cert="server", mutual=True)),
                access=AccessPolicy(operator_cert_names=("operator-1",), viewer_cert_names=("viewer-1",)),
            )
        )
    )
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    monkeypatch.setenv("TMPDIR", str(tmp))  # where the service puts the core's socket
    ep = f"tls/127.0.0.1:{free_port()}"
    svc = ServiceProcess(["--listen", ep, "--data-dir", str(tmp_path / "data"), "--security", str(server)])
    try:
        assert not [ln for ln in svc.output if "control core runs in the service's own process" in ln]
        kids = [k for t in Path(f"/proc/{svc.proc.pid}/task").iterdir() for k in (t / "children").read_text().split()]
        cores = [Path(f"/proc/{k}/cmdline").read_bytes().split(b"\0") for k in kids]
        cores = [c for c in cores if b"bridge.service.core.process" in c]
        assert len(cores) == 1 and b"login" in cores[0] and b"unixsock-stream" in b" ".join(cores[0])
        (sock,) = tmp.glob("hitch-core-link-*/core.sock")
        assert stat.S_IMODE(sock.parent.stat().st_mode) == 0o700
        operator, viewer = (
            tmp_path / f"{n}.json5" for n in ("operator", "viewer")
        )  # client files: the CA and each one's certificate
        operator.write_text(
            security_json5(SecuritySettings(tls=TlsSettings(**_tls(pki, "hitch-ca", "operator-1", True))))
        )
        viewer.write_text(security_json5(SecuritySettings(tls=TlsSettings(**_tls(pki, "hitch-ca", "viewer-1", True)))))
        with (
            HitchClient([ep], security=operator, timeout_s=10, user="operator-1") as c,  # its certificate's name
            HitchClient([ep], security=viewer, timeout_s=5) as v,
        ):
            wait_online(c)
            assert c.config()["user_keys"] is True
            assert c.goto({"z": 0.2})["accepted"]  # on its own keys, through the certificate ACL
            stopped = v.stop()  # the viewer's stop, answered by the core's own queryable
            assert stopped["stopped"] is True and isinstance(stopped["t"], float)
            assert v.state()["motion_id"] == stopped["motion_id"]
        with HitchClient([ep], security=viewer, timeout_s=2, user="operator-1") as posing:  # not its name
            with pytest.raises(ServiceError):
                posing.ik(0.0, 0.1, 0.0, 0.0)
        log = tmp_path / "data" / "log" / "events.jsonl"

        def gotos() -> list:
            recs = [json.loads(ln) for ln in log.read_text().splitlines() if ln.strip()]
            return [r.get("user") for r in recs if r.get("kind") == "request" and r.get("key") == "goto"]

        assert wait_until(lambda: gotos() != [], 10.0), log.read_text()[-2000:]
        assert gotos() == ["operator-1"]  # the black box knows which certificate moved it
        # another program of this user reaching the socket, without the core's id: the ACL allows it nothing
        z = zenoh.Config()
        z.insert_json5("mode", '"client"')
        z.insert_json5("connect/endpoints", json.dumps([f"unixsock-stream/{sock}"]))
        z.insert_json5("scouting/multicast/enabled", "false")
        with zenoh.open(z) as s:
            assert [r for r in s.get("hitch/config", payload=b"{}", timeout=1.5) if r.ok] == []
            assert [r for r in s.get("hitch/stop", payload=b"{}", timeout=1.5) if r.ok] == []
    finally:
        svc.proc.send_signal(signal.SIGTERM)
        svc.proc.wait(30)
    assert list(tmp.glob("hitch-core-link-*")) == []  # the socket's directory goes with the service


def test_a_client_given_a_services_file_takes_only_its_login_and_tls(tmp_path, users_file):
    # a new user's report: `hitch stop --security <the service's file>` was taken whole, and the access control
    # in it denied the client's own link (no reply, a generic message)
    from bridge.service.client import client_config

    _, path = _service_security_file(tmp_path, users_file)
    z = client_config(["tcp/127.0.0.1:7447"], security=path)
    assert json.loads(z.get_json("access_control"))["enabled"] is False
    usrpwd = json.loads(z.get_json("transport/auth/usrpwd"))
    assert (usrpwd["user"], usrpwd["password"], usrpwd["dictionary_file"]) == ("svc", "svc-pw", None)
    peer = client_config(["tcp/127.0.0.1:7447"], mode="peer", security=path)  # a peer listens: all of it
    assert json.loads(peer.get_json("access_control"))["enabled"] is True


def test_the_core_connects_to_routers_with_the_files_login_and_tls_only(tmp_path, users_file):
    settings, path = _service_security_file(tmp_path, users_file)
    out = connect_sections(path)
    assert json.loads(out["transport/auth/usrpwd"]) == {"user": "svc", "password": "svc-pw"}
    assert set(out) == {"transport/auth/usrpwd", "transport/link/tls"}  # no users dictionary, no access control
    z = zenoh.Config()
    for k, v in out.items():
        z.insert_json5(k, v)
    assert json.loads(z.get_json("access_control"))["enabled"] is False
    assert json.loads(z.get_json("transport/auth/usrpwd"))["dictionary_file"] is None


@pytest.mark.slow  # the service in its own process
def test_a_secured_client_mode_service_runs_its_core_in_its_own_process_logged_in_to_the_router(tmp_path, users_file):
    # before: with a security file the core ran in the service's threads (its link had no login)
    from bridge.service.client import HitchClient
    from tests.integration.service_process import ServiceProcess

    # a fleet's arrangement: the access control on the router, the service logs in to it as a service node
    path = tmp_path / "service.json5"
    path.write_text(security_json5(SecuritySettings(credentials=Credentials("svc", "svc-pw"))))
    port = free_port()
    router = loopback_zenoh_config("router", f"tcp/127.0.0.1:{port}")
    router_users = write_users_file(tmp_path / "router-users.txt", {"svc": "svc-pw", "alice": "alice-pw"})
    access = AccessPolicy(operators=("alice",), services=("svc",))
    apply_security(router, SecuritySettings(users_file=router_users, access=access))
    alice = tmp_path / "alice.json5"
    alice.write_text(security_json5(SecuritySettings(credentials=Credentials("alice", "alice-pw"))))
    with zenoh.open(router):
        args = ["--mode", "client", "--connect", f"tcp/127.0.0.1:{port}", "--security", str(path)]
        svc = ServiceProcess([*args, "--data-dir", str(tmp_path / "data")])
        try:
            assert not [ln for ln in svc.output if "control core runs in the service's own process" in ln]
            kids = [
                k for t in Path(f"/proc/{svc.proc.pid}/task").iterdir() for k in (t / "children").read_text().split()
            ]
            cores = [Path(f"/proc/{k}/cmdline").read_bytes().split(b"\0") for k in kids]
            cores = [c for c in cores if b"bridge.service.core.process" in c]
            assert len(cores) == 1 and b"login" not in cores[0]  # it logs in with the service's own file
            with HitchClient([f"tcp/127.0.0.1:{port}"], security=alice, timeout_s=10) as c:
                deadline = time.monotonic() + 20
                while not c.state()["ecu"]["online"] and time.monotonic() < deadline:
                    time.sleep(0.1)
                assert c.goto({"z": 0.2})["accepted"]  # the service's queryables, through the router's ACL
                stopped = c.stop()  # through the router to the core's own queryable
                assert stopped["stopped"] is True and isinstance(stopped["t"], float)
                assert c.state()["motion_id"] == stopped["motion_id"]
        finally:
            svc.kill()


def test_exposure_warnings(users_file):
    assert exposure_warnings(["tcp/127.0.0.1:7447", "tcp/[::1]:7447", "tcp/localhost:1"], None) == []
    w = exposure_warnings(["tcp/0.0.0.0:7447"], None)
    assert len(w) == 3 and any("unencrypted" in s for s in w) and any("access_control" in s for s in w)
    s = SecuritySettings(users_file=users_file, access=AccessPolicy(operators=("alice",)))
    assert exposure_warnings(["tcp/192.168.1.5:7447"], s) == [
        "tcp/192.168.1.5:7447 accepts unencrypted links from the network; use tls/… with a certificate"
    ]
    with pytest.raises(SecurityError) as exc:
        exposure_warnings(["tls/127.0.0.1:7447"], s)
    assert exc.value.field == "tls.certificate"
    # a security file says the same as its settings (hitch router takes files)
    path = users_file.parent / "router.json5"
    path.write_text(security_json5(s))
    assert exposure_warnings(["tcp/192.168.1.5:7447"], path) == exposure_warnings(["tcp/192.168.1.5:7447"], s)
    assert len(exposure_warnings(["tcp/192.168.1.5:7447"], {"transport": {}})) == 3


# ------------------------------------------------------------------------------------------ sessions
_SERVER = r"""
import json, sys, threading, time
import zenoh
from bridge.service.security import apply_security
# argv: mode (peer: the service listening; router: a bare router; client: the service behind a router),
# endpoint, security file or settings JSON
mode, endpoint, security = sys.argv[1], sys.argv[2], sys.argv[3]
c = zenoh.Config()
c.insert_json5("mode", json.dumps(mode))
c.insert_json5("connect/endpoints" if mode == "client" else "listen/endpoints", json.dumps([endpoint]))
c.insert_json5("scouting/multicast/enabled", "false")
apply_security(c, security if security.endswith(".json5") else json.loads(security))
s = zenoh.open(c)
def answer(q):
    q.reply(q.key_expr, json.dumps({{"key": str(q.key_expr)}}))
keys = ("goto", "ik", "presets/go", "presets/list", "mode", "presets/save", "maneuvers/delete")
keys += ("user/*/goto", "user/*/ik")  # each user's own keys (security.USER_SCOPE), as the service declares them
keys = () if mode == "router" else keys
qs = [s.declare_queryable("hitch/" + k, answer) for k in keys]
pub = None if mode == "router" else s.declare_publisher("hitch/state")
alive = None if mode == "router" else s.liveliness().declare_token("hitch/alive")  # as the service's
done = threading.Event()
threading.Thread(target=lambda: (sys.stdin.read(), done.set()), daemon=True).start()
print("ready", flush=True)
deadline = time.monotonic() + 40
while not done.is_set() and time.monotonic() < deadline:
    if pub is not None:
        pub.put(b'{{"t": 0}}')
    time.sleep(0.02)
s.close()
"""

_CLIENT = r"""
import json, sys, time
import zenoh
from bridge.service.security import Credentials, SecuritySettings, TlsSettings, apply_security
a = json.loads(sys.argv[1])
c = zenoh.Config()
c.insert_json5("mode", '"client"')
c.insert_json5("connect/endpoints", json.dumps([a["endpoint"]]))
c.insert_json5("scouting/multicast/enabled", "false")
creds = Credentials(a["user"], a["password"]) if a.get("user") else None
tls = TlsSettings(**a["tls"]) if a.get("tls") else None
apply_security(c, SecuritySettings(credentials=creds, tls=tls))
try:
    s = zenoh.open(c)
except Exception as exc:
    print(json.dumps({{"open": False, "error": str(exc)[:200]}}), flush=True)
    sys.exit(0)
states = []
sub = s.declare_subscriber("hitch/state", lambda sample: states.append(1))
time.sleep(0.4)
replies = {{}}
for key in a["keys"]:
    replies[key] = [json.loads(r.ok.payload.to_string())["key"] for r in s.get(key, timeout=1.0) if r.ok]
alive = sorted(str(r.ok.key_expr) for r in s.liveliness().get("**/alive", timeout=1.0) if r.ok)  # fleet ls
time.sleep(0.1)
print(json.dumps({{"open": True, "replies": replies, "states": len(states), "alive": alive}}), flush=True)
sub.undeclare()
s.close()
"""


class _Server:
    def __init__(self, tmp_path, endpoint, settings, mode="peer"):
        if isinstance(settings, SecuritySettings):
            sec = tmp_path / f"security-{time.monotonic_ns()}.json5"
            sec.write_text(security_json5(settings))
            settings = str(sec)
        script = tmp_path / "server.py"
        script.write_text(_SERVER.format())
        self.proc = subprocess.Popen(
            [sys.executable, str(script), mode, endpoint, settings],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
        )
        ready, _, _ = select.select([self.proc.stdout], [], [], 20)
        line = self.proc.stdout.readline() if ready else ""
        if line.strip() != "ready":
            self.close()
            pytest.fail(f"server did not start: {line!r} {self.proc.stderr.read()[-2000:]}")

    def close(self):
        try:
            self.proc.stdin.close()
            self.proc.wait(timeout=5)
        except Exception:  # noqa: BLE001 — always end the process below
            pass
        finally:
            if self.proc.poll() is None:
                self.proc.kill()
                self.proc.wait(timeout=5)
            self.proc.stdout.close()
            self.proc.stderr.close()


def _clients(tmp_path, runs: dict[str, dict]) -> dict[str, dict]:
    """Run every client in its own process, in parallel; name → its JSON report."""
    script = tmp_path / "client.py"
    script.write_text(_CLIENT.format())
    procs = {
        n: subprocess.Popen(
            [sys.executable, str(script), json.dumps(a)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        for n, a in runs.items()
    }
    out = {}
    try:
        for n, p in procs.items():
            stdout, stderr = p.communicate(timeout=30)
            lines = [ln for ln in stdout.splitlines() if ln.startswith("{")]
            assert lines, f"client {n} printed nothing: {stderr[-2000:]}"
            out[n] = json.loads(lines[-1])
    finally:
        for p in procs.values():
            if p.poll() is None:
                p.kill()
                p.wait(timeout=5)
    return out


@pytest.fixture
def server(tmp_path):
    started = []

    def start(endpoint, settings, mode="peer"):
        s = _Server(tmp_path, endpoint, settings, mode)
        started.append(s)
        return s

    yield start
    for s in started:
        s.close()


@pytest.mark.slow  # Zenoh peers in their own processes
def test_acl_permitted_user_moves_refused_user_only_reads(tmp_path, users_file, server):
    ep = f"tcp/127.0.0.1:{free_port()}"
    server(
        ep,
        SecuritySettings(users_file=users_file, access=AccessPolicy("hitch", operators=("alice",), viewers=("bob",))),
    )
    keys = ["hitch/goto", "hitch/ik", "hitch/presets/go", "hitch/presets/list", "hitch/mode", "hitch/**", "hitch/*"]
    keys += ["hitch/presets/save", "hitch/maneuvers/delete"]  # writing keys: operators only
    r = _clients(
        tmp_path,
        {
            "alice": {"endpoint": ep, "user": "alice", "password": "alice-pw", "keys": keys},
            "bob": {"endpoint": ep, "user": "bob", "password": "bob-pw", "keys": keys},
            "carol": {"endpoint": ep, "user": "carol", "password": "carol-pw", "keys": keys},  # no role
            "mallory": {"endpoint": ep, "user": "bob", "password": "guess", "keys": keys},
            "anonymous": {"endpoint": ep, "keys": keys},
        },
    )
    alice, bob, carol = r["alice"], r["bob"], r["carol"]
    assert alice["open"] and alice["replies"]["hitch/goto"] == ["hitch/goto"]
    assert alice["replies"]["hitch/presets/go"] == ["hitch/presets/go"] and alice["replies"]["hitch/mode"]
    # operators' queries are allowed by exact key since each user has keys of their own (a wildcard would
    # include them); the service never answered a wildcard anyway (it serves exact keys only)
    assert alice["replies"]["hitch/**"] == [] and alice["replies"]["hitch/*"] == []
    assert (
        alice["replies"]["hitch/presets/save"] == ["hitch/presets/save"] and alice["replies"]["hitch/maneuvers/delete"]
    )
    assert alice["states"] > 0
    assert bob["open"] and bob["states"] > 0  # the refused user still reads the state
    assert bob["replies"]["hitch/ik"] == ["hitch/ik"] and bob["replies"]["hitch/presets/list"]
    for k in ("hitch/goto", "hitch/presets/go", "hitch/mode", "hitch/**", "hitch/*"):
        assert bob["replies"][k] == [], k  # motion keys, and wildcards that would reach them, are denied
    for k in ("hitch/presets/save", "hitch/maneuvers/delete"):
        assert bob["replies"][k] == [], k  # a viewer cannot overwrite or delete an operator's data
    assert carol["open"] and carol["states"] == 0 and not any(carol["replies"].values())
    assert alice["alive"] == ["hitch/alive"] and bob["alive"] == ["hitch/alive"]  # hitch fleet ls
    assert carol["alive"] == []  # no role: not even the services' names
    assert not r["mallory"]["open"] and not r["anonymous"]["open"]


def _acl_of_an_older_version(policy: AccessPolicy) -> dict:
    """The ACL build_acl wrote before users had keys of their own: operators' queries on '<prefix>/**'."""
    acl = build_acl(policy)
    ids = {r["id"] for r in acl["rules"] if r["id"].startswith("user_scope")}
    acl["rules"] = [r for r in acl["rules"] if r["id"] not in ids]
    acl["subjects"] = [x for x in acl["subjects"] if x["id"] not in ids]
    acl["policies"] = [p for p in acl["policies"] if p["id"] not in ids]
    for p in acl["policies"]:
        p["rules"] = [r for r in p["rules"] if r not in ids]
    next(r for r in acl["rules"] if r["id"] == "operator_queries")["key_exprs"] = ["hitch/**"]
    return acl


def test_each_user_gets_request_keys_of_their_own_in_the_acl(tmp_path, users_file):
    policy = AccessPolicy("hitch", operators=("alice", "al/ce", "others"), viewers=("bob", "-x"), services=("svc",))
    acl = build_acl(policy)
    rules = {r["id"]: r for r in acl["rules"]}
    assert len(rules) == len(acl["rules"])  # unique ids (Zenoh refuses the config otherwise), a user 'others' too
    assert set(rules["user_scope_alice"]["key_exprs"]) == {
        *(f"hitch/user/alice/{k}" for k in OPERATOR_KEYS + VIEWER_QUERIES),
        "hitch/user/alice/track/**",
    }
    assert rules["user_scope_bob"]["key_exprs"] == [f"hitch/user/bob/{k}" for k in VIEWER_QUERIES]
    assert "user_scope_al/ce" not in rules and "user_scope_-x" not in rules  # not key chunks: shared keys only
    assert not any(k.endswith("/**") and "track" not in k for k in rules["operator_queries"]["key_exprs"])
    policies = {p["id"]: p for p in acl["policies"]}
    assert "user_scope" in policies["services"]["rules"]  # service nodes answer, never ask as a user
    assert "user_scope:viewers" in policies["viewers"]["rules"]  # as no_motion / no_writes on the plain keys
    assert "hitch/user/*/goto" in rules["user_scope:viewers"]["key_exprs"]
    assert policies["user_scope_alice"]["subjects"] == ["user_scope_alice"]
    assert scope_acl_users(acl) == acl  # idempotent
    assert scope_acl_users(_acl_of_an_older_version(policy)) == acl  # an older file gets the same rules
    carol = json.loads(json.dumps(acl))  # a user added to a role by hand later gets keys of her own too
    next(x for x in carol["subjects"] if x["id"] == "operators_users")["usernames"].append("carol")
    assert "user_scope_carol" in {r["id"] for r in scope_acl_users(carol)["rules"]}
    assert scope_acl_users({"enabled": False}) == {"enabled": False}
    hand_written = {"enabled": True, "default_permission": "deny", "rules": [], "subjects": [], "policies": []}
    assert scope_acl_users(hand_written) == hand_written
    # a prefix with '**' is not scoped: its rules would include the keys of a user named like its last chunk
    fleet = build_acl(AccessPolicy("fleet/**/hitch", viewers=("hitch",)))
    assert not any(r["id"].startswith("user_scope") for r in fleet["rules"])
    # a service takes the name in a user key only when its own access control scopes the users
    for settings, scoped in (
        (SecuritySettings(users_file=users_file, access=policy), True),
        (SecuritySettings(users_file=users_file), False),
    ):
        path = tmp_path / f"{scoped}.json5"
        path.write_text(security_json5(settings))
        assert acl_scopes_users(path) is scoped
    # certificate common names get keys of their own too (a new user's report: a certificate-only service
    # said `user_keys: true` while no certificate had keys, and their `--user` requests went unanswered)
    certs = build_acl(AccessPolicy(operator_cert_names=("operator-1", "Operator One"), viewer_cert_names=("v-1",)))
    rules = {r["id"]: r for r in certs["rules"]}
    assert "hitch/user/operator-1/goto" in rules["user_scope:cert:operator-1"]["key_exprs"]
    assert rules["user_scope:cert:v-1"]["key_exprs"] == [f"hitch/user/v-1/{k}" for k in VIEWER_QUERIES]
    assert "user_scope:cert:Operator One" not in rules  # not a key chunk: the plain keys only
    subject = next(x for x in certs["subjects"] if x["id"] == "user_scope:cert:operator-1")
    assert subject["cert_common_names"] == ["operator-1"] and not subject.get("usernames")
    assert acl_scopes_users({"access_control": certs}) is True
    assert AccessPolicy(operator_cert_names=("operator-1",)).role("operator-1") == "operator"  # the service's check
    with pytest.raises(SecurityError, match="one user to the service"):  # a name is one user: one role
        AccessPolicy(viewers=("op",), operator_cert_names=("op",))


@pytest.mark.slow  # Zenoh peers in their own processes
@pytest.mark.parametrize("written_by", ["this version", "an older version"])
def test_each_user_may_send_only_their_own_scoped_keys(tmp_path, users_file, server, written_by):
    ep = f"tcp/127.0.0.1:{free_port()}"
    policy = AccessPolicy("hitch", operators=("alice",), viewers=("bob",))
    if written_by == "this version":
        server(ep, SecuritySettings(users_file=users_file, access=policy))
    else:  # the file's operators may query '<prefix>/**': applying it scopes it (security.scope_acl_users)
        sections = build_security_config(SecuritySettings(users_file=users_file))
        sections["access_control"] = _acl_of_an_older_version(policy)
        old = tmp_path / "old.json5"
        old.write_text(json.dumps(sections))
        server(ep, str(old))
    mine = ["hitch/user/alice/goto", "hitch/user/alice/ik", "hitch/user/bob/ik", "hitch/user/bob/goto"]
    keys = [*mine, "hitch/user/*/ik", "hitch/user/**", "hitch/user/alice/**"]
    r = _clients(
        tmp_path,
        {
            n: {"endpoint": ep, "user": n, "password": f"{n}-pw", "keys": keys}
            for n in ("alice", "bob", "carol")  # operator, viewer, no role
        },
    )
    allowed = {n: sorted(k for k, v in r[n]["replies"].items() if v) for n in r}
    assert allowed == {
        "alice": ["hitch/user/alice/goto", "hitch/user/alice/ik"],  # her own, every key; nobody else's
        "bob": ["hitch/user/bob/ik"],  # his own reading keys only
        "carol": [],
    }
    assert r["alice"]["replies"]["hitch/user/alice/goto"] == ["hitch/user/alice/goto"]


@pytest.mark.slow  # Zenoh peers in their own processes
def test_acl_on_a_fleet_router_with_the_service_behind_it(tmp_path, users_file, server):
    users = write_users_file(tmp_path / "router-users.txt", {**USERS, "svc-t07": "svc-pw"})
    ep = f"tcp/127.0.0.1:{free_port()}"
    server(
        ep,
        SecuritySettings(
            users_file=users,
            access=AccessPolicy("hitch", operators=("alice",), viewers=("bob",), services=("svc-t07",)),
        ),
        mode="router",
    )
    service = build_security_config(SecuritySettings(credentials=Credentials("svc-t07", "svc-pw")))
    server(ep, json.dumps(service), mode="client")
    keys = ["hitch/goto", "hitch/ik", "hitch/**", "hitch/user/alice/goto", "hitch/user/bob/ik"]
    r = _clients(
        tmp_path,
        {
            "alice": {"endpoint": ep, "user": "alice", "password": "alice-pw", "keys": keys},
            "bob": {"endpoint": ep, "user": "bob", "password": "bob-pw", "keys": keys},
        },
    )
    assert r["alice"]["replies"] == {
        "hitch/goto": ["hitch/goto"],
        "hitch/ik": ["hitch/ik"],
        "hitch/**": [],
        "hitch/user/alice/goto": ["hitch/user/alice/goto"],  # her own keys, through the router's ACL
        "hitch/user/bob/ik": [],  # never another user's
    }
    assert r["alice"]["states"] > 0
    assert r["bob"]["replies"] == {
        "hitch/goto": [],
        "hitch/ik": ["hitch/ik"],
        "hitch/**": [],
        "hitch/user/alice/goto": [],
        "hitch/user/bob/ik": ["hitch/user/bob/ik"],
    }
    assert r["bob"]["states"] > 0
    # `hitch fleet ls` (a liveliness query on **/alive) finds the service behind the router: the policy
    # allowed liveliness queries only under its prefix, so a fleet's operators saw "(no services)"
    assert r["alice"]["alive"] == ["hitch/alive"] and r["bob"]["alive"] == ["hitch/alive"]


@pytest.fixture(scope="module")
def pki(tmp_path_factory):
    """A CA, a server certificate for 127.0.0.1, two client certificates and a rogue CA + certificate."""
    # the openssl command ships with this machine kind (Debian); without it the TLS tests must fail, not skip
    assert shutil.which("openssl") is not None, "the openssl command is needed to make test certificates"
    d = tmp_path_factory.mktemp("pki")

    def run(*args):
        subprocess.run(["openssl", *args], cwd=d, check=True, capture_output=True, timeout=30)

    def ca(name):
        run(
            "req",
            "-x509",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-days",
            "2",
            "-keyout",
            f"{name}-key.pem",
            "-out",
            f"{name}.pem",
            "-subj",
            f"/CN={name}",
            "-addext",
            "basicConstraints=critical,CA:TRUE",
            "-addext",
            "keyUsage=critical,keyCertSign,cRLSign",
        )

    def leaf(name, issuer, san):
        run(
            "req",
            "-newkey",
            "ec",
            "-pkeyopt",
            "ec_paramgen_curve:prime256v1",
            "-nodes",
            "-keyout",
            f"{name}-key.pem",
            "-out",
            f"{name}.csr",
            "-subj",
            f"/CN={name}",
        )
        (d / f"{name}.ext").write_text(
            f"subjectAltName={san}\nbasicConstraints=CA:FALSE\nextendedKeyUsage=serverAuth,clientAuth\n"
        )
        run(
            "x509",
            "-req",
            "-in",
            f"{name}.csr",
            "-CA",
            f"{issuer}.pem",
            "-CAkey",
            f"{issuer}-key.pem",
            "-CAcreateserial",
            "-days",
            "2",
            "-out",
            f"{name}.pem",
            "-extfile",
            f"{name}.ext",
        )

    ca("hitch-ca")
    ca("rogue-ca")
    leaf("server", "hitch-ca", "IP:127.0.0.1,DNS:localhost")
    leaf("operator-1", "hitch-ca", "DNS:operator-1")
    leaf("viewer-1", "hitch-ca", "DNS:viewer-1")
    leaf("rogue", "rogue-ca", "DNS:rogue")
    return d


def _tls(pki, ca="hitch-ca", cert=None, mutual=False):
    out = {"root_ca": str(pki / f"{ca}.pem"), "mutual": mutual}
    if cert:
        out.update(certificate=str(pki / f"{cert}.pem"), private_key=str(pki / f"{cert}-key.pem"))
    return out


@pytest.mark.slow  # Zenoh peers in their own processes
def test_tls_session_connects_wrong_ca_and_plain_tcp_do_not(tmp_path, pki, server):
    port = free_port()
    server(f"tls/127.0.0.1:{port}", SecuritySettings(tls=TlsSettings(**_tls(pki, cert="server"))))
    keys = ["hitch/ik"]
    r = _clients(
        tmp_path,
        {
            "good": {"endpoint": f"tls/127.0.0.1:{port}", "tls": _tls(pki), "keys": keys},
            "wrong_ca": {"endpoint": f"tls/127.0.0.1:{port}", "tls": _tls(pki, ca="rogue-ca"), "keys": keys},
            "plain_tcp": {"endpoint": f"tcp/127.0.0.1:{port}", "keys": keys},
        },
    )
    assert r["good"]["open"] and r["good"]["replies"]["hitch/ik"] == ["hitch/ik"] and r["good"]["states"] > 0
    assert not r["wrong_ca"]["open"]
    assert not r["plain_tcp"]["open"]


@pytest.mark.slow  # Zenoh peers in their own processes
def test_mtls_needs_a_client_certificate_from_the_ca_and_maps_names_to_roles(tmp_path, pki, server):
    port = free_port()
    ep = f"tls/127.0.0.1:{port}"
    server(
        ep,
        SecuritySettings(
            tls=TlsSettings(**_tls(pki, cert="server", mutual=True)),
            access=AccessPolicy(operator_cert_names=("operator-1",), viewer_cert_names=("viewer-1",)),
        ),
    )
    keys = ["hitch/goto", "hitch/ik"]
    mine = [
        "hitch/user/operator-1/goto",
        "hitch/user/operator-1/ik",
        "hitch/user/viewer-1/ik",
        "hitch/user/viewer-1/goto",
    ]
    keys += mine
    r = _clients(
        tmp_path,
        {
            "operator": {"endpoint": ep, "tls": _tls(pki, cert="operator-1", mutual=True), "keys": keys},
            "viewer": {"endpoint": ep, "tls": _tls(pki, cert="viewer-1", mutual=True), "keys": keys},
            "no_cert": {"endpoint": ep, "tls": _tls(pki), "keys": keys},
            "rogue_cert": {"endpoint": ep, "tls": _tls(pki, cert="rogue", mutual=True), "keys": keys},
        },
    )
    answered = {n: sorted(k for k, v in r[n]["replies"].items() if v) for n in ("operator", "viewer")}
    # each certificate's own user keys (its common name), and only its own; the viewer only reading ones
    assert answered == {
        "operator": ["hitch/goto", "hitch/ik", "hitch/user/operator-1/goto", "hitch/user/operator-1/ik"],
        "viewer": ["hitch/ik", "hitch/user/viewer-1/ik"],
    }
    assert r["viewer"]["states"] > 0
    assert not r["no_cert"]["open"]
    assert not r["rogue_cert"]["open"]


def test_build_security_config_for_a_mutual_tls_client(pki):
    cfg = build_security_config(
        SecuritySettings(
            credentials=Credentials("alice", "alice-pw"), tls=TlsSettings(**_tls(pki, cert="operator-1", mutual=True))
        )
    )
    tls = cfg["transport"]["link"]["tls"]
    assert tls["enable_mtls"] is True and tls["verify_name_on_connect"] is True
    assert tls["connect_certificate"] == str((pki / "operator-1.pem").resolve())
    assert tls["connect_private_key"] == str((pki / "operator-1-key.pem").resolve())
    assert cfg["transport"]["auth"]["usrpwd"] == {"user": "alice", "password": "alice-pw"}
    assert "access_control" not in cfg
    assert os.path.isabs(tls["root_ca_certificate"])


def test_an_empty_security_file_says_what_it_should_hold(tmp_path):
    """A fleet trial: an empty file gave Zenoh's parser error ("expected array, boolean, null, number, object,
    or string")."""
    from bridge.service.security import SecurityError, security_sections

    empty = tmp_path / "empty.json5"
    empty.write_text("  \n", encoding="utf-8")
    with pytest.raises(SecurityError, match=r"empty\.json5 is empty: a security file is a JSON5 object with"):
        security_sections(empty)


def test_a_security_file_written_before_stop_puts_gets_them():
    """A review: a file written before the stop_puts rule refused every put on stop (default deny), silently — a
    put has no reply. apply_security adds the rule to the operators' and viewers' policies, once."""
    import json

    import zenoh

    from bridge.service.security import allow_stop_puts

    acl = build_acl(AccessPolicy(prefix="fleet/t07/hitch", operators=("alice",), viewers=("bob",)))
    old = json.loads(json.dumps(acl))
    old["rules"] = [r for r in old["rules"] if r["id"] != "stop_puts"]
    for p in old["policies"]:
        p["rules"] = [r for r in p["rules"] if r != "stop_puts"]
    new = allow_stop_puts(old)
    rule = next(r for r in new["rules"] if r["id"] == "stop_puts")
    assert rule["key_exprs"] == ["fleet/t07/hitch/stop"]
    assert {p["id"] for p in new["policies"] if "stop_puts" in p["rules"]} == {"operators", "viewers"}
    assert allow_stop_puts(new) == new  # once
    assert allow_stop_puts(acl) == acl  # a current file: unchanged
    assert rule["messages"] == ["put", "delete", "declare_subscriber"]  # a delete stops too (a review: refused)
    first = json.loads(json.dumps(acl))  # the first version's rule, without delete: given it
    next(r for r in first["rules"] if r["id"] == "stop_puts")["messages"] = ["put", "declare_subscriber"]
    again = next(r for r in allow_stop_puts(first)["rules"] if r["id"] == "stop_puts")
    assert again["messages"] == ["put", "declare_subscriber", "delete"]
    conf = apply_security(zenoh.Config(), {"access_control": old})
    applied = json.loads(conf.get_json("access_control"))
    assert any(r["id"] == "stop_puts" for r in applied["rules"])
