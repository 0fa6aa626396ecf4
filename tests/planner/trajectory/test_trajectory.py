"""Trajectories: limits on every sample, exact endpoints, straight lines, continuity, stops, jog."""

import numpy as np
import pytest

from planner.trajectory import (
    ActuatorLimits,
    JogController,
    MotionState,
    PlanError,
    TrajectoryPlanner,
    Waypoint,
    verify_setpoints,
)

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
