"""The implement's limits in the guard: the upper height limit refuses (plans) or clips (jog) and names
itself; the lowering speed limit bounds the downward z speed of every planned sample and of jog rates.
Truth: the sampled plans' own z positions and finite-difference velocities, not the guard's bookkeeping."""

from __future__ import annotations

import numpy as np
import pytest

from planner.limits.guard import Guard, GuardRefusal
from planner.limits.implement_limits import (
    LOWERING_SPEED_LIMIT,
    UPPER_HEIGHT_LIMIT,
    ImplementLimitError,
    ImplementLimits,
    clip_jog_z_rate,
    lowering_speed_factor,
    track_bounds,
    upper_height_violation,
)
from planner.trajectory import JogController, MotionState, TrajectoryPlanner
from planner.trajectory.track import TrackFollower


@pytest.fixture(scope="module")
def planner(model):
    return TrajectoryPlanner(model)


def _guard(planner, **limits) -> Guard:
    return Guard(planner, implement_limits=ImplementLimits(**limits))


@pytest.mark.parametrize(
    "kwargs, field",
    [
        ({"upper_height_m": float("nan")}, "upper_height_m"),
        ({"upper_height_m": 5.0}, "upper_height_m"),
        ({"lowering_speed_m_s": 0.0}, "lowering_speed_m_s"),
        ({"lowering_speed_m_s": True}, "lowering_speed_m_s"),
        ({"transport_locked": 1}, "transport_locked"),
    ],
)
def test_limits_are_validated_naming_the_field(kwargs, field):
    with pytest.raises(ImplementLimitError, match=field):
        ImplementLimits(**kwargs)


def test_pure_checks():
    lim = ImplementLimits(upper_height_m=0.2, lowering_speed_m_s=0.1)
    # the highest sample, the goal of a goto (the first one over the limit read 200.6 mm for a goto to 300 mm)
    assert upper_height_violation(np.array([0.1, 0.2, 0.21, 0.3, 0.25]), lim) == (3, 0.3)
    assert upper_height_violation(np.array([0.3, 0.25, 0.2]), lim) is None  # starting above: may only go down
    assert upper_height_violation(np.array([0.3, 0.31]), lim) == (1, 0.31)
    assert upper_height_violation(np.array([0.1, np.nan]), lim) == (1, pytest.approx(np.nan, nan_ok=True))
    assert lowering_speed_factor(np.array([0.0, -0.05, 0.2]), lim) is None
    k, f, v = lowering_speed_factor(np.array([0.0, -0.4, -0.2]), lim)
    assert (k, v) == (1, 0.4) and f == pytest.approx(0.25)
    assert clip_jog_z_rate(0.0, -0.3, 1.0, lim) == (-0.1, LOWERING_SPEED_LIMIT)
    assert clip_jog_z_rate(0.15, 0.3, 1.0, lim) == (pytest.approx(0.05), UPPER_HEIGHT_LIMIT)
    assert clip_jog_z_rate(0.25, 0.3, 1.0, lim) == (0.0, UPPER_HEIGHT_LIMIT)
    assert clip_jog_z_rate(0.25, -0.05, 1.0, lim) == (-0.05, None)
    assert clip_jog_z_rate(0.0, 0.3, 1.0, ImplementLimits()) == (0.3, None)


def test_a_goto_above_the_upper_height_limit_is_refused_naming_it(planner):
    start = MotionState.at_rest(planner.model.neutral_pose.controlled())
    guard = _guard(planner, upper_height_m=0.2)
    with pytest.raises(GuardRefusal) as ei:
        guard.plan(start, {"z": 0.25})
    (reason,) = ei.value.decision.reasons
    assert reason.measure == UPPER_HEIGHT_LIMIT and reason.threshold == 0.2 and reason.value > 0.2
    # the goal's height, not the first sample over the limit (200.6 mm for a goto to 300 mm: a terminal trial)
    assert reason.value == pytest.approx(0.25, abs=1e-6)
    assert UPPER_HEIGHT_LIMIT in str(ei.value)
    gp = guard.plan(start, {"z": 0.19})  # below it: runs
    assert float(np.max(gp.setpoints.pose[:, 2])) <= 0.2
    assert _guard(planner).plan(start, {"z": 0.25}).decision.action == "ok"  # without the limit: runs


@pytest.mark.parametrize("goal_z, limit", [(-0.15, 0.05), (-0.2, 0.08), (0.0, 0.02)])
def test_no_planned_sample_descends_faster_than_the_lowering_speed_limit(planner, goal_z, limit):
    start = MotionState.at_rest(np.array([0.0, 0.28, 0.0, 0.0]))
    free = _guard(planner).plan(start, {"z": goal_z, "x": 0.03})
    sp_free = free.setpoints
    fastest_free = -float(np.min(np.diff(sp_free.pose[:, 2]) / np.diff(sp_free.t)))
    assert fastest_free > limit  # without the limit the move descends faster (the test means something)
    gp = _guard(planner, lowering_speed_m_s=limit).plan(start, {"z": goal_z, "x": 0.03})
    sp = gp.setpoints
    assert gp.decision.action == "scaled" and LOWERING_SPEED_LIMIT in [r.measure for r in gp.decision.reasons]
    vz_fd = np.diff(sp.pose[:, 2]) / np.diff(sp.t)  # independent of the planner's own velocities
    assert -float(np.min(vz_fd)) <= limit * (1 + 1e-6)
    assert -float(np.min(sp.pose_velocity[:, 1])) <= limit * (1 + 1e-6)
    assert sp.pose[-1, 2] == pytest.approx(goal_z, abs=1e-9)  # the same goal, only slower


def test_raising_is_not_slowed_by_the_lowering_speed_limit(planner):
    start = MotionState.at_rest(np.array([0.0, -0.1, 0.0, 0.0]))
    gp = _guard(planner, lowering_speed_m_s=0.01).plan(start, {"z": 0.25})
    assert gp.decision.action == "ok"


def test_jog_is_clipped_by_both_limits(planner):
    guard = _guard(planner, upper_height_m=0.2, lowering_speed_m_s=0.03)
    st = MotionState.at_rest(np.array([0.0, 0.1, 0.0, 0.0]))
    rates, dec = guard.check_jog(st, np.array([0.0, -0.2, 0.0, 0.0]))
    assert rates[1] >= -0.03 - 1e-12 and LOWERING_SPEED_LIMIT in [r.measure for r in dec.reasons]
    # the reason says what was asked for against the limit, with units (a new user's report: "implement lowering
    # speed limit would be -0.05 (threshold 0.05)", the clipped value against its own bound, no unit)
    (low,) = [r for r in dec.reasons if r.measure == LOWERING_SPEED_LIMIT]
    assert low.sentence() == "implement lowering speed limit would be 0.2 m/s (threshold 0.03 m/s) at t = 0.00 s"
    _, up = guard.check_jog(st, np.array([0.0, 0.2, 0.0, 0.0]))
    (high,) = [r for r in up.reasons if r.measure == UPPER_HEIGHT_LIMIT]
    h = guard.settings.jog_horizon
    assert high.unit == "m" and high.value == pytest.approx(0.1 + 0.2 * h) and high.threshold == 0.2
    assert dec.action == "scaled"
    # jogging up for a long time never passes the upper height limit
    jc = JogController(planner, st)
    z_max = -np.inf
    for _ in range(int(6 * planner.rate)):
        allowed, _ = guard.check_jog(jc.state, np.array([0.0, 0.2, 0.0, 0.0]))
        jc.command(allowed, 1.0)
        out = jc.step()
        z_max = max(z_max, float(out.state.position[1]))
    assert 0.19 < z_max <= 0.2 + 1e-3
    # jogging down for a long time never descends faster than the limit
    jc = JogController(planner, MotionState.at_rest(np.array([0.0, 0.25, 0.0, 0.0])))
    zs = []
    for _ in range(int(3 * planner.rate)):
        allowed, _ = guard.check_jog(jc.state, np.array([0.0, -0.3, 0.0, 0.0]))
        jc.command(allowed, 1.0)
        zs.append(float(jc.step().state.position[1]))
    assert -float(np.min(np.diff(zs))) * planner.rate <= 0.03 * (1 + 1e-6)
    assert zs[0] - zs[-1] > 0.05  # it did go down


def test_a_track_session_keeps_below_the_upper_height_and_descends_no_faster_than_the_limit(planner):
    """Setpoints above the upper height limit are clipped, naming it; a far setpoint below (a fast
    descent, also with a fast setpoint velocity) descends at most at the lowering speed limit.
    Truth: the follower's sampled z and their finite differences."""
    upper, lowering = 0.2, 0.03
    bounds = track_bounds(ImplementLimits(upper_height_m=upper, lowering_speed_m_s=lowering))
    f = TrackFollower(planner, MotionState.at_rest(np.array([0.0, 0.1, 0.0, 0.0])), ["z"], 0.5, bounds=bounds)
    sp = f.set_setpoint({"z": 0.35})
    assert sp.position[1] == pytest.approx(upper) and sp.limited == {"z": UPPER_HEIGHT_LIMIT}
    zs, flags = [], set()
    for _ in range(int(4 * planner.rate)):
        f.set_setpoint({"z": 0.35}, {"z": 0.1})
        out = f.step()
        zs.append(float(out.state.position[1]))
        flags |= set(out.limited.values())
    assert max(zs) <= upper + 1e-9 and zs[-1] == pytest.approx(upper, abs=1e-4)  # it got there and stayed
    assert UPPER_HEIGHT_LIMIT in flags
    sp = f.set_setpoint({"z": -0.1}, {"z": -0.5})  # a fast descent
    assert sp.velocity[1] == pytest.approx(-lowering) and sp.limited.get("vz") == LOWERING_SPEED_LIMIT
    for _ in range(int(3 * planner.rate)):
        f.set_setpoint({"z": -0.1}, {"z": -0.5} if len(zs) % 2 else None)
        zs.append(float(f.step().state.position[1]))
    vz = np.diff(zs) * planner.rate
    assert -float(np.min(vz)) <= lowering * (1 + 1e-6), float(np.min(vz))
    assert zs[-1] < upper - 0.08  # it did go down (3 s at up to 0.03 m/s)
    assert f.fallbacks == 0
    # without the bounds the same descent is faster (the test can tell)
    g = TrackFollower(planner, MotionState.at_rest(np.array([0.0, upper, 0.0, 0.0])), ["z"], 0.5)
    zg = [upper]
    for _ in range(int(1 * planner.rate)):
        g.set_setpoint({"z": -0.1})
        zg.append(float(g.step().state.position[1]))
    assert -float(np.min(np.diff(zg))) * planner.rate > 2 * lowering


def test_a_track_session_starting_above_the_upper_height_limit_may_only_go_down(planner):
    bounds = track_bounds(ImplementLimits(upper_height_m=0.1))
    f = TrackFollower(planner, MotionState.at_rest(np.array([0.0, 0.2, 0.0, 0.0])), ["z"], 0.5, bounds=bounds)
    zs = [0.2]
    for _ in range(int(4 * planner.rate)):
        f.set_setpoint({"z": 0.3})
        zs.append(float(f.step().state.position[1]))
    assert max(zs) <= 0.2 + 1e-9 and zs[-1] == pytest.approx(0.1, abs=1e-4)
