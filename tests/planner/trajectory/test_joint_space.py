"""``plan_joint_move``: a rest-to-rest move against Ruckig's own sampling (start, goal, limits kept), and bad input
refused with an error of the project naming the argument, the joint and the value (a reviewer's reproductions:
a goal of one value for six joints planned the other five to 0, NaN and mismatched limits escaped as Ruckig's or
numpy's errors, a goal beyond its limit did not say by how much)."""

from __future__ import annotations

import numpy as np
import pytest

from planner.errors import HitchInputError
from planner.trajectory import PlanError, TrajectoryInputError, plan_joint_move

KW = {"velocity": 1.0, "acceleration": 2.0, "jerk": 10.0}
LO, HI = np.full(6, -3.0), np.full(6, 3.0)


def test_a_move_starts_and_ends_at_rest_on_its_points_within_its_limits():
    q0, q1 = np.zeros(6), np.array([0.5, -1.0, 0.2, 0.0, 1.5, -0.3])
    v = np.array([1.0, 0.5, 1.0, 1.0, 2.0, 1.0])
    r = plan_joint_move(q0, q1, velocity=v, acceleration=2.0, jerk=10.0, rate=200.0, lower=LO, upper=HI)
    np.testing.assert_allclose(r.position[0], q0, atol=1e-12)
    np.testing.assert_allclose(r.position[-1], q1, atol=1e-9)
    np.testing.assert_allclose(r.velocity[[0, -1]], 0.0, atol=1e-9)
    assert np.all(np.abs(r.velocity) <= v + 1e-9) and np.all(np.abs(r.acceleration) <= 2.0 + 1e-9)
    # time-synchronised: every joint that moves is still moving until the end
    moving = np.abs(q1 - q0) > 0
    assert np.all(np.abs(r.position[-3][moving] - q1[moving]) > 0)


def test_an_infinite_joint_limit_is_no_limit_and_nan_is_refused():
    """A continuous joint has no limit: ±inf as before the input checks (a reviewer's finding); NaN is no limit."""
    lo, hi = np.full(6, -np.inf), np.full(6, np.inf)
    r = plan_joint_move(np.zeros(6), np.full(6, 10.0), **KW, lower=lo, upper=hi)
    np.testing.assert_allclose(r.position[-1], 10.0, atol=1e-9)
    with pytest.raises(TrajectoryInputError, match=r"upper\[1\] must be a number \(±inf: no limit\), got nan"):
        plan_joint_move(np.zeros(6), np.ones(6), **KW, lower=lo, upper=[np.inf, np.nan, 1, 1, 1, 1])


@pytest.mark.parametrize(
    ("args", "kw", "error", "text"),
    [
        ((np.zeros(6), [1.0]), KW, TrajectoryInputError, "goal must be 6 values"),
        ((np.zeros(6), [1.0] * 7), KW, TrajectoryInputError, "goal must be 6 values"),
        (([np.nan] * 6, np.zeros(6)), KW, TrajectoryInputError, "start[0] must be a finite number, got nan"),
        ((np.zeros(6), [0, 0, np.inf, 0, 0, 0]), KW, TrajectoryInputError, "goal[2] must be a finite number"),
        ((np.zeros(6), np.ones(6)), {**KW, "lower": LO[:3], "upper": HI}, TrajectoryInputError, "lower must be 6"),
        ((np.zeros(6), np.ones(6)), {**KW, "velocity": [1, 2]}, TrajectoryInputError, "one number or 6"),
        ((np.zeros(6), np.ones(6)), {**KW, "jerk": [1, 1, 0, 1, 1, 1]}, TrajectoryInputError, "jerk limit of joint 2"),
        ((0.0, 1.0), KW, TrajectoryInputError, "start must be a non-empty vector"),
        ((np.zeros(6), np.ones(6)), {**KW, "rate": float("nan")}, TrajectoryInputError, "rate must lie within"),
        ((np.zeros(6), np.ones(6)), {**KW, "lower": HI, "upper": LO}, TrajectoryInputError, "is above its upper"),
        (
            (np.zeros(6), np.ones(6)),
            {"velocity": 1e-9, "acceleration": 1e9, "jerk": 1e12},
            PlanError,
            "longer than Ruckig's numerical limit",
        ),
        (
            (np.zeros(6), [30, 0, 0, 0, 0, 0]),
            {**KW, "lower": LO, "upper": HI},
            PlanError,
            "goal joint 0 = 30 is above its limit 3 (allowed [-3, 3])",
        ),
    ],
)
def test_bad_input_is_refused_naming_the_argument_and_the_value(args, kw, error, text):
    with pytest.raises(error) as e:
        plan_joint_move(*args, **kw)
    assert isinstance(e.value, HitchInputError) and text in str(e.value), str(e.value)
