"""Unit controller (thesis 2.56–2.57 with the ECU modifications) and end-stop relay.

Expected commands are computed by hand in the comments from thesis table 3-4
(tilt Kv_pos 0.401, Kv_neg 0.452, L 0.1 s, T_F 0.01 s, dz 5, multiplier 0.5).
"""

import math

import pytest

from bridge.sim.controller import (
    THESIS_A,
    ControllerConfig,
    ControllerError,
    RelayLimits,
    UnitController,
    build_controller_gains,
    build_relay_limits,
)
from bridge.sim.cylinder import Cylinder, CylinderParams, build_cylinder_params
from planner.profiles.hitch import load_profile

NAMES = ("lift", "tilt", "top", "left", "right")


@pytest.fixture(scope="module")
def params():
    p = load_profile("thesis-t132")
    return {n: build_cylinder_params(n, p.actuator(n)) for n in NAMES}


def test_gains_follow_thesis_2_57(params):
    assert THESIS_A == 0.581
    g = build_controller_gains(params["tilt"])
    assert g.k_pos == pytest.approx(14.488778, abs=1e-6)  # 0.581 / (0.401 · 0.1)
    assert g.k_neg == pytest.approx(12.853982, abs=1e-6)  # 0.581 / (0.452 · 0.1)
    assert g.kd_pos == pytest.approx(0.14488778, abs=1e-8)  # 0.581 · 0.01 / (0.401 · 0.1)
    assert g.kd_neg == pytest.approx(0.12853982, abs=1e-8)
    g = build_controller_gains(params["left"], a=0.3)
    assert g.k_pos == pytest.approx(0.3 / 0.11085)
    assert g.k_neg == pytest.approx(0.3 / 0.1246)
    for n in NAMES:  # k_d / k = T_F: the D term cancels the valve lag (1 + T_F s)
        g = build_controller_gains(params[n])
        assert g.kd_pos / g.k_pos == pytest.approx(params[n].time_constant_s)
        assert g.kd_neg / g.k_neg == pytest.approx(params[n].time_constant_s)


def test_hand_computed_commands(params):
    tilt = params["tilt"]
    # e = 10: 14.4888·10 = 144.89 → ×0.5 = 72.44 → +5 = 77.44 → 77
    assert UnitController(tilt).update(490, 480).command == 77
    # e = −10: 12.8540·(−10) = −128.54 → ×0.5 = −64.27 → −5 → −69.27 → −69
    assert UnitController(tilt).update(470, 480).command == -69
    # e = 20: 289.8 → saturated at 254 → ×0.5 = 127 → +5 = 132
    out = UnitController(tilt).update(500, 480)
    assert out.command == 132 and out.pd == pytest.approx(289.77556, abs=1e-4)


def test_asymmetric_p_gains(params):
    for n in NAMES:
        p = params[n]
        up = UnitController(p).update(500, 495).pd
        down = UnitController(p).update(490, 495).pd
        assert -up / down == pytest.approx(p.kv_neg / p.kv_pos)


def test_derivative_acts_on_the_measurement_not_the_error(params):
    tilt = params["tilt"]
    c = UnitController(tilt)
    assert c.update(480, 480).command == 0
    assert c.update(480, 480).command == 0
    # reference step: no derivative kick, same as a fresh controller (77, see above)
    out = c.update(490, 480)
    assert out.rate_counts_per_s == 0.0 and out.command == 77
    # measurement moves 2 counts in 10 ms: rate 200 counts/s, s = 8 − 0.01·200 = 6
    # → 14.4888·6 = 86.93 → ×0.5 = 43.47 → +5 = 48.47 → 48
    out = c.update(490, 482)
    assert out.rate_counts_per_s == pytest.approx(200.0)
    assert out.command == 48
    # braking: fast approach makes the command point backwards although e > 0
    out = c.update(490, 487)  # rate 500, s = 3 − 5 = −2 → −25.71 → ×0.5 → −12.85 → −17.85 → −18
    assert out.error_counts == 3 and out.command == -18


def test_plain_cutoff_near_the_reference(params):
    # settle_counts = cutoff_counts: the plain cut-off without hysteresis
    tilt = params["tilt"]
    plain = ControllerConfig(cutoff_counts=1, settle_counts=1)
    for r in (479, 480, 481):
        assert UnitController(tilt, plain).update(r, 480).command == 0
    # e = 2: 28.98 → 14.49 → +5 → 19.49 → 19
    assert UnitController(tilt, plain).update(482, 480).command == 19
    wide = ControllerConfig(cutoff_counts=3, settle_counts=3)
    assert UnitController(tilt, wide).update(483, 480).command == 0
    assert UnitController(tilt, wide).update(477, 480).command == 0
    assert UnitController(tilt, wide).update(484, 480).command != 0


def test_default_cutoff_settles_on_the_count_and_holds_within_one(params):
    tilt = params["tilt"]
    c = UnitController(tilt)
    cfg = c.config
    assert (cfg.settle_counts, cfg.cutoff_counts, cfg.settle_wait_s, cfg.period_s) == (0, 1, 0.2, 0.01)
    # driven: e = 1 is not close enough; 14.49·1 → ×0.5 = 7.24 → +5 = 12.24 → 12
    out = c.update(481, 480)
    assert out.command == 12 and not c.holding
    # reached: command zero, 20 periods (0.2 s) of waiting for the oil in flight, then held
    for k in range(20):
        assert c.update(481, 481).command == 0 and not c.holding, k
    assert c.update(481, 481).command == 0 and c.holding
    # settled: the reading flickers by one count (AD noise, a piston on an AD edge): held
    for y in (480, 482, 481, 480):
        assert c.update(481, y).command == 0 and c.holding
    # beyond the band: driven again. The reading moved 482 → 483 in 10 ms: rate 100,
    # s = −2 − 0.01·100 = −3 → k_neg = 0.581/(0.452·0.1) = 12.854 → −38.56 → ×0.5 = −19.28
    # → −5 = −24.28 → −24
    assert c.update(481, 482).command == 0
    assert c.update(481, 483).command == -24 and not c.holding
    # a new reference one count away is driven to, not held: no one-count final error
    c2 = UnitController(tilt, ControllerConfig(settle_wait_s=0.0))
    assert c2.update(481, 481).command == 0 and c2.holding
    out = c2.update(482, 481)
    assert out.command > 0 and not c2.holding
    assert c2.update(482, 482).command == 0 and c2.holding
    c2.reset()
    assert not c2.holding


def test_a_cylinder_that_coasts_one_count_over_is_driven_back(params):
    tilt = params["tilt"]
    c = UnitController(tilt)
    c.update(481, 479)
    assert c.update(481, 481).command == 0  # reached, waiting
    for _ in range(5):
        assert c.update(481, 482).command == 0  # coasting over, within the band: wait
    for _ in range(14):
        assert c.update(481, 482).command == 0
    out = c.update(481, 482)  # 0.2 s after reaching: still one over
    assert out.command < 0 and not c.holding  # driven back (not held one count off)


def test_dead_zone_compensation_always_leaves_the_dead_zone(params):
    left = params["left"]
    c = UnitController(left, ControllerConfig(period_s=0.03))
    c.update(300, 293)
    # rate 5/0.03 = 166.7, s = 2 − 1.667 = 0.333 → 5.2413·0.333 = 1.747 → ×0.2 = 0.349
    # → +3 = 3.349 would round to 3 (inside the dead zone); the command is 4 = dz + 1
    out = c.update(300, 298)
    assert out.command == 4
    for n in NAMES:
        p = params[n]
        mid = (p.counts_min + p.counts_max) // 2
        for e in range(2, 40):
            for sign in (1, -1):
                u = UnitController(p).update(mid + sign * e, mid).command
                assert sign * u >= p.dead_zone + 1


def test_saturation_and_multiplier(params):
    # lift: 254 · 1 + 6 = 260 → clipped to 254;  tilt, top: 127 + 5 = 132;  sway limiters: 50.8 + 3 → 54
    expected = {"lift": 254, "tilt": 132, "top": 132, "left": 54, "right": 54}
    for n, u in expected.items():
        assert UnitController(params[n]).update(1000, 100).command == u
        assert UnitController(params[n]).update(10, 900).command == -u


def test_relay_limits_and_blocking(params):
    # margin = max(2, ceil(1 % of the span)): tilt 891 → 9, lift/top 229 → 3, left 480 → 5, right 477 → 5
    expected = {"tilt": (35, 908), "lift": (29, 252), "top": (29, 252), "left": (35, 505), "right": (31, 498)}
    for n, lim in expected.items():
        r = build_relay_limits(params[n])
        assert (r.low_counts, r.high_counts) == lim
    tilt = params["tilt"]
    c = UnitController(tilt)
    out = c.update(1000, 908)
    assert out.valve_unlimited > 0 and out.relay_blocked and out.command == 0 and c.relay.engaged
    out = c.update(500, 908)  # towards safety passes
    assert out.command < 0 and not out.relay_blocked
    out = c.update(1000, 907)  # back inside: released (no hysteresis)
    assert out.command > 0 and not c.relay.engaged
    c = UnitController(tilt)
    assert c.update(0, 35).command == 0 and c.relay.engaged
    assert c.update(500, 35).command > 0


def test_relay_hysteresis(params):
    c = UnitController(params["tilt"], ControllerConfig(relay_hysteresis_counts=3))
    assert c.update(1000, 908).command == 0
    assert c.update(1000, 906).command == 0  # 906 ≥ 908 − 3 = 905: still engaged
    assert c.update(1000, 905).command == 0
    assert c.update(1000, 904).command > 0  # released below 905
    assert not c.relay.engaged


def _dde_error(t, e0, lam, delay):
    """Error of the delayed integrator loop de/dt = −λ e(t − delay), e = e0 until t = delay
    (method of steps, closed form)."""
    return e0 * sum((-lam * (t - k * delay)) ** k / math.factorial(k) for k in range(int(t // delay) + 1))


def test_linear_closed_loop_matches_the_delay_differential_equation():
    # A valve without dead zone and minimum flow, unit multiplier, no saturation
    # (k·e0 = 5.81·40 = 232 < 254): the loop is de/dt = −(a/L) e(t − L').  The lag is
    # cancelled by the D term (k_d = k T_F); the 10 ms sampling adds half a period of
    # delay, L' = L + 5 ms.
    p = CylinderParams("linear", 0.0, 1.0, 0, 1000, 1.0, 1.0, 1.0, 0.1, 0.01, 0.0, 0.0)
    cfg = ControllerConfig(cutoff_counts=0)
    cyl, ctl = Cylinder(p, initial_counts=500.0), UnitController(p, cfg)
    lam = cfg.a / p.transport_delay_s
    worst, peak = 0.0, 0.0
    for j in range(300):
        u = ctl.update(540, cyl.measure()).command
        cyl.run(u, 10)
        t = (j + 1) * cfg.period_s
        e = 540 - cyl.position_counts
        worst = max(worst, abs(e - _dde_error(t, 40.0, lam, p.transport_delay_s + cfg.period_s / 2)))
        peak = max(peak, -e)
    assert worst < 2.0  # counts, of a 40-count step (quantised measurement)
    analytic_peak = max(-_dde_error(0.001 * k, 40.0, lam, 0.105) for k in range(3000))
    assert analytic_peak > 3.0  # a = 0.581 overshoots a little (λ·L > 1/e)
    assert peak == pytest.approx(analytic_peak, abs=1.5)
    assert abs(540 - cyl.position_counts) < 1.0


def test_bad_input_and_configuration(params):
    c = UnitController(params["tilt"])
    for ref, word in ((1024, "0…1023"), (-1, "0…1023"), (500.0, "integer"), (True, "integer")):
        with pytest.raises(ControllerError, match=word):
            c.update(ref, 500)
    with pytest.raises(ControllerError, match="measurement_counts"):
        c.update(500, 2000)
    with pytest.raises(ControllerError, match="a ="):
        ControllerConfig(a=0.0)
    with pytest.raises(ControllerError, match="period_s"):
        ControllerConfig(period_s=float("nan"))
    with pytest.raises(ControllerError, match="cutoff_counts"):
        ControllerConfig(cutoff_counts=-1)
    with pytest.raises(ControllerError, match="settle_counts = 2 must not exceed cutoff_counts = 1"):
        ControllerConfig(settle_counts=2)
    with pytest.raises(ControllerError, match="settle_wait_s"):
        ControllerConfig(settle_wait_s=-0.1)
    with pytest.raises(ControllerError, match="relay_margin_counts"):
        build_relay_limits(params["top"], ControllerConfig(relay_margin_counts=150))
    with pytest.raises(ControllerError, match="low_counts"):
        RelayLimits(500, 400)
    with pytest.raises(ControllerError, match="transport_delay_s"):
        build_controller_gains(CylinderParams("x", 0.0, 1.0, 0, 1000, 1.0, 1.0, 1.0, 0.0, 0.01, 0.0, 0.0))
