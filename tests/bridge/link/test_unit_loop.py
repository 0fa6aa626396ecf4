"""Feed-forward through the unit loops (bridge.link.unit_loop).

Truth used: hand values of G = m a / L (thesis 2.57, tables 3-3, 3-4); the loop's differential
equation integrated independently (fine Euler steps, exact delay line), where the shaped
reference must make the piston follow the plan and the plain one must lag by 1/G + T_F; the
simulated ECU's own cylinder and unit controller (quantised, dead zone, minimum flow).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

from bridge.link.unit_loop import (
    ActuatorMotion,
    FeedforwardShaper,
    build_unit_loops,
    feedforward_reference,
    safe_reference,
)
from bridge.sim.controller import UnitController
from bridge.sim.cylinder import Cylinder, build_cylinder_params
from planner.model.exact_inverse import ExactInverse
from planner.model.types import ACTUATOR_NAMES
from planner.trajectory import MotionState


def test_loop_constants_hand_values(model):
    loops = build_unit_loops(model.profile)
    assert [u.name for u in loops] == list(ACTUATOR_NAMES)
    # G = m·0.581/0.1 with m = 1, 0.5, 0.5, 0.2, 0.2 (table 3-3)
    assert [u.gain_per_s for u in loops] == pytest.approx([5.81, 2.905, 2.905, 1.162, 1.162])
    lift = loops[0]
    # Kv·dy_min counts/s through 0.886 rad / 229 counts: 0.12·2·0.886/229 rad/s
    assert lift.min_flow_pos == pytest.approx(0.12 * 2 * 0.886 / 229)
    assert lift.min_flow_neg == pytest.approx(0.14 * 2 * 0.886 / 229)
    with pytest.raises(ValueError, match="a must be"):
        build_unit_loops(model.profile, a=0.0)


def _smooth_move(t, t_end, dist):
    """Quintic rest-to-rest move (position, velocity, acceleration)."""
    s = np.clip(t / t_end, 0.0, 1.0)
    pos = dist * (10 * s**3 - 15 * s**4 + 6 * s**5)
    vel = dist * (30 * s**2 - 60 * s**3 + 30 * s**4) / t_end * (t < t_end)
    acc = dist * (60 * s - 180 * s**2 + 120 * s**3) / t_end**2 * (t < t_end)
    return pos, vel, acc


def test_shaped_reference_makes_the_linear_loop_follow_the_plan(model):
    """T_F ÿ + ẏ = G·[r − y − T_F ẏ](t − L), integrated at 0.1 ms with an exact delay line."""
    u = replace(
        build_unit_loops(model.profile)[3], min_flow_pos=0.0, min_flow_neg=0.0, lower=-1.0, upper=1.0
    )  # a sway limiter: the slowest loop, 1/G = 0.86 s
    h, t_end, dist = 1e-4, 2.0, 0.03
    n_delay = round(u.delay_s / h)
    errs = {}
    for shaped in (True, False):
        y, yd, hist, worst = 0.0, 0.0, [0.0] * n_delay, 0.0
        lag_err: list[tuple[float, float]] = []
        for k in range(round(6.0 / h)):
            t = k * h
            q, v, _ = _smooth_move(np.array(t), t_end, dist)
            _, v_l, a_l = _smooth_move(np.array(t + u.delay_s), t_end, dist)
            motion = ActuatorMotion(*(np.full(5, float(x)) for x in (q, v, v_l, a_l)))
            r = feedforward_reference((u,) * 5, motion)[0] if shaped else float(q)
            hist.append(r - y - u.lag_s * yd)  # the controller's PD input now, acting after L
            ydd = (u.gain_per_s * hist.pop(0) - yd) / u.lag_s
            y, yd = y + h * yd, yd + h * ydd
            worst = max(worst, abs(y - float(_smooth_move(np.array(t + h), t_end, dist)[0])))
            if 0.9 < t < 1.1:
                lag_err.append((float(q) - y, float(v)))
        errs[shaped] = (worst, lag_err)
    assert errs[True][0] < 2e-4 * dist / 0.03  # follows the plan (Euler error only)
    # unshaped it lags by centimetres (the ramp lag 1/G + T_F is checked against the ECU in
    # test_closed_loop.py); mid-move the piston is behind the plan
    e, v = errs[False][1][len(errs[False][1]) // 2]
    assert e > 0.25 * v / u.gain_per_s and errs[False][0] > 0.005
    assert errs[False][0] > 20 * errs[True][0]


def test_minimum_flow_is_compensated_with_the_sign_of_the_command(model):
    """Plant with the valve's minimum flow: T_F ÿ + ẏ = G·s(t − L) + w·sign s(t − L),
    s = r − y − T_F ẏ (dead-zone compensation makes any command give at least w). The shaped
    reference follows the plan when it knows w, and lags by about w/G when it does not."""
    u = replace(build_unit_loops(model.profile)[3], lower=-1.0, upper=1.0)  # left limiter
    assert u.min_flow_pos / u.gain_per_s > 2.5e-4  # ≈ 1.9 counts
    blind = replace(u, min_flow_pos=0.0, min_flow_neg=0.0)
    h, t_end, dist = 1e-4, 3.0, -0.02  # a retracting move
    n_delay = round(u.delay_s / h)
    worst = {}
    for name, loop in (("known", u), ("blind", blind)):
        y, yd, hist, err = 0.0, 0.0, [0.0] * n_delay, 0.0
        for k in range(round(5.0 / h)):
            t = k * h
            q, v, _ = _smooth_move(np.array(t), t_end, dist)
            _, v_l, a_l = _smooth_move(np.array(t + u.delay_s), t_end, dist)
            motion = ActuatorMotion(*(np.full(5, float(x)) for x in (q, v, v_l, a_l)))
            r = feedforward_reference((loop,) * 5, motion)[0]
            hist.append(r - y - u.lag_s * yd)
            s_l = hist.pop(0)
            w = u.min_flow_pos if s_l > 0 else u.min_flow_neg if s_l < 0 else 0.0
            ydd = (u.gain_per_s * s_l + math.copysign(w, s_l) * (s_l != 0) - yd) / u.lag_s
            y, yd = y + h * yd, yd + h * ydd
            err = max(err, abs(y - float(_smooth_move(np.array(t + h), t_end, dist)[0])))
        worst[name] = err
    print(f"worst tracking error: w known {worst['known']:.2e} m, w ignored {worst['blind']:.2e} m")
    # known: below the minimum flow (start and end of the move) the valve can only move in
    # bursts of at least w, so a third of a count (1.7e-4 m/count) remains
    assert worst["known"] < 1e-4
    assert worst["blind"] > 0.5 * u.min_flow_neg / u.gain_per_s and worst["blind"] > 5 * worst["known"]


def test_shaped_reference_against_the_simulated_cylinder_and_controller(model):
    """The ECU's own quantised loop (dead zone, minimum flow, 10 ms PD) on a 3 s, 8 mm tilt move
    (peak 5 mm/s = 30 counts/s, under the planner's 0.9·Kv·254·m = 46 counts/s)."""
    spec = model.profile.actuator("tilt")
    p = build_cylinder_params("tilt", spec)
    u = build_unit_loops(model.profile)[1]
    start = p.si_to_counts(0.62)
    worst = {}
    for shaped in (True, False):
        cyl, ctl = Cylinder(p, initial_counts=start), UnitController(p)
        err = 0.0
        for j in range(500):  # 5 s at the 10 ms controller period
            t = j * 0.01
            q, v, _ = _smooth_move(np.array(t), 3.0, 0.008)
            _, v_l, a_l = _smooth_move(np.array(t + u.delay_s), 3.0, 0.008)
            motion = ActuatorMotion(*(np.full(5, x) for x in (0.62 + float(q), float(v), float(v_l), float(a_l))))
            r_si = feedforward_reference((u,) * 5, motion)[0] if shaped else 0.62 + float(q)
            cmd = ctl.update(int(math.floor(p.si_to_counts(r_si) + 0.5)), cyl.measure()).command
            cyl.run(cmd, 10)
            want = p.si_to_counts(0.62 + float(_smooth_move(np.array(t + 0.01), 3.0, 0.008)[0]))
            err = max(err, abs(cyl.position_counts - want))
        worst[shaped] = err
    # unshaped the lag is (1/G + T_F)·v_max ≈ 0.35 s · 30 counts/s ≈ 10 counts
    print(f"worst tracking error: shaped {worst[True]:.2f} counts, plain {worst[False]:.2f} counts")
    assert worst[True] <= 2.0
    assert worst[False] > 8.0 and worst[False] > 4 * worst[True]


def test_shaped_reference_stays_in_the_strokes_and_is_pulled_back_when_refused(model):
    loops = build_unit_loops(model.profile)
    q = np.array([u.upper for u in loops]) - 1e-4
    v = np.array([1.0, 0.05, 0.05, 0.02, 0.02])  # fast towards the upper ends
    r = feedforward_reference(loops, ActuatorMotion(q, v, v, np.zeros(5)))
    assert np.all(r <= [u.upper for u in loops]) and np.all(r >= q)
    planned, shaped = np.zeros(5), np.full(5, 0.08)

    def check(x):  # refuses anything beyond 0.025 m
        if np.any(x > 0.025):
            raise ValueError("limit")

    ref, frac = safe_reference(check, planned, shaped)
    assert frac == 0.25 and np.allclose(ref, 0.02)
    ref, frac = safe_reference(lambda x: (_ for _ in ()).throw(ValueError("no")), planned, shaped)
    assert frac == 0.0 and np.all(ref == planned)
    # the shaper: a limiter moving at 20 mm/s leads by 0.2 ms·T_F + 20/1.162 mm ≈ 17.4 mm, refused
    # beyond 10 mm of lead by this check: half of it is streamed, and counted
    base = np.asarray(model.neutral, float)
    rates = np.array([0.0, 0.0, 0.0, 0.02, 0.0])
    full = feedforward_reference(loops, ActuatorMotion(base, rates, rates, np.zeros(5)))
    assert full[3] - base[3] == pytest.approx(0.01 * 0.02 + (0.02 - loops[3].min_flow_pos) / 1.162, rel=1e-9)

    def lead_check(x):
        if np.any(x - base > 0.010):
            raise ValueError("lead")

    inverse = ExactInverse(model)
    at_base = MotionState(model.forward(base).pose.controlled(), np.zeros(4), np.zeros(4))
    shaper = FeedforwardShaper(loops, inverse.solve_full, lead_check)
    assert np.allclose(shaper.for_state(at_base, base, rates), base + 0.5 * (full - base))
    assert shaper.pulled_back == 1
    off = FeedforwardShaper(loops, inverse.solve_full, lead_check, enabled=False)
    assert np.all(off.for_state(at_base, base, rates) == base)


def test_jog_reference_extrapolates_the_rates_and_stops_at_zero(model):
    """A jog is known only now: v(t+L) ≈ v + L·a, and a braking jog's lead ends at zero rate."""
    loops = build_unit_loops(model.profile)
    inverse = ExactInverse(model)
    pose = np.array([0.0, 0.1, 0.0, 0.0])
    q, jac = inverse.solve_full(pose)[:2]
    shaper = FeedforwardShaper(loops, inverse.solve_full, lambda x: None)
    vz, az = 0.05, -0.2  # rising at 50 mm/s, braking at 0.2 m/s²
    st = MotionState(pose, np.array([0.0, vz, 0.0, 0.0]), np.array([0.0, az, 0.0, 0.0]))
    rates, acc = jac @ st.velocity, jac @ st.acceleration
    r = shaper.for_state(st, q, rates)
    lift = loops[0]
    v_ahead = rates[0] + lift.delay_s * acc[0]
    drive = v_ahead + lift.lag_s * acc[0]
    w = lift.min_flow_pos if drive > 0 else lift.min_flow_neg
    assert r[0] == pytest.approx(
        q[0] + lift.lag_s * rates[0] + (drive - np.sign(drive) * w) / lift.gain_per_s, rel=1e-12
    )
    # nearly stopped: v + L·a would reverse; the reference leads by no more than the lag of the rate now
    st2 = MotionState(pose, np.array([0.0, 0.005, 0.0, 0.0]), np.array([0.0, -0.2, 0.0, 0.0]))
    r2 = shaper.for_state(st2, q, jac @ st2.velocity)
    assert r2[0] == pytest.approx(q[0] + lift.lag_s * (jac @ st2.velocity)[0], rel=1e-12)


def test_jog_and_track_reference_extrapolates_with_the_jerk_when_given(model):
    """With the jerk j now, the rate and acceleration one delay L ahead are v + L·a + L²·j/2 and a + L·j
    (a Taylor step, hand-computed here per actuator through the Jacobian); without it, as before (j = 0)."""
    loops = build_unit_loops(model.profile)
    inverse = ExactInverse(model)
    pose = np.array([0.0, 0.1, 0.02, 0.0])
    q, jac = inverse.solve_full(pose)[:2]
    shaper = FeedforwardShaper(loops, inverse.solve_full, lambda x: None)
    # rolling at 20 mrad/s, the braking building up: a = -30 mrad/s², j = -300 mrad/s³
    st = MotionState(pose, np.array([0.0, 0.0, 0.02, 0.0]), np.array([0.0, 0.0, -0.03, 0.0]))
    jerk = np.array([0.0, 0.0, -0.3, 0.0])
    rates, acc, jrk = jac @ st.velocity, jac @ st.acceleration, jac @ jerk
    r = shaper.for_state(st, q, rates, jerk=jerk)
    r0 = shaper.for_state(st, q, rates)
    for i, u in enumerate(loops):
        if abs(rates[i]) < 1e-9:
            continue
        v_ahead = rates[i] + u.delay_s * acc[i] + 0.5 * u.delay_s**2 * jrk[i]
        a_ahead = acc[i] + u.delay_s * jrk[i]
        if v_ahead * rates[i] < 0:
            v_ahead = a_ahead = 0.0
        drive = v_ahead + u.lag_s * a_ahead
        w = u.min_flow_pos if drive > 0 else u.min_flow_neg
        p_part = drive - np.sign(drive) * w if abs(drive) > w else 0.0
        want = min(max(q[i] + u.lag_s * rates[i] + p_part / u.gain_per_s, u.lower), u.upper)
        assert r[i] == pytest.approx(want, rel=1e-12, abs=1e-12)
    assert np.allclose(shaper.for_state(st, q, rates, jerk=np.zeros(4)), r0, rtol=0, atol=0)
    # a braking that builds up: the velocity ahead is smaller than v + L·a, so the reference leads less (the
    # lift and tilt here; the others' leads stay within their minimum flow either way)
    assert np.all(np.abs(r - q) <= np.abs(r0 - q) + 1e-15)
    assert np.sum(np.abs(r - q) < np.abs(r0 - q) - 1e-5) >= 2
