"""Mechanism-agnostic tests of the SQP/QP inverse-kinematics core (``planner.ik_qp``).

Independent truth: closed-form inverse kinematics of a planar two-link arm and of a rigid
bar on four prismatic coordinates, closed-form nearest points when a target is out of
reach (arm straight, stroke limit, inequality limit, workspace bound), brute-force grid
searches, and the KKT conditions of the QPs. Everything is SI (m, rad).
"""

import dataclasses
import math

import casadi as ca
import numpy as np
import pytest

from planner.ik_qp.backends import BACKENDS, QPData, make_backend
from planner.ik_qp.backends.osqp_backend import polish_solution
from planner.ik_qp.mechanism import Mechanism, build_mechanism
from planner.ik_qp.problem import TaskBounds, build_ik_problem
from planner.ik_qp.sqp import SQPSettings, SQPSolver

L1, L2 = 1.0, 0.7  # planar arm link lengths [m]
SPAN = 0.8  # rigid bar length [m]


# ---------------------------------------------------------------- test mechanisms
def arm2(lower=(-1.5, 0.2), upper=(1.5, 2.6), elbow_min=None):
    """Planar 2R arm, task = end point (x, y); optional inequality: elbow height >= elbow_min."""
    q = ca.SX.sym("q", 2)
    x = L1 * ca.cos(q[0]) + L2 * ca.cos(q[0] + q[1])
    y = L1 * ca.sin(q[0]) + L2 * ca.sin(q[0] + q[1])
    extra = {}
    if elbow_min is not None:
        extra = dict(
            inequality=L1 * ca.sin(q[0]), inequality_names=["elbow_height"], g_lower=[elbow_min], g_upper=[np.inf]
        )
    return build_mechanism(
        "arm2",
        q,
        ca.vertcat(x, y),
        actuator_names=["j1", "j2"],
        lower=lower,
        upper=upper,
        task_names=["x", "y"],
        **extra,
    )


def arm2_fk(q):
    return np.array(
        [L1 * math.cos(q[0]) + L2 * math.cos(q[0] + q[1]), L1 * math.sin(q[0]) + L2 * math.sin(q[0] + q[1])]
    )


def arm2_ik(x, y):
    """Closed-form inverse kinematics, elbow branch q2 > 0."""
    c2 = (x * x + y * y - L1 * L1 - L2 * L2) / (2 * L1 * L2)
    q2 = math.acos(c2)
    q1 = math.atan2(y, x) - math.atan2(L2 * math.sin(q2), L1 + L2 * math.cos(q2))
    return np.array([q1, q2])


def arm3():
    """Planar 3R arm, task = end point and orientation (x, y, phi)."""
    q = ca.SX.sym("q", 3)
    a = ca.cumsum(q)
    lengths = (1.0, 0.8, 0.5)
    x = sum(length * ca.cos(a[i]) for i, length in enumerate(lengths))
    y = sum(length * ca.sin(a[i]) for i, length in enumerate(lengths))
    return build_mechanism(
        "arm3",
        q,
        ca.vertcat(x, y, a[2]),
        actuator_names=["j1", "j2", "j3"],
        lower=[-1.0, 0.2, -2.0],
        upper=[1.5, 2.4, 2.0],
        task_names=["x", "y", "phi"],
    )


def bar(tilt=None, side_names=None):
    """Rigid bar L-R of length SPAN on four coordinates q = (xl, zl, xr, zr).

    Task: midpoint (x, z) and roll = atan2(zr - zl, xr - xl). Equality: |R - L| = SPAN (the
    analogue of the hitch's implement rigidity). Optional inequality: |zr - zl| <= tilt."""
    q = ca.SX.sym("q", 4)
    xl, zl, xr, zr = (q[i] for i in range(4))
    task = ca.vertcat((xl + xr) / 2, (zl + zr) / 2, ca.atan2(zr - zl, xr - xl))
    extra = {}
    if tilt is not None:
        extra = dict(
            inequality=zr - zl,
            inequality_names=["tilt"],
            g_lower=[-tilt],
            g_upper=[tilt],
            inequality_side_names=side_names,
        )
    return build_mechanism(
        "bar",
        q,
        task,
        actuator_names=["xl", "zl", "xr", "zr"],
        lower=[-2, 0, -2, 0],
        upper=[2, 1, 2, 1],
        task_names=["x", "z", "roll"],
        equality=ca.sqrt((xr - xl) ** 2 + (zr - zl) ** 2) - SPAN,
        equality_names=["rigidity"],
        **extra,
    )


def bar_ik(x, z, roll):
    h = 0.5 * SPAN * np.array([math.cos(roll), math.sin(roll)])
    return np.array([x - h[0], z - h[1], x + h[0], z + h[1]])


def bar_span(q):
    return math.hypot(q[2] - q[0], q[3] - q[1])


@pytest.fixture(scope="module")
def arm():
    return arm2()


@pytest.fixture(scope="module")
def rigid_bar():
    return bar()


def check_solution(sol, mech, tol=1e-9):
    """Invariants of every result: finite, inside the strokes, feasible unless failed."""
    for name in ("q", "task", "error"):
        assert np.all(np.isfinite(getattr(sol, name))), name
    assert np.all(sol.q >= mech.lower) and np.all(sol.q <= mech.upper)
    assert math.isfinite(sol.residual) and sol.iterations >= 0
    if sol.status != "failed":
        assert sol.violation <= tol


# ---------------------------------------------------------------- reachable targets
def test_arm_round_trip_matches_closed_form(arm, rng):
    solver = SQPSolver(arm)
    for _ in range(60):
        q_true = np.array([rng.uniform(-1.2, 1.2), rng.uniform(0.35, 2.4)])
        target = arm2_fk(q_true)
        sol = solver.solve(build_ik_problem(arm, target), seed=rng.uniform(arm.lower, arm.upper))
        check_solution(sol, arm)
        assert sol.status == "ok", sol.reason
        assert sol.residual <= 1e-9
        np.testing.assert_allclose(arm2_fk(sol.q), target, atol=1e-9)  # independent FK
        np.testing.assert_allclose(sol.q, arm2_ik(*target), atol=1e-7)
        assert sol.active == ()


def test_three_link_round_trip_from_random_seeds(rng):
    mech = arm3()
    solver = SQPSolver(mech)
    for _ in range(40):
        q_true = rng.uniform([-0.8, 0.4, -1.5], [1.2, 2.2, 1.5])
        target = np.array(mech.task(q_true)[0]).ravel()
        seed = np.clip(q_true + rng.uniform(-0.6, 0.6, 3), mech.lower, mech.upper)
        sol = solver.solve(build_ik_problem(mech, target), seed=seed)
        check_solution(sol, mech)
        assert sol.status == "ok", sol.reason
        assert np.abs(sol.task - target).max() <= 1e-9
        np.testing.assert_allclose(sol.q, q_true, atol=1e-7)  # the target's own branch


def test_equality_held_and_closed_form_from_infeasible_seeds(rigid_bar, rng):
    solver = SQPSolver(rigid_bar)
    for _ in range(40):
        target = np.array([rng.uniform(-1, 1), rng.uniform(0.3, 0.7), rng.uniform(-0.35, 0.35)])
        seed = rng.uniform(rigid_bar.lower, rigid_bar.upper)  # |R - L| != SPAN in general
        sol = solver.solve(build_ik_problem(rigid_bar, target), seed=seed)
        check_solution(sol, rigid_bar)
        assert sol.status == "ok", sol.reason
        assert abs(bar_span(sol.q) - SPAN) <= 1e-10  # rigidity, evaluated independently
        np.testing.assert_allclose(sol.q, bar_ik(*target), atol=1e-9)


@pytest.mark.parametrize("backend", BACKENDS)
def test_restoration_when_the_linearised_equality_is_out_of_step_range(rigid_bar, backend):
    # |R - L| = 0.1 at the seed, trust region 0.05 per iteration: the first QPs are infeasible
    solver = SQPSolver(rigid_bar, backend=backend)
    problem = build_ik_problem(rigid_bar, [0.0, 0.5, 0.0], max_step=0.05)
    sol = solver.solve(problem, seed=[0.0, 0.5, 0.1, 0.5])
    assert sol.status == "ok", sol.reason
    if backend == "osqp":
        assert solver.backend.problem("elastic") is not None  # the elastic QP was used
    np.testing.assert_allclose(sol.q, bar_ik(0.0, 0.5, 0.0), atol=1e-9)


def test_final_convergence_is_quadratic(arm):
    # Levenberg-Marquardt damping proportional to the error: r_{k+1} = O(r_k^2)
    q0 = np.array([0.3, 1.2])
    problem = build_ik_problem(arm, arm2_fk(q0 + 3e-3))
    r = [SQPSolver(arm, max_iterations=k).solve(problem, seed=q0).residual for k in (1, 2)]
    r0 = np.linalg.norm(problem.target - arm2_fk(q0))
    assert r[0] <= 10 * r0**2 and r[1] <= 10 * r[0] ** 2 + 1e-15
    sol = SQPSolver(arm).solve(problem, seed=q0)
    assert sol.status == "ok" and sol.iterations <= 3


@pytest.mark.parametrize("backend", BACKENDS)
def test_redundant_unbounded_mechanism(backend, rng):
    # 3 joints, 2 tasks, no strokes: the damping picks a step in the null space
    q = ca.SX.sym("q", 3)
    a = ca.cumsum(q)
    x = sum(length * ca.cos(a[i]) for i, length in enumerate((1.0, 0.8, 0.5)))
    y = sum(length * ca.sin(a[i]) for i, length in enumerate((1.0, 0.8, 0.5)))
    mech = build_mechanism(
        "redundant",
        q,
        ca.vertcat(x, y),
        actuator_names=["a", "b", "c"],
        lower=[-np.inf] * 3,
        upper=[np.inf] * 3,
        task_names=["x", "y"],
    )
    solver = SQPSolver(mech, backend=backend)
    for _ in range(15):
        target = np.array(mech.task(rng.uniform(-1.5, 1.5, 3))[0]).ravel()
        sol = solver.solve(build_ik_problem(mech, target), seed=rng.uniform(-1.5, 1.5, 3))
        check_solution(sol, mech)
        assert sol.status == "ok" and np.abs(sol.task - target).max() <= 1e-9


# ---------------------------------------------------------------- out of reach
def test_beyond_reach_arm_straightens_towards_target():
    mech = arm2(lower=(-3.0, -2.6), upper=(3.0, 2.6))  # q2 = 0 inside the strokes
    solver = SQPSolver(mech)
    for target, seed in (([2.5, 0.3], [0.3, 0.5]), ([0.0, -3.0], [-1.0, 2.0]), ([-1.0, 1.9], [2.0, -2.0])):
        sol = solver.solve(build_ik_problem(mech, target), seed=seed)
        check_solution(sol, mech)
        nearest = (L1 + L2) * np.asarray(target) / np.linalg.norm(target)  # closed form
        assert sol.status == "limited", sol.reason
        assert sol.active == ()  # stopped by the mechanism's reach, not by a limit
        np.testing.assert_allclose(sol.task, nearest, atol=1e-7)
        assert sol.residual == pytest.approx(np.linalg.norm(target) - (L1 + L2), abs=1e-9)


def test_beyond_reach_stopped_by_stroke_limit_closed_form():
    mech = arm2(lower=(-3.0, 0.5), upper=(3.0, 2.6))  # the elbow cannot straighten past 0.5 rad
    solver = SQPSolver(mech)
    r_max = abs(L1 + L2 * np.exp(0.5j))
    for phi in (-1.0, 0.2, 1.3):
        target = 2.5 * np.array([math.cos(phi), math.sin(phi)])
        sol = solver.solve(build_ik_problem(mech, target), seed=[0.0, 1.5])
        check_solution(sol, mech)
        assert sol.status == "limited"
        assert sol.active == ("stroke:j2:min",)
        assert "stroke:j2:min" in sol.reason
        assert sol.q[1] == pytest.approx(0.5, abs=1e-12)
        np.testing.assert_allclose(sol.task, r_max * np.array([math.cos(phi), math.sin(phi)]), atol=1e-8)


def test_stroke_limit_reason_names_the_target_out_of_reach():
    """The default (the hitch's wording and names): a stationary point is the nearest reachable one."""
    mech = arm2(lower=(-3.0, 0.5), upper=(3.0, 2.6))
    sol = SQPSolver(mech).solve(build_ik_problem(mech, [2.5, 0.0]), seed=[0.0, 1.5])
    assert sol.reason.startswith("target out of reach: nearest reachable point, weighted residual ")
    assert sol.reason.endswith("; stopped by stroke:j2:min")


def test_several_solution_mechanism_reason_does_not_claim_out_of_reach():
    base = arm2(lower=(-3.0, 0.5), upper=(3.0, 2.6))
    mech = dataclasses.replace(
        base, limit_kind="joint", several_solutions=True, several_solutions_note="see the closed form"
    )
    sol = SQPSolver(mech).solve(build_ik_problem(mech, [2.5, 0.0]), seed=[0.0, 1.5])
    ref = SQPSolver(base).solve(build_ik_problem(base, [2.5, 0.0]), seed=[0.0, 1.5])
    np.testing.assert_array_equal(sol.q, ref.q)  # same numerics, other words
    assert sol.status == "limited" and sol.active == ("joint:j2:min",) and sol.at_bound == ("joint:j2:min",)
    assert sol.reason == (
        f"stopped at limit joint:j2:min with weighted residual {sol.residual:.3g}: a local minimum or out of "
        "reach (a local solver cannot tell; see the closed form)"
    )


def test_inequality_limit_closed_form_nearest_point():
    # elbow height L1 sin(q1) >= 0.3: the target below needs a lower elbow
    mech = arm2(lower=(-1.5, -2.6), upper=(1.5, 2.6), elbow_min=0.3)
    solver = SQPSolver(mech)
    target = np.array([1.0, -1.2])
    sol = solver.solve(build_ik_problem(mech, target), seed=[1.0, -1.0])
    check_solution(sol, mech)
    q1 = math.asin(0.3 / L1)
    elbow = L1 * np.array([math.cos(q1), math.sin(q1)])
    nearest = elbow + L2 * (target - elbow) / np.linalg.norm(target - elbow)  # forearm aims at it
    assert sol.status == "limited"
    assert sol.active == ("elbow_height:min",)
    assert sol.q[0] == pytest.approx(q1, abs=1e-9)
    np.testing.assert_allclose(sol.task, nearest, atol=1e-8)


def test_limited_result_is_the_brute_force_nearest_point():
    mech = arm2(lower=(-0.5, 0.2), upper=(0.5, 2.0))
    target = np.array([-1.0, 0.4])
    g1, g2 = np.meshgrid(np.linspace(-0.5, 0.5, 1001), np.linspace(0.2, 2.0, 1801), indexing="ij")
    x = L1 * np.cos(g1) + L2 * np.cos(g1 + g2)
    y = L1 * np.sin(g1) + L2 * np.sin(g1 + g2)
    dist = np.hypot(x - target[0], y - target[1])
    i = np.unravel_index(np.argmin(dist), dist.shape)
    sol = SQPSolver(mech).solve(build_ik_problem(mech, target))  # from mid-stroke
    check_solution(sol, mech)
    assert sol.status == "limited"
    assert sol.residual <= dist[i] + 1e-12  # never worse than the grid
    assert sol.residual >= dist[i] - 2e-3  # and the grid is ~1e-3 fine
    np.testing.assert_allclose(sol.q, [g1[i], g2[i]], atol=2e-3)
    assert set(sol.active) <= set(sol.at_bound) and sol.active


def test_bar_stroke_limits_closed_form(rigid_bar):
    sol = SQPSolver(rigid_bar).solve(build_ik_problem(rigid_bar, [0.3, 1.5, 0.0]), seed=[0, 0.5, 0.5, 0.5])
    check_solution(sol, rigid_bar)
    assert sol.status == "limited"
    assert set(sol.active) == {"stroke:zl:max", "stroke:zr:max"}
    np.testing.assert_allclose(sol.task, [0.3, 1.0, 0.0], atol=1e-9)
    assert abs(bar_span(sol.q) - SPAN) <= 1e-10


@pytest.mark.parametrize("side_names, expected", [(None, "tilt:max"), ((("tilt_min", "tilt_max"),), "tilt_max")])
def test_bar_inequality_limit_closed_form(side_names, expected):
    mech = bar(tilt=0.3, side_names=side_names)
    sol = SQPSolver(mech).solve(build_ik_problem(mech, [0.3, 0.5, 0.6]), seed=[0, 0.5, 0.5, 0.5])
    check_solution(sol, mech)
    assert sol.status == "limited"
    assert sol.active == (expected,)
    np.testing.assert_allclose(sol.task, [0.3, 0.5, math.asin(0.3 / SPAN)], atol=1e-9)
    assert abs(bar_span(sol.q) - SPAN) <= 1e-10


def test_workspace_bounds_on_tasks(rigid_bar):
    solver = SQPSolver(rigid_bar)
    problem = build_ik_problem(rigid_bar, [0.8, 0.5, 0.1], task_bounds={"x": (-0.5, 0.5)})
    sol = solver.solve(problem, seed=[0, 0.5, 0.5, 0.5])
    check_solution(sol, rigid_bar)
    assert sol.status == "limited" and sol.active == ("workspace:x:max",)
    np.testing.assert_allclose(sol.task, [0.5, 0.5, 0.1], atol=1e-9)
    # the same target inside the box, other label: reached, nothing active
    inside = build_ik_problem(
        rigid_bar, [0.2, 0.5, 0.1], task_bounds=TaskBounds(np.array([-0.5, -1, -1]), np.array([0.5, 1, 1]), "box")
    )
    sol = solver.solve(inside)
    assert sol.status == "ok" and sol.active == ()


# ---------------------------------------------------------------- backends
def problems_for_backends(arm, rigid_bar):
    limited_arm = arm2(lower=(-3.0, 0.5), upper=(3.0, 2.6))
    tilt_bar = bar(tilt=0.3)
    return [
        (arm, [1.2, 0.6], [0.0, 1.0]),
        (rigid_bar, [0.2, 0.4, 0.3], [0.0, 0.5, 0.5, 0.5]),
        (limited_arm, [2.0, 1.0], [0.0, 1.5]),
        (tilt_bar, [0.3, 0.5, 0.6], [0.0, 0.5, 0.5, 0.5]),
    ]


def test_all_backends_agree(arm, rigid_bar):
    cases = problems_for_backends(arm, rigid_bar)
    reference = [SQPSolver(m).solve(build_ik_problem(m, t), seed=s) for m, t, s in cases]
    for backend in BACKENDS[1:]:
        for (mech, target, seed), ref in zip(cases, reference, strict=True):
            sol = SQPSolver(mech, backend=backend).solve(build_ik_problem(mech, target), seed=seed)
            check_solution(sol, mech)
            assert sol.status == ref.status, (backend, sol.reason)
            assert sol.active == ref.active, backend
            np.testing.assert_allclose(sol.q, ref.q, atol=1e-7, err_msg=backend)


def random_qp(rng, n=4, n_eq=1, n_ineq=3):
    M = rng.normal(size=(n, n))
    qp = QPData(n, n + n_eq + n_ineq)
    qp.P[:] = M @ M.T + 0.1 * np.eye(n)
    qp.c[:] = rng.normal(size=n) * 3
    qp.A[n:] = rng.normal(size=(n_eq + n_ineq, n))
    qp.l[:n], qp.u[:n] = -0.5, 0.5
    qp.l[n : n + n_eq] = qp.u[n : n + n_eq] = rng.normal(size=n_eq) * 0.1
    qp.l[n + n_eq :], qp.u[n + n_eq :] = -0.2, 1e30
    return qp


@pytest.mark.parametrize("name", BACKENDS)
def test_qp_backends_satisfy_kkt(name):
    # Own fixed seed: ProxQP (0.8) falsely reports ~0.2 % of these feasible QPs "primal
    # infeasible" (cf. proxsuite issue #445); this set is free of them.
    backend, rng = make_backend(name), np.random.default_rng(7)
    for _ in range(10):
        qp = random_qp(rng)
        res = backend.solve(qp, "test")
        assert res.solved, res.detail
        x, y = res.x, res.y
        z = qp.A @ x
        assert np.abs(qp.P @ x + qp.c + qp.A.T @ y).max() <= 1e-6  # stationarity
        assert np.all(z >= qp.l - 1e-7) and np.all(z <= qp.u + 1e-7)  # primal feasibility
        # OSQP signs: y < 0 only at a lower bound, y > 0 only at an upper bound
        assert np.all(y[z > qp.l + 1e-6] >= -1e-6) and np.all(y[z < qp.u - 1e-6] <= 1e-6)
        assert np.abs(y[(z > qp.l + 1e-6) & (z < qp.u - 1e-6)]).max(initial=0.0) <= 1e-6  # slackness


def test_polish_recovers_the_exact_solution(rng):
    qp = random_qp(rng)
    exact = make_backend("daqp").solve(qp, "x")
    rough_x = exact.x + 1e-5 * rng.normal(size=exact.x.size)
    rough_y = exact.y + 1e-5 * rng.normal(size=exact.y.size)
    x, y = polish_solution(qp.P, qp.c, qp.A, qp.l, qp.u, rough_x, rough_y)
    assert np.abs(qp.P @ x + qp.c + qp.A.T @ y).max() <= 1e-12
    np.testing.assert_allclose(x, exact.x, atol=1e-10)


def test_one_persistent_osqp_problem_per_shape(arm, rng):
    solver = SQPSolver(arm)
    for _ in range(20):
        solver.solve(build_ik_problem(arm, arm2_fk(rng.uniform([-1, 0.4], [1, 2.2]))))
    entry = solver.backend.problem("main")
    assert solver.backend.setups == 1 and entry.solves >= 20
    # a new row set (task bounds) is a new shape: one more set-up, then reused
    for x in (0.5, 0.6):
        solver.solve(build_ik_problem(arm, [x, 1.0], task_bounds={"x": (-1.0, 1.0)}), seed=[0.5, 1.5])
    assert solver.backend.setups == 2 and solver.backend.problem("elastic") is None


# ---------------------------------------------------------------- warm start, robustness
def test_warm_start_reduces_iterations_on_a_path(rng):
    mech = arm3()
    s = np.linspace(0.0, 1.0, 120)
    q_path = np.stack([0.2 + 0.6 * np.sin(2 * np.pi * s), 1.2 + 0.4 * np.cos(2 * np.pi * s), -0.4 + 0.8 * s], 1)
    targets = [np.array(mech.task(q)[0]).ravel() for q in q_path]
    warm, cold = SQPSolver(mech), SQPSolver(mech)
    warm_its = cold_its = 0
    for q, target in zip(q_path, targets, strict=True):
        problem = build_ik_problem(mech, target)
        a = warm.solve(problem)  # starts from the previous solution
        b = cold.solve(problem, seed=np.array([0.25, 1.3, 0.0]))
        assert a.status == b.status == "ok"
        np.testing.assert_allclose(a.q, q, atol=1e-7)  # no branch flipping along the path
        warm_its += a.iterations
        cold_its += b.iterations
    assert warm_its < 0.7 * cold_its  # measured: 3.0 vs 4.8 iterations per target
    assert warm.solve(build_ik_problem(mech, targets[-1])).iterations == 0  # already there


def test_nan_region_is_never_propagated():
    # t0 = asin(q0) is NaN for |q0| > 1, but the strokes allow |q0| <= 3
    q = ca.SX.sym("q", 2)
    mech = build_mechanism(
        "asin",
        q,
        ca.vertcat(ca.asin(q[0]), q[1]),
        actuator_names=["a", "b"],
        lower=[-3, -1],
        upper=[3, 1],
        task_names=["t0", "t1"],
    )
    solver = SQPSolver(mech)
    for seed in ([2.5, 0.0], [-2.9, 0.5], [0.9, -0.5]):
        sol = solver.solve(build_ik_problem(mech, [0.6, 0.2], max_step=2.0), seed=seed)
        check_solution(sol, mech)
        assert sol.status == "ok"
        np.testing.assert_allclose(sol.q, [math.sin(0.6), 0.2], atol=1e-9)
    sol = solver.solve(build_ik_problem(mech, [2.0, 0.2]), seed=[0.0, 0.0])  # asin <= pi/2
    check_solution(sol, mech)
    assert sol.status == "limited" and sol.task[0] <= math.pi / 2
    assert sol.task[0] == pytest.approx(math.pi / 2, abs=1e-3)


def test_mechanism_invalid_everywhere_fails_without_nan():
    q = ca.SX.sym("q", 1)
    mech = build_mechanism(
        "broken", q, ca.sqrt(-1 - q[0] ** 2), actuator_names=["a"], lower=[-1], upper=[1], task_names=["t"]
    )
    sol = SQPSolver(mech).solve(build_ik_problem(mech, [0.0]), seed=[0.5])
    assert sol.status == "failed" and "non-finite" in sol.reason
    assert not np.isnan(sol.q).any() and not np.isnan(sol.task).any() and not math.isnan(sol.residual)


def test_infeasible_constraints_fail_with_reason():
    q = ca.SX.sym("q", 2)
    mech = build_mechanism(
        "impossible",
        q,
        q,
        actuator_names=["a", "b"],
        lower=[-1, -1],
        upper=[1, 1],
        task_names=["x", "y"],
        equality=q[0] ** 2 + 1,
        equality_names=["never_zero"],
    )
    sol = SQPSolver(mech).solve(build_ik_problem(mech, [0.2, 0.3]))
    check_solution(sol, mech)
    assert sol.status == "failed" and "never_zero" in sol.reason


def test_iteration_limit_reported(rigid_bar):
    sol = SQPSolver(rigid_bar, max_iterations=1).solve(
        build_ik_problem(rigid_bar, [0.5, 0.5, 0.3], max_step=0.01), seed=[0, 0.2, 1.5, 0.9]
    )
    assert sol.status == "failed" and "iteration limit" in sol.reason
    check_solution(sol, rigid_bar)


def test_custom_task_error_wraps_angles():
    q = ca.SX.sym("q", 1)

    def wrapped(target, t):
        return (target - t + np.pi) % (2 * np.pi) - np.pi

    plain = build_mechanism("dial", q, q, actuator_names=["a"], lower=[-4], upper=[4], task_names=["phi"])
    wrap = build_mechanism(
        "dial", q, q, actuator_names=["a"], lower=[-4], upper=[4], task_names=["phi"], task_error=wrapped
    )
    target, seed = [math.pi - 0.05], [-math.pi + 0.05]
    assert SQPSolver(plain).solve(build_ik_problem(plain, target), seed=seed).q[0] == pytest.approx(math.pi - 0.05)
    sol = SQPSolver(wrap).solve(build_ik_problem(wrap, target), seed=seed)
    assert sol.status == "ok" and sol.q[0] == pytest.approx(-math.pi - 0.05, abs=1e-9)  # the short way


# ---------------------------------------------------------------- bad input
def test_bad_problem_input_is_rejected_with_field_name(arm):
    cases = [
        (dict(target=[np.nan, 0.0]), "target"),
        (dict(target=[np.inf, 0.0]), "target"),
        (dict(target=[1.0, 0.0, 0.0]), "target"),
        (dict(target="ab"), "target"),
        (dict(target=[1, 0], weights=[1, -1]), "weights"),
        (dict(target=[1, 0], weights=[0, 0]), "weights"),
        (dict(target=[1, 0], weights=[1, np.nan]), "weights"),
        (dict(target=[1, 0], damping=0.0), "damping"),
        (dict(target=[1, 0], damping=float("nan")), "damping"),
        (dict(target=[1, 0], max_step=[0.1, -1]), "max_step"),
        (dict(target=[1, 0], task_bounds={"x": (1, -1)}), "task_bounds"),
        (dict(target=[1, 0], task_bounds={"z": (0, 1)}), "task_bounds"),
        (dict(target=[1, 0], active_tasks=[1, 0]), "active_tasks"),
    ]
    for kwargs, field in cases:
        with pytest.raises(ValueError, match=field):
            build_ik_problem(arm, **kwargs)


def test_bad_solver_input_is_rejected_with_field_name(arm, rigid_bar):
    solver = SQPSolver(arm)
    problem = build_ik_problem(arm, [1.0, 0.5])
    with pytest.raises(ValueError, match="seed"):
        solver.solve(problem, seed=[np.nan, 0.0])
    with pytest.raises(ValueError, match="seed"):
        solver.solve(problem, seed=[0.0])
    with pytest.raises(ValueError, match="problem"):
        solver.solve(build_ik_problem(rigid_bar, [0, 0.5, 0]))
    with pytest.raises(ValueError, match="problem"):
        solver.solve("not a problem")
    with pytest.raises(ValueError, match="backend"):
        SQPSolver(arm, backend="cplex")
    with pytest.raises(ValueError, match="tol"):
        SQPSolver(arm, tol=-1.0)
    with pytest.raises(ValueError, match="max_iterations"):
        SQPSettings(max_iterations=0)
    with pytest.raises(ValueError, match="unknown setting"):
        SQPSolver(arm, tolerance=1e-3)


def test_bad_mechanism_is_rejected_with_field_name():
    q = ca.SX.sym("q", 2)
    task = ca.Function("t", [q], [q, ca.DM.eye(2)])
    base = dict(name="m", actuator_names=("a", "b"), lower=[0, 0], upper=[1, 1], task=task, task_names=("x", "y"))
    for change, field in [
        (dict(lower=[2, 0]), "lower"),
        (dict(upper=[1, np.nan]), "upper"),
        (dict(actuator_names=("a", "a")), "actuator_names"),
        (dict(task_names=("x",)), "task"),
        (dict(task="t"), "task"),
        (dict(inequality_names=("g",)), "inequality_names"),
    ]:
        with pytest.raises(ValueError, match=field):
            Mechanism(**{**base, **change})
    mech = Mechanism(**base)
    assert (mech.n, mech.m, mech.p, mech.r) == (2, 2, 0, 0)
