"""Forward kinematics against geometric invariants, finite differences and stated signs."""

import math

import numpy as np
import pytest

from planner.model.geometry import link_direction
from planner.model.kinematics import FEATURE_NAMES, POINT_NAMES, HitchModel
from planner.model.types import Actuators, KinematicsError, ModelInputError
from tests.helpers import random_closing_actuators

G = None


def dist(a, b):
    return float(np.linalg.norm(np.asarray(a) - np.asarray(b)))


def test_geometric_invariants_on_random_actuators(model, rng):
    g = model.profile.geometry
    for q in random_closing_actuators(model, rng, 300):
        s = model.forward(q)
        P = s.points
        assert set(POINT_NAMES) <= set(P)
        assert dist(P["L"], P["L0"]) == pytest.approx(g.lower_link_length, abs=1e-12)
        assert dist(P["R"], P["R0"]) == pytest.approx(g.lower_link_length, abs=1e-12)
        assert dist(P["S_l"], P["Q_l"]) == pytest.approx(g.lift_arm_length, abs=1e-12)
        assert dist(P["S_r"], P["Q_r"]) == pytest.approx(g.lift_arm_length, abs=1e-12)
        assert dist(P["A_l"], P["S_l"]) == pytest.approx(g.fixed_lift_rod_length, abs=1e-10)
        assert dist(P["A_r"], P["S_r"]) == pytest.approx(q[1], abs=1e-10)
        assert dist(P["B_l"], P["C_l"]) == pytest.approx(q[3], abs=1e-10)
        assert dist(P["B_r"], P["C_r"]) == pytest.approx(q[4], abs=1e-10)
        assert dist(P["U"], P["H"]) == pytest.approx(q[2], abs=1e-10)
        assert dist(P["U"], P["T"]) == pytest.approx(model.mast_height, abs=1e-12)
        assert np.dot(P["U"] - P["T"], P["R"] - P["L"]) == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose(P["T"], (P["L"] + P["R"]) / 2, atol=1e-15)
        assert P["S_l"][2] == pytest.approx(P["S_r"][2], abs=1e-15)  # shared lift shaft
        # A and B' lie on the link at their distances; the bracket is horizontal and ⟂ the link
        for side, piv, end in (("l", "L0", "L"), ("r", "R0", "R")):
            d = (P[end] - P[piv]) / g.lower_link_length
            np.testing.assert_allclose(P[f"A_{side}"], P[piv] + g.lift_rod_attachment * d, atol=1e-12)
            np.testing.assert_allclose(P[f"Bp_{side}"], P[piv] + g.limiter_bracket_position * d, atol=1e-12)
            br = P[f"B_{side}"] - P[f"Bp_{side}"]
            assert np.linalg.norm(br) == pytest.approx(g.limiter_bracket_offset, abs=1e-12)
            assert br[2] == pytest.approx(0.0, abs=1e-12) and np.dot(br, d) == pytest.approx(0.0, abs=1e-12)
        # the bracket points outward: left to +x, right to -x
        assert (P["B_l"] - P["Bp_l"])[0] > 0 and (P["B_r"] - P["Bp_r"])[0] < 0


def test_pose_definitions_match_points(model, rng):
    for q in random_closing_actuators(model, rng, 100):
        s = model.forward(q)
        P, p = s.points, s.pose
        L, R, T, U = P["L"], P["R"], P["T"], P["U"]
        np.testing.assert_allclose([p.x, p.y, p.z], T, atol=1e-15)
        assert p.roll == pytest.approx(math.atan2(R[2] - L[2], L[0] - R[0]), abs=1e-14)
        assert p.yaw == pytest.approx(math.atan2(L[1] - R[1], L[0] - R[0]), abs=1e-14)
        # pitch: right-hand rotation about x_i (R→L) of the mast from the vertical plane through x_i
        xi = (L - R) / np.linalg.norm(L - R)
        up = np.array([0, 0, 1.0]) - xi[2] * xi
        up /= np.linalg.norm(up)
        m = (U - T) / np.linalg.norm(U - T)
        assert p.pitch == pytest.approx(math.atan2(np.dot(np.cross(up, m), xi), np.dot(up, m)), abs=1e-12)
        assert s.lower_span == pytest.approx(np.linalg.norm(L - R), abs=1e-14)


def test_link_angles_reproduce_points(model, rng):
    """Thesis 2.19-2.20: L = L0 + l_vv · dir(θx, θz) with the fixed XYZ rotation."""
    for q in random_closing_actuators(model, rng, 50):
        s = model.forward(q)
        txl, tzl, txr, tzr = s.link_angles
        l_vv = model.profile.geometry.lower_link_length
        np.testing.assert_allclose(
            s.points["L"], s.points["L0"] + l_vv * np.array(link_direction(txl, tzl)).ravel(), atol=1e-12
        )
        np.testing.assert_allclose(
            s.points["R"], s.points["R0"] + l_vv * np.array(link_direction(txr, tzr)).ravel(), atol=1e-12
        )


def test_jacobian_matches_central_differences(model, rng):
    h = 1e-6
    for q in random_closing_actuators(model, rng, 40):
        _, jac = model.features(q)
        num = np.zeros_like(jac)
        for i in range(5):
            d = np.zeros(5)
            d[i] = h
            num[:, i] = (model.features(q + d)[0] - model.features(q - d)[0]) / (2 * h)
        np.testing.assert_allclose(jac, num, atol=2e-7, rtol=1e-6)
    assert jac.shape == (len(FEATURE_NAMES), 5)


def test_pose_is_continuous_along_actuator_sweeps(model):
    for i in range(5):
        q = model.neutral.copy()
        prev = None
        for v in np.linspace(model.lower[i], model.upper[i], 400):
            q[i] = v
            try:
                p = model.forward(q).pose.as_array()
            except KinematicsError:
                prev = None
                continue
            if prev is not None:
                step = (model.upper[i] - model.lower[i]) / 399
                # a pose change per step bounded by a few times the step (no branch jumps)
                assert np.max(np.abs(p - prev)) < 5 * step + 1e-12
            prev = p


def _dp(model, i, delta=0.005):
    q = model.neutral.copy()
    base = model.forward(q)
    q[i] += delta
    return base, model.forward(q)


def test_sign_conventions(model):
    """The signs stated in README "Frames and signs"."""
    b, s = _dp(model, 0)  # lift up
    assert s.pose.z > b.pose.z + 0.003
    b, s = _dp(model, 1)  # tilt (right lift rod) longer -> right end lower -> roll negative
    assert s.points["R"][2] < b.points["R"][2] and s.pose.roll < -1e-3
    b, s = _dp(model, 2)  # top link longer -> mast top rearward -> pitch negative (positive = mast top forward)
    assert s.points["U"][1] > b.points["U"][1] and s.pose.pitch < -1e-3
    # the limiter bracket sits outboard of the link (thesis 2.8), so a longer limiter pushes the
    # bracket rearward and swings its link INWARD (thesis 2.13 has the same sign)
    b, s = _dp(model, 3)  # left limiter longer -> left end inward (-x) -> implement moves right
    assert s.points["L"][0] < b.points["L"][0] and s.pose.x < b.pose.x
    b, s = _dp(model, 4)  # right limiter longer -> right end inward (+x) -> implement moves left
    assert s.points["R"][0] > b.points["R"][0] and s.pose.x > b.pose.x
    q = model.neutral.copy()
    q[3:] += 0.005  # both longer -> both links inward -> span shrinks
    assert model.forward(q).lower_span < model.span
    # +x is the driver's left: the left lower link is at +x
    assert b.points["L0"][0] > 0 and b.points["L"][0] > 0


def test_neutral_pose(model):
    s = model.forward(model.neutral)
    assert s.pose.x == pytest.approx(0, abs=1e-12) and s.pose.pitch == pytest.approx(0, abs=1e-12)
    assert s.pose.roll == pytest.approx(0, abs=1e-12) and s.pose.yaw == pytest.approx(0, abs=1e-12)
    assert s.lower_span == pytest.approx(0.825 + 0.040, abs=1e-12)
    # the assumed limiter tractor point puts both limiters mid-stroke for category 2
    assert model.neutral[3] == pytest.approx((0.540 + 0.5375) / 2, abs=1e-6)
    assert model.neutral[4] == pytest.approx((0.540 + 0.5375) / 2, abs=1e-6)
    assert np.all(model.neutral >= model.lower) and np.all(model.neutral <= model.upper)


@pytest.mark.parametrize(
    "change, cause",
    [
        ({1: 5.0}, "tilt cylinder"),
        ({3: 3.0}, "left sway limiter"),
        ({4: 3.0}, "right sway limiter"),
        ({2: 5.0}, "top link"),
        ({2: 0.01}, "top link"),
    ],
)
def test_impossible_actuators_raise_named_cause(model, change, cause):
    q = model.neutral.copy()
    for i, v in change.items():
        q[i] = v
    with pytest.raises(KinematicsError, match=cause):
        model.forward(q)


def test_bad_actuator_input(model):
    with pytest.raises(ValueError, match="actuators.tilt"):
        model.forward([0.2, math.nan, 0.7, 0.5, 0.5])
    with pytest.raises(ValueError, match="5 values"):
        model.forward([0.2, 0.6])
    assert model.forward(Actuators.from_array(model.neutral)).pose.x == pytest.approx(0, abs=1e-12)
    # text, and a lift angle in degrees (12.6 for the neutral 0.22 rad closed the mechanism: a pose z = -0.068 m)
    with pytest.raises(ModelInputError, match=r"expected 5 numbers .* got 'abcde'"):
        model.forward("abcde")
    degrees = model.neutral.copy()
    degrees[0] = math.degrees(model.neutral[0])
    with pytest.raises(ModelInputError, match=r"actuators.lift = 12.6\d* rad is beyond ±π.*did you mean degrees"):
        model.forward(degrees)
    edge = model.neutral.copy()
    edge[0] = math.pi + 2 * math.pi  # the same angle as π: refused too (one turn is never meant)
    with pytest.raises(ModelInputError, match="beyond ±π"):
        model.points(edge)


def test_never_nan_over_a_wide_box(model, rng):
    """Far outside the strokes: either a finite state or KinematicsError, never NaN."""
    lo, hi = model.lower - 0.5, model.upper + 0.5
    for _ in range(500):
        q = lo + (hi - lo) * rng.random(5)
        try:
            s = model.forward(q)
        except KinematicsError:
            continue
        assert np.all(np.isfinite(s.pose.as_array()))


def test_every_category_builds_and_has_its_span():
    for cat, span in [
        ("1N", 0.400),
        ("1", 0.683),
        ("2N", 0.683),
        ("2", 0.825),
        ("3N", 0.825),
        ("3", 0.965),
        ("4N", 0.952),
        ("4", 1.1665),
    ]:
        m = HitchModel.from_profile(category=cat)
        assert m.span == pytest.approx(span + 0.040)
        assert m.forward(m.neutral).lower_span == pytest.approx(span + 0.040, abs=1e-12)
