"""The thesis's inverse-kinematics models, as measured baselines (thesis §2.2.4-2.2.7).

All three map a target (x_T, z_T, α=roll, β=pitch) to lower-link angles θ and a top-link
length; actuators then follow from the exact angle maps and the result's pose from the
exact forward model, so what is measured is the error of each IK *method*:

* :class:`GeometricIK` (thesis 2.36-2.42): small-change formulas around the start pose,
  yaw from the previous cycle's angles.
* :class:`DLSIK` (thesis 2.45-2.54): damped least squares on s = [x_T, z_T, α, d_L^R]
  over θ = [θxl, θxr, θzl, θzr], λ = 1 − 1/‖J‖₂, step μ, top link through the augmented
  row of J_K (2.51-2.52).
* :class:`HybridIK`: DLS for the lower links, the geometric top-link formula (2.40-2.42).

Deviations from the typeset text, all of notation, not of method: angles and signs are
those of our frame (README); the yaw of 2.37 is computed from the previous cycle's
link ends including the pivot offset (the typeset Δx omits it); the mast direction of
2.40-2.41 is built from roll, pitch and yaw in our implement frame (the typeset matrix
is R_z(α)R_y(β)R_x(γ) with swapped labels); the −J_U4 of 2.52 is +J_U4 here because our
pitch is a right-hand rotation (the thesis's β = atan(y/z) has the opposite sign).
The thesis gives no μ or stopping margin ("never tuned"): μ = 1, margin 1e-6, at most
50 iterations, configurable.

The thesis's methods enforce no limit. Their result is checked, not corrected: status "ok"
only when the actuators lie within every hard limit (:class:`~planner.model.hard_limits.HardLimits`:
strokes, top-link angles, ground clearance) and the exact pose is within the method's
``reach_tol`` of the target; else "limited", with ``active`` naming the limits the actuators
break (the QP's names, ``stroke:<actuator>:min|max``, …) and ``reason`` the values and the
pose error. Unlike the QP's "limited" (the nearest reachable pose, within every limit), a
baseline's "limited" actuators may lie outside the limits: they are what the method computed.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass

import casadi as ca
import numpy as np

from planner.ik_qp.result import IKResult, check_target
from planner.model.angle_maps import AngleMaps
from planner.model.fast_function import FastFunction
from planner.model.geometry import LEFT, RIGHT, link_direction, side_geometry
from planner.model.hard_limits import STROKE_NAMES, HardLimits
from planner.model.kinematics import HitchModel
from planner.model.types import ACTUATOR_NAMES, Actuators, KinematicsError

__all__ = ["GeometricIK", "DLSIK", "HybridIK", "BaselineSettings", "REACH_TOL"]

#: Largest pose error ‖pose − target‖∞ [m, rad] of status "ok", per method: what each reaches on a reachable
#: target (docs/benchmarks.md: DLS ~2e-7, hybrid ~1e-5, geometric a few mm / mrad near the start pose, its
#: small-change model error), so a result further off says the method missed the target.
REACH_TOL = {"dls": 1e-5, "hybrid": 1e-4, "geometric": 5e-3}
#: Distance beyond a hard limit that counts as breaking it [m, rad] (the QP's feasibility tolerance).
LIMIT_TOL = 1e-9


@dataclass(frozen=True)
class BaselineSettings:
    step: float = 1.0  # μ (thesis 2.54)
    margin: float = 1e-6  # stop when ‖e‖∞ below this [m, rad]
    max_iterations: int = 50
    reach_tol: float | None = None  # status "ok" needs ‖pose − target‖∞ <= this [m, rad]; None: REACH_TOL[method]


def _build_angle_space(model: HitchModel):
    """θ = (θxl, θxr, θzl, θzr) → s = [x_T, z_T, α, |L−R|], J = ∂s/∂θ (thesis 2.46, 2.50), ends, yaw."""
    prof = model.profile
    left, right = side_geometry(prof, LEFT), side_geometry(prof, RIGHT)
    l_vv = prof.geometry.lower_link_length
    th = ca.SX.sym("theta", 4)
    L = ca.DM(left.pivot) + l_vv * link_direction(th[0], th[2])
    R = ca.DM(right.pivot) + l_vv * link_direction(th[1], th[3])
    T = (L + R) / 2
    v = L - R
    s = ca.vertcat(T[0], T[2], ca.atan2(-v[2], v[0]), ca.norm_2(v))
    yaw = ca.atan2(v[1], v[0])
    return FastFunction(ca.Function("dls_s", [th], [s, ca.densify(ca.jacobian(s, th)), T, yaw, L, R]))


def _build_top_link(model: HitchModel):
    """Top-link length from the pose by the thesis's rotation formula (2.40-2.42) and
    J_U = ∂d/∂(x, z, α, β) (2.51), with y_T and yaw γ given.

    U = T + R_z(γ)·R_y(α)·R_x(β)·[0, 0, d_T^U]ᵀ: fixed XYZ rotations (pitch about x, roll
    about the rearward y, yaw about z) in our frame's signs. It equals the exact mast
    point only to first order in combined angles; that is the method's model error.
    """
    prof = model.profile
    p = ca.SX.sym("p", 4)  # x, z, roll, pitch
    y_yaw = ca.SX.sym("yy", 2)
    roll, pitch, yaw = p[2], p[3], y_yaw[1]
    rx = ca.vertcat(
        ca.horzcat(1, 0, 0), ca.horzcat(0, ca.cos(pitch), -ca.sin(pitch)), ca.horzcat(0, ca.sin(pitch), ca.cos(pitch))
    )
    ry = ca.vertcat(
        ca.horzcat(ca.cos(roll), 0, ca.sin(roll)), ca.horzcat(0, 1, 0), ca.horzcat(-ca.sin(roll), 0, ca.cos(roll))
    )
    rz = ca.vertcat(
        ca.horzcat(ca.cos(yaw), -ca.sin(yaw), 0), ca.horzcat(ca.sin(yaw), ca.cos(yaw), 0), ca.horzcat(0, 0, 1)
    )
    T = ca.vertcat(p[0], y_yaw[0], p[1])
    U = T + rz @ ry @ rx @ ca.DM([0.0, 0.0, model.mast_height])  # (thesis 2.40-2.41)
    d = ca.norm_2(U - ca.DM(prof.geometry.top_link_tractor_point))  # (thesis 2.42)
    return FastFunction(ca.Function("top_link", [p, y_yaw], [d, ca.densify(ca.jacobian(d, p))]))


class _Baseline:
    method = "baseline"

    def __init__(self, model: HitchModel, settings: BaselineSettings | None = None):
        self.model = model
        self.settings = settings or BaselineSettings()
        self.maps = AngleMaps(model.profile)
        self.limits = HardLimits.from_model(model)
        tol = self.settings.reach_tol
        self.reach_tol = REACH_TOL[self.method] if tol is None else float(tol)
        self._s = _build_angle_space(model)
        self._top = _build_top_link(model)
        st = model.forward(model.neutral)
        txl, tzl, txr, tzr = st.link_angles
        self.neutral_theta = np.array([txl, txr, tzl, tzr])
        self.theta = self.neutral_theta.copy()  # previous cycle's angles
        self.top = float(model.neutral[2])

    def reset(self) -> None:
        self.theta = self.neutral_theta.copy()
        self.top = float(self.model.neutral[2])

    def _finish(self, target: np.ndarray, theta: np.ndarray, top: float, iterations: int, t0: float) -> IKResult:
        txl, txr, tzl, tzr = theta
        try:
            lift, tilt, left, right = self.maps.to_actuators([txl, tzl, txr, tzr])
            q = np.array([lift, tilt, top, left, right])
            state = self.model.forward(q)
        except KinematicsError as exc:
            return IKResult.failed(f"{self.method}: {exc}", iterations, time.perf_counter() - t0)
        self.theta, self.top = theta.copy(), top
        err = state.pose.controlled() - target
        residual = float(np.max(np.abs(err)))
        try:
            f, _ = self.model.features(q)
        except KinematicsError as exc:  # defensive: forward() closed at q
            return IKResult.failed(f"{self.method}: {exc}", iterations, time.perf_counter() - t0)
        broken = self.limits.violations(q, f, tol=LIMIT_TOL)
        missed = not residual <= self.reach_tol
        return IKResult(
            actuators=Actuators.from_array(q),
            pose=state.pose,
            status="limited" if broken or missed else "ok",
            active=broken,
            iterations=iterations,
            residual=residual,
            solve_time_s=time.perf_counter() - t0,
            reason=self._limited_reason(q, broken, err, residual) if broken or missed else "",
            extra={"violated": broken},
        )

    def _limited_reason(self, q: np.ndarray, broken: tuple[str, ...], err: np.ndarray, residual: float) -> str:
        """Why a result is "limited": the limits the actuators break (name, value, stroke) and the pose error."""
        parts = []
        if broken:
            said = []
            for name in broken:
                i = next((k for k, pair in enumerate(STROKE_NAMES) if name in pair), None)
                if i is None:
                    said.append(name)
                    continue
                unit = "rad" if ACTUATOR_NAMES[i] == "lift" else "m"
                said.append(
                    f"{name} ({ACTUATOR_NAMES[i]} = {q[i]:.5g} {unit}, stroke "
                    f"{self.model.lower[i]:g}..{self.model.upper[i]:g} {unit})"
                )
            parts.append(f"the method enforces no limit and breaks {', '.join(said)}")
        if not residual <= self.reach_tol:
            worst = int(np.argmax(np.abs(err)))
            dof = ("x", "z", "roll", "pitch")[worst]
            unit = "m" if worst < 2 else "rad"
            parts.append(
                f"pose error {residual:.3g} (worst {dof} {err[worst]:+.3g} {unit}) beyond the {self.method} "
                f"tolerance {self.reach_tol:g} m/rad"
            )
        return f"{self.method}: " + "; ".join(parts)

    def _dls_step(self, theta: np.ndarray, target: np.ndarray):
        s, J, T, yaw, _, _ = self._s(theta)
        e = np.array([target[0], target[1], target[2], self.model.span]) - s[:, 0]
        lam = 1.0 - 1.0 / np.linalg.norm(J, 2)  # (thesis 2.53)
        dtheta = J.T @ np.linalg.solve(J @ J.T + lam**2 * np.eye(4), e)  # (thesis 2.48)
        return dtheta, e, lam, float(T[1, 0]), float(yaw[0, 0])


class GeometricIK(_Baseline):
    """Thesis 2.36-2.42: closed-form small-change formulas around the start pose."""

    method = "geometric"

    def solve(self, target_pose) -> IKResult:
        t0 = time.perf_counter()
        x, z, roll, pitch = check_target(target_pose)
        l_vv, span = self.model.profile.geometry.lower_link_length, self.model.span
        tz0 = abs(self.neutral_theta[3])  # θ_z0: start-pose deviation of the links from y (2.36)
        a = math.asin(max(-1.0, min(1.0, x / l_vv)))
        b = math.asin(max(-1.0, min(1.0, span * (1 - math.cos(roll)) / (2 * l_vv))))
        tzr, tzl = -a + b + tz0, -a - b - tz0  # (thesis 2.36)
        _, _, _, yaw, _, _ = self._s(self.theta)  # previous cycle (2.37)
        gamma = float(yaw[0, 0])
        h = span * math.cos(gamma) * math.sin(roll) / 2  # (thesis 2.38)
        txl = math.asin(max(-1.0, min(1.0, (z - h) / l_vv)))  # (thesis 2.39)
        txr = math.asin(max(-1.0, min(1.0, (z + h) / l_vv)))
        theta = np.array([txl, txr, tzl, tzr])
        _, _, T, yaw_new, _, _ = self._s(theta)
        d, _ = self._top(np.array([x, z, roll, pitch]), np.array([T[1, 0], gamma]))  # (thesis 2.40-2.42)
        return self._finish(np.array([x, z, roll, pitch]), theta, float(d[0, 0]), 1, t0)


class DLSIK(_Baseline):
    """Thesis 2.45-2.54: damped least squares with the augmented top-link row."""

    method = "dls"

    def solve(self, target_pose) -> IKResult:
        t0 = time.perf_counter()
        target = np.array(check_target(target_pose))
        st = self.settings
        theta, top = self.theta.copy(), self.top
        k = 0
        for k in range(1, st.max_iterations + 1):
            dtheta, e, lam, y_t, yaw = self._dls_step(theta, target)
            q = self._actuators(theta, top)
            try:
                pitch = self.model.forward(q).pose.pitch if q is not None else None
            except KinematicsError:
                pitch = None
            if pitch is None:  # the iterate left the mechanism's valid region
                self.reset()
                return IKResult.failed(f"dls: iterate {k} does not close the mechanism", k, time.perf_counter() - t0)
            e_beta = target[3] - pitch
            _, ju = self._top(target, np.array([y_t, yaw]))
            ju = ju[0]
            dtop = (1 - lam) * (ju[0] * e[0] + ju[1] * e[1] + ju[2] * e[2]) + ju[3] * e_beta  # (2.52)
            theta = theta + st.step * dtheta  # (thesis 2.54)
            top = top + st.step * dtop
            if max(np.max(np.abs(e)), abs(e_beta)) < st.margin:
                break
        return self._finish(target, theta, top, k, t0)

    def _actuators(self, theta, top):
        try:
            txl, txr, tzl, tzr = theta
            lift, tilt, left, right = self.maps.to_actuators([txl, tzl, txr, tzr])
            return np.array([lift, tilt, top, left, right])
        except KinematicsError:
            return None


class HybridIK(_Baseline):
    """DLS lower links + the geometric top link (thesis §2.2.7)."""

    method = "hybrid"

    def solve(self, target_pose) -> IKResult:
        t0 = time.perf_counter()
        target = np.array(check_target(target_pose))
        st = self.settings
        theta = self.theta.copy()
        k = 0
        for _ in range(st.max_iterations):
            k += 1
            dtheta, e, _, _, _ = self._dls_step(theta, target)
            theta = theta + st.step * dtheta
            if np.max(np.abs(e)) < st.margin:
                break
        _, _, T, yaw, _, _ = self._s(theta)
        d, _ = self._top(target, np.array([T[1, 0], yaw[0, 0]]))
        return self._finish(target, theta, float(d[0, 0]), k, t0)
