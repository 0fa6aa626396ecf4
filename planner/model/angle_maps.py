"""Lower-link angles ↔ actuators (thesis 2.1-2.18), exact.

Angles θ = (θxl, θzl, θxr, θzr) [rad] are the fixed-XYZ angles of the lower links
(thesis 2.19-2.20). Angles → actuators is closed-form: the lift angle θ_E from the
fixed left lift rod (circle of S ∩ sphere around A_l, rearward branch, thesis
2.2-2.5), the tilt cylinder |A_r − S_r| (2.6), the limiters |B − C| (2.7-2.9).
Actuators → angles solves each side's loop closure exactly (thesis 2.10-2.18 give a
planar approximation; :func:`planner.model.geometry.solve_link_angles` is exact).
"""

from __future__ import annotations

import casadi as ca
import numpy as np

from planner.model.fast_function import FastFunction
from planner.model.geometry import LEFT, RIGHT, lift_arm_end, link_points, side_geometry, solve_link_angles
from planner.model.types import KinematicsError
from planner.profiles.hitch import Profile

__all__ = ["angles_to_actuators_sx", "AngleMaps"]


def angles_to_actuators_sx(profile: Profile, theta):
    """Symbolic (lift, tilt, left, right) from θ (4,) and the lift-rod reach argument (|·| ≤ 1 when valid)."""
    g = profile.geometry
    left, right = side_geometry(profile, LEFT), side_geometry(profile, RIGHT)
    pl = link_points(left, theta[0], theta[1])
    pr = link_points(right, theta[2], theta[3])
    w = pl["A"] - ca.DM(left.lift_arm_pivot)
    k = (ca.sumsqr(w) + g.lift_arm_length**2 - g.fixed_lift_rod_length**2) / (2 * g.lift_arm_length)
    reach = k / ca.sqrt(w[1] ** 2 + w[2] ** 2)
    lift = ca.atan2(w[2], w[1]) + ca.acos(ca.fmin(1.0, ca.fmax(-1.0, reach)))
    tilt = ca.norm_2(pr["A"] - lift_arm_end(right, lift))
    lim_l = ca.norm_2(pl["B"] - ca.DM(left.limiter_point))
    lim_r = ca.norm_2(pr["B"] - ca.DM(right.limiter_point))
    return ca.vertcat(lift, tilt, lim_l, lim_r), reach


class AngleMaps:
    """Numeric maps between lower-link angles and the four link actuators (lift, tilt, left, right)."""

    def __init__(self, profile: Profile):
        g = profile.geometry
        th = ca.SX.sym("theta", 4)
        act, reach = angles_to_actuators_sx(profile, th)
        self._to_act = FastFunction(ca.Function("angles_to_actuators", [th], [act, reach]))
        a = ca.SX.sym("a", 4)  # lift, tilt, left, right
        left, right = side_geometry(profile, LEFT), side_geometry(profile, RIGHT)
        txl, tzl, rl = solve_link_angles(left, lift_arm_end(left, a[0]), g.fixed_lift_rod_length, a[2])
        txr, tzr, rr = solve_link_angles(right, lift_arm_end(right, a[0]), a[1], a[3])
        self._to_ang = FastFunction(
            ca.Function("actuators_to_angles", [a], [ca.vertcat(txl, tzl, txr, tzr), ca.vertcat(rl, rr)])
        )

    def to_actuators(self, theta) -> np.ndarray:
        """(lift [rad], tilt [m], left [m], right [m]) from θ = (θxl, θzl, θxr, θzr) [rad]."""
        out, reach = self._to_act(np.asarray(theta, dtype=float))
        if not abs(reach[0, 0]) <= 1.0:
            raise KinematicsError("the fixed left lift rod cannot reach the left lower link at these angles")
        return out[:, 0].copy()

    def to_angles(self, lift: float, tilt: float, left: float, right: float) -> np.ndarray:
        """θ = (θxl, θzl, θxr, θzr) [rad] from the link actuators (exact loop closure)."""
        th, res = self._to_ang(np.array([lift, tilt, left, right], dtype=float))
        if not np.all(np.abs(res) <= 1e-9):
            raise KinematicsError(
                f"lower links cannot close with these actuators (closure error {np.abs(res).max():.3g} m)"
            )
        return th[:, 0].copy()
