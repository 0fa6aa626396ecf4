"""The maneuver language (strict parsing, errors with step index, field and range), validation by
planning (with a scripted planner and with the real guard), and the runner's step logic."""

import math
from dataclasses import dataclass

import numpy as np
import pytest
import yaml

from bridge.service.maneuvers.language import (
    MAX_SCRIPT_BYTES,
    MAX_STEPS,
    ManeuverError,
    ManeuverScript,
    PlanningContext,
    StepError,
    guarded_plan_step,
    parse_maneuver,
    validate,
)
from bridge.service.maneuvers.runner import LoopState, ManeuverRunner
from planner.limits.guard import Guard
from planner.trajectory import MotionState, PlanError, TrajectoryPlanner

HEADLAND = """
name: headland-lift
description: lift, wait for the headland turn, lower to work
timeout: 45
steps:
  - speed: 0.6
  - goto: {z: 0.25, pitch: 0.05}
  - wait_for: {distance: 12.0}
  - preset: work
  - wait: 1.5
  - goto: {x: 0.0, speed_scale: 1.0}
"""


# ------------------------------------------------------------------------------------------ parsing
def test_parse_the_documented_example_and_round_trip():
    s = parse_maneuver(HEADLAND)
    assert (s.name, s.timeout_s, len(s.steps)) == ("headland-lift", 45.0, 6)
    kinds = [st.kind for st in s.steps]
    assert kinds == ["speed", "goto", "wait_for", "preset", "wait", "goto"]
    assert s.steps[1].goal == {"z": 0.25, "pitch": 0.05}
    assert s.steps[2].distance == 12.0 and s.steps[3].name == "work" and s.steps[4].seconds == 1.5
    assert parse_maneuver(yaml.safe_dump(s.to_json())) == s
    assert parse_maneuver("steps: [{wait: 1}]").timeout_s == 60.0  # the default timeout


@pytest.mark.parametrize(
    "text, step, needles",
    [
        ("steps: [{goto: {z: 5}}]", 0, ["steps[0].goto.z = 5", "out of range", "z >= -2 and <= 2 m"]),
        ("steps: [{wait: 1}, {goto: {yaw: 0.1}}]", 1, ["steps[1].goto.yaw", "unknown key", "x, z, roll, pitch"]),
        ("steps: [{goto: {}}]", 0, ["at least one of x, z, roll, pitch"]),
        ("steps: [{wait: -1}]", 0, ["seconds = -1", "seconds > 0 and <= 3600 s"]),
        ("steps: [{wait: '3'}]", 0, ["seconds = '3'", "must be a number"]),
        ("steps: [{wait: .nan}]", 0, ["seconds = nan", "finite"]),
        ("steps: [{speed: .inf}]", 0, ["scale = inf", "finite", "scale >= 0.05 and <= 1"]),
        ("steps: [{speed: 0.01}]", 0, ["scale = 0.01", "out of range", "scale >= 0.05 and <= 1"]),
        ("steps: [{speed: yes}]", 0, ["scale = True"]),
        ("steps: [{goto: {x: 1.0e+999}}]", 0, ["x = inf", "finite"]),
        ("steps: [{goto: {z: 123456789012345678901234567890}}]", 0, ["integer of 30 digits", "out of range"]),
        ("steps: [{wait_for: 3}]", 0, ["wait_for must be a mapping", "distance"]),
        ("steps: [{wait_for: {distance: 0}}]", 0, ["distance = 0", "distance > 0 and <= 10000 m"]),
        ("steps: [{preset: 'two words'}]", 0, ["preset.name = 'two words'", "letters, digits"]),
        ("steps: [{preset: {speed_scale: 0.5}}]", 0, ["preset.name: is required"]),
        ("steps: [{goto: {z: 0.1, speed_scale: 0}}]", 0, ["speed_scale = 0", "speed_scale >= 0.05 and <= 1"]),
        ("steps: [{preset: {name: a, speed_scale: 0.001}}]", 0, ["speed_scale = 0.001", "speed_scale >= 0.05"]),
        ("steps: [{goto: {z: 0.1, z: 0.2}}]", None, ["duplicate key 'z'", "line 1"]),
        ("timeout: 3\nsteps: [{wait: 1}]\ntimeout: 9\n", None, ["duplicate key 'timeout'", "line 3"]),
        ("steps: [{wait: 1}]\nsteps: [{goto: {z: 0.1}}]\n", None, ["duplicate key 'steps'", "line 2"]),
        ("steps: [{fly: 1}]", 0, ["unknown step 'fly'", "goto, preset, wait, wait_for, speed"]),
        ("steps: [{wait: 1, speed: 1}]", 0, ["exactly one step key", "wait, speed"]),
        ("steps: [{wait: 1}, 7]", 1, ["steps[1] must be a mapping", "got 7"]),
        ("timeout: 0\nsteps: [{wait: 1}]", None, ["timeout = 0", "timeout > 0 and <= 3600 s"]),
        ("colour: red\nsteps: [{wait: 1}]", None, ["colour: unknown key", "name, description, timeout"]),
        ("name: 'a/b'\nsteps: [{wait: 1}]", None, ["name = 'a/b'"]),
        ("steps: []", None, ["non-empty list", "an empty list"]),
        ("[1, 2]", None, ["must be a mapping with 'steps'"]),
        ("steps: [{goto: {z: 0.1}", None, ["not valid YAML", "line 1"]),
        ("{1: 2, steps: [{wait: 1}]}", None, ["keys must be strings"]),
        ("a: &x [1, 2]\nb: *x\nsteps: [{wait: 1}]", None, ["aliases"]),
        # a field operator's report: no mm hint, where the CLI's goto gave one for the same value
        ("steps: [{goto: {z: 250}}]", 0, ["(allowed: z >= -2 and <= 2 m); did you mean mm? 250 mm = 0.25 m"]),
        ("steps: [{goto: {roll: 30}}]", 0, ["did you mean degrees? 30 deg = 0.523599 rad"]),
        ("steps: [{preset: {name: .nan}}]", 0, ["steps[0].preset.name = nan: must be text"]),  # "Input should be …"
    ],
)
def test_bad_scripts_name_step_field_and_range(text, step, needles):
    with pytest.raises(ManeuverError) as exc:
        parse_maneuver(text)
    first = exc.value.errors[0]
    assert first.step == step
    for n in needles:
        assert n in first.message, first.message
    assert exc.value.errors[0].to_json() == {"step": step, "message": first.message}


@pytest.mark.parametrize("value, expected", [("1e-3", 0.001), ("-.0", 0.0), ("2.5E-2", 0.025), ("1.", 1.0)])
def test_floats_are_read_as_yaml_12_numbers(value, expected):
    """PyYAML's YAML 1.1 read '1e-3' and '-.0' as strings (refused: 'not a valid number')."""
    script = parse_maneuver(f"steps:\n  - goto: {{x: {value}}}\n")
    assert script.steps[0].x == expected  # type: ignore[attr-defined]


@pytest.mark.parametrize("value, expected", [("010", 10.0), ("+3", 3.0), ("45", 45.0)])
def test_integers_are_decimal(value, expected):
    """PyYAML's YAML 1.1 read '010' as 8 (octal)."""
    assert parse_maneuver(f"timeout: {value}\nsteps:\n  - wait: 1\n").timeout_s == expected


@pytest.mark.parametrize("value", ["0x10", "1_0", "1:30", "0o7"])
def test_yaml_11_number_forms_are_not_numbers(value):
    """YAML 1.1 read 0x10 as 16, 1_0 as 10 and 1:30 as 90 (sexagesimal): a maneuver never guesses."""
    with pytest.raises(ManeuverError) as exc:
        parse_maneuver(f"steps:\n  - goto: {{z: {value}}}\n")
    assert f"z = '{value}'" in exc.value.errors[0].message, exc.value.errors[0].message


def test_every_problem_is_reported_with_its_own_index():
    text = "steps:\n  - wait: 1\n  - goto: {z: 9}\n  - speed: 2\n  - wait: 2\n  - preset: {name: a, colour: 1}\n"
    with pytest.raises(ManeuverError) as exc:
        parse_maneuver(text)
    assert [e.step for e in exc.value.errors] == [1, 2, 4]


def test_size_limits_and_yaml_bombs():
    with pytest.raises(ManeuverError, match=f"at most {MAX_SCRIPT_BYTES} bytes"):
        parse_maneuver("steps: [{wait: 1}]\n" + "#" * MAX_SCRIPT_BYTES)
    with pytest.raises(ManeuverError, match=f"at most {MAX_STEPS}"):
        parse_maneuver("steps:\n" + "  - wait: 1\n" * (MAX_STEPS + 1))
    assert len(parse_maneuver("steps:\n" + "  - wait: 1\n" * MAX_STEPS).steps) == MAX_STEPS
    laughs = "a: &a [x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{chr(98 + i)}: &{chr(98 + i)} [{', '.join(['*' + chr(97 + i)] * 9)}]\n" for i in range(8)
    )
    with pytest.raises(ManeuverError, match="aliases|deeper"):  # 9^9 references, refused without expanding
        parse_maneuver(laughs + "steps: [{wait: 1}]")
    with pytest.raises(ManeuverError, match="nesting too deep|deeper"):
        parse_maneuver("steps: " + "[" * 3000 + "]" * 3000)
    for bad in (None, b"steps: []", 12, ["steps"]):
        with pytest.raises(ManeuverError, match="YAML text"):
            parse_maneuver(bad)


@pytest.mark.parametrize(
    "text",
    [
        "!!timestamp 99999-01-01",
        "!!int",
        "!!python/object:os.system {}",
        "steps: [{wait: !!binary 'x'}]",
        "steps: [{wait: !!float 'abc'}]",
        "\x00",
    ],
)
def test_yaml_that_trips_the_parser_itself_is_a_clean_error(text):
    with pytest.raises(ManeuverError, match="not valid YAML") as exc:
        parse_maneuver(text)
    assert exc.value.errors[0].step is None


def test_fuzzed_scripts_only_ever_raise_maneuver_error():
    rng = np.random.default_rng(11)
    base = HEADLAND
    alphabet = list("{}[]:,-'\"&*!|>#%@ \n\t0123456789.eE+naxzrolpitchwaspedgfy_") + [
        "\x00",
        "é",
        ".nan",
        ".inf",
        "!!int",
        "!!timestamp 99999-01-01",
        "!!binary",
        "&a",
        "*a",
        "<<: *a",
    ]
    parsed = rejected = 0
    for _ in range(600):
        chars = list(base)
        for _ in range(int(rng.integers(1, 8))):
            pos = int(rng.integers(0, len(chars)))
            op = rng.integers(0, 3)
            if op == 0:
                chars.insert(pos, alphabet[int(rng.integers(0, len(alphabet)))])
            elif op == 1 and len(chars) > 1:
                del chars[pos]
            else:
                chars[pos] = alphabet[int(rng.integers(0, len(alphabet)))]
        text = "".join(chars)
        try:
            s = parse_maneuver(text)
        except ManeuverError as exc:
            rejected += 1
            assert exc.errors and all(isinstance(e, StepError) for e in exc.errors)
            assert all(e.step is None or 0 <= e.step < MAX_STEPS for e in exc.errors)
            continue
        parsed += 1
        assert isinstance(s, ManeuverScript) and 1 <= len(s.steps) <= MAX_STEPS
        for st in s.steps:  # whatever got through is finite and in range
            for v in st.model_dump().values():
                assert not isinstance(v, float) or math.isfinite(v)
    assert parsed > 20 and rejected > 100  # the fuzzer exercised both paths


# ------------------------------------------------------------------------------------------ validation
@dataclass
class Preset:
    pose: dict
    speed_scale: float | None = None


class ScriptedPlanner:
    """Test double: a move takes |Δ| / (0.1 × scale) seconds (max over DOF) and ends at rest at the goal."""

    def __init__(self, refuse_z_above=math.inf):
        self.calls = []
        self.refuse_z_above = refuse_z_above

    def __call__(self, start, goal, speed_scale):
        self.calls.append((start.position.copy(), dict(goal), speed_scale))
        p = start.position.copy()
        for i, k in enumerate(("x", "z", "roll", "pitch")):
            if k in goal:
                p[i] = goal[k]
        if p[1] > self.refuse_z_above:
            raise PlanError(f"refused: z = {p[1]:.3f} m is above {self.refuse_z_above} m")
        return float(np.max(np.abs(p - start.position)) / (0.1 * speed_scale)), MotionState.at_rest(p)


def _context(planner, presets=None, start=(0.0, 0.0, 0.0, 0.0)):
    presets = presets or {"work": Preset({"x": 0.02, "z": -0.1, "roll": 0.0, "pitch": 0.0}, 0.8)}
    return PlanningContext(MotionState.at_rest(np.array(start, float)), planner, presets.get)


def test_validation_chains_partial_goals_speeds_and_durations():
    planner = ScriptedPlanner()
    r = validate(HEADLAND, _context(planner))
    assert r.ok and r.errors == ()
    starts = [c[0] for c in planner.calls]
    goals = [c[1] for c in planner.calls]
    scales = [c[2] for c in planner.calls]
    np.testing.assert_allclose(starts[0], [0, 0, 0, 0])
    np.testing.assert_allclose(starts[1], [0, 0.25, 0, 0.05])  # the partial goto kept x and roll
    np.testing.assert_allclose(starts[2], [0.02, -0.1, 0, 0])  # the preset's full pose
    assert goals == [{"z": 0.25, "pitch": 0.05}, {"x": 0.02, "z": -0.1, "roll": 0.0, "pitch": 0.0}, {"x": 0.0}]
    assert scales == [0.6, 0.8, 1.0]  # `speed`, the preset's stored scale, the step's own scale
    expected = 0.25 / 0.06 + 0.35 / 0.08 + 1.5 + 0.02 / 0.1  # hand-computed from the double's law
    assert r.duration == pytest.approx(expected)
    assert r.distance_m == 12.0
    assert [(p.index, p.kind) for p in r.steps] == [
        (1, "goto"),
        (2, "wait_for"),
        (3, "preset"),
        (4, "wait"),
        (5, "goto"),
    ]
    assert r.steps[4].goal == {"x": 0.0, "z": -0.1, "roll": 0.0, "pitch": 0.0}  # full goal for the runner
    assert r.to_json() == {"ok": True, "duration": r.duration, "errors": []}


def test_a_step_without_speed_keeps_the_last_speed_and_a_preset_without_scale_too():
    planner = ScriptedPlanner()
    ctx = _context(planner, {"p": Preset({"x": 0.0, "z": 0.1, "roll": 0.0, "pitch": 0.0})})
    assert validate("steps: [{goto: {z: 0.2}}, {speed: 0.3}, {preset: p}, {goto: {z: 0.0}}]", ctx).ok
    assert [c[2] for c in planner.calls] == [1.0, 0.3, 0.3]


def test_validation_errors_carry_the_step_index():
    planner = ScriptedPlanner(refuse_z_above=0.2)
    r = validate("steps: [{preset: nope}, {wait: 1}, {preset: other}]", _context(planner))
    assert not r.ok and [e.step for e in r.errors] == [0, 2] and "nope" in r.errors[0].message
    assert planner.calls == []  # nothing is planned with unknown presets
    r = validate("steps: [{goto: {z: 0.1}}, {wait: 1}, {goto: {z: 0.3}}, {goto: {z: 0.0}}]", _context(planner))
    assert not r.ok and len(r.errors) == 1 and r.errors[0].step == 2
    assert "goto cannot be planned: refused: z = 0.300 m" in r.errors[0].message
    r = validate("timeout: 5\nsteps: [{wait: 2}, {goto: {z: 0.1}}, {wait: 2}, {wait: 2}]", _context(planner))
    assert [e.step for e in r.errors] == [3] and "timeout" in r.errors[0].message  # 2 + 1 + 2 + 2 > 5
    r = validate("steps: [{goto: {z: 9}}]", _context(planner))  # schema errors come back, never raise
    assert not r.ok and r.errors[0].step == 0 and r.to_json()["errors"][0]["step"] == 0


@pytest.fixture(scope="module")
def guard(model):
    return Guard(TrajectoryPlanner(model))


def test_validation_through_the_real_planner_and_guard(guard):
    plan_step = guarded_plan_step(guard)
    work = Preset({"x": 0.0, "z": -0.1, "roll": 0.0, "pitch": 0.0})
    ctx = PlanningContext(MotionState.at_rest(np.zeros(4)), plan_step, {"work": work}.get)
    r = validate("steps: [{speed: 0.5}, {goto: {z: 0.2, pitch: 0.03}}, {wait: 1}, {preset: work}]", ctx)
    assert r.ok, r.errors
    # independent truth: the same moves planned directly through the guard
    a = guard.plan(MotionState.at_rest(np.zeros(4)), {"z": 0.2, "pitch": 0.03}, speed_scale=0.5).plan
    b = guard.plan(MotionState.at_rest(np.array([0.0, 0.2, 0.0, 0.03])), work.pose, speed_scale=0.5).plan
    assert r.duration == pytest.approx(a.duration + 1.0 + b.duration, rel=1e-9)
    assert r.steps[0].goal == pytest.approx({"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.03})
    z_max = guard.planner.hi[1]
    r = validate(f"steps: [{{wait: 1}}, {{goto: {{z: {z_max + 0.05:.4f}}}}}]", ctx)
    assert not r.ok and r.errors[0].step == 1 and "workspace" in r.errors[0].message


def test_a_missing_preset_does_not_hide_what_cannot_be_planned_before_it(guard):
    """A fleet integrator's report: ``[goto {z: 0.5}, preset: nope]`` reported only the missing preset; the goto
    before it, above the workspace, was said only once the preset existed. Steps after a missing preset
    cannot be planned (where they would start is unknown) and are not."""
    z_max = guard.planner.hi[1]
    ctx = PlanningContext(MotionState.at_rest(np.zeros(4)), guarded_plan_step(guard), {}.get)
    r = validate(f"steps: [{{goto: {{z: {z_max + 0.2:.4f}}}}}, {{preset: nope}}]", ctx)
    assert [e.step for e in r.errors] == [0, 1] and not r.ok
    assert "workspace" in r.errors[0].message and "preset 'nope' does not exist" in r.errors[1].message
    r = validate(f"steps: [{{goto: {{z: 0.1}}}}, {{preset: nope}}, {{goto: {{z: {z_max + 0.2:.4f}}}}}]", ctx)
    assert [e.step for e in r.errors] == [1]


# ------------------------------------------------------------------------------------------ runner
def _validated(text, presets=None):
    r = validate(text, _context(ScriptedPlanner(), presets))
    assert r.ok, r.errors
    return r


def _state(moving=False, motion_id=None, ecu=0.0, violation=None):
    return LoopState(moving, motion_id, ecu, violation)


def test_runner_walks_every_step_kind_in_order():
    run = ManeuverRunner(_validated(HEADLAND))
    c = run.step(0.0, _state(ecu=0.0), 100.0)
    assert c.action == "goto" and c.step == 1 and c.speed_scale == 0.6
    assert c.goal == {"x": 0.0, "z": 0.25, "roll": 0.0, "pitch": 0.05}
    assert [e["event"] for e in c.events] == ["maneuver_started", "maneuver_step"]
    run.motion_started(101)
    assert run.step(0.02, _state(True, 101, 0.01), 100.1).action == "continue"
    assert run.step(0.04, _state(True, 101, 0.03), 100.2).action == "continue"
    c = run.step(4.0, _state(False, 101, 3.99), 105.0)  # motion done → wait_for begins at 105 m
    assert c.action == "continue" and c.step == 2 and c.events[0]["distance"] == 12.0
    assert run.step(5.0, _state(ecu=4.99), 116.99).action == "continue"
    c = run.step(5.1, _state(ecu=5.09), 117.0)  # 12 m travelled since the step began
    assert c.action == "goto" and c.step == 3 and c.speed_scale == 0.8
    assert c.goal == {"x": 0.02, "z": -0.1, "roll": 0.0, "pitch": 0.0}
    run.motion_started(102)
    c = run.step(9.0, _state(False, 102, 8.99), 117.0)
    assert c.action == "continue" and c.step == 4  # wait 1.5 s from t = 9.0
    assert run.step(10.49, _state(ecu=10.48)).action == "continue"
    c = run.step(10.5, _state(ecu=10.49))
    assert c.action == "goto" and c.step == 5 and c.speed_scale == 1.0
    run.motion_started(103)
    c = run.step(11.0, _state(False, 103, 10.99))
    assert c.action == "done" and c.events[-1]["event"] == "maneuver_finished"
    assert c.events[-1]["elapsed"] == pytest.approx(11.0)
    assert run.status == "finished"
    assert run.step(11.02, _state(ecu=11.0)).action == "done" and run.step(11.04, _state(ecu=11.0)).events == ()


def _started(text="steps: [{goto: {z: 0.1}}, {wait: 5}]", **kw):
    run = ManeuverRunner(_validated(text), **kw)
    assert run.step(0.0, _state(motion_id=7)).action == "goto"
    run.motion_started(8)
    return run


@pytest.mark.parametrize(
    "now, state, reason",
    [
        (61.0, _state(True, 8, 60.99), "timeout"),  # default timeout 60 s
        (1.0, _state(True, 8, 0.5), "ecu_silent"),  # silent 0.5 s > 0.3 s
        (1.0, _state(True, 8, None), "ecu_silent"),  # never heard
        (1.0, _state(True, 8, 0.99, "esm would be 4.1 kNm"), "predicted_violation"),
        (1.0, _state(True, 9, 0.99), "interrupted"),  # another motion replaced ours
    ],
)
def test_runner_abort_conditions(now, state, reason):
    run = _started()
    c = run.step(now, state)
    assert c.action == "stop" and run.status == "aborted"
    (ev,) = c.events
    assert ev["event"] == "maneuver_aborted" and ev["reason"] == reason and ev["step"] == 0
    assert run.step(now + 0.02, _state(ecu=now)).action == "done"  # aborted once, then over


def test_runner_stop_request_and_tolerance_of_a_late_snapshot():
    run = _started()
    assert run.step(0.02, _state(False, 7, 0.01)).action == "continue"  # snapshot still shows the old motion
    c = run.abort(0.5, "stop", "stop requested")
    assert c.action == "stop" and c.events[0]["reason"] == "stop" and c.events[0]["elapsed"] == 0.5
    assert run.abort(0.6, "stop", "again").action == "done"
    run = ManeuverRunner(_validated("timeout: 2\nsteps: [{wait: 1.5}]"), ecu_timeout_s=1.0)
    assert run.step(0.0, _state(ecu=0.0)).action == "continue"
    assert run.step(1.49, _state(ecu=1.0)).action == "continue"
    assert run.step(1.5, _state(ecu=1.0)).action == "done"


def test_wait_for_rebases_a_reset_odometer_and_waits_without_distance():
    run = ManeuverRunner(_validated("steps: [{wait_for: {distance: 5}}]"))
    assert run.step(0.0, _state(), None).action == "continue"  # no wheel speed yet
    assert run.step(0.1, _state(ecu=0.1), 50.0).action == "continue"  # baseline 50 m
    assert run.step(0.2, _state(ecu=0.2), 54.0).action == "continue"
    assert run.step(0.3, _state(ecu=0.3), 1.0).action == "continue"  # odometer reset → baseline 1 m
    assert run.step(0.4, _state(ecu=0.4), 5.9).action == "continue"  # only 4.9 m since the reset
    assert run.step(0.5, _state(ecu=0.5), 6.0).action == "done"


def test_a_distance_wait_without_wheel_speed_aborts_after_distance_silent_s_naming_the_step_and_the_message():
    """A field trial: with no tractor on the bus the docs' headland script sat in its wait_for distance step until
    the maneuver's timeout, its state saying nothing. Now aborted (trigger_unavailable) once no distance travelled
    came for DISTANCE_SILENT_S — since the step began, or since the last one — and not before; a pause stops
    that clock as it stops the step's."""
    from bridge.service.maneuvers.runner import DISTANCE_SILENT_S

    def events_until_abort(feed):
        run = ManeuverRunner(_validated("steps:\n  - wait: 0.1\n  - wait_for: {distance: 5}\n"))
        t = 0.0
        while t < 10.0:
            c = run.step(t, _state(ecu=t), feed(t))
            aborted = [e for e in c.events if e["event"] == "maneuver_aborted"]
            if aborted:
                return t, aborted[0]
            t = round(t + 0.02, 9)
        return None, None

    t, ev = events_until_abort(lambda t: None)  # never a wheel speed: the step began at 0.1 s
    assert t is not None and abs(t - (0.1 + DISTANCE_SILENT_S + 0.02)) < 0.021, t
    assert ev["reason"] == "trigger_unavailable" and ev["message"].startswith("step 2 (index 1): no distance travelled")
    assert "PGN 65096" in ev["message"], ev
    t, ev = events_until_abort(lambda t: 1.0 if t < 1.0 else None)  # the tractor fell silent at 1 s
    assert t is not None and abs(t - (1.0 + DISTANCE_SILENT_S)) < 0.03, t
    t, _ = events_until_abort(lambda t: t * 0.1)  # a steady 0.1 m/s: 5 m in 50 s, never silent
    assert t is None


def test_runner_finish_time_matches_the_waits_for_random_scripts():
    rng = np.random.default_rng(3)
    for _ in range(40):
        waits = [float(w) for w in rng.uniform(0.05, 2.0, int(rng.integers(1, 8)))]
        dt = float(rng.uniform(0.005, 0.05))
        text = "steps:\n" + "".join(f"  - wait: {w!r}\n" for w in waits)
        run = ManeuverRunner(_validated(text))
        t, k = 0.0, 0
        while run.step(t, _state(ecu=t)).action != "done":
            k += 1
            t = k * dt
            assert t < 60
        # each wait ends at the first tick at or after its deadline: lag under one tick per wait
        assert sum(waits) - 1e-9 <= t <= sum(waits) + len(waits) * dt + 1e-9


def test_runner_refuses_bad_use():
    with pytest.raises(ValueError, match="successful ValidationResult"):
        ManeuverRunner(validate("steps: [{goto: {z: 9}}]", _context(ScriptedPlanner())))
    run = ManeuverRunner(_validated("steps: [{wait: 1}]"))
    with pytest.raises(ValueError, match="has not asked for a motion"):
        run.motion_started(3)
    for bad in (math.nan, math.inf, "1", None):
        with pytest.raises(ValueError, match="now_s"):
            run.step(bad, _state())
    with pytest.raises(ValueError, match="distance_travelled_m"):
        run.step(0.0, _state(), math.nan)
    with pytest.raises(ValueError, match="ecu_timeout_s"):
        ManeuverRunner(_validated("steps: [{wait: 1}]"), ecu_timeout_s=0.0)


@pytest.mark.parametrize("value", ["null", "~", ""])
def test_a_goto_step_with_a_null_dof_is_refused_naming_it(value):
    """A review: goto refused {x: 0.01, z: null}, a maneuver's goto step ran it with z kept where it was."""
    from bridge.service.maneuvers.language import ManeuverError, parse_maneuver

    with pytest.raises(ManeuverError) as err:
        parse_maneuver(f"steps:\n  - goto: {{x: 0.01, z: {value}}}\n")
    assert "steps[0].goto: z must be a number (m), got null; a DOF left out keeps its value" in str(err.value)
