"""The transport-independent handler ``ServiceAPI.handle(key, payload, user)`` without Zenoh:
strict parsing (every bad payload answered with an error naming the field and the limit),
IK answers checked against forward kinematics, presets and maneuvers through a real store, and
the access policy a front end applies. Motion runs on the simulated CAN rig in simulated time.
"""

from __future__ import annotations

import json
import time

import numpy as np
import pytest

from bridge.service.api import ServiceAPI
from bridge.service.motion.controller import MotionController
from bridge.service.schemas import API_KEYS, MAX_PAYLOAD_BYTES, REQUESTS, RequestError, parse_request
from bridge.service.security import AccessPolicy
from bridge.service.store import HitchStore
from bridge.sim.move import SimRig
from planner.ik_qp.hitch_ik import IKSolver
from planner.limits.guard import Guard
from planner.trajectory import TrajectoryPlanner

VALID = {
    "ik": {"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.0},
    "plan": {"goal": {"z": 0.2}},
    "goto": {"goal": {"z": 0.2}},
    "jog": {"vx": 0.01, "ttl_ms": 100},
    "stop": {},
    "mode": {"mode": "auto"},
    "config": {},
    "events/recent": {"after": 12, "limit": 100},
    "presets/list": {},
    "presets/save": {"name": "a"},
    "presets/go": {"name": "a"},
    "presets/delete": {"name": "a"},
    "maneuvers/validate": {"script": "steps: [{wait: 1}]"},
    "maneuvers/save": {"name": "m", "script": "steps: []"},
    "maneuvers/list": {},
    "maneuvers/run": {"name": "m"},
    "maneuvers/delete": {"name": "m"},
    "faults/ack": {},
    "sim/fault": {"cut": "planner_to_ecu", "loss": 0.1, "delay_ms": 20, "restart_ecu": False},
    "track/start": {"frame": "tractor", "dof": ["x", "z"], "ttl_ms": 200},
    "track/setpoint": {"session": 1, "seq": 1, "pose": {"x": 0.01}, "velocity": {"x": 0.0}},
    "track/stop": {},
    "maneuvers/pause": {},
    "maneuvers/resume": {},
    "maneuvers/skip": {},
    "maneuvers/record/start": {},
    "maneuvers/record/stop": {"name": "taught"},
    "lines/save": {
        "name": "headland",
        "geojson": {"type": "LineString", "coordinates": [[11.0, 48.0], [11.001, 48.0]]},
    },
    "lines/list": {},
    "lines/delete": {"name": "headland"},
    "implements/list": {},
    "implements/define": {"name": "harrow", "category": "2", "mass_kg": 1200.0, "com_m": [0.0, 0.6, 0.4]},
    "implements/select": {"name": "harrow"},
    "implements/delete": {"name": "harrow"},
    "implements/lock": {},
    "implements/unlock": {},
    "hitch/raise": {},
    "hitch/return": {"speed_scale": 0.5},
    "sim/switch": {"position": "raise"},
    "work/settings": {"mode": "draft", "draft_setpoint_n": 20000.0},
    "work/start": {"z": 0.0},
    "work/stop": {},
    "work/resume": {},
}
MOTION_KEYS = ("goto", "jog", "presets/go", "maneuvers/run")


class Service:
    def __init__(self, model, tmp_path):
        self.rig = SimRig(model)
        self.rig.start()
        self.rig.run_until(0.5)
        self.events = []
        self.mc = MotionController(
            Guard(TrajectoryPlanner(model)),
            Guard(TrajectoryPlanner(model)),
            self.rig.link,
            lambda: self.rig.now_s,
            on_event=self.events.append,
            spawn=lambda fn: fn(),
        )
        self.mc.cycle()
        self.store = HitchStore(tmp_path / "hitch.sqlite3")
        self.api = ServiceAPI(self.mc, IKSolver(model), self.store, {"profile": "thesis-t132"})

    def call(self, key, payload=None, user=None):
        data = payload if isinstance(payload, (bytes, str)) else json.dumps(payload if payload is not None else {})
        return self.api.handle(key, data, user)

    def run(self, seconds):
        end = self.rig.now_s + seconds
        while self.rig.now_s < end - 1e-9:
            self.rig.run_until(self.rig.now_s + 0.02)
            self.mc.cycle()


@pytest.fixture
def svc(model, tmp_path):
    s = Service(model, tmp_path)
    yield s
    s.store.close()
    s.rig.close()


def test_every_key_has_a_schema_and_a_valid_example():
    assert set(VALID) == set(API_KEYS) == set(REQUESTS)
    for key, payload in VALID.items():
        parse_request(key, json.dumps(payload).encode())
    assert parse_request("stop", b"").model_dump() == {}  # an empty payload is {}


@pytest.mark.parametrize(
    "key, payload, expected",
    [
        ("goto", {"goal": {"x": 2.0}}, ["goal.x", "<= 1", "m"]),
        ("goto", {"goal": {"z": 0.1}, "speed_scale": 0}, ["speed_scale", ">= 0.05", "<= 1"]),
        ("goto", {"goal": {}}, ["goal", "at least one of x, z, roll, pitch"]),
        ("goto", {"goal": {"z": 0.1}, "speed": 1}, ["unknown field 'speed'", "goal, speed_scale"]),
        ("goto", {"goal": {"z": 0.1, "yaw": 0.0}}, ["unknown field 'goal.yaw'", "x, z, roll, pitch"]),
        ("ik", {"x": 0.0, "z": "0.2", "roll": 0.0, "pitch": 0.0}, ["z", "'0.2'", "number"]),
        ("ik", {"x": True, "z": 0.2, "roll": 0.0, "pitch": 0.0}, ["x = true", "true and false are not numbers"]),
        ("mode", {"mode": "AUTO"}, ["mode = 'AUTO' must be one of 'auto', 'manual'"]),  # not pydantic's "Input should"
        ("goto", {"goal": [1]}, ["goal must be a JSON object, got a JSON array"]),
        ("ik", {"x": 0.0, "roll": 0.0, "pitch": 0.0}, ["'z' is required"]),
        ("jog", {"vx": 0.1, "ttl_ms": 6000}, ["ttl_ms", "<= 5000", "ms"]),
        ("jog", {"vx": 1e300}, ["vx", "out of range", "m/s"]),
        ("mode", {"mode": "turbo"}, ["mode", "turbo"]),
        ("presets/save", {"name": "../etc"}, ["name", "letters, digits"]),
    ],
)
def test_errors_name_the_field_and_the_allowed_range(key, payload, expected):
    with pytest.raises(RequestError) as ei:
        parse_request(key, json.dumps(payload))
    assert ei.value.code == "bad_request"
    for text in expected:
        assert text in str(ei.value), (text, str(ei.value))


@pytest.mark.parametrize(
    "raw, expected",
    [
        (b'{"x": NaN, "z": 0, "roll": 0, "pitch": 0}', "NaN"),
        (b'{"x": -Infinity, "z": 0, "roll": 0, "pitch": 0}', "Infinity"),
        (b'{"x": 1e400, "z": 0, "roll": 0, "pitch": 0}', "finite"),
        (b'{"x": 1' + b"0" * 5000 + b', "z": 0, "roll": 0, "pitch": 0}', "an integer of more than 4300 digits"),
        (b"[" * 90_000, "nests too deeply"),
        (b"\xff\xfe{}", "not UTF-8"),
        (b'{"x": 0', "not valid JSON"),
        (b"[1, 2]", "must be a JSON object"),
        (b"{" + b" " * (MAX_PAYLOAD_BYTES + 1) + b"}", "bytes"),
    ],
)
def test_malformed_payloads_are_refused_with_a_reason(raw, expected):
    with pytest.raises(RequestError) as ei:
        parse_request("ik", raw)
    assert expected in str(ei.value)


def fuzz_payloads(rng: np.random.Generator, n: int):
    """(key, bytes) pairs that are invalid by construction (each mutation breaks the schema)."""
    keys = [k for k in VALID if k != "stop"]  # stop accepts any payload (test_strict_input.py)
    required = [k for k in keys if any(f.is_required() for f in REQUESTS[k].model_fields.values())]
    for i in range(n):
        kind = i % 8
        key = keys[rng.integers(len(keys))]
        base = json.dumps(VALID[key])
        if kind == 0:  # random bytes (never an empty/blank payload)
            raw = bytes(rng.integers(0, 256, rng.integers(1, 64), dtype=np.uint8))
            raw = b"\x00" + raw
        elif kind == 1:  # truncated JSON
            raw = base[: rng.integers(0, len(base) - 1)].encode() or b"{"
        elif kind == 2:  # an unknown key
            d = json.loads(base)
            d[f"bogus{rng.integers(1000)}"] = 1
            raw = json.dumps(d).encode()
        elif kind == 3:  # NaN / Infinity tokens
            raw = json.dumps({"x": float(["nan", "inf", "-inf"][i % 3])}).encode()
        elif kind == 4:  # a required field with a wrong type
            key = required[rng.integers(len(required))]
            d = json.loads(json.dumps(VALID[key]))
            f = sorted(d)[rng.integers(len(d))]
            d[f] = [["a"], {"a": 1}, True, "x" * int(rng.integers(1, 9))][rng.integers(4)]
            if isinstance(VALID[key][f], str) and isinstance(d[f], str):
                d[f] = 7
            raw = json.dumps(d).encode()
        elif kind == 5:  # huge numbers
            raw = json.dumps(
                {
                    "x": 10.0 ** int(rng.integers(5, 300)),
                    "z": 0,
                    "roll": 0,
                    "pitch": 0,
                    "goal": {"x": 1e200},
                    "name": "a",
                    "script": "",
                    "vx": 1e9,
                    "mode": None,
                }
            ).encode()
        elif kind == 6:  # not an object
            raw = json.dumps([[1, 2], "text", 3.5, None][rng.integers(4)]).encode()
        else:  # a required field missing
            key = required[rng.integers(len(required))]
            d = dict(VALID[key])
            d.pop(sorted(k for k in d if REQUESTS[key].model_fields[k].is_required())[0])
            raw = json.dumps(d).encode()
        yield key, raw


def test_fuzzed_payloads_are_all_answered_with_errors_and_nothing_moves(svc):
    rng = np.random.default_rng(20261123)
    codes = {}
    for key, raw in fuzz_payloads(rng, 2000):
        ok, reply = svc.api.handle(key, raw, None)
        assert not ok, (key, raw[:80], reply)
        assert set(reply) == {"error", "message"} and reply["message"].startswith(key), reply
        codes[reply["error"]] = codes.get(reply["error"], 0) + 1
    assert set(codes) == {"bad_request"}
    svc.run(0.2)
    assert svc.mc.current_state().moving is False and svc.events == []
    assert svc.rig.link.counters.references_tx == 0  # nothing was ever streamed
    ok, _ = svc.call("ik", VALID["ik"])
    assert ok


def test_ik_answers_match_forward_kinematics(svc, model, rng):
    tp = svc.mc.planner
    for _ in range(20):
        p = tp.lo + (tp.hi - tp.lo) * rng.random(4)
        ok, r = svc.call("ik", dict(zip(("x", "z", "roll", "pitch"), map(float, p), strict=True)))
        assert ok and r["status"] == "ok", r
        q = np.array([r["actuators"][k] for k in ("lift", "tilt", "top", "left", "right")])
        np.testing.assert_allclose(model.pose(q).controlled(), p, atol=1e-6)
    ok, r = svc.call("ik", {"x": 0.0, "z": 0.9, "roll": 0.0, "pitch": 0.0})  # out of reach: nearest pose
    assert ok and r["status"] == "limited" and r["active"] and r["pose"]["z"] < 0.9


def test_presets_round_trip_and_go_moves(svc):
    ok, r = svc.call("presets/save", {"name": "work", "pose": {"z": 0.2, "x": 0.01}, "speed_scale": 0.5})
    assert ok and r["pose"]["z"] == pytest.approx(0.2) and r["pose"]["x"] == pytest.approx(0.01)
    here = svc.mc.current_state().position
    assert r["pose"]["roll"] == pytest.approx(here[2]) and r["pose"]["pitch"] == pytest.approx(here[3])
    ok, r = svc.call("presets/list")
    assert ok and [p["name"] for p in r["presets"]] == ["work"] and r["presets"][0]["speed_scale"] == 0.5
    ok, r = svc.call("presets/go", {"name": "work"})
    assert ok and r["accepted"] and r["preset"] == "work"
    svc.run(r["duration"] + 0.3)
    np.testing.assert_allclose(svc.mc.current_state().position[:2], [0.01, 0.2], atol=1e-9)
    ok, r = svc.call("presets/save", {"name": "high", "pose": {"z": 0.5}})
    assert not ok and r["error"] == "unreachable" and "workspace:z:max" in r["message"]
    assert svc.call("presets/delete", {"name": "work"}) == (True, {"deleted": "work"})
    for key in ("presets/delete", "presets/go"):
        ok, r = svc.call(key, {"name": "work"})
        assert not ok and r["error"] == "not_found" and "'work'" in r["message"]


def test_a_preset_is_not_overwritten_unasked(svc):
    """A fleet trial: saving 'dup' at z 0.0 and then at z 0.1 answered ok both times and kept only z 0.1
    (maneuvers/save and lines/save refuse an existing name unless replace)."""
    assert svc.call("presets/save", {"name": "dup", "pose": {"z": 0.0}})[0]
    ok, r = svc.call("presets/save", {"name": "dup", "pose": {"z": 0.1}})
    assert not ok and r["error"] == "in_use" and "'dup'" in r["message"] and '"replace": true' in r["message"]
    assert "z 0 " in r["message"] or "z 0," in r["message"], r["message"]  # the pose it keeps
    assert svc.call("presets/list")[1]["presets"][0]["pose"]["z"] == pytest.approx(0.0)
    ok, r = svc.call("presets/save", {"name": "dup", "pose": {"z": 0.1}, "replace": True})
    assert ok and r["replaced"] is True and r["pose"]["z"] == pytest.approx(0.1)
    assert svc.call("presets/list")[1]["presets"][0]["pose"]["z"] == pytest.approx(0.1)
    ok, r = svc.call("presets/save", {"name": "new", "pose": {"z": 0.1}, "replace": True})
    assert ok and "replaced" not in r  # nothing to replace: saved


def test_plan_answers_without_moving(svc):
    ok, r = svc.call("plan", {"goal": {"z": 0.25}, "speed_scale": 0.5})
    assert ok and r["ok"] and r["duration"] > 0 and r["stability"]["ok"]
    ok, r = svc.call("plan", {"goal": {"x": 0.5}})
    assert ok and not r["ok"] and "workspace:x:max" in r["refused"]
    svc.run(0.2)
    assert svc.events == [] and svc.rig.link.counters.references_tx == 0


def test_maneuvers_validate_save_run_delete(svc):
    bad = "steps:\n  - goto: {z: 0.2}\n  - goto: {x: 0.5}\n"
    ok, r = svc.call("maneuvers/validate", {"script": bad})
    assert ok and not r["ok"] and r["errors"][0]["step"] == 1 and "workspace:x:max" in r["errors"][0]["message"]
    ok, r = svc.call("maneuvers/save", {"name": "m", "script": "steps:\n  - jump: 3\n"})
    assert not ok and r["error"] == "bad_request" and "jump" in r["message"]
    good = "steps:\n  - goto: {z: 0.22}\n  - wait: 0.1\n"
    assert svc.call("maneuvers/save", {"name": "m", "script": good}) == (True, {"saved": "m", "steps": 2})
    ok, r = svc.call("maneuvers/list")
    assert ok and r["maneuvers"][0]["name"] == "m" and r["maneuvers"][0]["steps"] == 2
    ok, r = svc.call("maneuvers/run", {"name": "m"})
    assert ok and r["accepted"] and r["duration"] > 0.1
    svc.run(r["duration"] + 0.5)
    assert [e["event"] for e in svc.events if e["event"].startswith("maneuver_")][-1] == "maneuver_finished"
    # the reply names the maneuver's id (its events'), not a motion: its step runs as a motion of its own
    ids = {e["maneuver_id"] for e in svc.events if e["event"].startswith("maneuver_")}
    assert ids == {r["maneuver_id"]}
    # named by the name it was run by, as the state names it (the script has no name: line; every event said
    # "maneuver": null, a new user's report)
    assert {e["maneuver"] for e in svc.events if e["event"].startswith("maneuver_")} == {"m"}
    steps = {e["motion_id"] for e in svc.events if e["event"] == "motion_finished"}
    assert steps and r["maneuver_id"] not in steps
    assert svc.call("maneuvers/delete", {"name": "m"}) == (True, {"deleted": "m"})
    ok, r = svc.call("maneuvers/run", {"name": "m"})
    assert not ok and r["error"] == "not_found"


def test_a_maneuver_counts_its_steps_the_same_way_at_save_list_run_and_start(svc):
    # a speed step sets a scale and runs nothing: save/list said 3, run and maneuver_started said 2 and
    # maneuver_step numbered by script index (a fleet integrator's report)
    script = "steps:\n  - speed: 0.6\n  - goto: {z: 0.22}\n  - wait: 0.1\n"
    assert svc.call("maneuvers/save", {"name": "s", "script": script}) == (True, {"saved": "s", "steps": 3})
    assert svc.call("maneuvers/list")[1]["maneuvers"][0]["steps"] == 3
    ok, r = svc.call("maneuvers/run", {"name": "s"})
    assert ok and r["steps"] == 3 and r["actions"] == 2, r
    svc.run(r["duration"] + 0.5)
    started = next(e for e in svc.events if e["event"] == "maneuver_started")
    assert started["steps"] == 3 and started["actions"] == 2
    assert [e["step"] for e in svc.events if e["event"] == "maneuver_step"] == [1, 2]  # script indexes
    assert all(e["t"] > 1e9 and "clock" in e for e in svc.events if e["event"].startswith("maneuver_"))


def test_mode_gates_motion_keys(svc):
    assert svc.call("mode") == (True, {"mode": "auto", "modes": ["auto", "manual", "attach", "transport", "config"]})
    assert svc.call("mode", {"mode": "transport"})[1]["mode"] == "transport"
    for key in MOTION_KEYS:
        payload = VALID[key]
        if key == "presets/go":
            svc.call("presets/save", {"name": "a"})
        if key == "maneuvers/run":
            svc.call("maneuvers/save", {"name": "m", "script": "steps: [{wait: 1}]"})
        ok, r = svc.call(key, payload)
        assert not ok and r["error"] == "mode" and "transport" in r["message"], (key, r)
    before = time.time()
    ok, r = svc.call("stop")
    assert ok and r["stopped"] is True and r["motion_id"] is None and before <= r["t"] <= time.time(), r


def test_a_front_end_user_gets_the_access_policy(svc):
    svc.api.policy = AccessPolicy(operators=("op",), viewers=("viewer",))
    ok, r = svc.call("goto", VALID["goto"], user="viewer")
    assert not ok and r["error"] == "forbidden" and "viewer" in r["message"] and "operator" in r["message"]
    assert svc.call("ik", VALID["ik"], user="viewer")[0]
    ok, r = svc.call("ik", VALID["ik"], user="mallory")
    assert not ok and r["error"] == "forbidden"
    ok, r = svc.call("goto", VALID["goto"], user="op")
    assert ok and r["accepted"]
    svc.run(r["duration"] + 0.2)
    ok, r = svc.call("goto", {"goal": {"z": 0.1}}, user=None)  # None: the transport (Zenoh ACL) authorised it
    assert ok and r["accepted"]


def test_unknown_key_and_internal_errors_never_raise(svc):
    ok, r = svc.api.handle("teleport", b"{}", None)
    assert not ok and r["error"] == "unknown_key" and "goto" in r["message"]
    svc.api.motion = None  # a broken collaborator: answered, not raised
    ok, r = svc.call("goto", VALID["goto"])
    assert not ok and r["error"] == "internal" and "AttributeError" in r["message"]
