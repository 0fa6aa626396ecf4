"""The thesis baselines check what they return: "limited" with the broken limits named when the actuators leave
their strokes or the pose misses the target (a new user's trial: ``hitch ik --x 0.5 … --method dls`` said "ok"
with both sway limiters off their strokes, and ``geometric`` said "ok" 16 mm off)."""

import numpy as np
import pytest

from planner.ik_qp.baselines import DLSIK, BaselineSettings, GeometricIK, HybridIK
from planner.ik_qp.result import Target
from planner.model.hard_limits import HardLimits

FAR_LEFT = Target(0.5, 0.2, 0.0, 0.0)  # beyond both sway limiters' strokes


@pytest.mark.parametrize("cls", [DLSIK, HybridIK, GeometricIK])
def test_a_baseline_outside_the_strokes_is_limited_and_names_them(model, cls):
    res = cls(model).solve(FAR_LEFT)
    assert res.status == "limited"
    assert {"stroke:left:min", "stroke:right:max"} <= set(res.active)
    q = res.actuators.as_array()
    f, _ = model.features(q)
    assert set(res.active) == set(HardLimits.from_model(model).violations(q, f, tol=1e-9))
    assert "stroke:right:max (right = 0.617" in res.reason and "stroke 0.5..0.575 m" in res.reason
    assert res.reason.startswith(f"{cls.method}: the method enforces no limit")


def test_the_geometric_pose_error_beyond_its_tolerance_is_named(model):
    res = GeometricIK(model).solve(FAR_LEFT)
    assert res.pose.x == pytest.approx(0.484, abs=1e-3) and res.residual > 5e-3
    assert "pose error 0.0199 (worst pitch -0.0199 rad) beyond the geometric tolerance 0.005 m/rad" in res.reason


def test_a_reachable_target_within_the_strokes_stays_ok(model):
    n = model.neutral_pose.controlled() + np.array([0.01, 0.02, 0.0, 0.0])
    for cls in (DLSIK, HybridIK, GeometricIK):
        res = cls(model).solve(n)
        assert res.status == "ok" and res.active == () and res.reason == "", (cls.method, res.reason)


def test_a_pose_error_alone_makes_the_result_limited(model):
    """Within every limit but further off than the asked tolerance: "limited", no limit named."""
    n = model.neutral_pose.controlled() + np.array([0.01, 0.02, 0.0, 0.0])
    res = GeometricIK(model, BaselineSettings(reach_tol=1e-9)).solve(n)
    assert res.status == "limited" and res.active == ()
    assert "beyond the geometric tolerance 1e-09 m/rad" in res.reason
