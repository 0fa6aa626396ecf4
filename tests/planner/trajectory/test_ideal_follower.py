"""The ideal follower: the sine gain's closed form, its bandwidth, and the QP follower of sampled signals.

Truth used: the actuator Jacobian column by central finite differences of the exact inverse (not
the CasADi Jacobian the module uses); the ω-power law of each limited region; a bisection of the
gain for the −3 dB point; finite differences of the follower's output against the DOF's bounds.
"""

import math

import numpy as np
import pytest

from planner.errors import HitchInputError
from planner.model.types import ACTUATOR_NAMES
from planner.trajectory import TrajectoryPlanner
from planner.trajectory.ideal_follower import IdealFollower, dof_limits, ideal_bandwidth_hz, ideal_sine_gain

DOFS = ("x", "z", "roll", "pitch")


@pytest.fixture(scope="module")
def tp(model):
    return TrajectoryPlanner(model)


def fd_limits(tp, d):
    """The DOF's (v, a, j) limits from a finite-difference Jacobian column at the neutral pose."""
    p = np.clip(tp.model.neutral_pose.controlled(), tp.lo, tp.hi)
    h = 1e-6
    e = np.eye(4)[d] * h
    col = (tp.inverse.solve(p + e)[0] - tp.inverse.solve(p - e)[0]) / (2 * h)
    a = np.abs(col)
    on = a > 1e-9
    L = tp.limits
    return tuple(float(np.min(x[on] / a[on])) for x in (L.velocity, L.acceleration, L.jerk))


@pytest.mark.parametrize("d", range(4))
def test_the_dof_limits_are_the_tightest_actuator_through_the_jacobian(tp, d):
    lim = dof_limits(tp, DOFS[d])
    np.testing.assert_allclose((lim.velocity, lim.acceleration, lim.jerk), fd_limits(tp, d), rtol=1e-5)
    assert all(n.split(":")[1] in ACTUATOR_NAMES for n in lim.names)


@pytest.mark.parametrize("d", range(4))
def test_gain_is_one_at_low_frequency_and_follows_the_power_laws(tp, d):
    dof, amp = DOFS[d], 0.01
    v, a, j = fd_limits(tp, d)
    assert ideal_sine_gain(tp, dof, amp, 0.01).gain == 1.0
    assert ideal_sine_gain(tp, dof, amp, 0.01).limit == ""
    # jerk-limited well above the corners: g = j / (A ω³), so doubling f divides g by 8
    hi = 4 * max(j / a, a / v) / (2 * math.pi)
    g1, g2 = ideal_sine_gain(tp, dof, amp, hi), ideal_sine_gain(tp, dof, amp, 2 * hi)
    assert g1.limit.startswith("jerk:") and g2.limit.startswith("jerk:")
    assert g1.gain == pytest.approx(j / (amp * (2 * math.pi * hi) ** 3), rel=1e-5)
    assert g1.gain / g2.gain == pytest.approx(8.0, rel=1e-9)


def test_velocity_and_acceleration_regions(tp):
    # roll at a large amplitude: velocity binds between v/A and a/v, acceleration between a/v and j/a
    v, a, j = fd_limits(tp, 2)
    amp = 0.2
    assert v / amp < a / v < j / a
    fv = math.sqrt(v / amp * a / v) / (2 * math.pi)  # geometric middle of the velocity region
    gv1, gv2 = ideal_sine_gain(tp, "roll", amp, fv), ideal_sine_gain(tp, "roll", amp, 1.2 * fv)
    assert gv1.limit == gv2.limit == "velocity:tilt"
    assert gv1.gain == pytest.approx(v / (amp * 2 * math.pi * fv), rel=1e-5)
    assert gv1.gain / gv2.gain == pytest.approx(1.2, rel=1e-9)  # ∝ 1/ω
    fa = math.sqrt(a / v * j / a) / (2 * math.pi)
    ga1, ga2 = ideal_sine_gain(tp, "roll", amp, fa), ideal_sine_gain(tp, "roll", amp, 1.2 * fa)
    assert ga1.limit == ga2.limit == "acceleration:tilt"
    assert ga1.gain / ga2.gain == pytest.approx(1.44, rel=1e-9)  # ∝ 1/ω²


@pytest.mark.parametrize("d", range(4))
@pytest.mark.parametrize("amp", [0.002, 0.02, 0.2])
def test_bandwidth_is_where_the_gain_is_minus_3_db(tp, d, amp):
    bw = ideal_bandwidth_hz(tp, DOFS[d], amp)
    lo, hi = 1e-4, 100.0  # bisection on the gain itself
    for _ in range(100):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if ideal_sine_gain(tp, DOFS[d], amp, mid).gain > 1 / math.sqrt(2) else (lo, mid)
    assert bw == pytest.approx(lo, rel=1e-6)
    assert ideal_sine_gain(tp, DOFS[d], amp, bw).gain == pytest.approx(1 / math.sqrt(2), rel=1e-9)


@pytest.mark.parametrize(
    "call",
    [
        lambda tp: ideal_sine_gain(tp, "yaw", 0.01, 1.0),
        lambda tp: ideal_sine_gain(tp, "x", 0.0, 1.0),
        lambda tp: ideal_sine_gain(tp, "x", 0.01, math.nan),
        lambda tp: ideal_bandwidth_hz(tp, "x", -1.0),
        lambda tp: IdealFollower(tp, "x").follow([0, 1, 2], [0, 0, 0]),
        lambda tp: IdealFollower(tp, "x").follow([0, 1, 3, 4], [0, 0, 0, 0]),
        lambda tp: IdealFollower(tp, "x").follow([0, 1, 2, 3], [0, math.nan, 0, 0]),
    ],
)
def test_bad_input_is_refused(tp, call):
    with pytest.raises(HitchInputError):
        call(tp)


def test_the_qp_follower_reproduces_a_feasible_signal_and_bounds_an_infeasible_one(tp):
    fol = IdealFollower(tp, "z")
    lim = fol.limits
    dt = 0.02
    t = np.arange(120) * dt
    w = 2 * math.pi * 0.2
    amp = 0.3 * min(lim.velocity / w, lim.acceleration / w**2, lim.jerk / w**3)
    z0 = 0.1
    feasible = z0 + amp * np.sin(w * t)
    out = fol.follow(t, feasible)
    assert out.max_error <= 1e-6 * amp
    # a step plus noise: far beyond the bounds; the follower keeps to them (finite differences)
    rng = np.random.default_rng(3)
    bad = z0 + np.where(t > 1.0, 0.05, 0.0) + rng.normal(0, 0.005, t.size)
    res = fol.follow(t, bad)  # the same instance, the same size: only the cost is updated
    x = res.x
    tol = 1 + 1e-5
    assert np.max(np.abs(np.diff(x)) / dt) <= lim.velocity * tol
    assert np.max(np.abs(np.diff(x, 2)) / dt**2) <= lim.acceleration * tol
    assert np.max(np.abs(np.diff(x, 3)) / dt**3) <= lim.jerk * tol
    assert res.rms_error < np.sqrt(np.mean((bad - np.mean(bad)) ** 2))  # better than standing still
    assert res.max_error > 1e-3  # it could not follow the step


def test_the_qp_follower_keeps_to_position_bounds_and_follows_exactly_inside_them(tp):
    """A slow sine (within the rate bounds) twice as wide as a box: the bounded follower stays in the box
    (to the solver's tolerance), follows the sine exactly where it is well inside, and rests on the face
    where the sine is beyond it; without bounds the same signal is reproduced (it leaves the box)."""
    fol = IdealFollower(tp, "roll")
    lim = fol.limits
    dt = 0.02
    t = np.arange(1500) * dt
    w = 2 * math.pi * 0.05
    amp = 0.2 * min(lim.velocity / w, lim.acceleration / w**2)
    s = amp * np.sin(w * t)
    lo, hi = -amp / 2, amp / 2
    free = fol.follow(t, s)
    assert free.max_error <= 1e-5 * amp and free.x.max() > hi + 0.4 * amp
    boxed = fol.follow(t, s, lower=lo, upper=hi)
    x = boxed.x
    assert x.min() >= lo - 1e-6 * amp and x.max() <= hi + 1e-6 * amp
    inside = np.abs(s) < 0.3 * amp
    assert np.max(np.abs(x - s)[inside]) <= 1e-4 * amp
    beyond = np.abs(s) > 0.7 * amp
    assert np.max(np.abs(x - np.clip(s, lo, hi))[beyond]) <= 1e-4 * amp
    tol = 1 + 1e-4
    assert np.max(np.abs(np.diff(x)) / dt) <= lim.velocity * tol
    assert np.max(np.abs(np.diff(x, 2)) / dt**2) <= lim.acceleration * tol
    with pytest.raises(HitchInputError, match="both"):
        fol.follow(t, s, lower=lo)
    with pytest.raises(HitchInputError, match="lower < upper"):
        fol.follow(t, s, lower=hi, upper=lo)
