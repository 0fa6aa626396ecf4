"""Roles for data: every API key is a reading or an operator key; a viewer can neither save nor
delete presets and maneuvers, through the handler's own policy check (ServiceAPI with a policy and
a user) as well as through the Zenoh ACL; owners and per-user limits reach the store; maneuvers/list
through the handler parses nothing."""

import json
from dataclasses import dataclass
from typing import Any, cast

import numpy as np
import pytest

from bridge.service.api import API_KEYS, ServiceAPI
from bridge.service.security import (
    MOTION_KEYS,
    OPERATOR_KEYS,
    VIEWER_QUERIES,
    WRITE_KEYS,
    AccessPolicy,
    SecurityError,
    access_policy_from_file,
    build_acl,
    key_access,
)
from bridge.service.store import HitchStore, StoreLimits
from planner.trajectory import MotionState, TrajectoryPlanner

WS = {"x": [-0.06, 0.06], "z": [-0.21627, 0.311729], "roll": [-0.058, 0.058], "pitch": [-0.1, 0.058]}


@dataclass
class _Accepted:
    goal: dict

    def to_json(self) -> dict:
        return {"accepted": True, "goal": self.goal}


class _Motion:
    """What the preset and maneuver handlers need of the motion controller; records every goto."""

    mode = "auto"

    def __init__(self, model):
        self.planner = TrajectoryPlanner(model)
        self.gotos: list[dict] = []

    def clock(self) -> float:
        return 0.0

    def current_state(self) -> MotionState:
        return MotionState.at_rest(np.zeros(4))

    def goto(self, goal, speed_scale, **_kw) -> _Accepted:
        self.gotos.append(dict(goal))
        return _Accepted(dict(goal))

    def plan_step(self, start, goal, speed_scale):
        return 1.0, MotionState.at_rest(self.planner.goal_vector(start.position, goal))


@pytest.fixture
def api(model, tmp_path):
    store = HitchStore(tmp_path / "h.sqlite3", limits=StoreLimits(max_presets_per_user=2))
    policy = AccessPolicy(operators=("olga", "oscar"), viewers=("vera",))
    a = ServiceAPI(cast(Any, _Motion(model)), cast(Any, None), store, {"limits": {"workspace": WS}}, policy=policy)
    yield a
    store.close()


def _call(api, key, payload=None, user=None):
    return api.handle(key, json.dumps(payload or {}), user)


# ------------------------------------------------------------------------------------------ classification
def test_every_api_key_is_classified_as_read_or_write():
    unclassified = [k for k in API_KEYS if key_access(k) is None]
    assert unclassified == [], f"classify {unclassified} in bridge.service.security (VIEWER_QUERIES or WRITE_KEYS)"
    assert {k for k in API_KEYS if key_access(k) == "read"} <= set(VIEWER_QUERIES)
    for k in ("presets/save", "presets/delete", "maneuvers/save", "maneuvers/delete", "faults/ack", "sim/fault"):
        assert key_access(k) == "write" and k in OPERATOR_KEYS
    assert key_access("track/start") == "write"  # every key under track/
    assert set(OPERATOR_KEYS) == set(MOTION_KEYS) | set(WRITE_KEYS)
    assert not set(VIEWER_QUERIES) & set(OPERATOR_KEYS)
    assert "stop" in VIEWER_QUERIES  # anyone who sees the hitch may stop it


def test_the_acl_denies_every_writing_key_to_viewers():
    acl = build_acl(AccessPolicy("hitch", operators=("olga",), viewers=("vera",)))
    rules = {r["id"]: r for r in acl["rules"]}
    viewers = next(p for p in acl["policies"] if p["id"] == "viewers")
    assert "no_writes" in viewers["rules"] and "no_motion" in viewers["rules"]
    assert rules["no_writes"]["permission"] == "deny"
    assert set(rules["no_writes"]["key_exprs"]) == {f"hitch/{k}" for k in WRITE_KEYS} | {"hitch/track/**"}
    allowed = set(rules["viewer_queries"]["key_exprs"])
    assert allowed == {f"hitch/{k}" for k in VIEWER_QUERIES}
    assert not allowed & {f"hitch/{k}" for k in OPERATOR_KEYS}


@pytest.mark.parametrize("key", ["presets/save", "maneuvers/delete", "faults/ack", "track/start"])
def test_viewer_queries_may_not_name_an_operator_key(key):
    with pytest.raises(SecurityError, match="operator key") as exc:
        AccessPolicy(operators=("olga",), viewer_queries=("ik", key))
    assert exc.value.field == "access.viewer_queries"


def test_a_security_file_that_lets_viewers_write_is_refused(tmp_path):
    acl = build_acl(AccessPolicy("hitch", operators=("olga",), viewers=("vera",)))
    for rule in acl["rules"]:
        if rule["id"] == "viewer_queries":
            rule["key_exprs"].append("hitch/presets/save")  # what an older version wrote
    path = tmp_path / "old-security.json5"
    path.write_text(json.dumps({"access_control": acl}))
    with pytest.raises(SecurityError, match="regenerate"):
        access_policy_from_file(path, "hitch")


# ------------------------------------------------------------------------------------------ the handler
def test_a_viewer_cannot_overwrite_an_operators_preset_and_go_still_moves_to_the_operators_pose(api):
    mine = {"x": 0.01, "z": 0.2, "roll": 0.0, "pitch": 0.02}
    assert _call(api, "presets/save", {"name": "work", "pose": mine}, "olga")[0]
    for key, payload in (
        ("presets/save", {"name": "work", "pose": {"z": -0.2}}),
        ("presets/delete", {"name": "work"}),
        ("maneuvers/save", {"name": "m", "script": "steps: [{wait: 1}]"}),
        ("maneuvers/delete", {"name": "m"}),
    ):
        ok, r = _call(api, key, payload, "vera")
        assert not ok and r["error"] == "forbidden", (key, r)
        assert "vera" in r["message"] and "viewer" in r["message"] and "operator" in r["message"]
    assert api.store.get_preset("work").pose == mine and api.store.list_maneuvers() == []
    ok, r = _call(api, "presets/go", {"name": "work"}, "olga")
    assert ok and api.motion.gotos[-1] == mine
    # a viewer still reads and stops
    assert _call(api, "presets/list", {}, "vera")[0] and _call(api, "maneuvers/list", {}, "vera")[0]
    assert _call(api, "maneuvers/validate", {"script": "steps: [{wait: 1}]"}, "vera")[0]
    ok, r = _call(api, "presets/go", {"name": "work"}, "vera")
    assert not ok and r["error"] == "forbidden" and "moves the hitch" in r["message"]


def test_saves_record_the_user_and_the_limit_is_per_user(api):
    for i in range(2):
        assert _call(api, "presets/save", {"name": f"o{i}", "pose": {"z": 0.1}}, "olga")[0]
    ok, r = _call(api, "presets/save", {"name": "o2", "pose": {"z": 0.1}}, "olga")
    assert not ok and r["error"] == "store" and "max_presets_per_user = 2" in r["message"], r
    assert _call(api, "presets/save", {"name": "o2", "pose": {"z": 0.1}}, "oscar")[0]
    assert api.store.get_preset("o0").owner == "olga" and api.store.get_preset("o2").owner == "oscar"
    assert _call(api, "maneuvers/save", {"name": "m", "script": "steps: [{wait: 1}]"}, "oscar")[0]
    assert api.store.get_maneuver("m").owner == "oscar"


def test_workspace_errors_through_the_handler(api):
    ok, r = _call(api, "goto", {"goal": {"z": 250}}, "olga")
    assert not ok and r["error"] == "unreachable" and "did you mean mm? 250 mm = 0.25 m" in r["message"]
    ok, r = _call(api, "presets/save", {"name": "w", "pose": {"x": 40, "z": 0.1}}, "olga")
    assert not ok and r["error"] == "unreachable" and "pose.x = 40 m" in r["message"]
    # a preset stored inside an older, larger workspace: go names today's range instead of moving
    api.store.save_preset("wide", {"x": 0.3, "z": 0.1, "roll": 0.0, "pitch": 0.0})
    ok, r = _call(api, "presets/go", {"name": "wide"}, "olga")
    assert not ok and r["error"] == "unreachable" and "x from -0.06 to 0.06 m" in r["message"]
    assert api.motion.gotos == []


def test_maneuvers_list_through_the_handler_parses_nothing(api, monkeypatch):
    import bridge.service.maneuvers.language as language
    import bridge.service.store as store_module

    api.store.limits = StoreLimits()
    for i in range(70):
        script = "steps:\n" + "".join(f"  - goto: {{z: 0.{k % 3}}}\n  - wait: 1\n" for k in range(20))
        assert _call(api, "maneuvers/save", {"name": f"m{i:02d}", "script": script}, "olga")[0]
    calls = []
    real = language.parse_maneuver
    monkeypatch.setattr(store_module, "parse_maneuver", lambda t: calls.append(t) or real(t))
    monkeypatch.setattr(language, "parse_maneuver", lambda t: calls.append(t) or real(t))
    ok, r = _call(api, "maneuvers/list", {}, "vera")
    assert (
        ok
        and len(r["maneuvers"]) == 70
        and r["maneuvers"][0]
        == {
            "name": "m00",
            "description": "",
            "steps": 40,
            "timeout": 60.0,
        }
    )
    assert calls == []


def test_plan_refuses_a_goal_in_mm_as_goto_does(api):
    # z = 250 (mm meant): goto said "unreachable … did you mean mm?", plan "allowed: >= -2 and <= 2 m"
    for key in ("goto", "plan"):
        ok, r = _call(api, key, {"goal": {"z": 250}}, "olga")
        assert not ok and r["error"] == "unreachable", (key, r)
        assert "workspace" in r["message"] and "did you mean mm? 250 mm = 0.25 m" in r["message"], (key, r)
    # a goal within the schema's range stays a preview ("refused" in an ok reply): test_service_api
