"""The serial arm through the same SQP core, checked against the closed-form 6R solutions."""

import numpy as np
import pytest

from planner.arm.analytic import build_spherical_wrist_arm, solve_arm_ik
from planner.arm.dh import forward_kinematics
from planner.arm.mechanism import arm_target, arm_weights, build_arm_mechanism
from planner.arm.profile import load_arm_profile
from planner.arm.transforms import ArmInputError
from planner.ik_qp.mechanism import Mechanism
from planner.ik_qp.problem import build_ik_problem
from planner.ik_qp.sqp import SQPSolver
from planner.trajectory import plan_joint_move


@pytest.fixture(scope="module")
def setup():
    chain = load_arm_profile().chain()
    return chain, build_spherical_wrist_arm(chain), build_arm_mechanism(chain)


def random_pose(chain, rng):
    q = rng.uniform(-2.5, 2.5, 6)
    T = forward_kinematics(chain, q).end
    return q, T[:3, 3], T[:3, :3]


def test_qp_seeded_near_an_analytic_solution_converges_to_it(setup, rng):
    chain, arm, mech = setup
    solver = SQPSolver(mech)
    hits, total = 0, 0
    for _ in range(40):
        _, p, R = random_pose(chain, rng)
        res = solve_arm_ik(arm, p, R)
        for s in res.solutions[:2]:
            total += 1
            prob = build_ik_problem(mech, arm_target(p, R), arm_weights())
            r = solver.solve(prob, seed=np.asarray(s.joints) + rng.normal(0, 0.01, 6))
            T = forward_kinematics(chain, r.q).end
            assert np.max(np.abs(T[:3, 3] - p)) < 1e-9 and np.max(np.abs(T[:3, :3] - R)) < 1e-9
            hits += np.max(np.abs(r.q - s.joints)) < 1e-6
    assert hits / total >= 0.95  # measured 49/50 in bench/arm_bench.py; a different branch is still exact


def test_qp_from_a_neutral_seed_reaches_the_target(setup, rng):
    chain, arm, mech = setup
    solver = SQPSolver(mech)
    ok = 0
    for _ in range(30):
        _, p, R = random_pose(chain, rng)
        r = solver.solve(build_ik_problem(mech, arm_target(p, R), arm_weights()), seed=np.zeros(6))
        if r.status == "ok":
            T = forward_kinematics(chain, r.q).end
            assert np.max(np.abs(T[:3, 3] - p)) < 1e-9
            ok += 1
    assert ok >= 25


def test_unreachable_arm_target_is_limited_not_nan(setup):
    chain, arm, mech = setup
    r = SQPSolver(mech).solve(
        build_ik_problem(mech, arm_target([1.0, 0.0, 0.5], np.eye(3)), arm_weights()), seed=np.zeros(6)
    )
    assert r.status == "limited" and np.all(np.isfinite(r.q))


def test_joint_space_ruckig_move_between_two_arm_poses(setup, rng):
    chain, arm, _ = setup
    q0, q1 = rng.uniform(-1, 1, 6), rng.uniform(-1, 1, 6)
    lo = np.array([link.lower for link in chain.links])
    hi = np.array([link.upper for link in chain.links])
    js = plan_joint_move(q0, q1, velocity=1.0, acceleration=2.0, jerk=10.0, rate=100.0, lower=lo, upper=hi)
    np.testing.assert_allclose(js.position[0], q0, atol=1e-12)
    np.testing.assert_allclose(js.position[-1], q1, atol=1e-12)
    assert np.all(np.abs(js.velocity) <= 1.0 + 1e-9) and np.all(np.abs(js.acceleration) <= 2.0 + 1e-9)
    # time-synchronised: every joint still moving until the end (none finishes early)
    moving = np.abs(q1 - q0) > 1e-6
    mid = len(js.t) // 2
    assert np.all(np.abs(js.velocity[mid, moving]) > 0)


# A reachable pose (the FK of an in-limit q, eight admissible closed-form solutions) on which the SQP
# from the zero seed stops in a local minimum at the wrist_bend limit π.
LOCAL_MINIMUM_Q = np.array([1.060136, -2.635184, 0.333577, -1.37129, 2.277907, -2.614713])


def test_qp_local_minimum_of_a_reachable_target_is_not_called_out_of_reach(setup):
    chain, arm, mech = setup
    T = forward_kinematics(chain, LOCAL_MINIMUM_Q).end
    assert len(solve_arm_ik(arm, T[:3, 3], T[:3, :3]).admissible) == 8  # reachable
    r = SQPSolver(mech).solve(build_ik_problem(mech, arm_target(T[:3, 3], T[:3, :3]), arm_weights()), seed=np.zeros(6))
    assert r.status == "limited" and r.residual > 0.05  # the local minimum (solver numerics unchanged)
    assert "target out of reach" not in r.reason
    assert "stopped at limit joint:wrist_bend:max with weighted residual 0.0871" in r.reason
    assert "a local minimum or out of reach (a local solver cannot tell" in r.reason and "solve_arm_ik" in r.reason
    # a revolute joint's limit is a joint limit, not a stroke
    assert r.active == ("joint:wrist_bend:max",) and r.at_bound == ("joint:wrist_bend:max",)
    assert "stroke" not in r.reason


def test_qp_unreachable_arm_target_reason_claims_no_more_than_a_local_solver_knows(setup):
    chain, arm, mech = setup
    p, R = [1.0, 0.0, 0.5], np.eye(3)
    assert not solve_arm_ik(arm, p, R).reachable  # the closed form knows; the SQP cannot
    r = SQPSolver(mech).solve(build_ik_problem(mech, arm_target(p, R), arm_weights()), seed=np.zeros(6))
    assert r.status == "limited"
    assert "a local minimum or out of reach" in r.reason and "target out of reach" not in r.reason
    assert all(name.startswith("joint:") for name in r.active + r.at_bound)


def test_arm_mechanism_names_joint_limits_the_hitch_keeps_strokes(setup):
    _, _, mech = setup
    assert isinstance(mech, Mechanism) and mech.limit_kind == "joint" and mech.several_solutions
    plain = Mechanism("plain", mech.actuator_names, mech.lower, mech.upper, mech.task, mech.task_names)
    assert plain.limit_kind == "stroke" and (plain.several_solutions, plain.several_solutions_note) == (False, "")


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: arm_target([0, 0], np.eye(3)), r"position must be 3 numbers \[m\] \(x, y, z\), got shape \(2,\)"),
        (lambda: arm_target([0, 0, "x"], np.eye(3)), r"position must be 3 numbers"),
        (lambda: arm_target([0, 0, float("nan")], np.eye(3)), r"position\[2\] must be finite, got nan"),
        (lambda: arm_target([0, 0, 0], np.eye(2)), r"rotation must be a 3x3 matrix \(9 numbers\), got shape \(2, 2\)"),
        (lambda: arm_weights(-1), r"orientation_length = -1\.0 m is outside the allowed \[0, 100\] m"),
        (lambda: arm_weights(float("nan")), r"orientation_length = nan m is outside the allowed \[0, 100\] m"),
        (lambda: arm_weights(float("inf")), r"orientation_length = inf m is outside"),
        (lambda: arm_weights(True), r"orientation_length must be a number \[m\], got bool True"),
        (lambda: arm_weights(150.0), r"outside the allowed \[0, 100\] m; did you mean mm\? 150 mm = 0\.15 m"),
    ],
)
def test_arm_target_and_weights_reject_bad_input_naming_the_field(call, match):
    with pytest.raises(ArmInputError, match=match):
        call()


def test_arm_target_and_weights_accept_what_they_did():
    R = np.arange(9.0).reshape(3, 3)
    np.testing.assert_array_equal(arm_target((1, 2, 3), R), np.r_[1.0, 2.0, 3.0, R.reshape(9, order="F")])
    np.testing.assert_array_equal(arm_target(np.array([[1], [2], [3]]), R.reshape(9)), arm_target((1, 2, 3), R))
    np.testing.assert_array_equal(arm_weights(0), np.r_[np.ones(3), np.zeros(9)])  # position only
    np.testing.assert_array_equal(arm_weights(np.float64(0.2)), np.r_[np.ones(3), np.full(9, 0.2)])
