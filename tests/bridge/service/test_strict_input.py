"""Strict request input: NaN/Infinity named by field, duplicate keys refused, the speed-scale lower
bound, stop with any payload, ``deadline_ms`` on every motion request, and workspace errors that
name the workspace range of every violated DOF (with a mm/deg hint)."""

import json
import math

import numpy as np
import pytest

from bridge.service.schemas import (
    DEFAULT_DEADLINE_MS,
    MAX_DEADLINE_MS,
    MIN_SPEED_SCALE,
    REQUESTS,
    RequestError,
    check_pose_in_workspace,
    parse_request,
)
from bridge.service.security import MOTION_KEYS
from planner.limits.guard import Guard
from planner.trajectory import MotionState, TrajectoryPlanner

#: the workspace of thesis-t132 category 2 (as the service's ``limits.workspace``)
WS = {"x": [-0.06, 0.06], "z": [-0.21627, 0.311729], "roll": [-0.058, 0.058], "pitch": [-0.1, 0.058]}


def _refusal(key, raw, **kw) -> RequestError:
    with pytest.raises(RequestError) as exc:
        parse_request(key, raw, **kw)
    return exc.value


# ------------------------------------------------------------------------------------------ NaN / Infinity
@pytest.mark.parametrize(
    "key, raw, field, token",
    [
        ("ik", b'{"x": NaN, "z": 0, "roll": 0, "pitch": 0}', "x =", "NaN"),
        ("goto", b'{"goal": {"z": Infinity}}', "goal.z =", "Infinity"),
        ("goto", b'{"goal": {"z": 0.1}, "speed_scale": -Infinity}', "speed_scale =", "-Infinity"),
        ("jog", b'{"vx": 1e999}', "vx =", "1e999"),  # overflows to infinity
        ("presets/save", b'{"name": "a", "pose": {"pitch": NaN}}', "pose.pitch =", "NaN"),
    ],
)
def test_non_finite_numbers_are_refused_naming_the_field(key, raw, field, token):
    e = _refusal(key, raw)
    assert e.code == "bad_request" and str(e).startswith(f"{key}: ")
    assert f"{field} {token}" in str(e) and "finite" in str(e), str(e)


def test_a_non_finite_number_in_the_allowed_range_message():
    e = _refusal("goto", b'{"goal": {"z": NaN}}')
    assert "goal.z = NaN" in str(e) and "(allowed: >= -2 and <= 2 m)" in str(e)


# ------------------------------------------------------------------------------------------ duplicate keys
@pytest.mark.parametrize(
    "key, raw, name",
    [
        ("goto", b'{"goal": {"z": 0.1, "z": 0.3}}', "'z'"),
        ("goto", b'{"goal": {"z": 0.1}, "speed_scale": 0.5, "speed_scale": 1.0}', "'speed_scale'"),
        ("presets/save", b'{"name": "work", "name": "other"}', "'name'"),
        ("stop", b'{"a": 1, "a": 2}', None),  # stop never reads its payload
    ],
)
def test_duplicate_json_keys_are_refused_naming_the_key(key, raw, name):
    if name is None:
        assert parse_request(key, raw).model_dump() == {}
        return
    e = _refusal(key, raw)
    assert e.code == "bad_request" and f"duplicate key {name}" in str(e), str(e)


# ------------------------------------------------------------------------------------------ speed scale
@pytest.mark.parametrize("scale", [1e-4, 1e-3, 0.049, 0.0, -0.5])
@pytest.mark.parametrize("key", ["plan", "goto", "presets/go", "presets/save"])
def test_speed_scale_below_the_documented_bound_is_refused(key, scale):
    payload = {"goal": {"z": 0.1}} if key in ("plan", "goto") else {"name": "a"}
    e = _refusal(key, json.dumps({**payload, "speed_scale": scale}))
    assert e.code == "bad_request" and "speed_scale" in str(e) and f">= {MIN_SPEED_SCALE:g}" in str(e), str(e)
    assert "Result" not in str(e)
    assert parse_request(key, json.dumps({**payload, "speed_scale": MIN_SPEED_SCALE}))


def test_a_plan_at_the_lowest_speed_scale_stays_small(model):
    """At the bound, a move across the whole workspace is one bounded plan (independent truth: its
    duration is the full-speed duration over the scale; the plan is short enough to compute)."""
    g = Guard(TrajectoryPlanner(model))
    lo = {k: v[0] * 0.9 for k, v in WS.items()}
    hi = {k: v[1] * 0.9 for k, v in WS.items()}
    start = MotionState.at_rest(g.planner.goal_vector(np.zeros(4), lo))
    fast = g.plan(start, hi, speed_scale=1.0).plan.duration
    slow = g.plan(start, hi, speed_scale=MIN_SPEED_SCALE).plan.duration
    assert slow == pytest.approx(fast / MIN_SPEED_SCALE, rel=0.05)
    assert slow < 200.0  # seconds of motion, i.e. a bounded number of samples to plan


# ------------------------------------------------------------------------------------------ stop
@pytest.mark.parametrize(
    "raw",
    [None, b"", b"{}", b'{"reason": "operator"}', b"garbage \xff\xfe", b"[1, 2]", b"null", b"{" * 100_000, "text"],
)
def test_any_payload_sent_to_stop_stops(raw):
    assert parse_request("stop", raw).model_dump() == {}


# ------------------------------------------------------------------------------------------ deadline_ms
MOTION_REQUESTS = {
    "goto": {"goal": {"z": 0.1}},
    "presets/go": {"name": "a"},
    "maneuvers/run": {"name": "m"},
    "jog": {"vz": 0.01},
    "hitch/raise": {},
    "hitch/return": {},
    "track/start": {"dof": ["z"]},
    "maneuvers/resume": {},
    "maneuvers/skip": {},
    "work/start": {},
    "work/resume": {},
}


@pytest.mark.parametrize("key", list(MOTION_REQUESTS))
def test_every_motion_request_carries_a_deadline(key):
    base = MOTION_REQUESTS[key]
    assert parse_request(key, json.dumps(base)).deadline_ms == DEFAULT_DEADLINE_MS == 1000
    assert parse_request(key, json.dumps({**base, "deadline_ms": 1})).deadline_ms == 1
    assert parse_request(key, json.dumps({**base, "deadline_ms": MAX_DEADLINE_MS})).deadline_ms == 60_000
    # a float64 encoder writes 1000 as 1000.0: the same integer (a fleet integrator's report: refused before)
    assert parse_request(key, json.dumps({**base, "deadline_ms": 1000.0})).deadline_ms == 1000
    for bad, needle in ((0, "out of range"), (60_001, "out of range"), (1.5, "integer"), (True, "integer")):
        e = _refusal(key, json.dumps({**base, "deadline_ms": bad}))
        assert "deadline_ms" in str(e) and needle in str(e), str(e)
        assert ">= 1 and <= 60000 ms" in str(e)


def test_only_motion_requests_have_a_deadline():
    """Every request that starts or resumes motion has one (resume, skip, track and work start were left
    without, so a queued one ran late); the ones that only brake have none (never refused late)."""
    with_deadline = {k for k, m in REQUESTS.items() if "deadline_ms" in m.model_fields}
    assert with_deadline == set(MOTION_REQUESTS)
    assert set(MOTION_KEYS) - with_deadline == {"mode", "maneuvers/pause", "work/stop"}


# ------------------------------------------------------------------------------------------ workspace
def test_a_value_just_beyond_a_bound_is_not_shown_equal_to_it():
    """A commissioning trial: "pitch = 0.062 rad is above the workspace (pitch from -0.1 to 0.062 rad)" (the
    bound was 0.061999, rounded to 4 digits): the bound is now shown with the digits that tell them apart."""
    ws = {**WS, "pitch": (-0.1, 0.061999)}
    msg = str(_refusal("goto", json.dumps({"goal": {"pitch": 0.062}}), workspace=ws))
    assert "goal.pitch = 0.062 rad is above the workspace (pitch from -0.1 to 0.061999 rad, workspace:pitch:max)" in msg
    ws = {**WS, "pitch": (-0.1, 0.062)}  # a value 2e-9 over its bound (a review)
    msg = str(_refusal("goto", json.dumps({"goal": {"pitch": 0.062000002}}), workspace=ws))
    assert "goal.pitch = 0.062000002 rad is above the workspace (pitch from -0.1 to 0.062 rad" in msg, msg


def test_a_goal_outside_the_workspace_names_the_workspace_range_of_every_dof():
    e = _refusal("goto", json.dumps({"goal": {"x": 30, "z": 250, "roll": 0.2, "pitch": 3}}), workspace=WS)
    msg = str(e)
    assert e.code == "unreachable" and msg.startswith("goto: outside the workspace")
    x_text = "goal.x = 30 m is left of the workspace (x from -0.06 to 0.06 m, workspace:x:max)"
    assert x_text + "; did you mean mm? 30 mm = 0.03 m" in msg
    assert (
        "goal.z = 250 m is above the workspace (z from -0.2163 to 0.3117 m, workspace:z:max); did you mean mm?" in msg
    )
    assert "goal.roll = 0.2 rad is above the workspace (roll from -0.058 to 0.058 rad, workspace:roll:max)" in msg
    assert "goal.pitch = 3 rad" in msg and "did you mean degrees? 3 deg = 0.0523599 rad" in msg
    assert "<= 2" not in msg and "<= 1" not in msg  # not the schema's sanity bounds
    assert (
        "roll = 0.2 rad is above the workspace (roll from -0.058 to 0.058 rad, workspace:roll:max); did you" not in msg
    )  # no hint


def test_workspace_hints_only_when_the_value_fits_in_mm():
    e = _refusal("goto", json.dumps({"goal": {"z": 0.5}}), workspace=WS)  # metres, just too high: no mm hint
    assert "goal.z = 0.5 m is above" in str(e) and "mm" not in str(e)
    e = _refusal("goto", json.dumps({"goal": {"z": -5000}}), workspace=WS)  # -5 m: too far for mm too
    assert "below the workspace" in str(e) and "did you mean" not in str(e)


def test_a_pose_out_of_the_schemas_range_hints_at_mm_and_degrees():
    """An engineer's report: `ik` with z = 200 named only the ±2 m, where goto hinted at mm."""
    e = _refusal("ik", json.dumps({"x": 0, "z": 200, "roll": 0, "pitch": 0}))
    assert "z = 200 is out of range (allowed: >= -2 and <= 2 m); did you mean mm? 200 mm = 0.2 m" in str(e), e
    e = _refusal("ik", json.dumps({"x": 0, "z": 0.2, "roll": 20, "pitch": 0}))
    assert "did you mean degrees? 20 deg = 0.349066 rad" in str(e), e
    e = _refusal("ik", json.dumps({"x": 0, "z": -5000, "roll": 0, "pitch": 0}))  # -5 m in mm: no hint
    assert "did you mean" not in str(e), e


@pytest.mark.parametrize("depth", [33, 5000])
def test_a_payload_nesting_too_deep_is_refused_naming_the_limit(depth):
    """An attacker's report: "payload nests too deeply" gave no limit."""
    e = _refusal("goto", '{"a":' * depth + "1" + "}" * depth)
    assert "nests" in str(e) and "(allowed: at most 32 levels)" in str(e), e


def test_preset_poses_are_checked_against_the_workspace():
    e = _refusal("presets/save", json.dumps({"name": "a", "pose": {"z": 120}}), workspace=WS)
    assert e.code == "unreachable" and "pose.z = 120 m" in str(e) and "z from -0.2163 to 0.3117 m" in str(e)
    with pytest.raises(RequestError, match="presets/go: outside the workspace: pose.x = 0.1 m"):
        check_pose_in_workspace({"x": 0.1, "z": 0.0, "roll": 0.0, "pitch": 0.0}, WS, key="presets/go", what="pose")
    check_pose_in_workspace({"x": 0.06, "z": 0.0, "roll": 0.0, "pitch": 0.0}, WS)  # on the face: fine
    check_pose_in_workspace({"z": math.nan}, WS)  # non-numbers are the schema's business
    check_pose_in_workspace({"z": 9.0}, None)  # no workspace known: nothing to check


def test_inside_the_workspace_and_without_one_the_schema_decides():
    assert parse_request("goto", json.dumps({"goal": {"z": 0.3}}), workspace=WS).goal.z == 0.3
    e = _refusal("goto", json.dumps({"goal": {"x": 2.0}}))  # no workspace: the schema's sanity bound
    assert e.code == "bad_request" and "<= 1" in str(e)


def test_an_item_of_a_list_field_names_its_range_and_unit():
    """A new user's report: ``com_m.1 = 600.0 is out of range`` named no range."""
    raw = json.dumps({"name": "bad2", "category": "2", "mass_kg": 1200, "com_m": [0, 600, 400]}).encode()
    msg = str(_refusal("implements/define", raw))
    assert "com_m.1 = 600" in msg and "(allowed: >= -10 and <= 10 m)" in msg


@pytest.mark.parametrize("com", [[0, 0], [0, 0, 0, 0]])
def test_a_list_of_the_wrong_length_says_how_many_items(com):
    raw = json.dumps({"name": "bad2", "category": "2", "mass_kg": 1200, "com_m": com}).encode()
    msg = str(_refusal("implements/define", raw))
    assert msg == f"implements/define: com_m must hold exactly 3 items, got {len(com)}"


def test_a_setpoint_velocity_names_its_range_in_m_per_s_and_rad_per_s():
    """The old message said 'velocity.z = 2 is out of range (allowed: >= -1 and <= 1 m)'."""
    for dof, unit in (("z", "m/s"), ("roll", "rad/s")):
        raw = json.dumps({"session": 1, "seq": 0, "pose": {dof: 0.0}, "velocity": {dof: 2.0}})
        with pytest.raises(RequestError) as exc:
            parse_request("track/setpoint", raw)
        assert f"velocity.{dof}" in str(exc.value) and f"(allowed: >= -1 and <= 1 {unit})" in str(exc.value), exc.value


@pytest.mark.parametrize(
    ("key", "payload", "wanted"),
    [
        ("goto", b'{"goal":{"x":"0.1"}}', "goto: goal.x = '0.1' must be a number (a JSON number, not text)"),
        ("presets/save", b'{"name":5}', "presets/save: name = 5 must be text (a JSON string)"),
        ("presets/delete", b'{"name":"a","force":"yes"}', "force = 'yes' must be true or false"),
        ("track/start", b'{"dof":"z"}', "track/start: dof = 'z' must be a JSON list"),
        ("track/setpoint", b'{"session":1,"seq":1e300,"pose":{"z":0}}', "<= 9007199254740992)"),
        (
            "maneuvers/validate",
            ('{"script":"' + "a" * 70000 + '"}').encode(),
            "maneuvers/validate: script is too long (allowed: at most 65536 characters (64 KiB))",
        ),
    ],
)
def test_type_errors_read_as_the_api_s_own_words(key, payload, wanted):
    # the validation library's wording leaked ("Input should be a valid number", "String should have at
    # most 65536 characters" beside docs saying 64 KiB, a bound of 9.0072e+15); a fleet integrator's report
    with pytest.raises(RequestError) as err:
        parse_request(key, payload)
    assert wanted in str(err.value) and "Input should" not in str(err.value) and "String should" not in str(err.value)


def test_a_null_pose_value_is_named_as_not_a_number():
    """A new user's report: {"pose": {"z": null}} was refused "pose = a JSON object needs at least one of x, z, roll,
    pitch", the z that was sent unnamed."""
    for pose, dof in (({"z": None}, "z"), ({"x": 0.1, "roll": None}, "roll")):
        raw = json.dumps({"session": 3, "seq": 1, "pose": pose})
        msg = str(_refusal("track/setpoint", raw))
        assert msg.startswith(f"track/setpoint: pose.{dof} must be a number"), msg
        assert "got null" in msg and "needs at least one" not in msg
    assert "needs at least one of x, z, roll, pitch" in str(
        _refusal("track/setpoint", b'{"session":3,"seq":1,"pose":{}}')
    )


@pytest.mark.parametrize(
    "key, field, body",
    [
        ("goto", "goal", {"goal": {"x": 0.01, "z": None}}),
        ("goto", "goal", {"goal": {"z": None}}),
        ("plan", "goal", {"goal": {"roll": None}}),
        ("presets/save", "pose", {"name": "a", "pose": {"pitch": None}}),
    ],
)
def test_a_null_dof_of_a_goal_or_a_preset_is_refused_naming_it(key, field, body):
    """A fleet trial: {"goal": {"x": 0.01, "z": null}} was accepted with z kept where it was; {"goal": {"z": null}}
    was refused "needs at least one of x, z, roll, pitch", the z that was sent unnamed."""
    dof = next(k for k, v in body[field].items() if v is None)
    msg = str(_refusal(key, json.dumps(body)))
    assert msg.startswith(f"{key}: {field}.{dof} must be a number ("), msg
    assert "got null; a DOF left out keeps its value" in msg and "needs at least one" not in msg


def test_the_twin_s_frame_delay_names_its_unit():
    """A trial: ``sim/fault`` with ``delay_ms = -3`` was refused "(allowed: >= 0 and <= 5000)", the only millisecond
    field whose range said no unit."""
    with pytest.raises(RequestError) as exc:
        parse_request("sim/fault", json.dumps({"delay_ms": -3}))
    assert "delay_ms = -3" in str(exc.value) and "(allowed: >= 0 and <= 5000 ms)" in str(exc.value), exc.value
