"""Stability measures of tractor + implement against hand-computed values and invariants.

Independent truths used: closed-form statics on a flat (planar) support triangle, a worked
example of the manuals' ballast formula, barycentric inside tests, brute-force rotation of the
CoM about each support edge, explicit rotation matrices for the slope convention.
"""

import json
import math

import numpy as np
import pytest

from planner.limits.stability import (
    _EDGES,
    EDGE_NAMES,
    StabilityInputError,
    StabilityThresholds,
    _cross3,
    _dot,
    _segment_distance,
    _support_frame,
    axle_loads,
    build_load_case,
    energy_margins,
    evaluate_stability,
    gravity_direction,
    minimum_front_ballast,
    support_margins,
)
from planner.limits.tractor import (
    STANDARD_GRAVITY as G,
)
from planner.limits.tractor import (
    ImplementRecord,
    Tractor,
    TractorProfileError,
    load_tractor_profile,
    tractor_profile_from_dict,
)

PIVOT_HEIGHT = 0.56  # the brief's hitch pivot height [m]; the functions take it as a parameter
I3 = np.eye(3)


@pytest.fixture(scope="module")
def profile():
    return load_tractor_profile("tractor-6t")


@pytest.fixture(scope="module")
def tractor(profile):
    return profile.tractor(PIVOT_HEIGHT)


@pytest.fixture(scope="module")
def heavy(profile):
    return profile.implement("cat2-power-harrow-1500")


def flat_tractor(mass=6000.0, com=(0.0, -0.5, 1.0)):
    """Hand-checkable tractor: rear contacts (±1, 0, 0), pivot ON the ground at (0, -2, 0).

    Ground at z = 0 (pivot height 0), so the support triangle is horizontal; CoM height = com[2].
    """
    return Tractor(
        "flat",
        mass,
        com,
        wheelbase=2.0,
        rear_track=2.0,
        rear_axle=[0, 0, 0.8],
        front_axle_pivot=[0, -2.0, 0.0],
        front_ballast_point=[0, -3.0, 0.5],
        ground_z=0.0,
    )


def rot(axis, angle):
    c, s = math.cos(angle), math.sin(angle)
    if axis == "x":
        return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])
    if axis == "y":
        return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


# ----------------------------------------------------------------------------- slope convention


def test_gravity_direction_signs_and_rotation_matrices():
    # Level ground: straight down.
    assert gravity_direction(0.0, 0.0) == pytest.approx([0, 0, -1])
    # Left side up (roll > 0): gravity pulls towards the right (-x). Nose up: towards the rear (+y).
    assert gravity_direction(0.3, 0.0)[0] < 0
    assert gravity_direction(0.0, 0.3)[1] > 0
    # Independent construction: attitude R = Rz(yaw) Rx(-pitch) Ry(-roll) (nose up is a negative
    # rotation about the left-pointing x axis, left-up a negative rotation about the rearward y
    # axis); gravity in the tractor frame is R^T (0, 0, -1), independent of yaw.
    rng = np.random.default_rng(5)
    for _ in range(50):
        roll, pitch, yaw = rng.uniform(-1.2, 1.2, 3)
        R = rot("z", yaw) @ rot("x", -pitch) @ rot("y", -roll)
        expected = R.T @ np.array([0, 0, -1.0])
        assert gravity_direction(roll, pitch) == pytest.approx(expected, abs=1e-12)


# ----------------------------------------------------------------------------- axle loads


def test_axle_loads_level_ground_hand_computed(tractor):
    # Empty tractor: front = T_L g (y_r - y_com)/b = 6000 g * 1.08/2.7 = 2400 g = 23535.96 N.
    loads = axle_loads(tractor, tractor.mass, tractor.centre_of_mass, gravity_direction(0, 0))
    assert loads.front == pytest.approx(2400 * G, rel=1e-12)
    assert loads.rear == pytest.approx(3600 * G, rel=1e-12)
    assert tractor.empty_front_axle_mass == pytest.approx(2400.0)
    # 1000 kg implement, CoM (0, 0.5, 0.2) in its frame, T = (0, 1.0, 0.0), upright (R = I):
    # p_i = (0, 1.5, 0.2). Moments about the rear axle (y = -0.3):
    # front * 2.7 = g (6000 * 1.08 - 1000 * 1.8) = 4680 g  ->  front = 1733.33 g, rear = 5266.67 g.
    imp = ImplementRecord("test", "2", 1000.0, [0, 0.5, 0.2])
    load = build_load_case(tractor, imp, [0, 1.0, 0.0], I3)
    assert load.centre_of_mass == pytest.approx([0, (6000 * -1.38 + 1000 * 1.5) / 7000, (6000 * 0.44 + 200) / 7000])
    loads = axle_loads(tractor, load.mass, load.centre_of_mass, gravity_direction(0, 0))
    assert loads.front == pytest.approx(4680 / 2.7 * G, rel=1e-12)
    assert loads.rear == pytest.approx((7000 - 4680 / 2.7) * G, rel=1e-12)


def test_axle_loads_on_slope_hand_computed(tractor):
    # Pure nose-up pitch 0.2 rad, empty tractor, CoM 1.08 m ahead of the rear axle, 1.00 m high:
    # front = m g [cos(0.2) 1.08 - sin(0.2) 1.00] / 2.7; the normal loads sum to m g cos(0.2).
    g = gravity_direction(0.0, 0.2)
    loads = axle_loads(tractor, tractor.mass, tractor.centre_of_mass, g)
    assert loads.front == pytest.approx(6000 * G * (math.cos(0.2) * 1.08 - math.sin(0.2) * 1.0) / 2.7, rel=1e-12)
    assert loads.total == pytest.approx(6000 * G * math.cos(0.2), rel=1e-12)
    # Pure roll scales both axles by cos(roll): the share is unchanged.
    rolled = axle_loads(tractor, tractor.mass, tractor.centre_of_mass, gravity_direction(0.3, 0.0))
    assert rolled.front == pytest.approx(2400 * G * math.cos(0.3), rel=1e-12)
    assert rolled.front_share == pytest.approx(0.4, rel=1e-12)


def test_front_load_vanishes_exactly_when_cog_over_rear_edge(tractor):
    # Tip-back pitch: tan(theta*) = (y_r - y_com) / h = 1.08 / 1.00.  Front load, rear-edge SSM
    # and rear-edge ESM all cross zero there (the weight line passes through the rear contacts).
    theta = math.atan2(1.08, 1.00)
    for dt, sign in ((-1e-3, 1), (1e-3, -1)):
        g = gravity_direction(0.0, theta + dt)
        load = build_load_case(tractor, None)
        assert np.sign(axle_loads(tractor, load.mass, load.centre_of_mass, g).front) == sign
        assert np.sign(support_margins(tractor, load.centre_of_mass, g).edge_distances[0]) == sign
        assert np.sign(energy_margins(tractor, load.mass, load.centre_of_mass, g).edge_energies[0]) == sign


# ----------------------------------------------------------------------------- SSM / LSM / ESM by hand


def test_flat_triangle_margins_hand_computed():
    t = flat_tractor(com=(0.0, -0.5, 1.0))
    m = t.mass
    g = gravity_direction(0, 0)
    sm = support_margins(t, t.centre_of_mass, g)
    # Edges: rear y = 0 -> 0.5 m; side edges through (±1, 0) and (0, -2): distance
    # |2 (0 - 1) - 1 (-0.5)| / sqrt(5) = 1.5 / sqrt(5) = 0.670820 m.
    side = 1.5 / math.sqrt(5)
    assert sm.edge_distances == pytest.approx((0.5, side, side), abs=1e-12)
    assert sm.ssm == pytest.approx(0.5) and sm.weakest_edge == "rear"
    # Travel line x = 0: rear exit at y = 0 (0.5 m), front exit at the apex y = -2 (1.5 m).
    assert (sm.lsm_rear, sm.lsm_front, sm.lsm) == pytest.approx((0.5, 1.5, 0.5))
    # ESM: edges lie on the ground, CoM 1 m high: E = m g (sqrt(d^2 + h^2) - h).
    em = energy_margins(t, m, t.centre_of_mass, g)
    expected = [m * G * (math.hypot(d, 1.0) - 1.0) for d in (0.5, side, side)]
    assert em.edge_energies == pytest.approx(expected, rel=1e-12)
    assert em.esm == pytest.approx(m * G * (math.hypot(0.5, 1.0) - 1.0)) and em.weakest_edge == "rear"
    # Roll 0.3 (left up): the projection shifts by h tan(roll) = 0.309336 m to the right (-x):
    # right edge distance = (1.5 - 2 * 0.309336) / sqrt(5) = 0.394139 m.
    s = math.tan(0.3)
    rolled = support_margins(t, t.centre_of_mass, gravity_direction(0.3, 0))
    assert rolled.edge_distances == pytest.approx((0.5, (1.5 - 2 * s) / math.sqrt(5), (1.5 + 2 * s) / math.sqrt(5)))
    assert rolled.projection == pytest.approx([-s, -0.5, 0.0])


def test_flat_triangle_offset_and_outside_points():
    g = gravity_direction(0, 0)
    # CoM at x = 0.25: left edge distance |2 (0.25 - 1) + 0.5| / sqrt(5) = 1 / sqrt(5) = 0.447214 (the SSM);
    # the travel line x = 0.25 leaves through the left edge x = 1 + y/2 at y = -1.5 -> lsm_front 1.0.
    t = flat_tractor(com=(0.25, -0.5, 1.0))
    sm = support_margins(t, t.centre_of_mass, g)
    assert sm.ssm == pytest.approx(1 / math.sqrt(5)) and sm.weakest_edge == "left"
    assert (sm.lsm_front, sm.lsm_rear) == pytest.approx((1.0, 0.5))
    # Behind the rear axle by 0.3 m: SSM = -0.3, lsm_rear = -0.3, ESM(rear) = -m g (sqrt(0.09 + 1) - 1).
    t = flat_tractor(com=(0.0, 0.3, 1.0))
    sm = support_margins(t, t.centre_of_mass, g)
    assert (sm.ssm, sm.lsm_rear, sm.lsm) == pytest.approx((-0.3, -0.3, -0.3))
    em = energy_margins(t, t.mass, t.centre_of_mass, g)
    assert em.esm == pytest.approx(-t.mass * G * (math.hypot(0.3, 1.0) - 1.0))
    # Laterally outside (x = 1.5, y = -0.5): the travel line misses the triangle; nearest point
    # (0.9, -0.2) on the left edge, distance 1.5 / sqrt(5): SSM = LSM = -0.670820.
    t = flat_tractor(com=(1.5, -0.5, 1.0))
    sm = support_margins(t, t.centre_of_mass, g)
    assert (sm.ssm, sm.lsm_front, sm.lsm_rear) == pytest.approx((-1.5 / math.sqrt(5),) * 3)


def test_symmetric_implement_on_level_ground_has_no_lateral_moment(tractor, profile):
    for name in profile.implements:
        imp = profile.implement(name)
        assert imp.centre_of_mass[0] == 0.0
        for z in (-0.3, 0.0, 0.4):
            r = evaluate_stability(tractor, imp, [0.0, 0.9, z], I3, 0.0, 0.0)
            p_i = r.load.implement_centre_of_mass
            lateral_moment = G * (tractor.mass * tractor.centre_of_mass[0] + imp.mass * p_i[0])
            assert lateral_moment == 0.0 and r.load.centre_of_mass[0] == 0.0
            _, right, left = r.margins.edge_distances
            assert right == pytest.approx(left, rel=1e-12)
            assert r.energy.edge_energies[1] == pytest.approx(r.energy.edge_energies[2], rel=1e-12)


# ----------------------------------------------------------------------------- ballast formula


def test_minimum_front_ballast_worked_example():
    # T_L = 6000 kg, T_V = 2400 kg, b = 2.7 m, a = 1.0 m, G_H = 2500 kg, c = 1.2 m, d = 1.3 m:
    # G_V,min = [2500 * 2.5 - 2400 * 2.7 + 0.2 * 6000 * 2.7] / (1.0 + 2.7)
    #         = (6250 - 6480 + 3240) / 3.7 = 3010 / 3.7 = 813.5135 kg.
    kw = dict(empty_mass=6000, empty_front_axle_mass=2400, wheelbase=2.7, ballast_arm=1.0)
    assert minimum_front_ballast(2500, 1.2, 1.3, **kw) == pytest.approx(3010 / 3.7)
    # 400 kg implement at the same place: 1000 - 6480 + 3240 < 0 -> no ballast needed (0, never negative).
    assert minimum_front_ballast(400, 1.2, 1.3, **kw) == 0.0
    # A 30 % rule instead of 20 %: (6250 - 6480 + 4860) / 3.7 = 1251.35 kg.
    assert minimum_front_ballast(2500, 1.2, 1.3, front_fraction=0.3, **kw) == pytest.approx(4630 / 3.7)


def test_ballast_advice_restores_the_rule_in_the_3d_model(tractor):
    # Same example through evaluate_stability: c = T_y - y_rear = 0.9 + 0.3 = 1.2, d = 1.3.
    imp = ImplementRecord("heavy-2500", "3", 2500.0, [0.0, 1.3, 0.4])
    r = evaluate_stability(tractor, imp, [0.0, 0.9, 0.1], I3, 0.0, 0.0)
    assert r.min_front_ballast_kg == pytest.approx(3010 / 3.7)
    assert not r.ok and any(v.measure == "front_axle_load" and v.level == "hard" for v in r.violations)
    # Fitting exactly that ballast brings the (independently computed) front-axle load to 20 % of T_L g.
    fitted = evaluate_stability(tractor, imp, [0.0, 0.9, 0.1], I3, 0.0, 0.0, front_ballast=r.min_front_ballast_kg)
    assert fitted.axle_loads.front == pytest.approx(0.2 * 6000 * G, rel=1e-12)


# ----------------------------------------------------------------------------- monotonicity and slopes


def test_margins_decrease_as_slope_grows_towards_the_weak_side(tractor, heavy):
    T = [0.0, 0.9, 0.2]
    rolls = np.linspace(0.0, 0.6, 13)
    side = [evaluate_stability(tractor, heavy, T, I3, r, 0.0) for r in rolls]
    # Roll towards the right (left side up): right edge is the weak side.
    assert np.all(np.diff([s.margins.edge_distances[1] for s in side]) < 0)
    assert np.all(np.diff([s.energy.edge_energies[1] for s in side]) < 0)
    assert np.all(np.diff([s.ssm for s in side]) <= 1e-12)
    assert np.all(np.diff([s.lsm for s in side]) <= 1e-12)
    assert np.all(np.diff([s.esm for s in side]) < 0)
    assert side[-1].ssm < 0.3 * side[0].ssm and side[-1].weakest_edge == "right"
    # Mirror slope gives mirror margins (symmetric tractor + implement).
    mirrored = evaluate_stability(tractor, heavy, T, I3, -0.4, 0.0)
    assert evaluate_stability(tractor, heavy, T, I3, 0.4, 0.0).ssm == pytest.approx(mirrored.ssm, rel=1e-12)
    assert mirrored.weakest_edge == "left"
    # Nose up with a heavy rear implement: rear is the weak side.
    pitches = np.linspace(0.0, 0.5, 11)
    up = [evaluate_stability(tractor, heavy, T, I3, 0.0, p) for p in pitches]
    for values in ([u.axle_loads.front for u in up], [u.ssm for u in up], [u.lsm for u in up], [u.esm for u in up]):
        assert np.all(np.diff(values) < 0)
    assert up[-1].ssm < 0 < up[0].ssm and up[-1].weakest_edge == "rear"


def test_lifting_heavy_implement_lowers_esm_on_side_slope_but_not_ssm_on_level(tractor, heavy):
    heights = np.linspace(-0.3, 0.6, 10)
    on_slope = [evaluate_stability(tractor, heavy, [0.0, 0.9, z], I3, 0.2, 0.0) for z in heights]
    assert np.all(np.diff([r.esm for r in on_slope]) < 0)
    assert np.all(np.diff([r.energy.edge_energies[1] for r in on_slope]) < 0)  # downhill edge
    # Seed 003 fig. 4.2b: on level ground SSM does not see CoM height, ESM does.
    level = [evaluate_stability(tractor, heavy, [0.0, 0.9, z], I3, 0.0, 0.0) for z in heights]
    assert np.ptp([r.ssm for r in level]) < 1e-12
    assert np.all(np.diff([r.esm for r in level]) < 0)


# ----------------------------------------------------------------------------- random invariants


def _inside_by_barycentric(tractor, p, g):
    """Independent inside test: project p along g onto the triangle's plane, barycentric coords."""
    V = tractor.support_vertices
    # Solve p + t g = V0 + u (V1 - V0) + v (V2 - V0) for (t, u, v).
    t, u, v = np.linalg.solve(np.column_stack([-g, V[1] - V[0], V[2] - V[0]]), p - V[0])
    return min(u, v, 1 - u - v)


def _brute_force_tip_energy(mass, p, A, B, g):
    """Rotate p about the axis A-B over a fine angle grid; energy to reach the highest point."""
    axis = (B - A) / np.linalg.norm(B - A)
    r = p - A
    psi = np.linspace(-math.pi, math.pi, 200001)
    # Rodrigues: r cos + (k x r) sin + k (k.r)(1 - cos)
    k_r = np.cross(axis, r)
    pts = np.outer(np.cos(psi), r) + np.outer(np.sin(psi), k_r) + np.outer(1 - np.cos(psi), axis * (axis @ r))
    heights = pts @ (-g)
    return mass * G * (heights.max() - r @ (-g))


def test_margins_positive_exactly_when_projection_inside_random(tractor):
    rng = np.random.default_rng(20261123)
    V = tractor.support_vertices
    inside_count = outside_count = 0
    for i in range(400):
        imp = ImplementRecord("r", "2", rng.uniform(100, 6000), rng.uniform([-0.8, -0.2, -0.2], [0.8, 2.5, 1.5]))
        T = rng.uniform([-0.3, 0.6, -0.4], [0.3, 1.2, 0.6])
        R = rot("z", rng.uniform(-0.3, 0.3)) @ rot("y", rng.uniform(-0.4, 0.4)) @ rot("x", rng.uniform(-0.4, 0.4))
        roll, pitch = rng.uniform(-0.7, 0.7, 2)
        r = evaluate_stability(tractor, imp, T, R, roll, pitch)
        g = gravity_direction(roll, pitch)
        bary = _inside_by_barycentric(tractor, r.load.centre_of_mass, g)
        if abs(bary) < 1e-9:
            continue
        inside = bary > 0
        inside_count += inside
        outside_count += not inside
        assert (r.esm > 0) == inside and (r.ssm > 0) == inside and (r.lsm > 0) == inside
        # Front-axle load and rear-edge margins change sign together (weight line over the rear contacts).
        assert np.sign(r.axle_loads.front) == np.sign(r.margins.edge_distances[0]) == np.sign(r.energy.edge_energies[0])
        # Per-edge energy magnitudes against brute-force rotation about the edge.
        if i % 20 == 0:
            for e, (a, b) in enumerate(((0, 1), (1, 2), (2, 0))):
                expected = _brute_force_tip_energy(r.load.mass, r.load.centre_of_mass, V[a], V[b], g)
                assert abs(r.energy.edge_energies[e]) == pytest.approx(expected, rel=1e-6, abs=1e-3)
    assert inside_count > 50 and outside_count > 50


# ----------------------------------------------------------------------------- report, thresholds


def test_report_fields_violations_and_thresholds(tractor, heavy):
    T = [0.0, 0.9, 0.2]
    r = evaluate_stability(tractor, heavy, T, I3, 0.0, 0.25)
    d = r.as_dict()
    assert json.loads(json.dumps(d)) == d
    assert set(d) >= {"axle_loads", "front_axle_share", "ssm", "lsm", "esm", "min_front_ballast", "ok", "violations"}
    assert d["front_axle_share"] == pytest.approx(r.axle_loads.front / (r.axle_loads.front + r.axle_loads.rear))
    front = next(v for v in r.violations if v.measure == "front_axle_load")
    assert front.level == "hard" and front.threshold == pytest.approx(0.2 * 6000 * G) and front.value < front.threshold
    assert not r.ok
    relaxed = StabilityThresholds(
        front_axle_fraction_hard=0.05, front_axle_fraction_caution=0.05, esm_hard=0.0, esm_caution=0.0
    )
    r2 = evaluate_stability(tractor, heavy, T, I3, 0.0, 0.25, thresholds=relaxed)
    assert r2.ok and all(v.level == "caution" for v in r2.violations)
    # Light implement on level ground: no violation at all.
    light = evaluate_stability(tractor, ImplementRecord("l", "2", 400.0, [0, 0.55, 0.45]), T, I3, 0.0, 0.0)
    assert light.ok and light.violations == () and light.min_front_ballast_kg == 0.0


# ----------------------------------------------------------------------------- bad input


@pytest.mark.parametrize(
    "kwargs, field",
    [
        (dict(slope_roll=math.nan), "slope_roll"),
        (dict(slope_pitch=math.pi / 2), "slope_pitch"),
        (dict(T=[0.0, math.nan, 0.0]), "T"),
        (dict(T=[0.0, 1.0]), "T"),
        (dict(R_i=2 * I3), "R_i"),
        (dict(R_i=np.diag([1.0, 1.0, -1.0])), "R_i"),
        (dict(front_ballast=-10.0), "front_ballast"),
    ],
)
def test_bad_evaluation_inputs_name_the_field(tractor, heavy, kwargs, field):
    args = dict(T=[0.0, 0.9, 0.0], R_i=I3, slope_roll=0.0, slope_pitch=0.0) | kwargs
    ballast = args.pop("front_ballast", 0.0)
    with pytest.raises(StabilityInputError, match=field):
        evaluate_stability(tractor, heavy, front_ballast=ballast, **args)


def test_bad_records_and_thresholds_name_the_field():
    with pytest.raises(StabilityInputError, match="mass"):
        ImplementRecord("x", "2", -5.0, [0, 0.5, 0.3])
    with pytest.raises(StabilityInputError, match="mass"):
        ImplementRecord("x", "2", math.nan, [0, 0.5, 0.3])
    with pytest.raises(StabilityInputError, match="category"):
        ImplementRecord("x", "5", 100.0, [0, 0.5, 0.3])
    with pytest.raises(StabilityInputError, match="centre_of_mass"):
        ImplementRecord("x", "2", 100.0, [0, math.inf, 0.3])
    with pytest.raises(StabilityInputError, match="ssm_caution"):
        StabilityThresholds(ssm_hard=0.3, ssm_caution=0.2)
    with pytest.raises(StabilityInputError, match="implement_mass"):
        minimum_front_ballast(-1, 1, 1, empty_mass=6000, empty_front_axle_mass=2400, wheelbase=2.7, ballast_arm=1)
    with pytest.raises(StabilityInputError, match="pivot_height"):
        load_tractor_profile().tractor(0.0)
    with pytest.raises(StabilityInputError, match="front_axle_pivot"):  # pivot not one wheelbase ahead
        Tractor("t", 6000, [0, -1, 1], 2.0, 2.0, [0, 0, 0.8], [0, -2.5, 0.0], [0, -3.0, 0.5], 0.0)
    with pytest.raises(StabilityInputError, match="mass"):
        flat_tractor(mass=0.0)
    with pytest.raises(StabilityInputError, match="gravity"):
        support_margins(flat_tractor(), [0, -0.5, 1.0], [0, 0, -2.0])


def _profile_dict():
    import tomllib
    from importlib import resources

    return tomllib.loads((resources.files("planner") / "profiles" / "tractors" / "tractor-6t.toml").read_text())


@pytest.mark.parametrize(
    "edit, field",
    [
        (lambda d: d["implements"]["cat2-spreader-400"].update(mass=-400.0), "implements.cat2-spreader-400.mass"),
        (lambda d: d["implements"]["cat2-spreader-400"].update(mass=math.nan), "implements.cat2-spreader-400.mass"),
        (lambda d: d["tractor"].update(mass=float("nan")), "tractor.mass"),
        (lambda d: d["tractor"].update(wheelbase=-2.7), "tractor.wheelbase"),
        (lambda d: d["tractor"].update(typo=1.0), "unknown key"),
        (lambda d: d["tractor"].update(front_axle_mass_empty=3000.0), "front_axle_mass_empty"),
        (lambda d: d["tractor"]["centre_of_mass"].update(y=0.5), "centre_of_mass.y"),
        (lambda d: d["implements"]["cat2-spreader-400"].update(category="7"), "category"),
        # a number must be a number (the old lax validation read these as 1.0 and 7500.0)
        (lambda d: d["tractor"].update(wheelbase=True), "tractor.wheelbase"),
        (lambda d: d["tractor"].update(mass="7500"), "tractor.mass"),
    ],
)
def test_bad_profiles_name_the_field(edit, field):
    data = _profile_dict()
    edit(data)
    with pytest.raises(TractorProfileError, match=field.replace(".", r"\.")):
        tractor_profile_from_dict(data)


def test_default_profile_values(profile, tractor):
    assert profile.spec.mass == 6000.0
    assert tractor.ground_z == -PIVOT_HEIGHT
    assert tractor.rear_axle[1] < 0 and tractor.rear_axle[2] > 0  # forward of and above the pivots
    masses = {n: (profile.implement(n).category, profile.implement(n).mass) for n in profile.implements}
    assert masses == {"cat2-spreader-400": ("2", 400.0), "cat2-power-harrow-1500": ("2", 1500.0)}
    with pytest.raises(TractorProfileError, match="allowed"):
        profile.implement("no-such-implement")
    assert profile.implement("cat2-spreader-400") == ImplementRecord("cat2-spreader-400", "2", 400, [0, 0.55, 0.45])
    assert EDGE_NAMES == ("rear", "right", "left")


# ----------------------------------------------------------------------------- pose-independent parts kept
def reference_support_margins(tractor, p, g):
    """The former support_margins, recomputing the support frame and the edges on every call."""
    V, n, e1, e2, V2 = _support_frame(tractor)
    q = p + (_dot(n, V[0] - p) / _dot(n, g)) * g  # per pose: _dot (the same bits on every CPU; BLAS's are not)
    q2 = np.array([_dot(q - V[0], e1), _dot(q - V[0], e2)])
    travel = np.array([e1[1], e2[1]])
    travel /= np.linalg.norm(travel)
    d, s_lo, s_hi, misses = [], -math.inf, math.inf, False
    for a, b, c in _EDGES:
        edge = V2[b] - V2[a]
        m = np.array([-edge[1], edge[0]]) / np.linalg.norm(edge)
        if m @ (V2[c] - V2[a]) < 0:
            m = -m
        di = _dot(m, q2 - V2[a])
        d.append(di)
        mv = float(m @ travel)
        if abs(mv) < 1e-12:
            misses |= di < 0
        elif mv > 0:
            s_lo = max(s_lo, -di / mv)
        else:
            s_hi = min(s_hi, -di / mv)
    if min(d) > 0:
        ssm = min(d)
    else:
        ssm = -min(_segment_distance(q2, V2[a], V2[b]) for a, b, _ in _EDGES)
    lsm = (ssm, ssm) if misses or s_lo > s_hi else (-s_lo, s_hi)
    return q, tuple(d), float(ssm), float(lsm[0]), float(lsm[1])


def reference_energies(tractor, mass, p, g):
    """The former energy_margins, recomputing every edge's axis and plane on every call."""
    up, V, out = -g, tractor.support_vertices, []
    for a_i, b_i, c_i in _EDGES:
        A = V[a_i]
        axis = (V[b_i] - A) / np.linalg.norm(V[b_i] - A)
        r = p - A
        r_perp = r - _dot(r, axis) * axis
        rise = math.sqrt(_dot(r_perp, r_perp)) * math.sqrt(max(0.0, 1.0 - float(axis @ up) ** 2)) - _dot(r_perp, up)
        side = np.cross(axis, up)
        if side @ (V[c_i] - A) < 0:
            side = -side
        out.append(float(np.sign(_dot(side, r))) * mass * G * max(0.0, float(rise)))
    return tuple(out)


def test_kept_support_and_edge_constants_give_the_former_values_bit_for_bit(tractor):
    """Two tractors and many slopes interleaved (the kept parts per tractor and slope)."""
    rng = np.random.default_rng(5)
    tractors = [tractor, flat_tractor(), tractor]
    for k in range(300):
        t = tractors[k % 3]
        g = gravity_direction(*(rng.uniform(-0.6, 0.6, 2) if k % 5 else (0.0, 0.0)))
        p = np.array([0.0, -1.0, 1.0]) + rng.normal(0, [1.2, 2.0, 0.8])
        sm = support_margins(t, p, g)
        q, d, ssm, lf, lr = reference_support_margins(t, p, g)
        assert np.array_equal(sm.projection, q) and sm.edge_distances == d
        assert (sm.ssm, sm.lsm_front, sm.lsm_rear) == (ssm, lf, lr)
        assert energy_margins(t, 7500.0, p, g).edge_energies == reference_energies(t, 7500.0, p, g)


def test_cross3_is_np_cross_bit_for_bit():
    rng = np.random.default_rng(6)
    for _ in range(500):
        a, b = rng.normal(size=3) * 10.0 ** rng.integers(-3, 3), rng.normal(size=3)
        assert np.array_equal(_cross3(a, b), np.cross(a, b))


def test_a_tractor_length_typed_in_mm_is_refused_with_its_unit_and_the_mm_reading():
    """The tractor profile's errors gave the range without a unit ("allowed: > 0.5 and <= 6")."""
    data = _profile_dict()
    data["tractor"]["wheelbase"] = 2500.0
    data["tractor"]["mass"] = -1.0
    with pytest.raises(TractorProfileError) as err:
        tractor_profile_from_dict(data)
    text = str(err.value)
    assert (
        "tractor.wheelbase = 2500.0: " in text
        and "(allowed: > 0.5 and <= 6 m; did you mean mm? 2500 mm = 2.5 m)" in text
    )
    assert "tractor.mass = -1.0: " in text and "(allowed: >= 300 and <= 50000 kg)" in text


def test_a_tractor_mass_typed_in_tonnes_is_a_range_error_in_kg_with_the_tonnes_reading():
    """mass = 6.0 (t) passed the range (> 0 kg) and read "centre_of_mass.y = -1080.3000 would match"."""
    data = _profile_dict()
    data["tractor"]["mass"] = 6.0
    with pytest.raises(TractorProfileError) as err:
        tractor_profile_from_dict(data)
    text = str(err.value)
    assert "tractor.mass = 6.0: " in text
    assert "(allowed: >= 300 and <= 50000 kg; did you mean t? 6 t = 6000 kg)" in text
    assert "would match" not in text and "centre_of_mass" not in text


@pytest.mark.parametrize("mass, taken", [(1.65, False), (20.0, False), (20.5, True), (20_000.0, True)])
def test_an_implement_mass_typed_in_tonnes_is_a_range_error_in_kg_with_the_tonnes_reading(mass, taken):
    """A user trial: ``[implements.my-plough-4f] mass = 1.65`` (t) was taken as a 1.65 kg implement. The records take
    (20, 20000] kg, as implements/define does; every mass up to 20 could be tonnes and is named so."""
    data = _profile_dict()
    data["implements"]["cat2-spreader-400"]["mass"] = mass
    if taken:
        assert tractor_profile_from_dict(data).implement("cat2-spreader-400").mass == mass
        return
    with pytest.raises(TractorProfileError) as err:
        tractor_profile_from_dict(data)
    assert f"implements.cat2-spreader-400.mass = {mass}: " in str(err.value)
    assert f"(allowed: > 20 and <= 20000 kg; did you mean t? {mass:g} t = {mass * 1000:g} kg)" in str(err.value)


def test_a_front_axle_mass_in_tonnes_or_above_the_mass_gives_no_centre_of_mass_outside_the_axles():
    data = _profile_dict()
    data["tractor"]["front_axle_mass_empty"] = 2.4
    with pytest.raises(TractorProfileError) as err:
        tractor_profile_from_dict(data)
    assert "did you mean t? 2.4 t = 2400 kg" in str(err.value) and "would match" not in str(err.value)
    data["tractor"]["front_axle_mass_empty"] = 7000.0
    with pytest.raises(TractorProfileError) as err:
        tractor_profile_from_dict(data)
    assert "must be less than the tractor's mass = 6000.0 kg" in str(err.value)
    assert "would match" not in str(err.value)


@pytest.mark.parametrize(
    ("com", "words"),
    [
        ([0.0, 1600.0, 350.0], "y_i = 1600 m must lie within ±10 m; did you mean mm? 1600 mm = 1.6 m"),
        ([1.6, 0.35], "must be 3 numbers [x_i, y_i, z_i] in the implement frame [m], got [1.6, 0.35]"),
    ],
)
def test_an_implement_centre_of_mass_in_mm_or_short_of_a_coordinate_is_named(com, words):
    """A user trial: [0, 1600, 350] (mm) said "coordinates must lie within ±10 m" without the mm reading the CLI's
    --com gives; [1.6, 0.35] said "centre_of_mass.2 = [1.6, 0.35]: Field required"."""
    data = _profile_dict()
    data["implements"]["cat2-spreader-400"]["centre_of_mass"] = com
    with pytest.raises(TractorProfileError) as err:
        tractor_profile_from_dict(data)
    assert "implements.cat2-spreader-400.centre_of_mass" in str(err.value) and words in str(err.value), str(err.value)
