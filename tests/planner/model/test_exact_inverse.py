"""Closed-form inverse vs forward kinematics (two independent computation paths)."""

import numpy as np
import pytest

from planner.model.angle_maps import AngleMaps
from planner.model.exact_inverse import ExactInverse
from planner.model.types import KinematicsError
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
