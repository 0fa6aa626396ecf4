"""JSON integers beyond a float's range (309+ digits: ``float(int)`` raises OverflowError) in every numeric field
of every request, with and without the service's workspace: refused as ``bad_request`` naming the field and its
range, never an exception out of the parser (a goto of z = 400 digits answered "internal error OverflowError").
Independent truth: Python's own float() of such an integer overflows."""

from __future__ import annotations

import json

import pytest

from bridge.service.schemas import RequestError, check_pose_in_workspace, parse_request

BIG = int("1" * 400)
WORKSPACE = {"x": [-0.2, 0.2], "z": [-0.2, 0.3], "roll": [-0.1, 0.1], "pitch": [-0.2, 0.2]}

CASES = [
    ("ik", {"x": 0, "z": BIG, "roll": 0, "pitch": 0}, "z"),
    ("plan", {"goal": {"z": BIG}}, "goal.z"),
    ("plan", {"goal": {"z": 0.1}, "speed_scale": BIG}, "speed_scale"),
    ("goto", {"goal": {"x": BIG}}, "goal.x"),
    ("goto", {"goal": {"roll": -BIG}}, "goal.roll"),
    ("goto", {"goal": {"z": 0.1}, "deadline_ms": BIG}, "deadline_ms"),
    ("jog", {"vz": BIG}, "vz"),
    ("jog", {"ttl_ms": BIG}, "ttl_ms"),
    ("presets/save", {"name": "a", "pose": {"pitch": BIG}}, "pose.pitch"),
    ("presets/go", {"name": "a", "deadline_ms": BIG}, "deadline_ms"),
    ("work/start", {"z": BIG}, "z"),
    ("work/start", {"deadline_ms": BIG}, "deadline_ms"),
    ("track/setpoint", {"session": 1, "seq": BIG, "pose": {"z": 0.1}}, "seq"),
    ("track/setpoint", {"session": 1, "seq": 1, "pose": {"z": BIG}}, "pose.z"),
    ("track/start", {"dof": ["z"], "ttl_ms": BIG}, "ttl_ms"),
    ("track/stop", {"last_seq": BIG}, "last_seq"),
    ("maneuvers/resume", {"deadline_ms": BIG}, "deadline_ms"),
    ("implements/define", {"name": "a", "category": "2", "mass_kg": BIG, "com_m": [0, 0, 0]}, "mass_kg"),
    ("hitch/raise", {"deadline_ms": BIG}, "deadline_ms"),
]


def test_the_premise_python_cannot_make_a_float_of_it():
    with pytest.raises(OverflowError):
        float(BIG)


@pytest.mark.parametrize("workspace", [None, WORKSPACE], ids=["no-workspace", "workspace"])
@pytest.mark.parametrize("key, payload, field", CASES, ids=[f"{k}:{f}" for k, _, f in CASES])
def test_an_integer_beyond_a_float_is_refused_naming_field_and_range(key, payload, field, workspace):
    with pytest.raises(RequestError) as info:
        parse_request(key, json.dumps(payload), workspace=workspace)
    err = info.value
    assert err.code == "bad_request"
    assert str(err).startswith(f"{key}: {field} = a number of 40"), str(err)
    assert "is out of range (allowed: " in str(err), str(err)


def test_an_unbounded_number_field_says_the_range_of_a_number():
    with pytest.raises(RequestError, match=r"work/settings: blend = a number of 400 digits is out of range \(a number"):
        parse_request("work/settings", json.dumps({"blend": BIG}))


def test_the_workspace_check_leaves_such_an_integer_to_the_schema_and_still_checks_the_others():
    check_pose_in_workspace({"z": BIG}, WORKSPACE)  # no OverflowError: the schema names it
    with pytest.raises(RequestError, match=r"goal\.x = 0\.5 m .* the workspace") as info:
        check_pose_in_workspace({"z": BIG, "x": 0.5}, WORKSPACE)
    assert info.value.code == "unreachable"
