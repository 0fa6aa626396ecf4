"""Vectorised stability measures and the batch plan check of the guard.

Independent truths: the per-sample :func:`evaluate_stability` (the batch must agree with it to
rounding, within its own stated bound); ``HitchModel.forward`` per sample for the mapped forward
kinematics; and a copy of the guard's former per-sample plan check (``reference_check`` below),
whose decisions the batch check must reproduce exactly on refused, scaled and ok plans,
including thresholds placed exactly on sample values.
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from planner.limits.guard import Guard, GuardDecision, GuardReason, GuardRefusal, _implement_frames
from planner.limits.stability import MEASURE_UNITS, StabilityThresholds, evaluate_stability
from planner.limits.stability_batch import MEASURE_NAMES, cross_rows, evaluate_stability_batch
from planner.limits.tractor import STANDARD_GRAVITY as G
from planner.limits.tractor import Tractor, load_tractor_profile
from planner.model.kinematics import HitchModel
from planner.model.types import ACTUATOR_NAMES, KinematicsError
from planner.profiles.hitch import load_profile, profile_from_dict
from planner.trajectory import MotionState, Setpoints, TrajectoryPlanner

SLOPES = ((0.0, 0.0), (0.35, 0.0), (-0.25, 0.15), (0.0, -0.3), (0.2, 0.45))


@pytest.fixture(scope="module")
def tractor_profile():
    return load_tractor_profile("tractor-6t")


@pytest.fixture(scope="module")
def ballasted():
    d = load_profile().model_dump()
    d["stability"]["front_ballast"] = 800.0
    return HitchModel(profile_from_dict(d))


@pytest.fixture(scope="module")
def heavy(tractor_profile):
    return tractor_profile.implement("cat2-power-harrow-1500")


def flat_tractor():
    """Support triangle on the ground plane (pivot on the ground), as in test_stability.py."""
    return Tractor(
        "flat",
        6000.0,
        (0.0, -0.5, 1.0),
        wheelbase=2.0,
        rear_track=2.0,
        rear_axle=[0, 0, 0.8],
        front_axle_pivot=[0, -2.0, 0.0],
        front_ballast_point=[0, -3.0, 0.5],
        ground_z=0.0,
    )


# ----------------------------------------------------------------------------- the former per-sample check


def _measure_values(rep):
    return {"front_axle_load": rep.axle_loads.front, "ssm": rep.ssm, "lsm": rep.lsm, "esm": rep.esm}


def _dedupe(reasons):
    seen = set()
    for r in reasons:
        if (r.measure, r.level) not in seen:
            seen.add((r.measure, r.level))
            yield r


def reference_check(self: Guard, sp: Setpoints) -> GuardDecision:
    """Guard.check_setpoints as it was before the batch evaluation (one sample at a time; the reasons
    carry their SI units since 2026-12-05)."""
    measures = ("front_axle_load", "ssm", "lsm", "esm")
    reasons: list[GuardReason] = []
    factor = 1.0
    start = self.stability_at(sp.actuators[0])
    start_vals = _measure_values(start)
    worst, worst_key = start, math.inf
    hard_th, caution_th = self._thresholds()
    end_stop = None
    for k in range(len(sp.t)):
        q, qd, t = sp.actuators[k], sp.actuator_velocity[k], float(sp.t[k])
        f, i = self.end_stops.speed_factor(q, qd)
        if i is not None and f < factor:
            factor = f
            end_stop = GuardReason(f"end_stop:{ACTUATOR_NAMES[i]}", f, 1.0, t, "speed")
        pts = self.model.forward(q).points
        for name, dist, r in self.keep_out_clearance(q, pts):
            if dist < r:
                reasons.append(GuardReason(f"keep_out:{name}", dist, r, t, "hard", "m"))
        rep = self.stability_at(q, pts)
        vals = _measure_values(rep)
        key = min(vals[m] / max(abs(hard_th[m]), 1e-9) for m in measures)
        if key < worst_key:
            worst, worst_key = rep, key
        for m in measures:
            v = vals[m]
            improving_only = start_vals[m] < hard_th[m] and v >= start_vals[m] - 1e-9
            if v < hard_th[m] and not improving_only:
                reasons.append(GuardReason(m, v, hard_th[m], t, "hard", MEASURE_UNITS[m]))
            elif v < caution_th[m] and not (start_vals[m] < caution_th[m] and v >= start_vals[m] - 1e-9):
                reasons.append(GuardReason(m, v, caution_th[m], t, "caution", MEASURE_UNITS[m]))
    if end_stop is not None:
        reasons.insert(0, end_stop)
    hard = sorted((r for r in reasons if r.level == "hard"), key=lambda r: r.t_s)
    if hard:
        return GuardDecision("refused", 0.0, tuple(_dedupe(hard)), worst)
    if any(r.level == "caution" for r in reasons):
        factor = min(factor, self.settings.caution_speed_factor)
    kept = tuple(_dedupe(reasons))
    return GuardDecision("ok" if factor >= 1.0 else "scaled", factor, tuple(kept), worst)


def assert_same_decision(new: GuardDecision, ref: GuardDecision):
    assert new.action == ref.action
    assert new.speed_factor == ref.speed_factor
    assert new.reasons == ref.reasons  # measure, value, threshold, t, level: exact equality
    assert new.worst.as_dict() == ref.worst.as_dict()
    assert np.array_equal(new.worst.load.centre_of_mass, ref.worst.load.centre_of_mass)
    assert new.worst.energy.edge_energies == ref.worst.energy.edge_energies
    assert new.to_json() == ref.to_json()


# ----------------------------------------------------------------------------- batch measures vs per sample


def _scales(tractor, implement, ballast):
    m = tractor.mass + ballast + (implement.mass if implement is not None else 0.0)
    return {"front_axle_load": m * G, "ssm": 1.0, "lsm": 1.0, "esm": m * G}


def _compare(tractor, implement, T, R, slope, ballast):
    batch = evaluate_stability_batch(tractor, implement, T, R, *slope, front_ballast=ballast)
    assert batch.values.shape == (len(T), 4)
    scale = _scales(tractor, implement, ballast)
    checked = 0
    for k in range(len(T)):
        rep = evaluate_stability(tractor, implement, T[k], R[k], *slope, front_ballast=ballast)
        exact = _measure_values(rep)
        if batch.suspect[k]:
            continue
        checked += 1
        for j, m in enumerate(MEASURE_NAMES):
            err = abs(batch.values[k, j] - exact[m])
            assert err <= 1e-12 * max(abs(exact[m]), scale[m]), (k, m, batch.values[k, j], exact[m])
            assert err <= 1e-2 * batch.tolerance[m] or (batch.exact and err == 0.0), (k, m, err)
    return batch, checked


@pytest.mark.parametrize("slope", SLOPES)
@pytest.mark.parametrize("which", ["tractor-6t", "flat"])
def test_batch_equals_per_sample_on_random_poses(tractor_profile, slope, which):
    rng = np.random.default_rng(SLOPES.index(slope) + (100 if which == "flat" else 0))
    tractor = tractor_profile.tractor(0.56) if which == "tractor-6t" else flat_tractor()
    n = 300
    # tool points from well inside to far behind / beside the tractor (CoM outside the triangle too)
    T = rng.uniform([-1.5, 0.3, -0.6], [1.5, 3.0, 1.0], (n, 3))
    R = Rotation.random(n, random_state=rng.integers(2**31)).as_matrix()
    for name in ("cat2-spreader-400", "cat2-power-harrow-1500"):
        for ballast in (0.0, 650.0):
            batch, checked = _compare(tractor, tractor_profile.implement(name), T, R, slope, ballast)
            assert checked >= n - 3  # suspect only next to the LSM / ESM branches
            assert not batch.exact


def test_batch_values_span_both_signs_of_every_measure(tractor_profile, heavy):
    """The random poses above exercise CoMs inside and outside the triangle (all branches)."""
    rng = np.random.default_rng(7)
    T = rng.uniform([-1.5, 0.3, -0.6], [1.5, 3.0, 1.0], (400, 3))
    R = Rotation.random(400, random_state=8).as_matrix()
    b = evaluate_stability_batch(flat_tractor(), heavy, T, R, 0.35, 0.3)
    for m in MEASURE_NAMES:
        v = getattr(b, m)
        assert v.min() < 0 < v.max(), m
    assert np.any(b.lsm != b.ssm) and np.any(b.lsm == b.ssm)


def test_without_implement_the_batch_is_the_per_sample_value(tractor_profile):
    tractor = tractor_profile.tractor(0.56)
    T, R = np.zeros((5, 3)), np.repeat(np.eye(3)[None], 5, axis=0)
    for slope in SLOPES:
        batch = evaluate_stability_batch(tractor, None, T, R, *slope, front_ballast=300.0)
        rep = _measure_values(evaluate_stability(tractor, None, None, None, *slope, front_ballast=300.0))
        assert batch.exact and not batch.suspect.any()
        for m in MEASURE_NAMES:
            assert np.all(getattr(batch, m) == rep[m])


def test_poses_the_per_sample_function_rejects_are_suspect(tractor_profile, heavy):
    tractor = tractor_profile.tractor(0.56)
    T = np.array([[0, 1.0, 0.0], [0, 1.0, np.nan], [0, 1.0, 0.0], [0, 1.0, 0.0]])
    R = np.repeat(np.eye(3)[None], 4, axis=0)
    R[2] = np.diag([1.0, 1.0, 1.0 + 1e-5])  # not orthonormal within 1e-6
    R[3] = np.diag([1.0, 1.0, -1.0])  # improper
    b = evaluate_stability_batch(tractor, heavy, T, R, 0.1, 0.0)
    assert b.suspect.tolist() == [False, True, True, True]
    for k in (1, 2, 3):
        with pytest.raises(ValueError):
            evaluate_stability(tractor, heavy, T[k], R[k], 0.1, 0.0)


def test_batch_from_plans_on_slopes_equals_stability_at(ballasted, heavy):
    """Poses from the hitch model (random plans), through the guard's own batch path."""
    g = Guard(TrajectoryPlanner(ballasted), implement=heavy)
    tp, rng = g.planner, np.random.default_rng(11)
    for slope in SLOPES:
        g.set_slope(*slope)
        p0, p1 = tp.lo + (tp.hi - tp.lo) * rng.random((2, 4))
        sp = tp.plan_move(MotionState.at_rest(p0), dict(zip(("x", "z", "roll", "pitch"), p1, strict=True))).setpoints
        P, bad = g._points_batch(sp.actuators)
        assert not bad.any()
        for k in range(0, len(sp.t), 7):  # the mapped FK is HitchModel.forward, bit for bit
            ref = g.model.forward(sp.actuators[k]).points
            for n in P:
                assert np.array_equal(P[n][k], ref[n])
        batch = evaluate_stability_batch(
            g.tractor, heavy, *_implement_frames(P), *slope, front_ballast=g.settings.front_ballast
        )
        scale = _scales(g.tractor, heavy, g.settings.front_ballast)
        for k in range(len(sp.t)):
            exact = _measure_values(g.stability_at(sp.actuators[k]))
            assert not batch.suspect[k]
            for j, m in enumerate(MEASURE_NAMES):
                assert abs(batch.values[k, j] - exact[m]) <= 1e-12 * max(abs(exact[m]), scale[m])


# ----------------------------------------------------------------------------- check_setpoints vs the former loop


def _plans(tp, rng, n_random):
    lo, hi = tp.lo, tp.hi
    yield MotionState.at_rest([0.0, lo[1], 0.0, 0.0]), {"z": hi[1]}, 1.0
    yield MotionState.at_rest([0.0, hi[1], 0.0, 0.0]), {"z": lo[1]}, 1.0
    yield MotionState.at_rest([0.0, 0.25, 0.0, 0.0]), {"z": -0.15}, 0.3
    yield MotionState.at_rest([lo[0], 0.1, 0.0, hi[3]]), {"x": hi[0], "roll": lo[2], "pitch": lo[3]}, 1.0
    for _ in range(n_random):
        p0, p1 = lo + (hi - lo) * rng.random((2, 4))
        yield (
            MotionState.at_rest(p0),
            dict(zip(("x", "z", "roll", "pitch"), p1, strict=True)),
            float(rng.choice([0.5, 1.0])),
        )


def _guards(ballasted, heavy, model):
    tp = TrajectoryPlanner(ballasted)
    yield "no implement", Guard(tp), (0.0, 0.0)
    yield "no implement, steep", Guard(tp), (0.55, 0.2)
    yield (
        "heavy, slope, esm hard 5 kJ",
        Guard(tp, implement=heavy, thresholds=StabilityThresholds(esm_hard=5000.0, esm_caution=5000.0)),
        (0.35, 0.0),
    )
    yield (
        "heavy, caution band",
        Guard(tp, implement=heavy, thresholds=StabilityThresholds(esm_hard=100.0, esm_caution=50_000.0)),
        (0.0, 0.0),
    )
    yield (
        "heavy, nose up, all measures",
        Guard(
            tp,
            implement=heavy,
            thresholds=StabilityThresholds(
                front_axle_fraction_hard=0.30,
                front_axle_fraction_caution=0.36,
                ssm_hard=0.45,
                ssm_caution=0.6,
                lsm_hard=0.45,
                lsm_caution=0.6,
                esm_caution=20_000.0,
            ),
        ),
        (-0.1, 0.25),
    )
    d = model.profile.model_dump()
    d["limits"]["keep_out"] = [
        {"name": "couplers", "centre": [0.0, 0.45, 0.70], "radius": 0.05},
        {"name": "pto", "centre": [0.0, 0.30, 0.10], "radius": 0.02},
    ]
    yield "keep-outs", Guard(TrajectoryPlanner(HitchModel(profile_from_dict(d)))), (0.0, 0.0)
    # the lowest z a hair above the lift's lower end stop: plans down there are slowed (test_guard.py)
    tp0 = TrajectoryPlanner(ballasted)
    target, a, b = ballasted.lower[0] + 1e-5, -0.35, 0.0
    for _ in range(80):
        mid = (a + b) / 2
        a, b = (mid, b) if tp0.inverse(0, mid, 0, 0)[0] < target else (a, mid)
    ws = dict(ballasted.workspace, z=(b, ballasted.workspace["z"][1]))
    yield "end stop", Guard(TrajectoryPlanner(ballasted, workspace=ws), implement=heavy), (0.1, 0.05)


def test_check_setpoints_equals_the_per_sample_loop(ballasted, heavy, model):
    rng = np.random.default_rng(2026)
    actions = set()
    for label, g, slope in _guards(ballasted, heavy, model):
        g.set_slope(*slope)
        for start, goal, speed in _plans(g.planner, rng, 6):
            sp = g.planner.plan_move(start, goal, speed_scale=speed).setpoints
            new, ref = g.check_setpoints(sp), reference_check(g, sp)
            assert_same_decision(new, ref)
            actions.add(ref.action)
            levels = {r.level for r in ref.reasons}
            actions |= {f"{label}: {lv}" for lv in levels}
    assert actions >= {"ok", "scaled", "refused"}
    assert any(a.endswith("caution") for a in actions) and any(a.endswith("speed") for a in actions)
    assert any(a.startswith("keep-outs") and a.endswith("hard") for a in actions)


def test_thresholds_exactly_on_sample_values(ballasted, heavy):
    """Thresholds equal to a sample's value (and to the start value): the batch cannot decide
    those comparisons by itself; the per-sample values must, as before."""
    tp = TrajectoryPlanner(ballasted)
    probe = Guard(tp, implement=heavy)
    probe.set_slope(0.3, 0.1)
    lo, hi = tp.lo[1], tp.hi[1]
    for start, goal in (([0.0, lo, 0.0, 0.0], {"z": hi}), ([0.0, hi, 0.02, 0.0], {"z": lo, "roll": -0.03})):
        sp = tp.plan_move(MotionState.at_rest(start), goal).setpoints
        n = len(sp.t)
        for k in (0, 1, n // 3, n // 2, n - 1):
            v = _measure_values(probe.stability_at(sp.actuators[k]))
            w = probe.tractor.empty_weight
            for th in (
                StabilityThresholds(esm_hard=v["esm"], esm_caution=v["esm"]),
                StabilityThresholds(esm_hard=v["esm"] - 1e-9, esm_caution=v["esm"] + 1e-9),
                StabilityThresholds(ssm_hard=v["ssm"] - 0.3, ssm_caution=v["ssm"]),
                StabilityThresholds(lsm_hard=v["lsm"], lsm_caution=v["lsm"] + 0.2),
                StabilityThresholds(
                    front_axle_fraction_hard=v["front_axle_load"] / w,
                    front_axle_fraction_caution=min(1.0, v["front_axle_load"] / w + 0.01),
                ),
            ):
                g = Guard(tp, implement=heavy, thresholds=th)
                g.set_slope(0.3, 0.1)
                assert_same_decision(g.check_setpoints(sp), reference_check(g, sp))


def test_plan_results_and_refusals_unchanged(ballasted, heavy):
    """Guard.plan (which iterates check_setpoints) gives the same plans and refusals."""
    tp = TrajectoryPlanner(ballasted)
    g = Guard(tp, implement=heavy, thresholds=StabilityThresholds(esm_hard=5000.0, esm_caution=5000.0))
    g.set_slope(0.35, 0.0)
    lo, hi = tp.lo[1], tp.hi[1]
    with pytest.raises(GuardRefusal) as exc:
        g.plan(MotionState.at_rest([0.0, lo, 0.0, 0.0]), {"z": hi})
    sp = tp.plan_move(MotionState.at_rest([0.0, lo, 0.0, 0.0]), {"z": hi}).setpoints
    assert_same_decision(exc.value.decision, reference_check(g, sp))
    gp = g.plan(MotionState.at_rest([0.0, hi, 0.0, 0.0]), {"z": lo})
    assert_same_decision(gp.decision, reference_check(g, gp.setpoints))


def test_a_sample_that_cannot_close_raises_as_before(model):
    g = Guard(TrajectoryPlanner(model))
    sp = g.planner.plan_move(MotionState.at_rest([0.0, 0.1, 0.0, 0.0]), {"z": 0.0}).setpoints
    bad = sp.actuators.copy()
    bad[40, 3] = 5.0  # a sway limiter far beyond its reach
    sp_bad = Setpoints(sp.rate, sp.t, sp.pose, sp.pose_velocity, bad, sp.actuator_velocity)
    with pytest.raises(KinematicsError) as new:
        g.check_setpoints(sp_bad)
    with pytest.raises(KinematicsError) as ref:
        reference_check(g, sp_bad)
    assert str(new.value) == str(ref.value)


def test_only_a_few_samples_are_evaluated_one_by_one(ballasted, heavy, monkeypatch):
    g = Guard(
        TrajectoryPlanner(ballasted),
        implement=heavy,
        thresholds=StabilityThresholds(esm_hard=100.0, esm_caution=50_000.0),
    )
    sp = g.planner.plan_move(MotionState.at_rest([0.0, -0.15, 0.0, 0.0]), {"z": 0.25}, speed_scale=0.3).setpoints
    assert len(sp.t) > 700
    calls = []
    orig = Guard.stability_at
    monkeypatch.setattr(Guard, "stability_at", lambda self, q, points=None: calls.append(1) or orig(self, q, points))
    dec = g.check_setpoints(sp)
    assert dec.action == "scaled" and len(calls) <= 6, len(calls)


def reference_plan(g: Guard, start, goal, speed_scale=1.0):
    """Guard.plan as it was: every plan checked afresh with check_setpoints (nothing shared)."""
    total, caution_applied, reasons = 1.0, False, []
    for _ in range(8):
        plan = g.planner.plan_move(start, goal, speed_scale=speed_scale * total)
        sp = plan.sampled()
        dec = g.check_setpoints(sp)
        if dec.action == "refused":
            raise GuardRefusal(dec)
        reasons.extend(r for r in dec.reasons if r not in reasons)
        end_stop = min((r.value for r in dec.reasons if r.level == "speed"), default=1.0)
        caution = any(r.level == "caution" for r in dec.reasons)
        if end_stop < 1.0:
            total *= end_stop * 0.98
        elif caution and not caution_applied:
            total *= g.settings.caution_speed_factor
            caution_applied = True
        else:
            return sp, GuardDecision("ok" if total >= 1.0 else "scaled", total, tuple(_dedupe(reasons)), dec.worst)
    raise GuardRefusal(GuardDecision("refused", 0.0, tuple(_dedupe(reasons)), dec.worst))


def test_plans_sharing_per_sample_results_decide_as_checked_afresh(ballasted, heavy):
    """Guard.plan keeps the per-sample results between its plans (start and goal recur); the
    plans and decisions are those of checking every plan on its own, also after a slope change."""
    tp = TrajectoryPlanner(ballasted)
    g = Guard(tp, implement=heavy)
    rng = np.random.default_rng(11)
    seen = set()
    for k in range(10):
        g.set_slope(0.1 if k % 2 else 0.25, 0.05 * (k % 3))
        p0 = tp.lo + (tp.hi - tp.lo) * rng.choice([0.05, 0.95], 4)
        goal = dict(zip(("x", "z", "roll", "pitch"), tp.lo + (tp.hi - tp.lo) * rng.random(4), strict=True))
        try:
            sp_ref, dec_ref = reference_plan(g, MotionState.at_rest(p0), goal)
        except GuardRefusal as ref:
            with pytest.raises(GuardRefusal) as new:
                g.plan(MotionState.at_rest(p0), goal)
            assert_same_decision(new.value.decision, ref.decision)
            seen.add("refused")
            continue
        gp = g.plan(MotionState.at_rest(p0), goal)
        assert np.array_equal(gp.setpoints.actuators, sp_ref.actuators)
        assert_same_decision(gp.decision, dec_ref)
        seen.add(gp.decision.action)
    assert "scaled" in seen  # the caution re-plan (the case that shares results) happened


def test_cross_rows_is_np_cross_bit_for_bit():
    """The guard's frames and the batch's determinant use cross_rows: np.cross's values exactly
    (also for huge, tiny and non-finite entries, and for no rows)."""
    rng = np.random.default_rng(11)
    for n in (0, 1, 250):
        a = rng.normal(size=(n, 3)) * rng.choice([1e-300, 1.0, 1e300], (n, 3))
        b = rng.normal(size=(n, 3))
        if n:
            a[0, 1], b[-1, 2] = np.nan, np.inf
        got, want = cross_rows(a, b), np.cross(a, b)
        assert got.shape == want.shape == (n, 3)
        assert np.array_equal(got, want, equal_nan=True)
