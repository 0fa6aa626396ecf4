"""Trajectories: limits on every sample, exact endpoints, straight lines, continuity, stops, jog."""

import numpy as np
import pytest
from ruckig import InputParameter, Ruckig, Trajectory

from planner.model.kinematics import POINT_NAMES, HitchModel
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES, KinematicsError, ModelInputError
from planner.trajectory import (
    ActuatorLimits,
    JogController,
    MotionState,
    Plan,
    PlanError,
    Setpoints,
    TrajectoryPlanner,
    Violation,
    Waypoint,
    sample_plan,
    straight_line_limits,
    verify_setpoints,
)
from planner.trajectory.plan import _profile_states, forward_batch, plan_states, sample_times

DOFS = ("x", "z", "roll", "pitch")


@pytest.fixture(scope="module")
def tp(model):
    return TrajectoryPlanner(model)


def random_pose(tp, rng):
    return tp.lo + (tp.hi - tp.lo) * rng.random(4)


def fd_check(tp, sp):
    """Independent check: positions within strokes, velocities and finite-difference accelerations within limits."""
    lim = tp.limits
    assert np.all(sp.actuators >= tp.model.lower - 1e-12) and np.all(sp.actuators <= tp.model.upper + 1e-12)
    assert np.all(np.abs(sp.actuator_velocity) <= lim.velocity * (1 + 1e-6))
    # velocities from finite differences of positions agree with the sampled ones (sampling is consistent)
    fd_v = np.diff(sp.actuators, axis=0) / np.diff(sp.t)[:, None]
    mid = 0.5 * (sp.actuator_velocity[1:] + sp.actuator_velocity[:-1])
    assert np.max(np.abs(fd_v - mid)) < 0.02 * np.max(lim.velocity)
    fd_a = np.diff(sp.actuator_velocity, axis=0) / np.diff(sp.t)[:, None]
    assert np.all(np.abs(fd_a) <= lim.acceleration * (1 + 1e-6))


def test_point_to_point_limits_endpoints_and_straight_line(tp, rng):
    for _ in range(12):
        p0, p1 = random_pose(tp, rng), random_pose(tp, rng)
        plan = tp.plan_move(MotionState.at_rest(p0), dict(zip(DOFS, p1, strict=True)))
        sp = tp.sample(plan)
        assert verify_setpoints(sp, tp.model, tp.hard, tp.limits) == []
        fd_check(tp, sp)
        np.testing.assert_allclose(sp.pose[0][[0, 2, 3, 4]], p0, atol=1e-12)
        np.testing.assert_allclose(sp.pose[-1][[0, 2, 3, 4]], p1, atol=1e-12)
        np.testing.assert_allclose(sp.actuator_velocity[[0, -1]], 0.0, atol=1e-12)
        u = (p1 - p0) / np.linalg.norm(p1 - p0)
        rel = sp.pose[:, [0, 2, 3, 4]] - p0
        dev = rel - np.outer(rel @ u, u)
        assert np.max(np.abs(dev[:, :2])) <= 1e-3 and np.max(np.abs(dev[:, 2:])) <= 1e-3
        assert plan.duration <= 1.25 * plan.lower_bound
        assert plan.duration >= plan.lower_bound - 1e-9  # a lower bound is a lower bound


def test_partial_goal_keeps_unspecified_dof(tp, model):
    p0 = model.neutral_pose.controlled()
    plan = tp.plan_move(MotionState.at_rest(p0), {"z": p0[1] + 0.1})
    sp = tp.sample(plan)
    np.testing.assert_allclose(sp.pose[:, [0, 3, 4]], np.tile(p0[[0, 2, 3]], (len(sp.t), 1)), atol=1e-12)
    assert sp.pose[-1, 2] == pytest.approx(p0[1] + 0.1, abs=1e-12)


@pytest.mark.parametrize("rate", [50.0, 200.0])
def test_sampling_rate(tp, model, rate):
    p0 = model.neutral_pose.controlled()
    plan = tp.plan_move(MotionState.at_rest(p0), {"x": 0.04})
    sp = tp.sample(plan, rate)
    assert np.allclose(np.diff(sp.t)[:-1], 1 / rate) and sp.t[-1] == pytest.approx(plan.duration)


def test_goal_outside_workspace_is_refused_naming_the_limit(tp, model):
    p0 = model.neutral_pose.controlled()
    with pytest.raises(PlanError, match=r"workspace:x:max"):
        tp.plan_move(MotionState.at_rest(p0), {"x": tp.hi[0] + 0.01})
    with pytest.raises(ValueError, match=r"goal.z must be a finite number"):
        tp.plan_move(MotionState.at_rest(p0), {"z": float("nan")})
    with pytest.raises(ValueError, match=r"unknown field\(s\) y"):
        tp.plan_move(MotionState.at_rest(p0), {"y": 0.1})
    with pytest.raises(ValueError, match=r"speed_scale must be a number in \(0, 1\]"):
        tp.plan_move(MotionState.at_rest(p0), {"x": 0.0}, speed_scale=2.0)


def test_replan_mid_motion_is_continuous(tp, model, rng):
    for _ in range(5):
        p0, p1, p2 = random_pose(tp, rng), random_pose(tp, rng), random_pose(tp, rng)
        first = tp.plan_move(MotionState.at_rest(p0), dict(zip(DOFS, p1, strict=True)))
        t_switch = first.duration * rng.uniform(0.2, 0.7)
        st = first.state_at(t_switch)
        second = tp.plan_move(st, dict(zip(DOFS, p2, strict=True)))
        s0 = second.state_at(0.0)
        np.testing.assert_allclose(s0.position, st.position, atol=1e-12)
        np.testing.assert_allclose(s0.velocity, st.velocity, atol=1e-12)
        np.testing.assert_allclose(s0.acceleration, st.acceleration, atol=1e-12)
        sp = tp.sample(second)
        assert verify_setpoints(sp, tp.model, tp.hard, tp.limits) == []
        np.testing.assert_allclose(sp.pose[-1][[0, 2, 3, 4]], p2, atol=1e-12)


@pytest.mark.parametrize("blend", [False, True])
def test_sequences_are_continuous_and_within_limits(tp, model, blend):
    p0 = model.neutral_pose.controlled()
    wps = [
        Waypoint({"x": 0.04, "z": p0[1] + 0.05}),
        Waypoint({"z": p0[1] + 0.15}, 0.5),
        Waypoint({"x": -0.03, "roll": 0.03}),
    ]
    plan = tp.plan_sequence(MotionState.at_rest(p0), wps, blend=blend)
    # continuity at the joins
    t = 0.0
    for a, b in zip(plan.segments[:-1], plan.segments[1:], strict=True):
        pa, va, aa = a.at_time(a.duration)
        pb, vb, ab = b.at_time(0.0)
        np.testing.assert_allclose([pa, va, aa], [pb, vb, ab], atol=1e-12)
        t += a.duration
        speed = np.linalg.norm(va)
        assert (speed > 1e-4) if blend else (speed < 1e-12)
    sp = tp.sample(plan)
    assert verify_setpoints(sp, tp.model, tp.hard, tp.limits) == []
    np.testing.assert_allclose(sp.pose[-1][[0, 2, 3, 4]], [-0.03, p0[1] + 0.15, 0.03, p0[3]], atol=1e-12)


def test_stop_is_bounded_and_ends_at_rest(tp, model, rng):
    for _ in range(5):
        p0, p1 = random_pose(tp, rng), random_pose(tp, rng)
        plan = tp.plan_move(MotionState.at_rest(p0), dict(zip(DOFS, p1, strict=True)))
        st = plan.state_at(plan.duration / 2)
        stop = tp.plan_stop(st)
        end = stop.state_at(stop.duration)
        np.testing.assert_allclose(end.velocity, 0.0, atol=1e-12)
        lim = tp.any_direction
        v, a = np.abs(st.velocity), np.abs(st.acceleration)
        # jerk-limited stopping distance bound per DOF: (v + a²/(2j))²/(2 a_max) + (v + a²/(2j))·a_max/j + a³/j²
        ve = v + a**2 / (2 * lim.jerk)
        bound = ve**2 / (2 * lim.acceleration) + ve * lim.acceleration / lim.jerk + a**3 / lim.jerk**2 + 1e-9
        assert np.all(np.abs(end.position - st.position) <= bound)


def test_jog_dead_man_and_limits(tp, model):
    p0 = model.neutral_pose.controlled()
    jog = JogController(tp, MotionState.at_rest(p0))
    # fresh commands every 0.1 s with a 0.2 s TTL drive towards +x until the workspace face
    xs, flags = [], {}
    for k in range(600):
        if k % 5 == 0:
            jog.command({"vx": 0.05, "vz": 0.0}, ttl_s=0.2)
        out = jog.step()
        xs.append(out.state.position[0])
        flags.update(out.limited)
        assert np.all(np.abs(out.actuator_velocity) <= tp.limits.velocity * (1 + 1e-6))
    assert max(xs) <= tp.hi[0] + 1e-9 and xs[-1] == pytest.approx(tp.hi[0], abs=2e-3)
    assert flags == {"x+": "workspace:x:max"}
    assert out.limited == {"x+": "workspace:x:max"} and abs(out.state.velocity[0]) < 1e-9
    # away from the face is free: no flag, motion starts
    jog.command({"vx": -0.02, "vz": 0.01}, ttl_s=0.2)
    for _ in range(5):
        out = jog.step()
    assert out.limited == {} and out.state.velocity[0] < 0 and out.state.velocity[1] > 0
    # TTL expiry: no fresh command -> jerk-limited stop
    for _ in range(100):
        out = jog.step()
    assert out.expired and np.all(np.abs(out.state.velocity) < 1e-12)
    with pytest.raises(ValueError, match="jog.vx must be a finite number"):
        jog.command({"vx": float("inf")}, ttl_s=0.2)
    with pytest.raises(ValueError, match="jog ttl must lie within"):
        jog.command({"vx": 0.0}, ttl_s=0)


def test_actuator_limits_come_from_the_valves(model):
    lim = ActuatorLimits.from_profile(model.profile)
    # tilt: 0.9 · min(0.401, 0.452) counts/s/unit · 254 · 0.5 · (0.150 m / 891 counts)
    assert lim.velocity[1] == pytest.approx(0.9 * 0.401 * 254 * 0.5 * 0.150 / 891)
    assert lim.acceleration[1] == pytest.approx(lim.velocity[1] / 0.3)
    assert lim.jerk[1] == pytest.approx(lim.acceleration[1] / 0.15)


# ---------------------------------------------------------------------------- batched sampling and verification
def reference_sample(plan, inverse, rate):
    """The former per-sample sampling: Plan.state_at and ExactInverse.solve_full at every sample."""
    ts = sample_times(plan.duration, rate)
    n = len(ts)
    pose, pv, q, qd = np.zeros((n, 6)), np.zeros((n, 4)), np.zeros((n, 5)), np.zeros((n, 5))
    for k, t in enumerate(ts):
        st = plan.state_at(t)
        try:
            qk, jac, (y, yaw) = inverse.solve_full(st.position)
        except KinematicsError as exc:
            raise PlanError(f"sample at t = {t:.3f} s is not reachable: {exc}") from None
        x, z, roll, pitch = st.position
        pose[k] = (x, y, z, roll, pitch, yaw)
        pv[k], q[k], qd[k] = st.velocity, qk, jac @ st.velocity
    return Setpoints(rate, ts, pose, pv, q, qd)


def reference_verify(sp, model, hard, limits, rel_tol=1e-6):
    """The former per-sample verification (HitchModel.features and HardLimits.violations per sample), and the mean
    velocity between samples from the positions."""
    out = []
    for k in range(len(sp.t)):
        f, _ = model.features(sp.actuators[k])
        out += [Violation(n, float(sp.t[k]), float("nan"), float("nan")) for n in hard.violations(sp.actuators[k], f)]
        for i in np.flatnonzero(np.abs(sp.actuator_velocity[k]) > limits.velocity * (1 + rel_tol)).tolist():
            v, b = float(sp.actuator_velocity[k, i]), float(limits.velocity[i])
            out.append(Violation(str(LimitName("velocity", ACTUATOR_NAMES[i])), float(sp.t[k]), v, b))
    for k in range(1, len(sp.t)):  # the mean velocity between samples, from the positions (1e-5 relative)
        for i in range(len(ACTUATOR_NAMES)):
            rate = (sp.actuators[k, i] - sp.actuators[k - 1, i]) / (sp.t[k] - sp.t[k - 1])
            if abs(rate) > limits.velocity[i] * (1 + 1e-5):
                name = str(LimitName("velocity", ACTUATOR_NAMES[i]))
                out.append(Violation(name, float(sp.t[k - 1]), float(rate), float(limits.velocity[i])))
    acc = np.diff(sp.actuator_velocity, axis=0) / np.diff(sp.t)[:, None]
    rows, cols = np.nonzero(np.abs(acc) > limits.acceleration * (1 + rel_tol))
    for k, i in zip(rows.tolist(), cols.tolist(), strict=True):
        name = str(LimitName("acceleration", ACTUATOR_NAMES[i]))
        out.append(Violation(name, float(sp.t[k]), float(acc[k, i]), float(limits.acceleration[i])))
    return out


def same_violations(a, b):
    """Equal lists of violations (NaN values, as for the hard limits, compare equal)."""
    num = [np.array([(v.t, v.value, v.bound) for v in x], float).reshape(-1, 3) for x in (a, b)]
    return [v.limit for v in a] == [v.limit for v in b] and np.array_equal(*num, equal_nan=True)


def _plans(tp, rng):
    """Moves between random poses, a re-plan from a moving state, a blended sequence (several segments)."""
    plans = [
        tp.plan_move(
            MotionState.at_rest(random_pose(tp, rng)),
            dict(zip(DOFS, random_pose(tp, rng), strict=True)),
            speed_scale=float(rng.choice([1.0, 0.4])),
        )
        for _ in range(8)
    ]
    mid = (tp.lo + tp.hi) / 2
    moving = MotionState(mid, np.array([0.05, -0.03, 0.01, 0.0]), np.array([0.0, 0.1, 0.0, 0.0]))
    plans.append(tp.plan_move(moving, {"x": tp.hi[0], "z": tp.lo[1]}))
    at = tp.lo + (tp.hi - tp.lo) * np.array([[0.5, 0.8, 0.5, 0.5], [0.2, 0.7, 0.7, 0.5], [0.3, 0.2, 0.6, 0.4]])
    wps = [Waypoint({"z": at[0, 1]}), Waypoint({"x": at[1, 0], "roll": at[1, 2]}, 0.5), Waypoint({"z": at[2, 1]})]
    plans.append(tp.plan_sequence(MotionState.at_rest(mid), wps, blend=True))
    assert len(plans[-1].segments) == 3
    return plans


def test_batched_sampling_equals_the_per_sample_loop(tp, rng):
    """Times, poses, pose velocities and actuators bit for bit; actuator velocities to 1e-12
    (one directional derivative instead of jac @ v)."""
    for plan in _plans(tp, rng):
        for rate in (tp.rate, 37.0):
            new, ref = sample_plan(plan, tp.inverse, rate), reference_sample(plan, tp.inverse, rate)
            for name in ("t", "pose", "pose_velocity", "actuators"):
                assert np.array_equal(getattr(new, name), getattr(ref, name)), name
            np.testing.assert_allclose(new.actuator_velocity, ref.actuator_velocity, rtol=0, atol=1e-12)
        if plan.setpoints is not None:  # the planner's own samples are those too
            assert np.array_equal(plan.setpoints.actuators, reference_sample(plan, tp.inverse, tp.rate).actuators)


def test_an_unreachable_sample_is_refused_as_before(tp, model):
    """A trajectory that leaves the reachable set: the same PlanError, naming the first such sample."""
    p0 = model.neutral_pose.controlled()
    inp = InputParameter(4)
    inp.current_position, inp.target_position = list(p0), list(p0 + [0.0, -2.0, 0.0, 0.0])
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [0.5] * 4, [1.0] * 4, [5.0] * 4
    traj = Trajectory(4)
    Ruckig(4).calculate(inp, traj)
    plan = Plan((traj,), MotionState.at_rest(p0), traj.duration, 0.0)
    with pytest.raises(PlanError, match="is not reachable") as new:
        sample_plan(plan, tp.inverse, tp.rate)
    with pytest.raises(PlanError) as ref:
        reference_sample(plan, tp.inverse, tp.rate)
    assert str(new.value) == str(ref.value)


def test_batched_verification_equals_the_per_sample_loop(tp, rng):
    """Every violation (hard limits, velocity, acceleration) in the same order with the same values."""
    found = 0
    for plan in _plans(tp, rng):
        sp = plan.setpoints or sample_plan(plan, tp.inverse, tp.rate)
        assert same_violations(
            verify_setpoints(sp, tp.model, tp.hard, tp.limits), reference_verify(sp, tp.model, tp.hard, tp.limits)
        )
        wobble = 1 + 0.04 * np.sin(9 * sp.t)[:, None] * np.array([1, -1, 1, 0.5, -0.5])
        bad = Setpoints(sp.rate, sp.t, sp.pose, sp.pose_velocity, sp.actuators * wobble, sp.actuator_velocity * 2.5)
        new, ref = (
            verify_setpoints(bad, tp.model, tp.hard, tp.limits),
            reference_verify(bad, tp.model, tp.hard, tp.limits),
        )
        assert same_violations(new, ref)
        found += len(new)
    assert found > 100


def test_verification_raises_as_before_for_a_sample_that_cannot_close(tp, model):
    sp = tp.plan_move(MotionState.at_rest(model.neutral_pose.controlled()), {"z": tp.hi[1]}).setpoints
    q = sp.actuators.copy()
    q[17, 3] = 5.0  # a sway limiter far beyond its reach
    bad = Setpoints(sp.rate, sp.t, sp.pose, sp.pose_velocity, q, sp.actuator_velocity)
    with pytest.raises(KinematicsError) as new:
        verify_setpoints(bad, model, tp.hard, tp.limits)
    with pytest.raises(KinematicsError) as ref:
        reference_verify(bad, model, tp.hard, tp.limits)
    assert str(new.value) == str(ref.value)


def test_forward_batch_is_forward_bit_for_bit_and_read_only(tp, model, rng):
    sp = tp.plan_move(
        MotionState.at_rest(random_pose(tp, rng)), dict(zip(DOFS, random_pose(tp, rng), strict=True))
    ).setpoints
    fb = forward_batch(model)
    assert forward_batch(model) is fb
    other = sp.actuators[::-1].copy()
    for Q in (sp.actuators, other, sp.actuators):  # the kept result follows the rows asked for
        f, pts, checks = fb(Q)
        assert not (f.flags.writeable or pts.flags.writeable or checks.flags.writeable)
        for k in range(0, len(Q), 7):
            st = model.forward(Q[k])
            assert np.array_equal(f[k], model.features(Q[k])[0])
            for i, name in enumerate(POINT_NAMES):
                assert np.array_equal(pts[k, :, i], st.points[name]), name


def test_plan_states_are_state_at_bit_for_bit(tp, rng):
    """From the profiles (one segment), through at_time (several segments, a brake pre-profile
    from a state beyond the limits, times past the segment's end): the states of state_at."""
    plans = _plans(tp, rng)
    inp = InputParameter(4)  # moving faster than the limits: Ruckig brakes first
    mid = (tp.lo + tp.hi) / 2
    inp.current_position, inp.current_velocity, inp.target_position = list(mid), [0.2, -0.2, 0.1, 0.0], list(tp.hi)
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [0.05] * 4, [0.2] * 4, [1.0] * 4
    braking = Trajectory(4)
    Ruckig(4).calculate(inp, braking)
    assert any(p.brake.duration > 0 for p in braking.profiles[0])
    plans.append(Plan((braking,), MotionState(mid, np.array(inp.current_velocity)), braking.duration, 0.0))
    seg = plans[0].segments[0]
    assert _profile_states(seg, sample_times(seg.duration, 50.0)) is not None  # a move: from its profiles
    assert _profile_states(braking, sample_times(braking.duration, 50.0)) is None
    plans.append(Plan((seg,), plans[0].start, seg.duration + 0.3, 0.0))  # held at the end
    for plan in plans:
        ts = np.concatenate([sample_times(plan.duration, 50.0), rng.uniform(-0.1, plan.duration + 0.1, 40)])
        pos, vel = plan_states(plan, ts)
        for k, t in enumerate(ts):
            st = plan.state_at(t)
            assert np.array_equal(pos[k], st.position) and np.array_equal(vel[k], st.velocity), (k, t)


def test_line_limits_are_kept_per_line_and_actuator_limits(model, rng):
    """A guarded move plans the same line twice: the kept limits are those computed afresh,
    and other actuator limits (or another line) are computed again."""
    tp = TrajectoryPlanner(model)
    p0, p1 = random_pose(tp, rng), random_pose(tp, rng)
    a = tp._line_limits(p0, p1)
    assert tp._line_limits(p0.copy(), p1.copy()) is a
    fresh = straight_line_limits(tp.inverse, p0, p1, tp.limits)
    assert all(np.array_equal(getattr(a, f), getattr(fresh, f)) for f in ("velocity", "acceleration", "jerk"))
    tp.limits = ActuatorLimits(tp.limits.velocity * 0.5, tp.limits.acceleration, tp.limits.jerk)
    b = tp._line_limits(p0, p1)
    assert b is not a and np.array_equal(b.velocity, straight_line_limits(tp.inverse, p0, p1, tp.limits).velocity)
    assert tp._line_limits(p1, p0) is not b


def test_forward_batch_refuses_rows_that_are_not_actuators(model):
    with pytest.raises(ModelInputError, match="actuators"):
        forward_batch(model)(np.zeros((10, 4)))


def test_a_violation_says_its_value_and_bound_in_the_limit_s_unit():
    """A commissioning trial: "the plan would exceed top_link_yaw_min at t = 5.92 s" gave neither the value nor
    the bound. A review: a value within rounding of its bound read as equal to it, and a negative velocity read
    against a positive bound."""
    assert (
        Violation("top_link_yaw_min", 5.918, -0.30123, -0.3).sentence()
        == "top_link_yaw_min = -0.30123 rad against its bound -0.3 rad at t = 5.92 s"
    )
    assert (
        Violation("top_link_yaw_min", 1.0, -0.300000002, -0.3).sentence()
        == "top_link_yaw_min = -0.300000002 rad against its bound -0.3 rad at t = 1.00 s"
    )
    assert (
        Violation("velocity:lift", 0.5, -0.2, 0.15).sentence()
        == "|velocity:lift| = 0.2 rad/s against its bound 0.15 rad/s at t = 0.50 s"
    )
    assert (
        Violation("acceleration:top", 0.5, 1.25, 1.0).sentence()
        == "|acceleration:top| = 1.25 m/s² against its bound 1 m/s² at t = 0.50 s"
    )


@pytest.mark.parametrize(("actuator", "unit"), [(0, "rad/s³"), (2, "m/s³")])
def test_the_actuators_jerk_is_judged_by_second_divided_differences(tp, model, actuator, unit):
    """Closed form: q(t) = q0 + j t³ / 6 has velocity j t² / 2, whose second divided difference is j exactly. Just
    under the limit passes, 1.001 × the limit is named (``jerk:<actuator>``, its unit, the middle sample's time);
    without ``check_jerk`` the jerk is not judged (the other callers' setpoints, as before)."""
    t = np.arange(6) / 50.0
    q0 = np.asarray(model.neutral, float)
    for share, named in ((1.0 - 1e-9, False), (1.001, True)):
        j = share * float(tp.limits.jerk[actuator])
        q = np.tile(q0, (len(t), 1))
        qd = np.zeros_like(q)
        q[:, actuator] += j * t**3 / 6
        qd[:, actuator] = j * t**2 / 2
        sp = Setpoints(50.0, t, np.zeros((len(t), 6)), np.zeros((len(t), 4)), q, qd)
        assert verify_setpoints(sp, model, tp.hard, tp.limits) == []
        bad = verify_setpoints(sp, model, tp.hard, tp.limits, check_jerk=True)
        if not named:
            assert bad == []
            continue
        assert [v.limit for v in bad] == [str(LimitName("jerk", ACTUATOR_NAMES[actuator]))] * (len(t) - 2)
        assert [v.t for v in bad] == pytest.approx(t[1:-1].tolist())
        assert bad[0].value == pytest.approx(j, rel=1e-9) and bad[0].unit == unit
        assert bad[0].sentence().startswith(f"|jerk:{ACTUATOR_NAMES[actuator]}| = ") and unit in bad[0].sentence()


def test_a_slower_blended_sequence_passes_its_waypoints_slower_too(tp):
    """A blended sequence made again slower (its speed factor, after a rate excess) passes its waypoints with its
    velocities × the factor: with the pass-through velocities kept while the limits were lowered, the segment ran
    past its waypoint and out of the workspace (random blends, seed 7, no. 50: "pitch reaches 0.0581 … max
    0.0580", refused)."""
    a, b, c, d = (
        [0.0564, -0.1094, -0.0286, -0.0684],
        [0.059, -0.0649, 0.0122, 0.0565],
        [0.054, -0.1939, 0.0025, -0.005],
        [0.0243, -0.0389, -0.02, -0.0993],
    )
    wps = [Waypoint(dict(zip(DOFS, b, strict=True))), Waypoint(dict(zip(DOFS, c, strict=True)), 0.5)]
    plan = tp.plan_sequence(MotionState.at_rest(a), [*wps, Waypoint(dict(zip(DOFS, d, strict=True)))], blend=True)
    assert plan.info["speed_factor"] < 1.0  # the slower copy is the case
    sp = plan.sampled()
    assert verify_setpoints(sp, tp.model, tp.hard, tp.limits, check_jerk=True) == []
    assert np.all(sp.pose[:, [0, 2, 3, 4]] <= tp.hi + 1e-6) and np.all(sp.pose[:, [0, 2, 3, 4]] >= tp.lo - 1e-6)


def test_random_blended_sequences_keep_the_actuators_jerk(tp):
    """Blended sequences do not move on one line, so the actuators' jerk is not kept by construction: 200 random
    ones (seed 7) had 53 beyond it, up to 1.30 ×. They are now made slower until within it, as for the velocity
    and acceleration."""
    rng = np.random.default_rng(7)
    planned = 0
    for _ in range(60):
        a, b, c, d = (tp.lo + (tp.hi - tp.lo) * rng.random(4) for _ in range(4))
        wps = [Waypoint(dict(zip(DOFS, p, strict=True)), s) for p, s in ((b, 1.0), (c, 0.5), (d, 1.0))]
        try:
            plan = tp.plan_sequence(MotionState.at_rest(a), wps, blend=True)
        except PlanError:
            continue  # a blend that leaves the workspace (refused as before)
        planned += 1
        assert verify_setpoints(plan.sampled(), tp.model, tp.hard, tp.limits, check_jerk=True) == [], plan.info
    assert planned >= 50


def test_a_blended_sequence_after_a_stop_first_passes_its_waypoints_slower_with_its_move(tp):
    """From a moving state a blended sequence may become a stop first whose move is made slower (``move_scale``):
    its pass-through velocities are slowed with it, as a slower copy's are (they were kept at full speed while the
    segments' limits were lowered: the cause of seed 7 no. 50's excursion out of the workspace)."""
    s = MotionState(
        np.array([0.007357802472308208, 0.02523249904554241, -0.008666261926630735, -0.037590573533141915]),
        np.array([0.015603767845752979, -0.012939818326218103, 0.027867022091061247, 0.0393812145599559]),
        np.zeros(4),
    )
    c = [-0.03168073361413386, -0.1633548714002128, 0.03344833582773785, -0.027170720963257233]
    d = [-0.055018570759930455, 0.13129999530100137, -0.03545777214873745, 0.002488785690938078]
    e = [0.048982907403988654, 0.205240554940858, 0.04226650601292604, -0.09832293866500028]
    wps = [Waypoint(dict(zip(DOFS, p, strict=True)), k) for p, k in ((c, 1.0), (d, 0.5), (e, 1.0))]
    plan = tp.plan_sequence(s, wps, blend=True)
    assert "stop_duration" in plan.info and plan.info["move_scale"] < 1.0, plan.info  # the case
    first = plan.segments[1]  # after the stop: to c, passing it
    _, v, _ = first.at_time(first.duration)
    blend = tp._blend_velocity(s.position, np.array(c), np.array(d), 0.5, 0.5)
    np.testing.assert_allclose(v, blend * plan.info["move_scale"], rtol=1e-6, atol=1e-9)
    assert verify_setpoints(plan.sampled(), tp.model, tp.hard, tp.limits) == []


def _fine_jerk_ratio(tp, plan, after: float = -1.0) -> float:
    """The actuators' largest |jerk| / limit at 2 kHz (second divided differences), after time ``after`` [s]."""
    sp = sample_plan(plan, tp.inverse, 2000.0)
    acc = np.diff(sp.actuator_velocity, axis=0) / np.diff(sp.t)[:, None]
    jerk = 2.0 * np.diff(acc, axis=0) / (sp.t[2:] - sp.t[:-2])[:, None]
    keep = sp.t[:-2] > after + 1e-9  # windows starting after ``after``
    return float(np.max(np.abs(jerk[keep]) / tp.limits.jerk))


def test_a_jerk_excess_shorter_than_the_control_period_is_found():
    """The 50 Hz windows average a short excess away: a re-plan 22 ms over the jerk at its start (1.34 × at 1 kHz,
    0.87 at 50 Hz) and a blend 6.5 ms over it (1.40 ×, 0.92 at 50 Hz) passed (a review; random cases of seed 12,
    nos. 45 and 107, default category). Chains that start moving or pass waypoints moving are judged at 1 kHz."""
    tp = TrajectoryPlanner(HitchModel.from_profile())
    a, b, c = (
        [-0.0592, 0.2412, -0.0285, 0.0104],
        [-0.0489, 0.0293, -0.0148, 0.0129],
        [-0.0269, -0.1606, -0.0274, -0.0913],
    )
    first = tp.plan_move(MotionState.at_rest(a), dict(zip(DOFS, b, strict=True)))
    plan = tp.plan_move(first.state_at(0.4665 * first.duration), dict(zip(DOFS, c, strict=True)))
    assert _fine_jerk_ratio(tp, plan, plan.info.get("stop_duration", -1.0)) <= 1.0 + 1e-3, plan.info
    a, b, c, d = (
        [-0.0418, 0.232, -0.0156, 0.0361],
        [0.0521, 0.1237, 0.0438, -0.0045],
        [0.0316, 0.288, -0.0557, 0.0148],
        [0.0171, 0.1577, -0.0407, -0.0935],
    )
    wps = [Waypoint(dict(zip(DOFS, p, strict=True)), s) for p, s in ((b, 1.0), (c, 0.5), (d, 1.0))]
    plan = tp.plan_sequence(MotionState.at_rest(a), wps, blend=True)
    assert _fine_jerk_ratio(tp, plan) <= 1.0 + 1e-3, plan.info
