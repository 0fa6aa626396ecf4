"""Exact inverse of the hitch geometry without limits: pose (x, z, roll, pitch) → actuators.

The thesis dropped its algebraic inverse (2.43-2.44) as a quartic with no way to pick
the root. Working with vectors (its own recommendation, §4.4) the inverse is a 2×2
root-finding problem followed by closed forms:

1. With the implement span s fixed, the lower hitch points are L = T + (s/2)·n and
   R = T − (s/2)·n, n the unit vector R→L given by roll and yaw. The unknowns y_T and
   yaw follow from |L − L0| = |R − R0| = l_vv (thesis 2.19-2.20, 2.44), solved by
   Newton from the symmetric solution.
2. Link angles from L − L0 and R − R0 (inverse of thesis 2.19-2.20).
3. Lift angle θ_E from the fixed left lift rod: circle of S (lift arm) ∩ sphere
   |S − A_l| = d_AS, rearward branch (thesis 2.2-2.5); tilt = |A_r − S_r| (2.6);
   limiters |B − C| (2.7-2.9); top link |U − H| with U on the mast (2.41-2.42).

This is not the planner's IK (that one honours limits, see :mod:`planner.ik_qp`): it is
the independent closed-form truth the QP IK and the tests are checked against.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from planner.errors import unit_hint
from planner.model.angle_maps import angles_to_actuators_sx
from planner.model.fast_function import FastFunction, MappedFunction
from planner.model.geometry import LEFT, RIGHT, mast_frame, side_geometry
from planner.model.kinematics import HitchModel
from planner.model.types import Actuators, KinematicsError, ModelInputError

__all__ = ["ExactInverse", "InverseBatch"]

_TOL_M = 1e-9


@dataclass(frozen=True)
class InverseBatch:
    """The exact inverse at N poses: actuators (N, 5), their velocities (N, 5) for the given
    pose velocities, y_T [m] and yaw [rad] (N,), and ``ok`` (N,): the rows
    :meth:`ExactInverse.solve_full` accepts (the others hold unchecked values)."""

    actuators: np.ndarray
    actuator_velocity: np.ndarray
    y: np.ndarray
    yaw: np.ndarray
    ok: np.ndarray


def _build(model: HitchModel, newton: int = 8, *, rate: bool = False) -> ca.Function:
    """pose → (actuators, d actuators / d pose, checks, (y_T, yaw)); with ``rate``, (pose, pose
    velocity) → (actuators, actuator velocity, checks, (y_T, yaw)) by the same instructions
    for every value, the velocity by forward AD through the closed forms and the last Newton
    step only. At the converged solution that is the implicit-function derivative, which
    differentiating every iteration reaches as well: the terms the earlier iterations add are
    proportional to the residual before the last step (~1e-16 m over the workspace)."""
    prof = model.profile
    g = prof.geometry
    left, right = side_geometry(prof, LEFT), side_geometry(prof, RIGHT)
    s, d_mast, l_vv = model.span, model.mast_height, g.lower_link_length
    L0, R0 = ca.DM(left.pivot), ca.DM(right.pivot)
    target = ca.SX.sym("pose", 4)  # x, z, roll, pitch
    x, z, roll, pitch = (target[i] for i in range(4))

    def ends(y, yaw):
        n = ca.vertcat(1.0, ca.tan(yaw), -ca.tan(roll))
        n = n / ca.norm_2(n)
        t = ca.vertcat(x, y, z)
        return t + (s / 2) * n, t - (s / 2) * n

    u = ca.SX.sym("u", 2)
    le, re = ends(u[0], u[1])
    res = ca.vertcat(ca.sumsqr(le - L0) - l_vv**2, ca.sumsqr(re - R0) - l_vv**2)
    jac = ca.jacobian(res, u)
    half_gap = (s - g.lower_link_pivot_span) / 2
    y0 = ca.sqrt(ca.fmax(1e-6, l_vv**2 - half_gap**2 - z**2))
    sol = ca.vertcat(y0, 0.0)
    before, last = sol, sol
    for k in range(newton):
        if rate and k == newton - 1:  # the last step from a free symbol (bound to the iterate below)
            before, sol = sol, ca.SX.sym("u_last", 2)
            last = sol
        rk, jk = ca.substitute([res, jac], [u], [sol])
        det = jk[0, 0] * jk[1, 1] - jk[0, 1] * jk[1, 0]
        sol = sol - ca.vertcat(jk[1, 1] * rk[0] - jk[0, 1] * rk[1], -jk[1, 0] * rk[0] + jk[0, 0] * rk[1]) / det
    L, R = ends(sol[0], sol[1])

    def angles(end, pivot):
        v = end - pivot
        return ca.asin(ca.fmin(1.0, ca.fmax(-1.0, v[2] / l_vv))), ca.atan2(-v[0], v[1])

    theta = ca.vertcat(*angles(L, L0), *angles(R, R0))
    link_act, lift_arg = angles_to_actuators_sx(prof, theta)
    lift, tilt, lim_l, lim_r = (link_act[i] for i in range(4))
    _, u0, wv = mast_frame(L, R)
    U = (L + R) / 2 + d_mast * (ca.cos(pitch) * u0 + ca.sin(pitch) * wv)
    top = ca.norm_2(U - ca.DM(g.top_link_tractor_point))
    q = ca.vertcat(lift, tilt, top, lim_l, lim_r)
    checks = ca.vertcat(ca.norm_2(L - L0) - l_vv, ca.norm_2(R - R0) - l_vv, lift_arg)
    if rate:
        v = ca.SX.sym("pose_velocity", 4)
        outs = [q, ca.jtimes(q, target, v), checks, ca.vertcat(sol[0], sol[1])]
        step = ca.Function("step", [target, last, v], outs)
        newton_start = ca.Function("newton_start", [target], [before])
        p, pv = ca.SX.sym("pose", 4), ca.SX.sym("pose_velocity", 4)
        values: list[ca.SX] = list(step(p, newton_start(p), pv))  # the graphs inlined, as symbols
        return ca.Function("hitch_exact_inverse_rate", [p, pv], ca.cse(values))
    outs = [q, ca.densify(ca.jacobian(q, target)), checks, ca.vertcat(sol[0], sol[1])]
    return ca.Function("hitch_exact_inverse", [target], ca.cse(outs))


class ExactInverse:
    """Closed-form inverse kinematics of one :class:`~planner.model.kinematics.HitchModel` (no limits)."""

    def __init__(self, model: HitchModel):
        self.model = model
        self.function = _build(model)
        self._fast = FastFunction(self.function, compiled=True)
        self._batch: MappedFunction | None = None
        self._jac_batch: MappedFunction | None = None
        # the last target solve_full answered, and its answer: a control cycle asks for the same
        # pose up to three times (the follower's reference, the feed-forward, the guard's "now")
        self._last: tuple[bytes, np.ndarray, np.ndarray, tuple[float, float]] | None = None

    def __call__(self, x: float, z: float, roll: float, pitch: float) -> np.ndarray:
        """Actuators (lift, tilt, top, left, right) reaching the pose exactly; KinematicsError if none,
        ModelInputError for an argument that is not a number (text failed as numpy's ValueError)."""
        try:
            target = np.array([x, z, roll, pitch], dtype=float)
        except (TypeError, ValueError):
            raise ModelInputError(
                f"target must be 4 finite numbers (x [m], z [m], roll [rad], pitch [rad]), got {[x, z, roll, pitch]!r}"
            ) from None
        return self.solve(target)[0]

    def solve(self, target: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
        """(actuators, d actuators / d (x, z, roll, pitch)) for a target of 4 values."""
        q, jac, _ = self.solve_full(target)
        return q, jac

    def solve_full(self, target: ArrayLike) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
        """(actuators, d actuators / d target, (y_T [m], yaw [rad])) for a target of 4 values."""
        try:  # a Target, a mapping or text is not 4 numbers: said as such, not numpy's TypeError
            t = np.asarray(target, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise ModelInputError(
                f"target must be 4 finite numbers (x [m], z [m], roll [rad], pitch [rad]), got {type(target).__name__}"
            ) from None
        tl = t.tolist()
        if len(tl) != 4 or not all(map(math.isfinite, tl)):
            raise ModelInputError(f"target must be 4 finite numbers (x [m], z [m], roll [rad], pitch [rad]), got {tl}")
        for name, v in (("roll", tl[2]), ("pitch", tl[3])):
            if abs(v) >= math.pi / 2:  # named, with its value and the unit it may have been meant in
                hint = unit_hint(v, -math.pi / 2, math.pi / 2, "rad")
                raise KinematicsError(f"target {name} = {v:.6g} rad must lie within ±π/2 rad{hint}")
        key = t.tobytes()
        last = self._last
        if last is not None and last[0] == key:  # a pure function of the target: the same answer
            return last[1].copy(), last[2].copy(), last[3]
        q, jac, checks, y_yaw = self._fast(t)
        c0, c1, c2 = checks[:, 0].tolist()
        if not (abs(c0) <= _TOL_M and abs(c1) <= _TOL_M):
            far = next(  # a length given in mm reads as metres far beyond any hitch
                (
                    f"; target {n} = {v:.6g} m{unit_hint(v, -2.0, 2.0, 'm')}"
                    for n, v in (("x", tl[0]), ("z", tl[1]))
                    if abs(v) > 2.0
                ),
                "",
            )
            raise KinematicsError(
                f"lower links cannot reach the implement at this pose (closure error {max(abs(c0), abs(c1)):.3g} m)"
                + far
            )
        if not abs(c2) <= 1.0:
            raise KinematicsError("the fixed left lift rod cannot reach the left lower link at this pose")
        qv = q[:, 0].copy()
        if not all(map(math.isfinite, qv.tolist())):
            raise KinematicsError("degenerate pose")
        y_t = (float(y_yaw[0, 0]), float(y_yaw[1, 0]))
        self._last = (key, qv.copy(), jac.copy(), y_t)
        return qv, jac.copy(), y_t

    def solve_batch(self, targets: ArrayLike, velocities: ArrayLike) -> InverseBatch:
        """The inverse at N targets (N, 4) moving at ``velocities`` (N, 4) (x, z, roll, pitch and
        their rates) in one mapped evaluation.

        Actuators, y_T and yaw are those of :meth:`solve_full`, bit for bit; the actuator
        velocities are d actuators / d target · velocity as one forward directional derivative
        (``jac @ velocity`` of :meth:`solve_full` to rounding, ~1e-16 relative; see
        :func:`_build`). Rows with ``ok`` False are those :meth:`solve_full` refuses; ask it
        for the reason.
        """
        p = np.asarray(targets, dtype=float)
        v = np.asarray(velocities, dtype=float)
        if p.ndim != 2 or p.shape[1] != 4 or v.shape != p.shape:
            raise ModelInputError(f"targets and velocities must both be (N, 4), got {p.shape} and {v.shape}")
        if self._batch is None:
            self._batch = MappedFunction(_build(self.model, rate=True), compiled=True)
        q, qd, checks, y_yaw = self._batch(p.T, v.T)
        ok = _solved(p, q, checks)
        return InverseBatch(q.T, qd.T, y_yaw[0].copy(), y_yaw[1].copy(), ok)

    def jacobians(self, targets: ArrayLike) -> np.ndarray:
        """d actuators / d target (N, 5, 4) at N targets (N, 4) in one mapped evaluation: those of
        :meth:`solve`, bit for bit; at a target :meth:`solve` refuses, its error (the first such
        target raises)."""
        p = np.asarray(targets, dtype=float)
        if p.ndim != 2 or p.shape[1] != 4:
            raise ModelInputError(f"targets must be (N, 4), got {p.shape}")
        if self._jac_batch is None:
            self._jac_batch = MappedFunction(self.function, compiled=True)
        q, jac, checks, _ = self._jac_batch(p.T)
        ok = _solved(p, q, checks)
        out = jac.reshape(5, len(p), 4).transpose(1, 0, 2).copy()  # column block k is target k's
        for k in np.flatnonzero(~ok).tolist():  # raises as solve does
            out[k] = self.solve(p[k])[1]
        return out

    def actuators(self, x: float, z: float, roll: float, pitch: float) -> Actuators:
        """:meth:`__call__` as named :class:`~planner.model.types.Actuators` (lift [rad]; tilt, top, left, right
        [m]) for the pose x, z [m], roll, pitch [rad]; no limit is checked."""
        return Actuators.from_array(self(x, z, roll, pitch))


def _solved(p: np.ndarray, q: np.ndarray, checks: np.ndarray) -> np.ndarray:
    """Per target (rows of ``p``, N×4): finite, roll and pitch within ±π/2, the mapped function's
    closure checks within tolerance and finite actuators (columns of ``q``)."""
    with np.errstate(invalid="ignore"):
        return (
            np.isfinite(p).all(axis=1)
            & (np.abs(p[:, 2]) < math.pi / 2)
            & (np.abs(p[:, 3]) < math.pi / 2)
            & (np.abs(checks[0]) <= _TOL_M)
            & (np.abs(checks[1]) <= _TOL_M)
            & (np.abs(checks[2]) <= 1.0)
            & np.isfinite(q).all(axis=0)
        )
