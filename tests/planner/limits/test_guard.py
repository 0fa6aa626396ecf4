"""Guard: refusal at the right sample, improving motions allowed, caution slow-down, keep-outs,
end-stop zone, kinematic margin, jog evaluated ahead, and the stability CLI."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.limits.end_stop import EndStopZone
from planner.limits.guard import Guard, GuardRefusal
from planner.limits.stability import StabilityThresholds
from planner.limits.tractor import load_tractor_profile
from planner.model.kinematics import HitchModel
from planner.profiles.hitch import load_profile, profile_from_dict
from planner.trajectory import MotionState, TrajectoryPlanner

DOFS = ("x", "z", "roll", "pitch")
SLOPE = 0.35  # rad of side slope (left side up)
ESM_HARD = 5000.0


@pytest.fixture(scope="module")
def ballasted():
    d = load_profile().model_dump()
    d["stability"]["front_ballast"] = 800.0  # the heavy implement needs front ballast for the 20 % rule
    return HitchModel(profile_from_dict(d))


@pytest.fixture(scope="module")
def heavy():
    return load_tractor_profile().implement("cat2-power-harrow-1500")


@pytest.fixture
def guard(ballasted, heavy):
    g = Guard(
        TrajectoryPlanner(ballasted),
        implement=heavy,
        thresholds=StabilityThresholds(esm_hard=ESM_HARD, esm_caution=ESM_HARD),
    )
    g.set_slope(SLOPE, 0.0)
    return g


def esm_at_height(g, z):
    return g.stability_at(g.planner.inverse(0.0, z, 0.0, 0.0)).esm


def test_lifting_a_heavy_implement_on_a_slope_is_refused_at_the_right_sample(guard):
    tp = guard.planner
    lo, hi = tp.lo[1], tp.hi[1]
    # independent truth: the height where ESM crosses the threshold (ESM falls as the CoM rises)
    a, b = lo, hi
    assert esm_at_height(guard, a) > ESM_HARD > esm_at_height(guard, b)
    for _ in range(60):
        mid = (a + b) / 2
        a, b = (mid, b) if esm_at_height(guard, mid) > ESM_HARD else (a, mid)
    z_cross = (a + b) / 2
    with pytest.raises(GuardRefusal) as exc:
        guard.plan(MotionState.at_rest([0.0, lo, 0.0, 0.0]), {"z": hi})
    dec = exc.value.decision
    assert dec.action == "refused"
    first = dec.reasons[0]
    assert first.measure == "esm" and first.level == "hard" and first.threshold == ESM_HARD and first.value < ESM_HARD
    assert "esm would be" in str(exc.value) and f"t = {first.t_s:.2f} s" in str(exc.value)
    assert first.unit == "J" and f"(threshold {ESM_HARD:.4g} J)" in str(exc.value)  # the SI unit, named
    # the refusal names the first sample past the crossing height
    plan = guard.planner.plan_move(MotionState.at_rest([0.0, lo, 0.0, 0.0]), {"z": hi})
    sp = plan.setpoints
    k = int(np.flatnonzero(np.isclose(sp.t, first.t_s))[0])
    assert sp.pose[k, 2] >= z_cross - 1e-9 and sp.pose[k - 1, 2] < z_cross


def test_lowering_it_is_allowed_even_from_below_the_threshold(guard):
    tp = guard.planner
    start = MotionState.at_rest([0.0, tp.hi[1], 0.0, 0.0])
    assert esm_at_height(guard, tp.hi[1]) < ESM_HARD  # already low: a motion that improves it is allowed
    gp = guard.plan(start, {"z": tp.lo[1]})
    assert gp.decision.action in ("ok", "scaled")
    assert not [r for r in gp.decision.reasons if r.level == "hard"]


def test_caution_slows_the_motion(ballasted, heavy):
    g = Guard(
        TrajectoryPlanner(ballasted),
        implement=heavy,
        thresholds=StabilityThresholds(esm_hard=100.0, esm_caution=50_000.0),
    )
    start = MotionState.at_rest([0.0, g.planner.lo[1], 0.0, 0.0])
    gp = g.plan(start, {"z": 0.2})
    fast = g.planner.plan_move(start, {"z": 0.2})
    assert gp.decision.action == "scaled" and gp.decision.speed_factor == pytest.approx(0.8)
    assert any(r.measure == "esm" and r.level == "caution" for r in gp.decision.reasons)
    assert gp.plan.duration > fast.duration * 1.2


class _CountingPlanner:
    """Counts ``plan_move`` calls of a TrajectoryPlanner (the guard's plans) while in ``with``."""

    def __init__(self, tp):
        self.tp, self.calls = tp, 0

    def __enter__(self):
        orig = self.tp.plan_move

        def plan_move(*a, **k):
            self.calls += 1
            return orig(*a, **k)

        self.tp.plan_move = plan_move
        return self

    def __exit__(self, *exc):
        del self.tp.plan_move  # the class's method again


def test_a_goal_in_the_caution_band_is_planned_once_at_the_caution_speed(ballasted, heavy):
    """Every plan's last sample is its goal: a goal below the caution threshold (and worse than the
    start) makes the full-speed plan a throw-away. It was planned, sampled and checked first (two plans
    for every cautioned move of a heavy implement); now the move is planned at the caution factor at once,
    and its caution reason names a sample of the plan returned, with that sample's own value."""
    g = Guard(
        TrajectoryPlanner(ballasted),
        implement=heavy,
        thresholds=StabilityThresholds(esm_hard=100.0, esm_caution=50_000.0),
    )
    start, goal = MotionState.at_rest([0.0, g.planner.lo[1], 0.0, 0.0]), {"z": 0.2}
    with _CountingPlanner(g.planner) as counted:
        gp = g.plan(start, goal)
    assert counted.calls == 1  # two before
    assert [r.measure for r in g.caution_at_goal(start, goal)] == ["esm"]  # raising lowers the ESM
    assert gp.decision.action == "scaled" and gp.decision.speed_factor == 0.8
    slow = g.planner.plan_move(start, goal, speed_scale=0.8).sampled()
    np.testing.assert_array_equal(gp.setpoints.actuators, slow.actuators)  # the plan it was before, bit for bit
    (reason,) = [r for r in gp.decision.reasons if r.level == "caution"]
    k = int(np.flatnonzero(gp.setpoints.t == reason.t_s)[0])
    assert reason.measure == "esm" and reason.value == g.stability_at(gp.setpoints.actuators[k]).esm
    assert reason.value < 50_000.0 and k > 0


def test_no_caution_is_foreseen_for_a_goal_that_improves_a_low_start_or_is_refused(ballasted, heavy):
    g = Guard(
        TrajectoryPlanner(ballasted),
        implement=heavy,
        thresholds=StabilityThresholds(esm_hard=100.0, esm_caution=50_000.0),
    )
    lo, hi = g.planner.lo[1], g.planner.hi[1]
    assert g.caution_at_goal(MotionState.at_rest([0.0, hi, 0.0, 0.0]), {"z": lo}) == ()  # lowering: better
    with _CountingPlanner(g.planner) as counted:
        gp = g.plan(MotionState.at_rest([0.0, hi, 0.0, 0.0]), {"z": lo})
    assert gp.decision.action == "ok" and counted.calls == 1
    hard = Guard(
        TrajectoryPlanner(ballasted),
        implement=heavy,
        thresholds=StabilityThresholds(esm_hard=50_000.0, esm_caution=60_000.0),
    )
    assert hard.caution_at_goal(MotionState.at_rest([0.0, lo, 0.0, 0.0]), {"z": hi}) == ()  # refused: the plan says so
    assert g.caution_at_goal(MotionState.at_rest([0.0, lo, 0.0, 0.0]), {"z": 9.0}) == ()  # outside: planning says why


def _z_at_lift_lower_end(model) -> float:
    """The height z (x, roll, pitch 0) where the lift is a hair (1e-5 rad) above its lower end stop: bisection
    (the lift grows with z), from just above."""
    tp, target = TrajectoryPlanner(model), model.lower[0] + 1e-5
    a, b = -0.35, 0.0
    for _ in range(80):
        mid = (a + b) / 2
        a, b = (mid, b) if tp.inverse(0, mid, 0, 0)[0] < target else (a, mid)
    return b


def test_an_end_stop_slowing_and_a_foreseen_caution_multiply(ballasted, heavy):
    """A cautioned move into the lift's end-stop zone: the end-stop-limited speed × the caution factor,
    as when the full-speed plan is checked first (0.8 × 0.7724 = 0.6180 then, 0.6178 now), every
    sample within the zone speed, and the end-stop factor stated relative to the speed asked for."""
    b = _z_at_lift_lower_end(ballasted)
    tp = TrajectoryPlanner(ballasted, workspace=dict(ballasted.workspace, z=(b, ballasted.workspace["z"][1])))
    start, goal = MotionState.at_rest([0.06, -0.15, 0.0, 0.0]), {"x": -0.06, "z": b}

    def guard(esm_caution):
        g = Guard(tp, implement=heavy, thresholds=StabilityThresholds(esm_hard=100.0, esm_caution=esm_caution))
        g.set_slope(SLOPE, 0.0)
        return g

    plain = guard(100.0)  # no caution band
    e0, e1 = (plain.stability_at(tp.inverse(*p)).esm for p in (start.position, [-0.06, b, 0.0, 0.0]))
    assert e1 < e0  # the goal is the less stable end
    ref = plain.plan(start, goal)
    cautious = guard((e0 + e1) / 2)
    gp = cautious.plan(start, goal)
    assert [r.measure for r in ref.decision.reasons] == ["end_stop:lift"]
    assert [r.measure for r in gp.decision.reasons] == ["end_stop:lift", "esm"]
    assert gp.decision.speed_factor == pytest.approx(0.8 * ref.decision.speed_factor, rel=2e-3)
    assert gp.decision.reasons[0].value == pytest.approx(ref.decision.reasons[0].value, rel=2e-3)
    zone = cautious.end_stops
    for q, qd in zip(gp.setpoints.actuators, gp.setpoints.actuator_velocity, strict=True):
        assert np.all(np.abs(qd) <= zone.allowed_speed(q, np.sign(qd)) + 1e-9)


def test_keep_out_refuses_motion_into_it(model):
    d = model.profile.model_dump()
    # a coupler block right where the top link passes when the implement is lifted
    d["limits"]["keep_out"] = [{"name": "couplers", "centre": [0.0, 0.45, 0.70], "radius": 0.05}]
    m = HitchModel(profile_from_dict(d))
    g = Guard(TrajectoryPlanner(m))
    ko = g.keep_out[0]
    dists = [g.keep_out_clearance(g.planner.inverse(0, z, 0, 0))[0][1] for z in (g.planner.lo[1], g.planner.hi[1])]
    assert dists[0] > ko[2] > dists[1]  # clear when low, inside when high
    with pytest.raises(GuardRefusal, match="keep_out:couplers") as exc:
        g.plan(MotionState.at_rest([0, g.planner.lo[1], 0, 0]), {"z": g.planner.hi[1]})
    assert exc.value.decision.reasons[0].unit == "m" and "(threshold 0.05 m)" in str(exc.value)


def test_end_stop_zone_by_hand():
    z = EndStopZone(np.zeros(5), np.ones(5), np.full(5, 2.0), zone_fraction=0.1)
    q = np.array([0.5, 0.975, 0.025, 0.95, 0.0])
    # moving towards the near end: allowed 2·sqrt(d/0.1)
    allow = z.allowed_speed(q, np.array([1, 1, -1, -1, -1]))
    np.testing.assert_allclose(allow, [2.0, 2 * np.sqrt(0.25), 2 * np.sqrt(0.25), 2.0, 0.0])
    f, i = z.speed_factor(q, np.array([0.0, 2.0, 0.0, 0.0, 0.0]))
    assert f == pytest.approx(0.5) and i == 1
    assert z.speed_factor(q, np.array([0.0, -2.0, 0.0, 0.0, 0.0])) == (1.0, None)  # away from the end


def test_plan_into_an_end_stop_is_slowed(model):
    """A goal a hair above the lift's lower end stop: within the last 5 % of the stroke the
    lift must crawl, so the guard slows the plan and every sample keeps to the zone speed."""
    target = model.lower[0] + 1e-5
    z_end = _z_at_lift_lower_end(model)
    ws = dict(model.workspace, z=(z_end, model.workspace["z"][1]))
    g = Guard(TrajectoryPlanner(model, workspace=ws))
    gp = g.plan(MotionState.at_rest([0, 0.1, 0, 0]), {"z": z_end})
    assert gp.decision.action == "scaled" and gp.decision.reasons[0].measure == "end_stop:lift"
    assert gp.setpoints.actuators[-1][0] == pytest.approx(target, abs=1e-9)
    zone = g.end_stops
    for q, qd in zip(gp.setpoints.actuators, gp.setpoints.actuator_velocity, strict=True):
        assert np.all(np.abs(qd) <= zone.allowed_speed(q, np.sign(qd)) + 1e-9)


def test_kinematic_margin_by_hand(model):
    g = Guard(TrajectoryPlanner(model))
    p = model.neutral_pose.controlled()
    v = np.array([0.01, 0.0, 0.0, 0.0])  # 1 cm/s to the left
    q, jac, _ = g.planner.inverse.solve_full(p)
    km = g.margin(q, jac @ v)
    assert km.per_dof["x"]["limit"] == "workspace:x:max"
    assert km.per_dof["x"]["time_s"] == pytest.approx((g.planner.hi[0] - p[0]) / 0.01, rel=1e-9)
    assert km.time_s <= km.per_dof["x"]["time_s"] and km.limit
    assert g.margin(q, np.zeros(5)).time_s == float("inf")


def test_jog_is_evaluated_one_second_ahead(guard):
    tp = guard.planner
    z_mid = 0.5 * (tp.lo[1] + tp.hi[1])
    # find a height just below the crossing: lifting for 1 s would cross it, lowering improves
    zs = np.linspace(tp.lo[1], tp.hi[1], 60)
    z0 = next(z for z in zs if esm_at_height(guard, z + 0.03) < ESM_HARD)
    state = MotionState.at_rest([0.0, z0, 0.0, 0.0])
    rates, dec = guard.check_jog(state, np.array([0.0, 0.03, 0.0, 0.0]))
    assert dec.action == "refused" and np.all(rates == 0) and dec.reasons[0].measure == "esm"
    rates, dec = guard.check_jog(state, np.array([0.0, -0.03, 0.0, 0.0]))
    assert dec.action == "ok" and rates[1] == pytest.approx(-0.03)
    assert z_mid  # the mid height exists (sanity of the fixture geometry)


def test_stability_cli_json():
    hitch = str(Path(sys.executable).with_name("hitch"))
    r = subprocess.run(
        [hitch, "stability", "--pose", "z=0.2", "--slope-roll", "0.1", "--implement", "cat2-spreader-400", "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert set(d) >= {"axle_loads", "front_axle_share", "ssm", "lsm", "esm", "min_front_ballast", "ok", "violations"}
    assert set(d["axle_loads"]) == {"front", "rear"}
    total = d["axle_loads"]["front"] + d["axle_loads"]["rear"]
    assert d["front_axle_share"] == pytest.approx(d["axle_loads"]["front"] / total)
    assert d["ok"] is True


def test_an_implement_name_for_the_record_is_refused_saying_how_to_get_one(ballasted, heavy):
    """A new user's trial: ``Guard(planner, implement="cat2-power-harrow-1500")`` was accepted and the first plan
    crashed with "'str' object has no attribute 'centre_of_mass'"."""
    from planner.errors import HitchInputError

    tp = TrajectoryPlanner(ballasted)
    with pytest.raises(
        HitchInputError,
        match=r"implement must be an ImplementRecord or None, got str "
        r"'cat2-power-harrow-1500'; get the record from its tractor profile: "
        r"load_tractor_profile\('tractor-6t'\)\.implement\('cat2-power-harrow-1500'\)",
    ):
        Guard(tp, implement="cat2-power-harrow-1500")
    g = Guard(tp, implement=heavy)
    with pytest.raises(HitchInputError, match=r"implement must be an ImplementRecord or None, got dict"):
        g.set_implement({"mass": 1500.0})
    assert g.implement is heavy  # the refused one did not replace it
    g.set_implement(None)
    assert g.implement is None


def test_in_zone_by_hand():
    z = EndStopZone(np.zeros(5), np.ones(5), np.full(5, 2.0), zone_fraction=0.1)
    q = np.array([0.5, 0.95, 0.05, 0.5, 0.5])
    up, down = np.ones(5), -np.ones(5)
    assert [z.in_zone(q, up, i) for i in range(5)] == [False, True, False, False, False]
    assert [z.in_zone(q, down, i) for i in range(5)] == [False, False, True, False, False]
    assert z.in_zone(np.array([np.nan, 0, 0, 0, 0]), up, 0)  # fail closed


def test_a_jog_faster_than_an_actuator_mid_stroke_is_named_for_its_speed_not_its_end_stop(model):
    """An operator trial: `hitch jog --vz 0.2` with the lift at 40 % said "lift arm slowing before its stroke end
    [end_stop:lift]": the factor below 1 was the lift's plain speed limit, far from either end. Now the reason is
    velocity:<actuator> outside the end-stop zone and end_stop:<actuator> inside it."""
    guard = Guard(TrajectoryPlanner(model))
    tp = guard.planner
    mid = MotionState.at_rest([0.0, tp.lo[1] + 0.4 * (tp.hi[1] - tp.lo[1]), 0.0, 0.0])  # the lift at ~40 %
    q_mid = tp.inverse(*mid.position)
    zone = guard.end_stops
    assert not zone.in_zone(q_mid, np.ones(5), 0) and not zone.in_zone(q_mid, -np.ones(5), 0)  # lift mid-stroke
    rates, dec = guard.check_jog(mid, np.array([0.0, 0.2, 0.0, 0.0]))  # faster than the lift goes (the trial's)
    speed = [r for r in dec.reasons if r.level == "speed"]
    assert dec.action == "scaled" and rates[1] < 0.2
    assert [r.measure for r in speed] == ["velocity:lift"], dec.reasons
    # close to the lift's lower end (the workspace reaching it), moving down: the end stop binds, named so
    z_end = _z_at_lift_lower_end(model)
    g = Guard(TrajectoryPlanner(model, workspace=dict(model.workspace, z=(z_end, model.workspace["z"][1]))))
    low = MotionState.at_rest([0.0, z_end + 0.002, 0.0, 0.0])
    assert g.end_stops.in_zone(g.planner.inverse(*low.position), -np.ones(5), 0)
    _, dec = g.check_jog(low, np.array([0.0, -0.1, 0.0, 0.0]))
    assert "end_stop:lift" in [r.measure for r in dec.reasons if r.level == "speed"], dec.reasons


def test_an_implement_with_its_centre_of_mass_10_m_off_in_every_axis_is_evaluated_not_refused_as_input():
    """An operator's trial: an implement the service accepted (20 t, centre of mass [10, 10, 10] m) made the
    guard raise "d = 10.07 is outside the allowed range [-10.0, 10.0]" (the ballast formula's input check on the
    evaluation's own lever arm) and latched an ``internal`` fault; every motion was refused until another
    implement was selected. The evaluation holds for every implement the schema accepts."""
    from planner.limits.tractor import ImplementRecord

    tp = TrajectoryPlanner(HitchModel(load_profile()))
    for com in ((10.0, 10.0, 10.0), (0.0, 9.95, 0.0), (-10.0, 10.0, -10.0)):
        g = Guard(tp, implement=ImplementRecord("heavy", "2", 20_000.0, com))
        for pitch in (tp.lo[3], 0.0, tp.hi[3]):
            r = g.stability_at(tp.inverse(0.0, 0.15, 0.0, pitch))
            assert np.isfinite(r.esm) and np.isfinite(r.min_front_ballast_kg) and r.min_front_ballast_kg > 0.0
