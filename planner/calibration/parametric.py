"""Forward kinematics as a CasADi function of (actuator readings, calibration parameters).

The same equations as :mod:`planner.model.kinematics` (thesis §2.2), written with the geometry as
symbols instead of numbers: the direction and mast functions of :mod:`planner.model.geometry` are
used as they are (``link_direction``, ``bracket_direction``, ``mast_point``); the few lines that
place the side points (pivot, lift-arm pivot Q, limiter point C, lift-arm end S, link points A, B', B
and the link end) are repeated here with symbolic fields, since the model's versions take numbers.

The link angles θ = (θxl, θzl, θxr, θzr) solve the loop closure G(q, θ, p) = 0 with a CasADi
Newton rootfinder (seeded from the nominal model); its derivatives with respect to the actuators
and the parameters come from the implicit-function theorem (CasADi differentiates the rootfinder
that way). With ``rigid_span=True`` (the default, like the twin's true machine) a fifth unknown,
the sway limiters' common-mode give ``s``, makes the balls sit at the implement's span:
|L − R| = span; the limiters' difference (the lateral position) is kept. ``rigid_span=False`` is
plain forward kinematics and equals :class:`~planner.model.kinematics.HitchModel` at nominal.

Outputs per pose (:data:`OUTPUT_NAMES`): the pose x, y, z, roll, pitch, yaw of T and the marked
points L, R (ball centres) and U (top-link pin) [m, rad].

With the lag among the parameters (:class:`~planner.calibration.parameters.ParameterSet`,
``include_lag``) a pose's ``side`` (−1 approached rising, +1 falling, 0 unknown or averaged) adds
``side · lag`` to its x, z, roll and pitch: the implement rests the play's half-band behind the
mechanism. The marked points are not shifted (measure points with the play averaged: from both sides).
"""

from __future__ import annotations

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike

from planner.calibration.parameters import CalibrationError, ParameterSet
from planner.model.geometry import LEFT, RIGHT, bracket_direction, link_direction, mast_point
from planner.model.kinematics import HitchModel
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES, KinematicsError
from planner.profiles.hitch import Profile

__all__ = ["OUTPUT_NAMES", "POSE_ROWS", "POINT_ROWS", "ParametricModel"]

#: rows of one pose's output vector
OUTPUT_NAMES: tuple[str, ...] = (
    "x",
    "y",
    "z",
    "roll",
    "pitch",
    "yaw",
    *(f"{p}_{c}" for p in ("L", "R", "U") for c in "xyz"),
)
#: output rows of the controlled pose x, z, roll, pitch
POSE_ROWS: dict[str, int] = {"x": 0, "z": 2, "roll": 3, "pitch": 4}
#: output rows (3 each) of the marked points
POINT_ROWS: dict[str, int] = {"L": 6, "R": 9, "U": 12}
_CLOSURE_TOL_M = 1e-9
#: output rows of x, z, roll, pitch (the DOF of the lag parameters)
_POSE_ROWS_XZRP = np.array([POSE_ROWS[k] for k in ("x", "z", "roll", "pitch")])


def _field_expressions(ps: ParameterSet, p: ca.SX) -> dict[str, ca.SX]:
    """Every geometry field and AD term as an expression: a parameter symbol, or the profile's constant."""
    g = ps.profile.geometry
    out: dict[str, ca.SX] = {}
    for f in ("lift_arm_pivot", "top_link_tractor_point", "limiter_tractor_point"):
        for i, v in enumerate(getattr(g, f)):
            out[f"geometry.{f}[{i}]"] = ca.SX(float(v))
    for f in (
        "lower_link_pivot_span",
        "pivot_height",
        "lower_link_length",
        "lift_rod_attachment",
        "limiter_bracket_position",
        "limiter_bracket_offset",
        "fixed_lift_rod_length",
        "lift_arm_length",
    ):
        out[f"geometry.{f}"] = ca.SX(float(getattr(g, f)))
    for n in ACTUATOR_NAMES:
        out[f"ad_offset.{n}"] = ca.SX(0.0)
        out[f"ad_gain.{n}"] = ca.SX(0.0)
    for k, name in enumerate(ps.names):
        out[name] = p[k]
    return out


def _vec3(e: dict[str, ca.SX], f: str) -> ca.SX:
    return ca.vertcat(e[f"geometry.{f}[0]"], e[f"geometry.{f}[1]"], e[f"geometry.{f}[2]"])


class ParametricModel:
    """The hitch's forward kinematics (and marked points) as a function of actuator readings and parameters.

    ``params``: the calibration parameters (default all of :class:`ParameterSet` for ``profile``);
    ``category``: the implement's ISO 730 category (default the profile's).
    """

    def __init__(
        self,
        profile: Profile,
        category: str | None = None,
        *,
        params: ParameterSet | None = None,
        rigid_span: bool = True,
    ) -> None:
        self.params = params if params is not None else ParameterSet.from_profile(profile)
        if self.params.profile is not profile and self.params.profile != profile:
            raise CalibrationError("params must be built from the same profile as the model")
        self.profile = profile
        self.nominal_model = HitchModel(profile, category)
        self.category = self.nominal_model.category
        self.rigid_span = bool(rigid_span)
        self._sc = SensorScaling(profile)
        self._fn, self._jac_fn, self._n_x = self._build()
        self._batch: dict[tuple[int, bool], ca.Function] = {}
        #: the lag parameters' indices (:attr:`ParameterSet.lag_index`) and the output rows they shift
        self._lag_index = self.params.lag_index
        self._lag_rows = _POSE_ROWS_XZRP[list(self.params.lag_dofs)]

    @property
    def n_params(self) -> int:
        return len(self.params)

    def _build(self) -> tuple[ca.Function, ca.Function, int]:
        ps = self.params
        n = len(ps)
        q_read = ca.SX.sym("q", 5)
        p = ca.SX.sym("p", n)
        n_x = 5 if self.rigid_span else 4
        x = ca.SX.sym("x", n_x)
        e = _field_expressions(ps, p)
        si_min = ca.DM(self._sc.si_min)
        off = ca.vertcat(*(e[f"ad_offset.{a}"] for a in ACTUATOR_NAMES))
        gain = ca.vertcat(*(e[f"ad_gain.{a}"] for a in ACTUATOR_NAMES))
        q = si_min + off + (1.0 + gain) * (q_read - si_min)  # true actuators from the nominal reading
        common = x[4] if self.rigid_span else 0.0
        lift, tilt, top, lim_l, lim_r = q[0], q[1], q[2], q[3] + common, q[4] + common

        span_p = e["geometry.lower_link_pivot_span"]
        qa, cc, hh = _vec3(e, "lift_arm_pivot"), _vec3(e, "limiter_tractor_point"), _vec3(e, "top_link_tractor_point")
        l_vv, d_a = e["geometry.lower_link_length"], e["geometry.lift_rod_attachment"]
        d_b, d_e = e["geometry.limiter_bracket_position"], e["geometry.limiter_bracket_offset"]
        rod, arm = e["geometry.fixed_lift_rod_length"], e["geometry.lift_arm_length"]

        def side_points(side: float, tx: ca.SX, tz: ca.SX) -> dict[str, ca.SX]:
            px = side * span_p / 2.0
            pivot = ca.vertcat(px, 0.0, 0.0)
            q_pt = ca.vertcat(px + side * qa[0], qa[1], qa[2])
            c_pt = ca.vertcat(px + side * cc[0], cc[1], cc[2])
            d = link_direction(tx, tz)
            bp = pivot + d_b * d
            return {
                "S": q_pt + arm * ca.vertcat(0.0, ca.cos(lift), ca.sin(lift)),  # thesis 2.14
                "A": pivot + d_a * d,
                "B": bp + d_e * bracket_direction(tz, side),
                "C": c_pt,
                "end": pivot + l_vv * d,
            }

        left, right = side_points(LEFT, x[0], x[1]), side_points(RIGHT, x[2], x[3])
        L, R = left["end"], right["end"]
        closure = [
            ca.sumsqr(left["A"] - left["S"]) - rod**2,
            ca.sumsqr(left["B"] - left["C"]) - lim_l**2,
            ca.sumsqr(right["A"] - right["S"]) - tilt**2,
            ca.sumsqr(right["B"] - right["C"]) - lim_r**2,
        ]
        if self.rigid_span:
            closure.append(ca.norm_2(L - R) - self.nominal_model.span)
        g = ca.vertcat(*closure)
        U, pitch, reach = mast_point(L, R, hh, top, self.nominal_model.mast_height)
        T = (L + R) / 2.0
        v = L - R
        y = ca.vertcat(T, ca.atan2(-v[2], v[0]), pitch, ca.atan2(v[1], v[0]), L, R, U)
        checks = ca.vertcat(
            ca.norm_2(left["A"] - left["S"]) - rod,
            ca.norm_2(left["B"] - left["C"]) - lim_l,
            ca.norm_2(right["A"] - right["S"]) - tilt,
            ca.norm_2(right["B"] - right["C"]) - lim_r,
            reach,
        )
        par = ca.vertcat(q_read, p)
        g_fn = ca.Function("closure", [x, par], [g])
        out_fn = ca.Function("outputs", [x, par], [y, checks])
        rf = ca.rootfinder("closure_root", "newton", g_fn, {"abstol": 1e-14, "max_iter": 40, "error_on_fail": False})
        qm, pm, x0 = ca.MX.sym("q", 5), ca.MX.sym("p", n), ca.MX.sym("x0", n_x)
        xs = rf(x0, ca.vertcat(qm, pm))
        ym, cm = out_fn(xs, ca.vertcat(qm, pm))
        fn = ca.Function("parametric_fk", [qm, pm, x0], [ym, cm, xs])
        jac_fn = ca.Function("parametric_fk_jac", [qm, pm, x0], [ym, ca.jacobian(ym, pm), cm, xs])
        return fn, jac_fn, n_x

    # ------------------------------------------------------------------ evaluation
    def _seed(self, q_read: np.ndarray) -> np.ndarray:
        """Initial link angles (and zero limiter give) from the nominal model at the reading."""
        try:
            th = np.array(self.nominal_model.forward(q_read).link_angles)
        except KinematicsError:
            th = np.zeros(4)
        return np.concatenate([th, [0.0]])[: self._n_x]

    def _reading(self, q_read: ArrayLike) -> np.ndarray:
        q = np.asarray(q_read, dtype=float).reshape(-1)
        if q.size != 5 or not np.all(np.isfinite(q)):
            raise CalibrationError(f"actuator reading must be 5 finite numbers ({', '.join(ACTUATOR_NAMES)})")
        return q

    def _check(self, checks: np.ndarray, q: np.ndarray) -> None:
        if not (np.all(np.abs(checks[:4]) <= _CLOSURE_TOL_M) and abs(checks[4]) <= 1.0):
            raise KinematicsError(
                f"the mechanism with these parameters cannot close at actuators {np.round(q, 6).tolist()} "
                f"(closure errors {np.round(checks[:4], 12).tolist()} m, top-link reach {checks[4]:.4g})"
            )

    def predict(self, q_read: ArrayLike, p: ArrayLike | None = None, side: float = 0.0) -> np.ndarray:
        """Outputs (:data:`OUTPUT_NAMES`, 15) at one actuator reading (SI, nominal AD map) and parameters,
        approached from ``side`` (module docstring)."""
        q = self._reading(q_read)
        pv = self.params.nominal if p is None else self.params.vector(p)
        y, c, _ = self._fn(q, pv, self._seed(q))
        self._check(np.asarray(c).reshape(-1), q)
        out = np.asarray(y).reshape(-1)
        lag = self._lag_index
        if lag.size:
            out[self._lag_rows] += float(side) * pv[lag]
        return out

    def batch(
        self,
        q_read: ArrayLike,
        p: ArrayLike | None = None,
        *,
        jacobian: bool = True,
        seeds: np.ndarray | None = None,
        sides: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Outputs (N, 15) and, with ``jacobian``, d outputs / d parameters (N, 15, n) at N readings (N, 5),
        approached from ``sides`` (N,) (module docstring; default 0: no lag)."""
        qs = np.asarray(q_read, dtype=float)
        if qs.ndim != 2 or qs.shape[1] != 5 or not np.all(np.isfinite(qs)):
            raise CalibrationError("actuator readings must be an (N, 5) array of finite numbers")
        pv = self.params.nominal if p is None else self.params.vector(p)
        n_pose = qs.shape[0]
        x0 = seeds if seeds is not None else self.seeds(qs)
        key = (n_pose, jacobian)
        if key not in self._batch:
            self._batch[key] = (self._jac_fn if jacobian else self._fn).map(n_pose)
        f = self._batch[key]
        out = f(qs.T, np.tile(pv[:, None], (1, n_pose)), x0.T)
        y = np.asarray(out[0]).T.reshape(n_pose, 15)
        c = np.asarray(out[2] if jacobian else out[1]).T.reshape(n_pose, 5)
        for k in range(n_pose):
            self._check(c[k], qs[k])
        lag = self._lag_index
        side = np.zeros(n_pose) if sides is None else np.asarray(sides, dtype=float).reshape(-1)
        if side.shape != (n_pose,):
            raise CalibrationError(f"sides must hold one approach side per reading ({n_pose}), got {side.size}")
        rows = self._lag_rows
        if lag.size:
            y[:, rows] += side[:, None] * pv[lag][None, :]
        if not jacobian:
            return y, None
        j = np.asarray(out[1]).reshape(15, n_pose, self.n_params).transpose(1, 0, 2)
        if lag.size:
            j[:, rows, lag] += side[:, None]
        return y, j

    def seeds(self, q_read: np.ndarray) -> np.ndarray:
        """Rootfinder seeds (N, 4 or 5) for N readings."""
        return np.array([self._seed(q) for q in np.asarray(q_read, dtype=float)])
