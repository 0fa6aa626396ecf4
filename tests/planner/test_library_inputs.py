"""Bad input at the library's own entries gets a HitchError naming the argument, never a crash, NaN or "ok".

A library user's report (README and examples, then their own program): ``Plan.state_at(nan)`` crashed the
interpreter (Ruckig's ``at_time`` with NaN), ``HardLimits.violations`` found nothing wrong with NaN,
``Guard.check_setpoints`` called a tilt of 0.9 m against a 0.73 m stroke "ok" (the README says it checks the
strokes), a NaN or 6-value ``MotionState`` went on to Ruckig or numpy, and ``TrajectoryPlanner(workspace=…)``
and ``Guard(model)`` failed with KeyError / AttributeError.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys

import numpy as np
import pytest

from planner import ActuatorLimits, Guard, HardLimits, HitchModel, MotionState, TrajectoryPlanner
from planner.errors import HitchError
from planner.limits.tractor import StabilityInputError
from planner.trajectory.plan import TrajectoryInputError


@pytest.fixture(scope="module")
def parts():
    m = HitchModel.from_profile()
    tp = TrajectoryPlanner(m)
    return m, tp, Guard(tp), MotionState.at_rest(m.neutral_pose.controlled())


def test_a_plan_at_a_nan_time_is_refused_not_a_crash(parts):
    m, tp, _, s0 = parts
    plan = tp.plan_move(s0, {"x": 0.03, "z": 0.25})
    with pytest.raises(TrajectoryInputError, match="t must be a number of seconds, got nan"):
        plan.state_at(float("nan"))
    assert plan.state_at(float("inf")).position == pytest.approx(plan.state_at(plan.duration).position)
    # the crash itself, in a process of its own: it ended the interpreter (exit code 139)
    code = (
        "from planner import *; m = HitchModel.from_profile(); tp = TrajectoryPlanner(m)\n"
        "p = tp.plan_move(MotionState.at_rest(m.neutral_pose.controlled()), {'z': 0.25})\n"
        "try:\n    p.state_at(float('nan'))\nexcept Exception as e:\n    print(type(e).__name__)\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "TrajectoryInputError", (out.returncode, out.stderr[-300:])


def test_a_nan_lies_within_no_hard_limit(parts):
    m = parts[0]
    found = HardLimits.from_model(m).violations(np.full(5, np.nan), np.full(11, np.nan))
    assert "stroke:lift:min" in found and "stroke:right:min" in found and len(found) >= 5


def test_check_setpoints_checks_the_strokes_it_is_given(parts):
    _, tp, g, s0 = parts
    sp = tp.plan_move(s0, {"x": 0.03, "z": 0.25}).setpoints
    assert g.check_setpoints(sp).action == "ok"
    q = sp.actuators.copy()
    q[-1, 1] = 0.9  # tilt, stroke 0.58…0.73 m
    dec = g.check_setpoints(dataclasses.replace(sp, actuators=q))
    assert dec.action == "refused"
    first = dec.reasons[0]
    assert (first.measure, first.value, first.threshold, first.unit) == ("stroke:tilt:max", 0.9, 0.73, "m")
    assert "stroke:tilt:max would be 0.9 m (threshold 0.73 m)" in first.sentence()
    with pytest.raises(StabilityInputError, match="setpoints must be a Setpoints"):
        g.check_setpoints(None)  # a stop's plan has none


@pytest.mark.parametrize(
    "state, words",
    [
        (lambda m: MotionState.at_rest([np.nan, 0.1, 0.0, 0.0]), "position must be 4 finite numbers"),
        (lambda m: MotionState.at_rest(m.neutral_pose.as_array()), "position must be 4 finite numbers"),
        (lambda m: MotionState.at_rest(m.neutral_pose), "position must be 4 numbers"),
    ],
)
def test_a_motion_state_is_four_finite_numbers(parts, state, words):
    with pytest.raises(TrajectoryInputError, match=words):
        state(parts[0])


def test_a_plan_from_a_state_with_nan_is_refused_naming_it(parts):
    _, tp, _, _ = parts
    bad = MotionState(np.array([0.0, 0.15, 0.0, 0.0]), np.array([np.nan, 0.1, 0.0, 0.0]), np.zeros(4))
    with pytest.raises(TrajectoryInputError, match=r"start\.velocity must be 4 finite numbers"):
        tp.plan_move(bad, {"z": 0.2})
    with pytest.raises(TrajectoryInputError, match=r"state\.velocity must be 4 finite numbers"):
        tp.plan_stop(bad)


@pytest.mark.parametrize(
    "change, words",
    [
        (lambda ws: {"x": ws["x"]}, "workspace must map each of x, z, roll, pitch"),
        (lambda ws: {**ws, "x": (0.1, -0.1)}, r"workspace\.x must be finite with lo < hi \[m\]"),
        (lambda ws: {**ws, "roll": (float("nan"), 0.1)}, r"workspace\.roll must be finite with lo < hi \[rad\]"),
        (lambda ws: {**ws, "z": "low"}, r"workspace\.z must be two numbers"),
    ],
)
def test_a_workspace_argument_is_checked_naming_it(parts, change, words):
    m = parts[0]
    with pytest.raises(TrajectoryInputError, match=words):
        TrajectoryPlanner(m, workspace=change(dict(m.workspace)))


def test_a_guard_needs_a_planner(parts):
    with pytest.raises(StabilityInputError, match=r"\(Guard\(TrajectoryPlanner\(model\)\)\), got HitchModel") as e:
        Guard(parts[0])
    assert isinstance(e.value, HitchError)


def test_misspelt_fields_wrong_types_and_units_are_named(parts):
    """Only what was missing was named ("missing field(s) right" for a "rigth"), text was read as 3 values,
    ``category=2`` was "not in profile; allowed: …, 2, …", and ``set_slope(20, 0)`` named "slope_roll"."""
    from planner import Actuators
    from planner.ik_qp.result import check_target
    from planner.model.types import ModelInputError
    from planner.profiles.hitch import ProfileError

    m, _, g, _ = parts
    with pytest.raises(ModelInputError, match=r"missing field\(s\) right; unknown field\(s\) rigth"):
        Actuators.from_mapping({"lift": 0.2, "tilt": 0.63, "top": 0.74, "left": 0.54, "rigth": 0.54})
    with pytest.raises(HitchError, match=r"missing field\(s\) pitch; unknown field\(s\) ptch"):
        check_target({"x": 0.0, "z": 0.1, "roll": 0.0, "ptch": 0.0})
    with pytest.raises(HitchError, match="got text 'abc'"):
        check_target("abc")
    with pytest.raises(ProfileError, match=r"a category is text: '2', not int"):
        HitchModel.from_profile(category=2)
    with pytest.raises(StabilityInputError, match=r"set_slope: roll \(the tractor's slope\) .* did you mean degrees"):
        g.set_slope(20, 0)


def test_the_exact_inverse_names_the_value_and_the_unit_it_may_have_been_meant_in(parts):
    """ "roll and pitch must lie within ±π/2" named neither nor its value; a target in mm read "closure error
    1.6e+05 m" (a library user's report; IKSolver said all of it)."""
    from planner import ExactInverse
    from planner.model.types import KinematicsError, ModelInputError

    inv = ExactInverse(parts[0])
    with pytest.raises(KinematicsError, match=r"target roll = 5 rad must lie within ±π/2 rad; did you mean degrees"):
        inv.actuators(0.0, 0.2, 5.0, 0.0)
    with pytest.raises(KinematicsError, match=r"target x = 30 m; did you mean mm\? 30 mm = 0.03 m"):
        inv.actuators(30.0, 200.0, 0.0, 0.0)
    with pytest.raises(ModelInputError, match=r"got \[nan, 0.0, 0.0, 0.0\]"):
        inv.actuators(float("nan"), 0.0, 0.0, 0.0)


# --- a second user trial: bare Python / numpy errors, and bad values taken silently --------------------------------


def test_a_model_needs_a_profile_and_a_profile_name_is_text():
    """``HitchModel("thesis-t132")`` failed as "'str' object has no attribute 'implement'", and
    ``HitchModel.from_profile(None)`` as a TypeError from ``Path``."""
    from planner.model.types import ModelInputError
    from planner.profiles.hitch import ProfileError

    with pytest.raises(ModelInputError, match=r"profile must be a Profile .* use HitchModel\.from_profile\(name"):
        HitchModel("thesis-t132")
    with pytest.raises(ProfileError, match=r"a built-in name \(.*thesis-t132.*\) or a path to a \.toml file"):
        HitchModel.from_profile(None)


def test_the_exact_inverse_of_text_names_the_target(parts):
    from planner import ExactInverse
    from planner.model.types import ModelInputError

    with pytest.raises(ModelInputError, match=r"target must be 4 finite numbers .* got \['a', 0.2, 0, 0\]"):
        ExactInverse(parts[0])("a", 0.2, 0, 0)


@pytest.mark.parametrize(
    "values, words",
    [
        ((float("nan"), 0.63, 0.74, 0.54, 0.54), r"Actuators\.lift must be a finite number \[rad\], got nan"),
        (("a", 0.63, 0.74, 0.54, 0.54), r"Actuators\.lift must be a finite number \[rad\], got 'a'"),
        ((0.22, 0.63, 0.74, float("inf"), 0.54), r"Actuators\.left must be a finite number \[m\], got inf"),
        ((0.22, True, 0.74, 0.54, 0.54), r"Actuators\.tilt must be a finite number \[m\], got True"),
    ],
)
def test_actuators_are_five_finite_numbers(values, words):
    from planner import Actuators
    from planner.model.types import ModelInputError

    with pytest.raises(ModelInputError, match=words):
        Actuators(*values)
    assert Actuators(0.22, 0.63, np.float64(0.74), np.int64(1), 0.54).left == 1  # numpy numbers are numbers


def test_sensor_scaling_needs_five_values(parts):
    from planner import SensorScaling
    from planner.model.types import ModelInputError

    sc = SensorScaling(parts[0].profile)
    with pytest.raises(ModelInputError, match=r"actuators must be 5 numbers \(lift, tilt, top, left, right\)"):
        sc.to_counts([0.2, 0.6, 0.7])
    with pytest.raises(ModelInputError, match=r"counts must be 5 numbers"):
        sc.to_si([100, 200])


def test_an_ik_warm_start_is_five_finite_actuators(parts):
    from planner import IKSolver
    from planner.ik_qp.errors import IKInputError

    ik = IKSolver(parts[0])
    with pytest.raises(IKInputError, match=r"actuators must be 5 finite actuator values .* got \[nan"):
        ik.reset([np.nan] * 5)
    with pytest.raises(IKInputError, match=r"seed must be 5 finite actuator values .* got 'abc'"):
        ik.solve({"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.0}, seed="abc")
    ik.reset(parts[0].neutral)
    assert ik.solve({"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.0}).status == "ok"


@pytest.mark.parametrize(
    "make, words",
    [
        (lambda: ActuatorLimits(np.ones(3), np.ones(3), np.ones(3)), r"velocity must be 5 numbers .* shape \(3,\)"),
        (
            lambda: ActuatorLimits(-np.ones(5), np.ones(5), np.ones(5)),
            r"velocity\.lift must lie within \(0, inf\) rad/s",
        ),
        (
            lambda: ActuatorLimits(np.ones(5), np.full(5, np.nan), np.ones(5)),
            r"acceleration\.lift .* \(0, inf\) rad/s²",
        ),
        (lambda: ActuatorLimits(np.ones(5), np.ones(5), [1, 1, 0, 1, 1]), r"jerk\.top must lie within \(0, inf\) m/s³"),
        (lambda: ActuatorLimits(np.ones(5), np.ones(5), "fast"), r"jerk must be 5 numbers"),
        (lambda: ActuatorLimits(np.ones(5), np.ones(5), np.ones(5)).scaled(0), r"factor .* within \(0, inf\), got 0"),
        (lambda: ActuatorLimits(np.ones(5), np.ones(5), np.ones(5)).scaled(-1), r"factor .* \(0, inf\), got -1"),
    ],
)
def test_actuator_limits_are_five_positive_finite_numbers_each(make, words):
    """3 limits failed in the planner as numpy's broadcast error; negative, zero and NaN limits were taken."""
    from planner.trajectory.actuator_limits import ActuatorLimitsError

    with pytest.raises(ActuatorLimitsError, match=words):
        make()


def test_a_planner_with_three_limits_is_refused_naming_them(parts):
    from planner.trajectory.actuator_limits import ActuatorLimitsError

    m = parts[0]
    with pytest.raises(ActuatorLimitsError, match=r"velocity must be 5 numbers"):
        TrajectoryPlanner(m, limits=ActuatorLimits(np.ones(3), np.ones(3), np.ones(3)))
    lim = ActuatorLimits([1, 1, 1, 1, 1], np.ones(5), np.ones(5)).scaled(0.5)  # a list is kept as a float array
    assert lim.velocity.tolist() == [0.5] * 5 and lim.jerk.tolist() == [0.125] * 5


def test_the_guard_wants_a_motion_state_and_four_rates(parts):
    """``check_jog(start, [0, 0.1])`` failed as numpy's broadcast error; a mapping for the state as an
    AttributeError."""
    _, _, g, s0 = parts
    with pytest.raises(StabilityInputError, match=r"rates must be 4 finite numbers .* got \[0, 0\.1\]"):
        g.check_jog(s0, [0, 0.1])
    with pytest.raises(StabilityInputError, match=r"rates must be 4 finite numbers .* got \[nan, 0, 0, 0\]"):
        g.check_jog(s0, [np.nan, 0, 0, 0])
    with pytest.raises(TrajectoryInputError, match=r"state must be a MotionState .* got dict"):
        g.check_jog({"z": 0.2}, [0, 0.1, 0, 0])
    for call in (g.plan, g.caution_at_goal):
        with pytest.raises(TrajectoryInputError, match=r"start must be a MotionState .* got dict"):
            call({"z": 0.1}, {"z": 0.2})
        with pytest.raises(TrajectoryInputError, match=r"start must be a MotionState .* got ndarray"):
            call(np.zeros(4), {"z": 0.2})
    assert g.check_jog(s0, [0, 0.01, 0, 0])[1].action in ("ok", "scaled")


def test_caution_at_goal_refuses_an_unknown_field_as_plan_move_does(parts):
    _, tp, g, s0 = parts
    with pytest.raises(TrajectoryInputError, match=r"goal: unknown field\(s\) height; allowed: x, z, roll, pitch"):
        tp.plan_move(s0, {"height": 0.2})
    with pytest.raises(TrajectoryInputError, match=r"goal: unknown field\(s\) height; allowed: x, z, roll, pitch"):
        g.caution_at_goal(s0, {"height": 0.2})
    with pytest.raises(TrajectoryInputError, match=r"goal\.z must be a finite number, got 'a'"):
        g.caution_at_goal(s0, {"z": "a"})
    assert g.caution_at_goal(s0, {"z": 5.0}) == ()  # a goal planning refuses (outside): planning says why


def test_setpoints_without_a_sample_are_refused_naming_them(parts):
    """Setpoints of 0 rows failed as an IndexError at the first sample."""
    _, tp, g, s0 = parts
    sp = tp.plan_move(s0, {"z": 0.25}).setpoints
    empty = dataclasses.replace(
        sp,
        t=sp.t[:0],
        pose=sp.pose[:0],
        pose_velocity=sp.pose_velocity[:0],
        actuators=sp.actuators[:0],
        actuator_velocity=sp.actuator_velocity[:0],
    )
    with pytest.raises(StabilityInputError, match=r"setpoints\.t must hold at least one sample time"):
        g.check_setpoints(empty)
    with pytest.raises(StabilityInputError, match=r"setpoints\.actuators must be \(\d+, 5\) .* got shape \(\d+, 4\)"):
        g.check_setpoints(dataclasses.replace(sp, actuators=sp.actuators[:, :4]))


def test_the_trajectory_planner_names_each_bad_argument(parts):
    """A user trial: plan_move / plan_sequence / plan_stop with a dict or an array for the state failed as
    "'dict' object has no attribute 'check'"; lower_bound of NaN raised RuckigError and of 3 values IndexError;
    check_in_workspace took a NaN pose as inside; limits of another type failed later."""
    m, tp, _, s0 = parts
    for bad, got in (({"z": 0.1}, "dict"), (np.zeros(4), "ndarray")):
        with pytest.raises(TrajectoryInputError, match=rf"start must be a MotionState .* got {got}"):
            tp.plan_move(bad, {"z": 0.2})
        with pytest.raises(TrajectoryInputError, match=rf"start must be a MotionState .* got {got}"):
            tp.plan_sequence(bad, [])
        with pytest.raises(TrajectoryInputError, match=rf"state must be a MotionState .* got {got}"):
            tp.plan_stop(bad)
    q = m.neutral  # the 5 actuators at the neutral pose
    with pytest.raises(TrajectoryInputError, match=r"q0 must be finite"):
        tp.lower_bound([np.nan] * 5, q)
    with pytest.raises(TrajectoryInputError, match=r"q0 must be 5 numbers .* shape \(3,\)"):
        tp.lower_bound([0.1, 0.2, 0.3], q)
    with pytest.raises(TrajectoryInputError, match=r"q0_velocity must be finite"):
        tp.lower_bound(q, q, [np.inf, 0, 0, 0, 0])
    assert tp.lower_bound(q, q) == 0.0
    with pytest.raises(TrajectoryInputError, match=r"goal must be finite"):
        tp.check_in_workspace(np.full(4, np.nan))
    with pytest.raises(TrajectoryInputError, match=r"goal must be 4 numbers"):
        tp.check_in_workspace(["a", 0, 0, 0])
    tp.check_in_workspace(s0.position)  # inside: no error
    with pytest.raises(TrajectoryInputError, match=r"limits must be ActuatorLimits"):
        TrajectoryPlanner(m, limits={"velocity": 1.0})
    with pytest.raises(TrajectoryInputError, match=r"model must be a HitchModel"):
        TrajectoryPlanner("thesis-t132")


def test_setpoints_whose_positions_jump_are_refused_whatever_their_velocity_column_says(parts):
    """A user's trial: two samples 0.02 s apart, lift moving 0.149 rad (7.4 rad/s against 0.106 rad/s) with zero
    velocities, passed check_setpoints ("ok"): only the velocity column was compared with the limits."""
    from planner import ExactInverse, Setpoints

    m, tp, g, _ = parts
    inv = ExactInverse(m)
    p0 = m.neutral_pose.controlled()
    p1 = p0 + np.array([0.0, 0.14, 0.0, 0.0])

    def full(p):
        st = m.forward(inv(*p))
        return [p[0], st.pose.y, p[1], p[2], p[3], st.pose.yaw]

    q0, q1 = np.asarray(inv(*p0), float), np.asarray(inv(*p1), float)
    sp = Setpoints(
        rate=50.0,
        t=np.array([0.0, 0.02]),
        pose=np.array([full(p0), full(p1)]),
        pose_velocity=np.zeros((2, 4)),
        actuators=np.array([q0, q1]),
        actuator_velocity=np.zeros((2, 5)),
    )
    d = g.check_setpoints(sp)
    assert d.action == "refused" and d.reasons[0].measure == "velocity:lift", d
    # the same move planned: accepted, and its own samples' mean velocities are within the limits
    plan = tp.plan_move(MotionState.at_rest(p0), {"z": float(p1[1])})
    assert g.check_setpoints(plan.setpoints).action in ("ok", "scaled")


@pytest.mark.parametrize("t1", [float("nan"), float("inf"), 0.0, -0.02])
def test_setpoint_times_must_be_finite_and_increasing(parts, t1):
    """A review: with t = [0, nan] the 70x jump above passed again ("ok"), with [0, 0] it was judged at an infinite
    rate with numpy's divide warning."""
    m, tp, g, s0 = parts
    sp = tp.plan_move(s0, {"z": 0.25}).setpoints
    bad = dataclasses.replace(sp, t=np.r_[0.0, t1, sp.t[2:]])
    with pytest.raises(StabilityInputError, match=r"setpoints\.t must be finite and strictly increasing"):
        g.check_setpoints(bad)


def test_rest_poses_are_not_judged_as_a_trajectory(parts):
    """Poses the hitch rests at one after another (a count approach's via and final pose, made-up times): their
    distance over the times is no speed (Guard.check_setpoints rest_poses)."""
    from planner import Setpoints

    m, tp, g, s0 = parts
    a = tp.plan_move(s0, {"z": 0.25}).setpoints
    idx = [0, len(a.t) - 1]  # the start and the end of a move, 0.05 s apart
    sp = Setpoints(a.rate, np.array([0.0, 0.05]), a.pose[idx], np.zeros((2, 4)), a.actuators[idx], np.zeros((2, 5)))
    assert g.check_setpoints(sp).action == "refused"
    assert g.check_setpoints(sp, rest_poses=True).action in ("ok", "scaled")


@pytest.mark.parametrize(
    "ceiling", [[1.0, 2.0], [float("nan")] * 4, "abc", [10**400, 0, 0, 0], ["1", "2", "3", "4"], [-np.inf, 0, 0, 0]]
)
def test_a_bad_ceiling_is_named_whether_or_not_a_final_approach_uses_it(parts, ceiling):
    """A re-run of a trial: plan_move(..., ceiling=[1, 2] | [nan]*4 | "abc") planned on without a final approach,
    and with one raised numpy's broadcast / conversion error or "target must be 4 finite numbers"."""
    _, tp, _, s0 = parts
    with pytest.raises(TrajectoryInputError, match=r"ceiling must be 4 numbers"):
        tp.plan_move(s0, {"z": 0.2}, ceiling=ceiling)
    assert tp.plan_move(s0, {"z": 0.2}, ceiling=[np.inf, 0.3, np.inf, np.inf]).duration > 0
