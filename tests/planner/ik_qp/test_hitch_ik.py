"""Hitch IK (QP) against the closed-form inverse, limits, reachability and continuity."""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from planner.ik_qp.baselines import DLSIK, GeometricIK, HybridIK
from planner.ik_qp.hitch_ik import IKSolver
from planner.ik_qp.result import Target
from planner.model.exact_inverse import ExactInverse
from planner.model.hard_limits import HardLimits
from planner.model.workspace import Reachability

DOFS = ("x", "z", "roll", "pitch")


@pytest.fixture(scope="module")
def solver(model):
    return IKSolver(model)


@pytest.fixture(scope="module")
def truth(model):
    return ExactInverse(model)


def box_arrays(box):
    return np.array([box[k][0] for k in DOFS]), np.array([box[k][1] for k in DOFS])


def assert_within_limits(model, q):
    f, _ = model.features(q)
    assert HardLimits.from_model(model).violations(q, f, tol=1e-9) == ()


def test_round_trip_on_random_workspace_targets(model, solver, truth, rng):
    lo, hi = box_arrays(model.workspace)
    for _ in range(200):
        t = lo + (hi - lo) * rng.random(4)
        seed = model.lower + (model.upper - model.lower) * rng.random(5)  # any seed inside the strokes
        r = solver.solve(Target(*t), seed=seed)
        assert r.status == "ok", r.reason
        assert r.residual <= 1e-9
        np.testing.assert_allclose(r.pose.controlled(), t, atol=1e-9)
        np.testing.assert_allclose(r.actuators.as_array(), truth(*t), atol=1e-8)  # the unique solution
        assert_within_limits(model, r.actuators.as_array())
        assert r.iterations >= 1 and r.solve_time_s > 0


def test_out_of_reach_returns_nearest_reachable_pose_with_the_limit(model, solver):
    n = model.neutral_pose
    cases = [
        # far left (+x): the mast point U moves to +x, the top link yaws negative (README signs)
        (Target(0.12, n.z, 0.0, 0.0), "top_link_yaw_min"),
        (Target(-0.12, n.z, 0.0, 0.0), "top_link_yaw_max"),
        (Target(0.0, 0.8, 0.0, 0.0), "top_link_pitch_max"),  # the top link tilts up before the lift ends
        (Target(0.0, -0.8, 0.0, 0.0), "stroke:lift:min"),
        (Target(0.0, n.z, 0.0, 0.6), "stroke:top:min"),  # mast far forward needs a short top link
        (Target(0.0, n.z, 0.0, -0.6), "stroke:top:max"),
    ]
    reach = Reachability(model)
    for target, limit in cases:
        r = solver.solve(target, seed=model.neutral)
        assert r.status == "limited", (target, r.status, r.reason)
        assert limit in r.active, (target, r.active)
        q = r.actuators.as_array()
        assert_within_limits(model, q)
        p = r.pose.controlled()
        assert reach(p)  # the returned pose is reachable
        assert r.residual > 1e-3


def test_limited_pose_is_the_nearest_in_the_weighted_sense(model, solver, rng):
    """No reachable pose sampled around the answer is nearer to the target."""
    n = model.neutral_pose
    target = np.array([0.12, n.z + 0.05, 0.02, 0.0])
    r = solver.solve(Target(*target), seed=model.neutral)
    w = np.array([1, 1, model.mast_height, model.mast_height])
    best = np.linalg.norm(w * (r.pose.controlled() - target))
    reach = Reachability(model)
    for _ in range(400):
        p = r.pose.controlled() + rng.normal(scale=[0.005, 0.005, 0.005, 0.005])
        if reach(p):
            assert np.linalg.norm(w * (p - target)) >= best - 1e-9


def test_continuity_along_a_streamed_path(model, rng):
    solver = IKSolver(model)
    n = model.neutral_pose.controlled()
    prev = None
    for s in np.linspace(0, 1, 300):
        t = n + s * np.array([0.05, 0.15, 0.04, -0.05])
        r = solver.solve(Target(*t))  # warm start from the last solution
        assert r.status == "ok"
        q = r.actuators.as_array()
        if prev is not None:
            assert np.max(np.abs(q - prev)) < 0.01  # 1/300 of the path: small target change, small actuator change
        prev = q


def test_workspace_option(model):
    solver = IKSolver(model, use_workspace=True)
    ws = model.workspace
    r = solver.solve(Target(ws["x"][1] + 0.02, model.neutral_pose.z, 0.0, 0.0), seed=model.neutral)
    assert r.status == "limited" and "workspace:x:max" in r.active
    assert r.pose.x == pytest.approx(ws["x"][1], abs=1e-9)


@pytest.mark.parametrize("backend", ["daqp", "quadprog", "proxqp", "clarabel"])
def test_backends_agree_with_osqp(model, solver, backend, rng):
    other = IKSolver(model, backend=backend)
    lo, hi = box_arrays(model.workspace)
    for _ in range(10):
        t = lo + (hi - lo) * rng.random(4)
        a, b = solver.solve(Target(*t), seed=model.neutral), other.solve(Target(*t), seed=model.neutral)
        assert b.status == "ok"
        np.testing.assert_allclose(a.actuators.as_array(), b.actuators.as_array(), atol=1e-8)
    lim = other.solve(Target(0.12, model.neutral_pose.z, 0.0, 0.0), seed=model.neutral)
    assert lim.status == "limited" and "top_link_yaw_min" in lim.active


@pytest.mark.parametrize(
    "bad, field",
    [
        ({"x": math.nan}, "x must be finite"),
        ({"z": math.inf}, "z must be finite"),
        ({"roll": "0.1"}, "roll must be a number"),
        ({"pitch": None}, "pitch must be a number"),
        ({"x": 1e9}, "x = 1000000000.0 is outside the accepted range"),
        ({"z": 300.0}, r"z = 300.0 is outside the accepted range ±10 m; did you mean mm\? 300 mm = 0.3 m"),
        (
            {"roll": 10.0},
            r"roll = 10.0 is outside the accepted range ±1.570796 rad; did you mean degrees\? 10 deg = 0.1745",
        ),
    ],
)
def test_bad_input_names_the_field(model, solver, bad, field):
    kw = {"x": 0.0, "z": 0.1, "roll": 0.0, "pitch": 0.0, **bad}
    with pytest.raises(ValueError, match=field):
        solver.solve(Target(**kw))
    with pytest.raises(ValueError, match=field.split(" ")[0]):
        solver.solve(kw)


def test_a_mapping_with_an_unknown_field_is_refused(solver):
    """An engineer's report: a target mapping with "yaw" was solved with the yaw silently ignored."""
    with pytest.raises(ValueError, match=r"target: unknown field\(s\) yaw; allowed: x, z, roll, pitch"):
        solver.solve({"x": 0.0, "z": 0.2, "roll": 0.0, "pitch": 0.0, "yaw": 0.1})


def test_baselines_agree_with_qp_near_neutral(model, solver, rng):
    """Thesis methods near the start pose: DLS/hybrid converge on the exact model; the
    geometric small-change formulas stay within a few mm / mrad for small moves."""
    n = model.neutral_pose.controlled()
    for cls, tol_m, tol_rad in ((DLSIK, 1e-6, 1e-6), (HybridIK, 1e-6, 5e-5), (GeometricIK, 3e-3, 3e-3)):
        b = cls(model)
        for _ in range(10):
            t = n + np.array([0.02, 0.04, 0.02, 0.02]) * (2 * rng.random(4) - 1)
            rb = b.solve(t)
            rq = solver.solve(Target(*t), seed=model.neutral)
            assert rb.status == "ok"
            d = rb.pose.controlled() - rq.pose.controlled()
            assert np.all(np.abs(d[:2]) <= tol_m) and np.all(np.abs(d[2:]) <= tol_rad), (cls.method, d)


def test_cli_ik_json(model):
    hitch = str(Path(sys.executable).with_name("hitch"))
    r = subprocess.run(
        [hitch, "ik", "--x", "0.02", "--z", "0.2", "--roll", "0.01", "--pitch", "0", "--json"],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 0, r.stderr
    d = json.loads(r.stdout)
    assert set(d) >= {"status", "actuators", "pose", "active", "iterations", "residual", "solve_time_s"}
    assert d["status"] == "ok" and set(d["actuators"]) == {"lift", "tilt", "top", "left", "right"}
    assert d["pose"]["x"] == pytest.approx(0.02, abs=1e-9)
    for m in ("dls", "hybrid", "geometric"):
        r = subprocess.run(
            [hitch, "ik", "--x", "0", "--z", "0.15", "--roll", "0", "--pitch", "0", "--method", m, "--json"],
            capture_output=True,
            text=True,
            timeout=120,
        )
        assert r.returncode == 0 and json.loads(r.stdout)["status"] == "ok"
