"""Each service node behind a fleet router owns its own prefix (security.AccessPolicy.service_prefix): the ACL
that build_acl writes lets service ``t01`` declare, publish and answer only under ``fleet/t01/hitch`` and send
no query at all — never a motion or a writing query to another tractor's service (a fleet trial: t01's
service login drove t02 and published a fake ``fleet/t02/hitch/state`` that clients took in).

Checked on the generated ACL (an evaluator of Zenoh's rules: allowed when an allow rule of one of the user's
policies includes the message's key, and no deny rule does) and with a real Zenoh router and sessions on
127.0.0.1."""

from __future__ import annotations

import json
import threading
import time

import pytest
import zenoh

from bench._common import free_port
from bridge.service.security import (
    AccessPolicy,
    Credentials,
    SecurityError,
    SecuritySettings,
    apply_security,
    build_acl,
    confine_services,
    scope_acl_users,
    write_users_file,
)

FLEET = "fleet/*/hitch"


def may(acl: dict, user: str, flow: str, message: str, key: str, kind: str = "usernames") -> bool:
    """Does ``acl`` let ``user`` (a username, or a certificate name with ``kind="cert_common_names"``) send
    ``message`` on ``key`` in ``flow`` (ingress: from the user's node to the router; egress: to it)?"""
    if not acl.get("enabled"):
        return True
    subjects = {x["id"] for x in acl["subjects"] if user in (x.get(kind) or ())}
    rule_ids = {r for p in acl["policies"] if subjects & set(p.get("subjects") or ()) for r in p["rules"]}
    matching = [
        r
        for r in acl["rules"]
        if r["id"] in rule_ids
        and flow in r["flows"]
        and message in r["messages"]
        and any(zenoh.KeyExpr(k).includes(zenoh.KeyExpr(key)) for k in r["key_exprs"])
    ]
    if any(r["permission"] == "deny" for r in matching):
        return False
    if any(r["permission"] == "allow" for r in matching):
        return True
    return acl["default_permission"] == "allow"


def _fleet_policy(**kw) -> AccessPolicy:
    return AccessPolicy(FLEET, operators=("alice",), viewers=("bob",), services=("t01", "t02"), **kw)


# ------------------------------------------------------------------------------------------ the ACL
def test_a_service_node_may_declare_publish_and_answer_only_under_its_own_prefix():
    acl = build_acl(_fleet_policy())
    for what in ("declare_queryable", "put", "reply", "liveliness_token", "declare_subscriber", "delete"):
        assert may(acl, "t01", "ingress", what, "fleet/t01/hitch/state"), what  # its own keys
        for other in ("fleet/t02/hitch/state", "fleet/*/hitch/state", "fleet/t02/hitch/stop"):
            assert not may(acl, "t01", "ingress", what, other), (what, other)  # never another tractor's
    assert may(acl, "t01", "ingress", "declare_queryable", "fleet/t01/hitch/user/*/goto")  # each user's lane
    assert may(acl, "t01", "ingress", "liveliness_token", "fleet/t01/hitch/alive")
    assert not may(acl, "t01", "ingress", "liveliness_token", "fleet/t02/hitch/alive")
    assert not may(acl, "t02", "ingress", "put", "fleet/t01/hitch/events")  # forged events into t01's black box
    # a service answers, it never asks: no query, not to another service, not to its own keys, not a reading one
    for key in ("fleet/t02/hitch/goto", "fleet/t02/hitch/sim/fault", "fleet/t02/hitch/ik", "fleet/t01/hitch/goto"):
        assert not may(acl, "t01", "ingress", "query", key), key
    # what reaches it: the operators' queries to its queryables, the setpoints to its subscriber
    assert may(acl, "t01", "egress", "query", "fleet/t01/hitch/goto")
    assert may(acl, "t01", "egress", "put", "fleet/t01/hitch/track/setpoint")
    # the roles of the people are as before
    assert may(acl, "alice", "ingress", "query", "fleet/t02/hitch/goto")
    assert not may(acl, "bob", "ingress", "query", "fleet/t02/hitch/goto")
    assert may(acl, "bob", "ingress", "query", "fleet/t02/hitch/ik")
    assert not may(acl, "mallory", "ingress", "put", "fleet/t01/hitch/state")


def test_which_prefix_each_service_owns():
    policy = _fleet_policy()
    assert policy.service_prefix("t01") == "fleet/t01/hitch"  # its name in place of the prefix's '*'
    # a prefix without wildcards is one service's keys: every service user listed owns it (as before)
    assert AccessPolicy("hitch", services=("svc-t07",)).service_prefix("svc-t07") == "hitch"
    # an explicit mapping: service users named otherwise, and prefixes with several wildcards
    mapped = AccessPolicy(
        FLEET, operators=("alice",), services=("svc-a",), service_prefixes={"svc-a": "fleet/t07/hitch"}
    )
    acl = build_acl(mapped)
    assert may(acl, "svc-a", "ingress", "put", "fleet/t07/hitch/state")
    assert not may(acl, "svc-a", "ingress", "put", "fleet/svc-a/hitch/state")
    deep = AccessPolicy("farm/**/hitch", services=("t01",), service_prefixes={"t01": "farm/north/t01/hitch"})
    assert may(build_acl(deep), "t01", "ingress", "put", "farm/north/t01/hitch/state")
    # service certificates (mutual TLS) own theirs by their common name
    certs = build_acl(AccessPolicy(FLEET, operators=("alice",), service_cert_names=("t03",)))
    assert may(certs, "t03", "ingress", "put", "fleet/t03/hitch/state", kind="cert_common_names")
    assert not may(certs, "t03", "ingress", "put", "fleet/t01/hitch/state", kind="cert_common_names")
    # ids are unique (Zenoh refuses the config otherwise), and Zenoh takes the section
    assert len({r["id"] for r in acl["rules"]}) == len(acl["rules"])
    apply_security(zenoh.Config(), {"access_control": build_acl(policy)})


@pytest.mark.parametrize(
    "kwargs, words",
    [
        ({"prefix": "fleet/**/hitch", "services": ("t01",)}, ["'fleet/**/hitch'", "access.service_prefixes"]),
        ({"prefix": "a/*/b/*", "services": ("t01",)}, ["one '*' chunk", "'a/t07/b/t07'"]),
        ({"prefix": FLEET, "services": ("-t01",)}, ["'-t01' cannot stand for the '*'", "a letter or digit first"]),
        (
            {"prefix": FLEET, "services": ("t01",), "service_prefixes": {"t9": "fleet/t9/hitch"}},
            ["'t9' is not a service"],
        ),
        ({"prefix": FLEET, "services": ("t01",), "service_prefixes": {"t01": "farm/t01/hitch"}}, ["under the prefix"]),
        ({"prefix": FLEET, "services": ("t01",), "service_prefixes": {"t01": "fleet/*/hitch"}}, ["without wildcards"]),
        ({"prefix": FLEET, "services": ("t01",), "service_prefixes": [("t01", "x")]}, ["must map service names"]),
    ],
)
def test_a_service_without_a_prefix_of_its_own_is_refused_naming_the_field(kwargs, words):
    with pytest.raises(SecurityError) as exc:
        AccessPolicy(operators=("alice",), **kwargs)
    assert exc.value.field == "access.service_prefixes"
    for w in words:
        assert w in str(exc.value), str(exc.value)


def _older_file_acl(policy: AccessPolicy) -> dict:
    """The ACL build_acl wrote before services had prefixes of their own: one rule 'service' allowing every
    message, both ways, under the whole prefix to every service node."""
    acl = build_acl(policy)
    ids = {r["id"] for r in acl["rules"] if r["id"].startswith("service:")}
    acl["rules"] = [r for r in acl["rules"] if r["id"] not in ids]
    acl["subjects"] = [x for x in acl["subjects"] if x["id"] not in ids]
    acl["policies"] = [p for p in acl["policies"] if p["id"] not in ids]
    rule = next(r for r in acl["rules"] if r["id"] == "service_out")
    rule.update(id="service", flows=["ingress", "egress"])
    services = next(p for p in acl["policies"] if p["id"] == "services")
    services["rules"] = ["service" if r == "service_out" else r for r in services["rules"]]
    return acl


def test_a_file_of_an_older_version_confines_its_services_when_applied(tmp_path):
    policy = _fleet_policy()
    old = _older_file_acl(policy)
    assert may(old, "t01", "ingress", "put", "fleet/t02/hitch/state")  # what the trial found
    assert scope_acl_users(confine_services(old)) == build_acl(policy)  # the same rules as this version's
    assert confine_services(build_acl(policy)) == build_acl(policy)  # idempotent
    users = write_users_file(tmp_path / "users.txt", {"t01": "t01-pw"})
    cfg = apply_security(
        zenoh.Config(), {"transport": {"auth": {"usrpwd": {"dictionary_file": str(users)}}}, "access_control": old}
    )
    applied = json.loads(cfg.get_json("access_control"))
    assert not may(applied, "t01", "ingress", "put", "fleet/t02/hitch/state")
    assert may(applied, "t01", "ingress", "put", "fleet/t01/hitch/state")
    # a file whose prefix says nothing about which keys are whose is refused, not run with the old rule
    deep = _older_file_acl(AccessPolicy("fleet/*/hitch", services=("t01",)))
    for r in deep["rules"]:
        r["key_exprs"] = [k.replace("fleet/*/hitch", "fleet/**/hitch") for k in r["key_exprs"]]
    with pytest.raises(SecurityError) as exc:
        apply_security(zenoh.Config(), {"access_control": deep})
    assert exc.value.field == "access_control" and "older version" in str(exc.value)
    assert "access.service_prefixes" in str(exc.value)


# ------------------------------------------------------------------------------------------ real Zenoh


def _session(ep: str, mode: str, settings: SecuritySettings) -> zenoh.Session:
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("listen/endpoints" if mode == "router" else "connect/endpoints", json.dumps([ep]))
    c.insert_json5("scouting/multicast/enabled", "false")
    apply_security(c, settings)
    return zenoh.open(c)


class _FleetRouter:
    """A real router on loopback with the fleet policy and users ``passwords`` (name → password); :meth:`login`
    opens a client session as one of them; :meth:`close` closes every session, the router last."""

    def __init__(self, tmp_path, passwords: dict[str, str]):
        self.passwords = passwords
        self.ep = f"tcp/127.0.0.1:{free_port()}"
        users = write_users_file(tmp_path / "users.txt", passwords)
        self.opened = [_session(self.ep, "router", SecuritySettings(users_file=users, access=_fleet_policy()))]

    def login(self, user: str) -> zenoh.Session:
        self.opened.append(
            _session(self.ep, "client", SecuritySettings(credentials=Credentials(user, self.passwords[user])))
        )
        return self.opened[-1]

    def close(self) -> None:
        for s in reversed(self.opened):
            s.close()


def test_through_a_real_router_a_service_login_cannot_reach_or_pose_as_another_service(tmp_path):
    fleet = _FleetRouter(tmp_path, {"alice": "alice-pw", "t01": "t01-pw", "t02": "t02-pw"})
    login = fleet.login

    def answer(tag: str):
        return lambda q: q.reply(q.key_expr, json.dumps({"by": tag}))

    def asked(s: zenoh.Session, key: str) -> list[str]:
        return [json.loads(r.ok.payload.to_string())["by"] for r in s.get(key, timeout=1.0) if r.ok]

    try:
        t01, t02, alice = login("t01"), login("t02"), login("alice")
        decls = [
            svc.declare_queryable(f"fleet/{name}/hitch/{key}", answer(name))
            for svc, name in ((t01, "t01"), (t02, "t02"))
            for key in ("goto", "stop", "sim/fault")
        ]
        forged: list[str] = []
        decls.append(t02.declare_subscriber("fleet/t02/hitch/events", lambda s: forged.append(s.payload.to_string())))
        decls += [t.liveliness().declare_token(f"fleet/{n}/hitch/alive") for t, n in ((t01, "t01"), (t02, "t02"))]
        # t01's login in other sessions (no answer from a session to itself blurs what the router allows)
        poser, asker = login("t01"), login("t01")
        decls += [poser.declare_queryable(f"fleet/t02/hitch/{k}", answer("poser")) for k in ("goto", "stop")]
        states: dict[tuple[str, str], int] = {}
        lock = threading.Lock()

        def on_state(s: zenoh.Sample) -> None:
            with lock:
                k = (str(s.key_expr), s.payload.to_string())
                states[k] = states.get(k, 0) + 1

        decls.append(alice.declare_subscriber(FLEET + "/state", on_state))  # every tractor's state
        time.sleep(0.8)
        for _ in range(10):
            t01.put("fleet/t01/hitch/state", "t01")
            t02.put("fleet/t02/hitch/state", "t02")
            poser.put("fleet/t02/hitch/state", "FAKE")
            poser.put(FLEET + "/state", "FAKE")
            poser.put("fleet/t02/hitch/events", "FORGED")
            time.sleep(0.02)
        time.sleep(0.5)
        with lock:
            seen = set(states)
        assert seen == {("fleet/t01/hitch/state", "t01"), ("fleet/t02/hitch/state", "t02")}  # no fake state
        assert forged == []  # nothing lands in t02's black box from t01
        assert asked(alice, "fleet/t02/hitch/stop") == ["t02"]  # the real service only: no posing queryable
        assert asked(alice, "fleet/t02/hitch/goto") == ["t02"] and asked(alice, "fleet/t01/hitch/goto") == ["t01"]
        for key in ("fleet/t02/hitch/goto", "fleet/t02/hitch/sim/fault", "fleet/t01/hitch/goto"):
            assert asked(asker, key) == [], key  # a service login moves nothing, its own tractor's neither
        alive = sorted(str(r.ok.key_expr) for r in alice.liveliness().get("**/alive", timeout=1.0) if r.ok)
        assert alive == ["fleet/t01/hitch/alive", "fleet/t02/hitch/alive"]  # hitch fleet ls
    finally:
        fleet.close()


def test_through_a_real_router_one_wildcard_put_on_the_fleet_prefix_stops_every_tractor(tmp_path):
    """A fleet router's ACL (prefix ``fleet/*/hitch``) has the ``stop_puts`` rule on ``fleet/*/hitch/stop``, which
    includes the put ``fleet/*/hitch/stop``: a viewer's one broadcast reaches every tractor's stop subscriber (a
    fleet trial found the docs saying such a put is refused under access control). A wider wildcard
    (``fleet/**/stop``) is included in no rule and reaches none."""
    acl = build_acl(_fleet_policy())
    assert may(acl, "bob", "ingress", "put", FLEET + "/stop")
    assert not may(acl, "bob", "ingress", "put", "fleet/**/stop")
    fleet = _FleetRouter(tmp_path, {"bob": "bob-pw", "t01": "t01-pw", "t02": "t02-pw"})
    try:
        t01, t02, bob = fleet.login("t01"), fleet.login("t02"), fleet.login("bob")
        got: list[tuple[str, str]] = []
        lock = threading.Lock()

        def on_stop(name: str):
            def cb(s: zenoh.Sample) -> None:
                with lock:
                    got.append((name, s.payload.to_string()))

            return cb

        subs = [svc.declare_subscriber(f"fleet/{n}/hitch/stop", on_stop(n)) for svc, n in ((t01, "t01"), (t02, "t02"))]
        time.sleep(0.8)
        bob.put("fleet/**/stop", "wide")
        bob.put(FLEET + "/stop", "fleet")
        time.sleep(0.5)
        with lock:
            assert sorted(got) == [("t01", "fleet"), ("t02", "fleet")]
        del subs
    finally:
        fleet.close()
