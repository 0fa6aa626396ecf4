"""Valve + cylinder model (thesis 1.1) against closed-form solutions and the thesis tables."""

import math

import numpy as np
import pytest

from bridge.sim.cylinder import (
    AD_MAX_COUNTS,
    Cylinder,
    CylinderError,
    CylinderParams,
    build_cylinder_params,
    valve_flow_counts_per_s,
)
from planner.profiles.hitch import load_profile

NAMES = ("lift", "tilt", "top", "left", "right")

# Thesis table 3-4 typed in independently of the profile:
# name: (Kv_pos, Kv_neg, L, T_F, dy_min, dz); table 3-1/3-2: (min, max, AD_min, AD_max); table 3-3: multiplier.
TABLE_3_4 = {
    "tilt": (0.401, 0.452, 0.1, 0.01, 2, 5),
    "top": (0.219, 0.257, 0.1, 0.01, 2, 5),
    "lift": (0.120, 0.140, 0.1, 0.01, 2, 6),
    "right": (1.119, 1.117, 0.1, 0.01, 2, 3),
    "left": (1.1085, 1.246, 0.1, 0.01, 2, 3),
}
TABLE_3_1 = {
    "tilt": (0.580, 0.730, 26, 917),
    "top": (0.655, 0.905, 26, 255),
    "right": (0.500, 0.575, 26, 503),
    "left": (0.500, 0.580, 30, 510),
    "lift": (-0.223, 0.663, 26, 255),
}
TABLE_3_3 = {"tilt": 0.5, "top": 0.5, "lift": 1.0, "right": 0.2, "left": 0.2}


@pytest.fixture(scope="module")
def params():
    p = load_profile("thesis-t132")
    return {n: build_cylinder_params(n, p.actuator(n)) for n in NAMES}


def closed_form_position(x0, qc, t, L, T):
    """Position of K/(s(1+Ts)) e^(-sL) after a step in flow demand qc at t = 0, from rest."""
    tau = t - L
    if tau <= 0:
        return x0
    return x0 + qc * (tau - T * (1.0 - math.exp(-tau / T)))


def test_parameters_are_the_thesis_tables(params):
    for n in NAMES:
        p = params[n]
        kvp, kvn, L, T, dymin, dz = TABLE_3_4[n]
        assert (p.kv_pos, p.kv_neg, p.transport_delay_s, p.time_constant_s, p.min_flow, p.dead_zone) == (
            kvp,
            kvn,
            L,
            T,
            dymin,
            dz,
        )
        assert (p.stroke_min, p.stroke_max, p.counts_min, p.counts_max) == TABLE_3_1[n]
        assert p.valve_multiplier == TABLE_3_3[n]


def test_calibration_is_linear_through_the_stroke_ends(params):
    tilt = params["tilt"]
    assert tilt.counts_to_si(26) == pytest.approx(0.580, abs=1e-12)
    assert tilt.counts_to_si(917) == pytest.approx(0.730, abs=1e-12)
    # 655 mm is the middle of 580…730 mm → middle of 26…917 counts
    assert tilt.si_to_counts(0.655) == pytest.approx(471.5, abs=1e-9)
    # 891 counts over 150 mm
    assert tilt.counts_per_unit == pytest.approx(891 / 0.150)
    rng = np.random.default_rng(1)
    for n in NAMES:
        p = params[n]
        for v in p.stroke_min + (p.stroke_max - p.stroke_min) * rng.random(20):
            assert p.counts_to_si(p.si_to_counts(v)) == pytest.approx(v, abs=1e-12)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("u", [120, -120, 40, -254])
def test_open_loop_step_matches_closed_form(params, name, u):
    p = params[name]
    x0 = 0.5 * (p.counts_min + p.counts_max)
    cyl = Cylinder(p, initial_counts=x0)
    kv = p.kv_pos if u > 0 else p.kv_neg
    qc = math.copysign(kv * (abs(u) - p.dead_zone + p.min_flow), u)
    assert valve_flow_counts_per_s(p, u) == pytest.approx(qc, rel=1e-15)
    t_end = 0.6
    n = int(round(t_end / cyl.step_s))
    checked = 0
    for k in range(1, n + 1):
        cyl.step(u)
        t = k * cyl.step_s
        expected = closed_form_position(x0, qc, t, p.transport_delay_s, p.time_constant_s)
        if p.counts_min < expected < p.counts_max:
            assert cyl.position_counts == pytest.approx(expected, abs=1e-9), t
            checked += 1
    assert checked == n
    # nothing moves during the 100 ms transport delay, then the slope is Kv·(|u| − dz + dy_min)
    assert cyl.delay_steps == 100
    c2 = Cylinder(p, initial_counts=x0)
    c2.run(u, 100)
    assert c2.position_counts == x0
    c2.run(u, 200)  # 20 time constants after the delay: lag settled
    assert c2.flow_counts_per_s == pytest.approx(qc, rel=1e-8)
    before = c2.position_counts
    c2.run(u, 100)
    assert (c2.position_counts - before) / 0.1 == pytest.approx(qc, rel=1e-8)


def test_integration_is_exact_independent_of_step(params):
    p = params["tilt"]
    a = Cylinder(p, step_s=1e-3, initial_counts=400.0)
    b = Cylinder(p, step_s=2.5e-4, initial_counts=400.0)
    for u in (80, -30, 200, 0, -150):  # commands on a 10 ms grid
        a.run(u, 10)
        b.run(u, 40)
    a.run(0, 300)
    b.run(0, 1200)
    assert a.position_counts == pytest.approx(b.position_counts, abs=1e-9)


@pytest.mark.parametrize("name", NAMES)
def test_dead_zone_gives_no_motion_and_minimum_flow_beyond(params, name):
    p = params[name]
    dz = int(p.dead_zone)
    for u in range(-dz, dz + 1):
        cyl = Cylinder(p, initial_counts=p.counts_min + 100)
        cyl.run(u, 2000)
        assert cyl.position_counts == p.counts_min + 100
        assert valve_flow_counts_per_s(p, u) == 0.0
    # just outside the dead zone the flow is Kv·(1 + dy_min), not Kv·(dz + 1)
    assert valve_flow_counts_per_s(p, dz + 1) == pytest.approx(p.kv_pos * (1 + p.min_flow))
    assert valve_flow_counts_per_s(p, -dz - 1) == pytest.approx(-p.kv_neg * (1 + p.min_flow))


def test_direction_dependent_gains(params):
    for n in NAMES:
        p = params[n]
        up = Cylinder(p, initial_counts=p.counts_min + 0.5 * (p.counts_max - p.counts_min))
        down = Cylinder(p, initial_counts=up.position_counts)
        x0 = up.position_counts
        up.run(60, 500)
        down.run(-60, 500)
        ratio = (up.position_counts - x0) / (x0 - down.position_counts)
        assert ratio == pytest.approx(p.kv_pos / p.kv_neg, rel=1e-9)


def test_gain_error_scales_the_slope(params):
    p = params["top"]
    nominal = Cylinder(p, initial_counts=100.0)
    fast = Cylinder(p, initial_counts=100.0, gain_error=0.25)
    nominal.run(100, 400)
    fast.run(100, 400)
    assert (fast.position_counts - 100.0) == pytest.approx(1.25 * (nominal.position_counts - 100.0), rel=1e-12)


@pytest.mark.parametrize("name", NAMES)
def test_end_stops_hold(params, name):
    p = params[name]
    cyl = Cylinder(p, initial_counts=p.counts_max - 10)
    cyl.run(254, 3000)
    assert cyl.position_counts == p.counts_max
    assert cyl.measure() == p.counts_max
    # reversing: the piston leaves the stop only after the transport delay
    cyl.run(-254, 100)
    assert cyl.position_counts == p.counts_max
    cyl.run(-254, 50)
    assert cyl.position_counts < p.counts_max
    cyl.run(-254, 20000)
    assert cyl.position_counts == p.counts_min
    assert cyl.measure() == p.counts_min


def test_ad_quantisation(params):
    p = params["tilt"]
    cyl = Cylinder(p, initial_counts=100.0)
    seen = []
    for _ in range(3000):
        cyl.step(20)
        m = cyl.measure()
        assert isinstance(m, int)
        assert abs(m - cyl.position_counts) <= 0.5
        assert m == math.floor(cyl.position_counts + 0.5)
        seen.append(m)
    # a slow monotone ramp visits every integer between start and end exactly in order
    uniq = sorted(set(seen))
    assert uniq == list(range(uniq[0], uniq[-1] + 1))
    assert uniq[-1] - uniq[0] > 10


def test_noise_is_reproducible_and_has_the_requested_spread(params):
    p = params["tilt"]

    def samples(seed):
        cyl = Cylinder(p, initial_counts=400.25, noise_counts=2.0, rng=np.random.default_rng(seed))
        return np.array([cyl.measure() for _ in range(20000)])

    a, b, c = samples(5), samples(5), samples(6)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    # Gaussian σ = 2 plus uniform quantisation error (variance 1/12)
    assert a.std() == pytest.approx(math.sqrt(4 + 1 / 12), rel=0.03)
    assert a.mean() == pytest.approx(400.25, abs=0.05)
    assert a.min() >= 0 and a.max() <= AD_MAX_COUNTS


def test_zero_time_constant_is_a_pure_delayed_integrator():
    p = CylinderParams("x", 0.0, 1.0, 0, 1000, 1.0, 1.0, 2.0, 0.05, 0.0, 0.0, 0.0)
    cyl = Cylinder(p, initial_counts=500.0)
    cyl.run(100, 50)
    assert cyl.position_counts == 500.0
    cyl.run(100, 100)
    assert cyl.position_counts == pytest.approx(500.0 + 100 * 0.1)
    cyl.run(-100, 150)
    assert cyl.position_counts == pytest.approx(500.0 + 100 * 0.15 - 200 * 0.1)


def test_bad_input_is_rejected_with_a_named_field(params):
    p = params["tilt"]
    cyl = Cylinder(p)
    for u, word in ((255, "254"), (-300, "254"), (1.5, "integer"), (True, "integer")):
        with pytest.raises(CylinderError, match=word):
            cyl.step(u)
    with pytest.raises(CylinderError, match="gain_error"):
        Cylinder(p, gain_error=-1.0)
    with pytest.raises(CylinderError, match="rng"):
        Cylinder(p, noise_counts=1.0)
    with pytest.raises(CylinderError, match="noise_counts"):
        Cylinder(p, noise_counts=float("nan"), rng=np.random.default_rng(0))
    with pytest.raises(CylinderError, match="initial_counts"):
        Cylinder(p, initial_counts=1000.0)
    with pytest.raises(CylinderError, match="stroke"):
        p.si_to_counts(0.9)
    with pytest.raises(CylinderError, match="0…1023"):
        p.counts_to_si(1024)
    with pytest.raises(CylinderError, match="finite"):
        p.counts_to_si(float("nan"))
    with pytest.raises(CylinderError, match="counts_min"):
        CylinderParams("bad", 0.0, 1.0, 500, 400, 1.0, 1.0, 1.0, 0.1, 0.01, 2, 3)
    with pytest.raises(CylinderError, match="valve_multiplier"):
        CylinderParams("bad", 0.0, 1.0, 0, 400, 1.5, 1.0, 1.0, 0.1, 0.01, 2, 3)


@pytest.mark.parametrize("name", NAMES)
def test_run_equals_as_many_steps_bit_for_bit(params, name):
    """``run(u, n)`` (which skips the integration at rest) leaves exactly the state of ``n`` calls of
    ``step(u)``: position, flow, held command and the transport-delay line, over random command runs
    that start, stop, stay inside the dead zone and wait out the delay (after a move the lag's flow
    stops changing in floating point only after some 7 s: the long runs reach true rest)."""
    p = params[name]
    rng = np.random.default_rng(11)
    a, b = Cylinder(p), Cylinder(p)  # mid-stroke
    choices = (0, 0, 1, -1, p.dead_zone, -p.dead_zone, p.dead_zone + 1, 40, -90)
    d = a.delay_steps
    # short pulses from true rest, followed by quiet runs shorter and longer than the transport delay
    pulses = [(u, n) for k in (1, 3, d - 1) for u, n in ((40, k), (0, d - k - 1), (0, 3), (0, 9000))]
    runs = pulses + [
        (int(rng.choice(choices)), int(rng.integers(0, 250)) if rng.random() < 0.5 else 9000)  # 9000: lag settles
        for _ in range(300)
    ]
    rests = 0
    for u, n in runs:
        rests += a.settled() and abs(u) <= p.dead_zone and n > 0
        a.run(u, n)
        for _ in range(n):
            b.step(u)
        assert a.position_counts == b.position_counts
        assert a.flow_counts_per_s == b.flow_counts_per_s
        assert a.valve_command == b.valve_command
        assert list(a._line) == list(b._line)  # noqa: SLF001 — the delay line is the state that matters here
    assert rests >= 20  # the runs at true rest (the skipped integration) were exercised
