"""Closed-form inverse vs forward kinematics (two independent computation paths)."""

import numpy as np
import pytest

from planner.model.angle_maps import AngleMaps
from planner.model.exact_inverse import ExactInverse
from planner.model.types import KinematicsError, ModelInputError
from tests.helpers import random_closing_actuators


@pytest.fixture(scope="module")
def inverse(model):
    return ExactInverse(model)


def test_round_trip_pose_actuators_pose(model, inverse, rng):
    ws = model.workspace
    lo = np.array([ws[k][0] for k in ("x", "z", "roll", "pitch")]) - 0.05
    hi = np.array([ws[k][1] for k in ("x", "z", "roll", "pitch")]) + 0.05
    for _ in range(500):
        t = lo + (hi - lo) * rng.random(4)
        q, jac = inverse.solve(t)
        s = model.forward(q)
        np.testing.assert_allclose(s.pose.controlled(), t, atol=1e-12)
        assert s.lower_span == pytest.approx(model.span, abs=1e-12)  # rigidity (thesis 2.49)


def test_jacobian_is_the_inverse_of_the_forward_jacobian(model, inverse, rng):
    for _ in range(20):
        t = np.array([0.05, 0.15, 0.03, -0.02]) * (2 * rng.random(4) - 1) + model.neutral_pose.controlled()
        q, dq_dt = inverse.solve(t)
        _, jf = model.features(q)
        rows = [0, 2, 3, 4]  # x, z, roll, pitch
        np.testing.assert_allclose(jf[rows] @ dq_dt, np.eye(4), atol=1e-9)


def test_actuators_pose_actuators_for_implement_consistent_vectors(model, inverse, rng):
    """Vectors that satisfy the rigidity constraint come back unchanged."""
    for q0 in random_closing_actuators(model, rng, 200):
        s = model.forward(q0)
        if abs(s.lower_span - model.span) > 0.01:
            continue
        # move the right limiter so the span matches exactly, then invert the pose
        q = q0.copy()
        for _ in range(30):
            f, j = model.features(q)
            q[4] -= (f[6] - model.span) / j[6, 4]
        p = model.forward(q).pose
        np.testing.assert_allclose(inverse(p.x, p.z, p.roll, p.pitch), q, atol=1e-10)


@pytest.mark.parametrize("target", [{"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.0}, "abc", None])
def test_a_target_that_is_not_four_numbers_is_a_model_input_error(inverse, target):
    """An engineer's report: a Target given to ExactInverse.solve raised numpy's TypeError, not a HitchError."""
    with pytest.raises(ModelInputError, match=r"target must be 4 finite numbers \(x \[m\]"):
        inverse.solve(target)


def test_unreachable_pose_raises(inverse):
    with pytest.raises(KinematicsError):
        inverse(0.0, 3.0, 0.0, 0.0)
    with pytest.raises(ValueError, match="finite"):
        inverse(0.0, float("nan"), 0.0, 0.0)


def test_angle_maps_round_trip(model, rng):
    maps = AngleMaps(model.profile)
    for q in random_closing_actuators(model, rng, 100):
        th = np.array(model.forward(q).link_angles)
        np.testing.assert_allclose(maps.to_angles(*q[[0, 1, 3, 4]]), th, atol=1e-12)
        np.testing.assert_allclose(maps.to_actuators(th), q[[0, 1, 3, 4]], atol=1e-12)


def test_batch_inverse_is_solve_full_row_by_row(model, inverse, rng):
    """solve_batch: actuators, y_T and yaw bit for bit those of solve_full; the actuator velocity
    its jac @ v to 1e-12; ``ok`` exactly the rows solve_full accepts (also out of the workspace)."""
    ws = model.workspace
    lo = np.array([ws[k][0] for k in ("x", "z", "roll", "pitch")]) - 0.05
    hi = np.array([ws[k][1] for k in ("x", "z", "roll", "pitch")]) + 0.05
    P = lo + (hi - lo) * rng.random((400, 4))
    V = rng.normal(0.0, 0.3, (400, 4))
    P[5] = [0.0, -3.0, 0.0, 0.0]  # far below any reach
    P[6, 2] = np.pi / 2  # roll at the singular limit
    P[7, 3] = -np.pi / 2
    P[8, 1] = np.nan
    P[9, 0] = np.inf
    b = inverse.solve_batch(P, V)
    assert b.actuators.shape == b.actuator_velocity.shape == (400, 5) and b.y.shape == b.yaw.shape == (400,)
    refused = 0
    for k in range(len(P)):
        try:
            q, jac, (y, yaw) = inverse.solve_full(P[k])
        except (KinematicsError, ModelInputError):
            assert not b.ok[k], k
            refused += 1
            continue
        assert b.ok[k], k
        assert np.array_equal(b.actuators[k], q) and b.y[k] == y and b.yaw[k] == yaw, k
        np.testing.assert_allclose(b.actuator_velocity[k], jac @ V[k], rtol=0, atol=1e-12)
    assert refused >= 5


def test_batch_inverse_refuses_bad_shapes(inverse):
    with pytest.raises(ModelInputError, match="targets and velocities"):
        inverse.solve_batch(np.zeros((3, 4)), np.zeros((3, 3)))
    with pytest.raises(ModelInputError, match="targets and velocities"):
        inverse.solve_batch(np.zeros(4), np.zeros(4))
    empty = inverse.solve_batch(np.zeros((0, 4)), np.zeros((0, 4)))
    assert empty.actuators.shape == (0, 5) and empty.ok.shape == (0,)


def test_jacobians_are_those_of_solve_bit_for_bit(model, inverse, rng):
    """jacobians (one mapped call, as straight_line_limits uses it): solve()[1] of every target,
    bit for bit; the first target solve refuses raises solve's error."""
    ws = model.workspace
    lo = np.array([ws[k][0] for k in ("x", "z", "roll", "pitch")])
    hi = np.array([ws[k][1] for k in ("x", "z", "roll", "pitch")])
    P = lo + (hi - lo) * rng.random((77, 4))
    J = inverse.jacobians(P)
    assert J.shape == (77, 5, 4)
    for k in range(len(P)):
        assert np.array_equal(J[k], inverse.solve(P[k])[1]), k
    assert inverse.jacobians(np.zeros((0, 4))).shape == (0, 5, 4)
    bad = P[:3].copy()
    bad[1] = [0.0, 3.0, 0.0, 0.0]
    with pytest.raises(KinematicsError):
        inverse.jacobians(bad)
    bad[1] = [0.0, np.nan, 0.0, 0.0]
    with pytest.raises(ModelInputError, match="finite"):
        inverse.jacobians(bad)
    with pytest.raises(ModelInputError, match=r"\(N, 4\)"):
        inverse.jacobians(np.zeros(4))


def test_solve_full_repeated_target_gives_fresh_equal_answers(inverse):
    """The last answer is kept for a repeated target: the same values, in new arrays (a caller
    changing what it got changes nothing for the next), and a different target is solved afresh."""
    t = np.array([0.01, 0.6, 0.02, -0.01])
    q1, j1, yy1 = inverse.solve_full(t)
    q1[:] = 0.0
    j1[:] = 0.0
    q2, j2, yy2 = inverse.solve_full(t.copy())
    q_other = inverse.solve_full(t + [0.01, 0.0, 0.0, 0.0])[0]
    q3, j3, _ = inverse.solve_full(t)
    assert yy1 == yy2 and np.any(q2 != 0.0) and np.any(j2 != 0.0)
    assert np.array_equal(q2, q3) and np.array_equal(j2, j3) and not np.array_equal(q_other, q2)
    fresh = ExactInverse(inverse.model).solve_full(t)
    assert np.array_equal(fresh[0], q2) and np.array_equal(fresh[1], j2) and fresh[2] == yy2
