"""The serial arm through the same SQP core, checked against the closed-form 6R solutions."""

import numpy as np
import pytest

from planner.arm.analytic import build_spherical_wrist_arm, solve_arm_ik
from planner.arm.dh import forward_kinematics
from planner.arm.mechanism import arm_target, arm_weights, build_arm_mechanism
from planner.arm.profile import load_arm_profile
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
