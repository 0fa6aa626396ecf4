"""Exact forward kinematics of the 4-DOF advanced rear hitch (thesis §2.2).

The model is built once per (profile, category) as CasADi symbolic functions
actuators → named points → pose, so every derivative comes from automatic
differentiation, and is evaluated through pre-bound buffers (~µs per call).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from planner.errors import unit_hint
from planner.model.fast_function import FastFunction
from planner.model.geometry import (
    LEFT,
    RIGHT,
    closure_residual,
    direction_angles,
    lift_arm_end,
    link_points,
    mast_point,
    side_geometry,
    solve_link_angles,
)
from planner.model.types import ACTUATOR_NAMES, Actuators, HitchState, KinematicsError, ModelInputError, Pose
from planner.profiles.hitch import CATEGORY_LENGTH_MAX_M, Profile, ProfileError, load_profile

__all__ = ["HitchModel", "SymbolicModel", "FEATURE_NAMES", "POINT_NAMES"]

#: Rows of the feature vector (pose, lower span, raw top-link angles, link-end heights).
FEATURE_NAMES: tuple[str, ...] = (
    "x",
    "y",
    "z",
    "roll",
    "pitch",
    "yaw",
    "lower_span",
    "top_link_yaw",
    "top_link_pitch",
    "z_left_end",
    "z_right_end",
)
#: Names of the points returned by :meth:`HitchModel.forward` (``_l``/``_r`` = left/right).
POINT_NAMES: tuple[str, ...] = (
    "L0",
    "R0",
    "L",
    "R",
    "T",
    "U",
    "H",
    "Q_l",
    "Q_r",
    "S_l",
    "S_r",
    "A_l",
    "A_r",
    "Bp_l",
    "Bp_r",
    "B_l",
    "B_r",
    "C_l",
    "C_r",
)
_RESIDUAL_CAUSES = (
    "left lift rod cannot reach the left lower link",
    "left sway limiter cannot reach its bracket with this length",
    "tilt cylinder cannot reach the right lower link",
    "right sway limiter cannot reach its bracket with this length",
)
_CLOSURE_TOL_M = 1e-9
#: the largest ISO span and mast height of a category [m] (the profile schema's)
_SPAN_MAX_M = _MAST_MAX_M = CATEGORY_LENGTH_MAX_M


def _within(lo: float, hi: float, top: float) -> str:
    """A range of a length field [m] that is positive and at most ``top``, rounded inward to 0.1 mm (each number
    said lies in it): ``within a..b m``, ``at most b m`` (from 0), ``at least a m`` (to ``top``); "none" when
    nothing of it is left after rounding."""
    a, b = math.ceil(lo * 1e4) / 1e4, math.floor(hi * 1e4) / 1e4
    if lo <= 0.0:
        return f"at most {b:.4f} m" if hi < top else f"within (0, {top:g}] m"
    if a > b:
        return "none"
    return f"at least {a:.4f} m" if hi >= top else f"within {a:.4f}..{b:.4f} m"


def _build(profile: Profile, category: str) -> tuple[ca.Function, ca.Function, SymbolicModel]:
    """Build the symbolic model: returns (points_fn, feature_fn, symbolic).

    The link angles θ = (θxl, θzl, θxr, θzr) are first kept symbolic: points,
    features F(q, θ) and the closure equations G(q, θ) = 0 are written in (q, θ).
    Values substitute θ*(q) from :func:`~planner.model.geometry.solve_link_angles`; the
    Jacobian comes from the implicit-function theorem, dθ/dq = −G_θ⁻¹ G_q, which is
    exact at the solution and far smaller than differentiating the iterations.
    """
    g = profile.geometry
    left, right = side_geometry(profile, LEFT), side_geometry(profile, RIGHT)
    mast = profile.category(category).mast_height
    q = ca.SX.sym("q", 5)
    th = ca.SX.sym("theta", 4)
    lift, tilt, top, lim_l, lim_r = (q[i] for i in range(5))

    s_l, s_r = lift_arm_end(left, lift), lift_arm_end(right, lift)
    pl, pr = link_points(left, th[0], th[1]), link_points(right, th[2], th[3])
    L, R = pl["end"], pr["end"]
    H = ca.DM(g.top_link_tractor_point)
    U, pitch, reach = mast_point(L, R, H, top, mast)
    T = (L + R) / 2.0  # tool point T, the midpoint of the lower-link ends (thesis 2.21)
    v = L - R
    roll = ca.atan2(-v[2], v[0])  # atan2(z_R − z_L, x_L − x_R) (thesis 2.22 in this frame)
    yaw = ca.atan2(v[1], v[0])
    tl_yaw, tl_pitch = direction_angles(U - H)
    features = ca.vertcat(T[0], T[1], T[2], roll, pitch, yaw, ca.norm_2(v), tl_yaw, tl_pitch, L[2], R[2])
    pts = {
        "L0": ca.DM(left.pivot),
        "R0": ca.DM(right.pivot),
        "L": L,
        "R": R,
        "T": T,
        "U": U,
        "H": H,
        "Q_l": ca.DM(left.lift_arm_pivot),
        "Q_r": ca.DM(right.lift_arm_pivot),
        "S_l": s_l,
        "S_r": s_r,
        "A_l": pl["A"],
        "A_r": pr["A"],
        "Bp_l": pl["Bp"],
        "Bp_r": pr["Bp"],
        "B_l": pl["B"],
        "B_r": pr["B"],
        "C_l": ca.DM(left.limiter_point),
        "C_r": ca.DM(right.limiter_point),
    }
    point_matrix = ca.densify(ca.horzcat(*(ca.SX(pts[n]) for n in POINT_NAMES)))

    closure = ca.vertcat(
        closure_residual(left, s_l, g.fixed_lift_rod_length, lim_l, th[0], th[1]),
        closure_residual(right, s_r, tilt, lim_r, th[2], th[3]),
    )
    g_th = ca.jacobian(closure, th)  # block diagonal 2×2 + 2×2
    g_q = ca.jacobian(closure, q)
    dth_dq = ca.SX.zeros(4, 5)
    for k in (0, 2):
        blk = g_th[k : k + 2, k : k + 2]
        det = blk[0, 0] * blk[1, 1] - blk[0, 1] * blk[1, 0]
        inv = ca.vertcat(ca.horzcat(blk[1, 1], -blk[0, 1]), ca.horzcat(-blk[1, 0], blk[0, 0])) / det
        dth_dq[k : k + 2, :] = -inv @ g_q[k : k + 2, :]
    jac = ca.densify(ca.jacobian(features, q) + ca.jacobian(features, th) @ dth_dq)

    txl, tzl, res_l = solve_link_angles(left, s_l, g.fixed_lift_rod_length, lim_l)
    txr, tzr, res_r = solve_link_angles(right, s_r, tilt, lim_r)
    th_star = ca.vertcat(txl, tzl, txr, tzr)
    features, jac, point_matrix, reach = ca.substitute([features, jac, point_matrix, reach], [th], [th_star])
    checks = ca.vertcat(res_l, res_r, reach)
    # common-subexpression elimination: the substituted Newton graph is shared by all outputs
    points_fn = ca.Function("hitch_points", [q], ca.cse([features, point_matrix, th_star, checks]))
    feature_fn = ca.Function("hitch_features", [q], ca.cse([features, jac, checks]))
    # NaN wherever the mechanism cannot close, so optimisers reject such points instead of
    # trusting the finite garbage of a non-converged Newton iteration.
    valid = ca.logic_and(ca.mmax(ca.fabs(ca.vertcat(res_l, res_r))) <= _CLOSURE_TOL_M, ca.fabs(reach) <= 1.0)
    poison = ca.if_else(valid, 0.0, math.nan)
    symbolic = SymbolicModel(q=q, features=features + poison, jacobian=jac + poison)
    return points_fn, feature_fn, symbolic


@dataclass(frozen=True)
class SymbolicModel:
    """CasADi SX expressions of the model in the actuator symbol ``q`` (5,).

    ``features`` (:data:`FEATURE_NAMES`) and ``jacobian`` (11×5, implicit-function theorem)
    evaluate to NaN where the mechanism cannot close.
    """

    q: ca.SX
    features: ca.SX
    jacobian: ca.SX


#: the profile field of each hard limit the neutral pose can break (:meth:`HitchModel._check_neutral`)
_NEUTRAL_LIMIT_FIELDS = {
    "top_link_yaw_min": "limits.top_link_yaw_max",
    "top_link_yaw_max": "limits.top_link_yaw_max",
    "top_link_pitch_min": "limits.top_link_pitch_down_max",
    "top_link_pitch_max": "limits.top_link_pitch_up_max",
    "ground_clearance_left": "limits.ground_clearance",
    "ground_clearance_right": "limits.ground_clearance",
}


class HitchModel:
    """Kinematic model of one hitch profile with one implement category attached.

    Attributes (SI): ``span`` ball-centre lower hitch span [m], ``mast_height`` d_T^U [m],
    ``lower``/``upper`` actuator strokes (order :data:`~planner.model.types.ACTUATOR_NAMES`),
    ``neutral`` actuators of the neutral pose, ``top_link_reference`` (yaw, pitch) [rad]
    from which top-link angle limits are measured, ``workspace`` the restricted box
    ``{"x": (min, max), "z": …, "roll": …, "pitch": …}`` in SI, or None if the profile
    has none for this category.
    """

    def __init__(self, profile: Profile, category: str | None = None):
        if not isinstance(profile, Profile):  # a name failed as "'str' object has no attribute 'implement'"
            raise ModelInputError(
                f"profile must be a Profile (load_profile(name)), got {type(profile).__name__} {profile!r}; "
                "for a built-in name or a .toml path use HitchModel.from_profile(name_or_path)"
            )
        self.profile = profile
        self.category = category if category is not None else profile.implement.default_category
        profile.category(self.category)  # validates the name
        self.span = profile.span(self.category)
        self.mast_height = profile.category(self.category).mast_height
        self.points_function, self.feature_function, self.symbolic = _build(profile, self.category)
        self._points = FastFunction(self.points_function, compiled=True)
        self._features = FastFunction(self.feature_function, compiled=True)
        specs = [profile.actuator(n) for n in ACTUATOR_NAMES]
        self.lower = np.array([s.min for s in specs])
        self.upper = np.array([s.max for s in specs])
        self.neutral = self._solve_neutral()
        state = self.forward(self.neutral)
        if profile.limits.top_link_angle_reference == "neutral":
            self.top_link_reference = (state.top_link_angles[0], state.top_link_angles[1])
        else:
            self.top_link_reference = (0.0, 0.0)
        self.neutral_pose = state.pose
        self.workspace = self._workspace()
        if self.workspace is not None:  # a category without a workspace (no Cartesian motion) may lack a home
            self._check_neutral()

    @classmethod
    def from_profile(cls, name_or_path: str | Path = "thesis-t132", category: str | None = None) -> HitchModel:
        """The model of a built-in profile name (``thesis-t132``, the default) or a ``.toml`` profile path;
        ``category``: the ISO 730 category of the implement attached (its lower-link span and mast height;
        default: the profile's ``implement.default_category``). Raises ProfileError naming the field of a bad
        profile or the categories allowed."""
        return cls(load_profile(name_or_path), category)

    # ------------------------------------------------------------------ evaluation
    def features(self, q) -> tuple[np.ndarray, np.ndarray]:
        """Feature vector (:data:`FEATURE_NAMES`) and its 11×5 Jacobian at actuators ``q``.

        Raises :class:`KinematicsError` when the mechanism cannot close. Returned
        arrays are copies.
        """
        f, jac, checks = self._features(self._as_vector(q))
        if not self._fast_ok(checks[:, 0], f[:, 0]):
            self._check(checks[:, 0], f[:, 0], self._as_vector(q))
        return f[:, 0].copy(), jac.copy()

    def forward(self, actuators: Actuators | np.ndarray) -> HitchState:
        """Exact forward kinematics: pose of T and the implement, and every named point, for any actuators the
        mechanism closes with — strokes and other hard limits are not checked here (``HardLimits.violations``,
        :func:`~planner.trajectory.plan.verify_setpoints`, ``hitch fk`` check them); KinematicsError when it
        cannot close."""
        q = self._as_vector(actuators)
        f, pts, angles, checks = self._points(q)
        self._check(checks[:, 0], f[:, 0], q)
        f = f[:, 0]
        ref = getattr(self, "top_link_reference", (0.0, 0.0))
        th = angles[:, 0]
        return HitchState(
            actuators=Actuators.from_array(q),
            pose=Pose.from_array(f[:6]),
            points={n: pts[:, i].copy() for i, n in enumerate(POINT_NAMES)},
            link_angles=(float(th[0]), float(th[1]), float(th[2]), float(th[3])),
            top_link_angles=(float(f[7] - ref[0]), float(f[8] - ref[1])),
            lower_span=float(f[6]),
        )

    def points(self, actuators: Actuators | np.ndarray) -> dict[str, np.ndarray]:
        """The named points (3,) [m] of :meth:`forward` (``forward(q).points``, bit for bit, same
        checks and errors) without building the rest of its state."""
        q = self._as_vector(actuators)
        f, pts, _, checks = self._points(q)
        self._check(checks[:, 0], f[:, 0], q)
        return {n: pts[:, i].copy() for i, n in enumerate(POINT_NAMES)}

    def pose(self, actuators) -> Pose:
        return self.forward(actuators).pose

    # ------------------------------------------------------------------ helpers
    @staticmethod
    def _as_vector(actuators) -> np.ndarray:
        """The five actuators [rad, m, m, m, m] as a float vector; ModelInputError for anything else, and for a
        lift angle beyond ±π: the same physical angle as one within, so almost surely degrees (12.6 for
        0.22 rad closed the mechanism and gave a pose: a reviewer's reproduction)."""
        if isinstance(actuators, Actuators):
            q = actuators.as_array()
        else:
            try:
                q = np.asarray(actuators, dtype=float).reshape(-1)
            except (TypeError, ValueError) as exc:
                raise ModelInputError(
                    f"actuators: expected 5 numbers ({', '.join(ACTUATOR_NAMES)}), got {actuators!r}"
                ) from exc
        if q.size != 5:
            raise ModelInputError(f"actuators: expected 5 values ({', '.join(ACTUATOR_NAMES)}), got {q.size}")
        for name, v in zip(ACTUATOR_NAMES, q, strict=True):
            if not math.isfinite(v):
                raise ModelInputError(f"actuators.{name} must be a finite number, got {v}")
        if not -math.pi <= q[0] <= math.pi:
            raise ModelInputError(
                f"actuators.lift = {q[0]:.6g} rad is beyond ±π (allowed [-3.14159, 3.14159] rad)"
                + unit_hint(float(q[0]), -math.pi, math.pi, "rad")
            )
        return q

    def _check(self, checks: np.ndarray, features: np.ndarray, q: np.ndarray | None = None) -> None:
        closure = self._closure_error(checks, q)
        if closure is not None:
            raise closure
        if not abs(checks[4]) <= 1.0:
            raise KinematicsError(
                "top link cannot reach the implement mast with this length (circle-sphere miss, "
                f"cos argument {checks[4]:.4g})"
            )
        if not np.all(np.isfinite(features)):
            raise KinematicsError("degenerate configuration (lower-link ends coincide)")

    def _closure_error(self, checks: np.ndarray, q: np.ndarray | None) -> KinematicsError | None:
        """The error of a side whose lower link does not close (lift rod or tilt cylinder, sway limiter), or None."""
        bad = [i for i in range(4) if not abs(checks[i]) <= _CLOSURE_TOL_M]  # also catches NaN
        if not bad:
            return None
        cause = self._closure_cause(q) if q is not None else None
        return KinematicsError(f"{cause or _RESIDUAL_CAUSES[bad[0]]} (closure error {checks[bad[0]]:.3g} m)")

    @staticmethod
    def _fast_ok(checks: np.ndarray, features: np.ndarray) -> bool:
        return bool(
            np.max(np.abs(checks[:4])) <= _CLOSURE_TOL_M and abs(checks[4]) <= 1.0 and np.isfinite(features).all()
        )

    def _closure_cause(self, q: np.ndarray) -> str | None:
        """Which member cannot close, by reach intervals around the lower-link pivot.

        B is at the fixed distance √(d_OB'² + d_BB'²) from the pivot and A at d_O^A, so
        |B − C| and |A − S| must lie within the triangle-inequality intervals.
        """
        g = self.profile.geometry
        rb = math.hypot(g.limiter_bracket_position, g.limiter_bracket_offset)
        for k, side in enumerate((LEFT, RIGHT)):
            sg = side_geometry(self.profile, side)
            piv = np.array(sg.pivot)
            dc = np.linalg.norm(np.array(sg.limiter_point) - piv)
            lim = q[3 + k]
            if not abs(dc - rb) <= lim <= dc + rb:
                who = "left" if side == LEFT else "right"
                return (
                    f"{who} sway limiter length {lim:.4g} m cannot reach its bracket "
                    f"(reachable {abs(dc - rb):.4g}..{dc + rb:.4g} m)"
                )
            qa = np.array(sg.lift_arm_pivot)
            s_pt = qa + g.lift_arm_length * np.array([0.0, math.cos(q[0]), math.sin(q[0])])
            ds = np.linalg.norm(s_pt - piv)
            rod = g.fixed_lift_rod_length if side == LEFT else q[1]
            if not abs(ds - g.lift_rod_attachment) <= rod <= ds + g.lift_rod_attachment:
                who = "left lift rod" if side == LEFT else "tilt cylinder"
                return (
                    f"{who} length {rod:.4g} m cannot reach the lower link "
                    f"(reachable {abs(ds - g.lift_rod_attachment):.4g}..{ds + g.lift_rod_attachment:.4g} m)"
                )
        return None

    def _check_neutral(self) -> None:
        """The neutral pose (home) of a category with a restricted workspace within every hard limit, else a
        :class:`ProfileError` naming the profile field (a stroke that misses it loaded before and failed at the
        first plan, "exceed stroke:top:max at t = 0"). The thesis profile's category 4 has no workspace: its
        home needs the top link at 0.973 m, beyond the 0.905 m stroke."""
        from planner.model.hard_limits import HardLimits  # it builds on this module

        p, q = self.profile, self.neutral
        for i, n in enumerate(ACTUATOR_NAMES):
            if not self.lower[i] - 1e-9 <= q[i] <= self.upper[i] + 1e-9:
                unit = "rad" if n == "lift" else "m"
                mast = ""
                if n == "top":  # the mast the top link holds upright: a mast height is the likelier slip
                    field = f"implement.categories.{self.category}.mast_height"
                    heights = self._mast_heights_for_top(q)
                    mast = (
                        f", or {field} = {self.mast_height:g} m must be {heights} (the masts the stroke holds "
                        "upright, the other fields as given)"
                        if heights != "none"
                        else f"; no {field} puts it within the stroke (the other fields as given)"
                    )
                raise ProfileError(
                    f"profile {p.name}: the neutral pose (x = 0, pitch = 0, the category's span) needs {n} = "
                    f"{q[i]:.4f} {unit}, outside its stroke actuators.{n} [{self.lower[i]:g}, {self.upper[i]:g}] "
                    f"{unit}: the stroke must contain it (category {self.category} has a workspace: "
                    f"workspace.restricted){mast}"
                )
        f, _ = self.features(q)
        for name in HardLimits.from_model(self).violations(q, f):
            field = _NEUTRAL_LIMIT_FIELDS.get(name, name)
            if field == "limits.ground_clearance":
                z_end = f[FEATURE_NAMES.index("z_left_end" if name.endswith("left") else "z_right_end")]
                detail = (
                    f"the lower link ends are {z_end + p.geometry.pivot_height:.4f} m above the ground there "
                    f"(limits.ground_clearance = {p.limits.ground_clearance:g} m, "
                    f"geometry.pivot_height = {p.geometry.pivot_height:g} m)"
                )
            else:
                detail = f"{name} is exceeded there"
            raise ProfileError(f"profile {p.name}: the neutral pose breaks {field}: {detail}")

    def _solve_neutral(self) -> np.ndarray:
        """Neutral actuators: lift and tilt at their profile neutrals; limiters and top link
        chosen so that x = 0, |L−R| = span and pitch = 0 (Newton on the exact model).

        x and the span do not depend on the top link: the limiters are solved first (from mid-stroke), and the
        top link starts at the length that holds the mast upright there (started mid-stroke, a mast its middle
        could not reach failed as "top link cannot reach the implement mast", though the pose needs only a longer
        top link). A span the lower links cannot reach is refused naming the category's span and the spans they
        reach (:meth:`_span_refusal`)."""
        p = self.profile
        q = np.array(
            [
                p.actuators.lift.neutral
                if p.actuators.lift.neutral is not None
                else (self.lower[0] + self.upper[0]) / 2,
                p.actuators.tilt.neutral
                if p.actuators.tilt.neutral is not None
                else (self.lower[1] + self.upper[1]) / 2,
                0.0,
                0.0,
                0.0,
            ]
        )
        q[2:] = (self.lower[2:] + self.upper[2:]) / 2
        limiters, step, exc = self._neutral_limiters(q, self.span)
        if limiters is None:
            cause = str(exc) if step == 0 else self._span_refusal(q)  # step 0: no span closes the start
            raise KinematicsError(f"profile {p.name}: cannot find the neutral pose: {cause}")
        q[3:] = limiters
        p_th, u0 = self._upright_terms(q)
        q[2] = float(np.linalg.norm(p_th + self.mast_height * u0))
        free = [2, 3, 4]
        for _ in range(50):
            try:
                f, jac = self.features(q)
            except KinematicsError as exc:
                field = f"implement.categories.{self.category}.mast_height"
                raise KinematicsError(
                    f"profile {p.name}: cannot find the neutral pose: {field} = {self.mast_height:g} m: the top "
                    f"link cannot hold the mast upright ({exc})"
                ) from None
            r = np.array([f[0], f[6] - self.span, f[4]])
            if np.max(np.abs(r)) < 1e-13:
                return q
            J = jac[[0, 6, 4]][:, free]
            q[free] -= np.linalg.solve(J, r)
        raise KinematicsError(f"profile {p.name}: neutral pose did not converge (residual {r})")

    def _neutral_limiters(self, q0: np.ndarray, span: float) -> tuple[np.ndarray | None, int, KinematicsError | None]:
        """The sway limiters [m] that put x = 0 and the ball-centre span ``span`` [m] with lift and tilt of
        ``q0`` (Newton from ``q0``'s limiters; neither depends on the top link): (limiters, steps, None), or
        (None, the step at which it failed, why) when the links do not close there."""
        q = q0.copy()
        r = np.zeros(2)
        for k in range(50):
            f, jac, checks = self._features(q)
            exc = self._closure_error(checks[:, 0], q)
            if exc is None and not np.isfinite(f[[0, 6], 0]).all():
                exc = KinematicsError("degenerate configuration (lower-link ends coincide)")
            if exc is not None:
                return None, k, exc
            r = np.array([f[0, 0], f[6, 0] - span])
            if np.max(np.abs(r)) < 1e-13:
                return q[3:].copy(), k, None
            try:
                q[3:] -= np.linalg.solve(jac[[0, 6]][:, [3, 4]], r)
            except np.linalg.LinAlgError:
                return None, k, KinematicsError("degenerate geometry (singular Newton step)")
        return None, 50, KinematicsError(f"neutral pose did not converge (residual {r})")

    def _span_refusal(self, q0: np.ndarray) -> str:
        """Why the lower links do not close at the category's span: the profile field, its value and the ISO
        spans (other fields as given) they close at, found by bisection with :meth:`_neutral_limiters` from the
        same start (so a span within them loads as far as the links go), rounded inward to 0.1 mm."""
        corr = self.profile.implement.ball_centre_correction
        field = f"implement.categories.{self.category}.span"
        given = self.span - corr
        head = (
            f"{field} = {given:g} m: the lower links cannot reach this span with lift and tilt at their neutrals "
            f"(actuators.lift.neutral, actuators.tilt.neutral)"
        )

        def closes(ball: float) -> bool:
            return self._neutral_limiters(q0, ball)[0] is not None

        start = float(self._features(q0)[0][6, 0])  # the links' span at the start (x about 0)
        if not closes(start):
            return head

        def edge(good: float, bad: float) -> tuple[float, bool]:
            """(the last span that closes between ``good`` and ``bad``, whether ``bad`` itself closes)."""
            if closes(bad):
                return bad, True
            for _ in range(32):  # 2 m / 2^32: below 1e-9 m
                mid = (good + bad) / 2.0
                good, bad = (mid, bad) if closes(mid) else (good, mid)
            return good, False

        lowest, highest = corr + 1e-9, corr + _SPAN_MAX_M  # the schema's ISO span is (0, 2] m
        if self.span > start:
            (lo, lo_end), (hi, hi_end) = edge(start, lowest), edge(start, self.span)
        else:
            (lo, lo_end), (hi, hi_end) = edge(start, self.span), edge(start, highest)
        within = _within(0.0 if lo_end else lo - corr, _SPAN_MAX_M if hi_end else hi - corr, _SPAN_MAX_M)
        return (
            f"{head}; with the other fields as given, {field} must be {within} (ISO 730, inner faces; the ball "
            f"centres are implement.ball_centre_correction = {corr:g} m wider)"
            if within != "none"
            else head
        )

    def _upright_terms(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(T − H, u0) [m, 1] at ``q``: with the mast upright (pitch 0) the top link is |T − H + h·u0| long for a
        mast of height h (:func:`~planner.model.geometry.mast_point`); the lower links must close at ``q``."""
        _, pts, _, _ = self._points(q)
        at = {n: pts[:, i].copy() for i, n in enumerate(POINT_NAMES)}
        xi = (at["L"] - at["R"]) / np.linalg.norm(at["L"] - at["R"])
        up = np.array([0.0, 0.0, 1.0]) - xi[2] * xi
        return at["T"] - at["H"], up / np.linalg.norm(up)

    def _mast_heights_for_top(self, q: np.ndarray) -> str:
        """The mast heights (0, 2] m whose upright mast the top link reaches within its stroke at ``q`` (the
        lower links as there), as :func:`_within` says them (two ranges joined by "or"); "none" if none.
        |T − H + h·u0|² = h² + 2βh + |T − H|² with β = (T − H)·u0, so each stroke end is a quadratic's roots."""
        p_th, u0 = self._upright_terms(q)
        beta, c = float(p_th @ u0), float(p_th @ p_th)

        def roots(top: float) -> tuple[float, float] | None:
            disc = beta * beta - c + top * top
            return None if disc < 0 else (-beta - math.sqrt(disc), -beta + math.sqrt(disc))

        outer, inner = roots(self.upper[2]), roots(self.lower[2])
        if outer is None:
            return "none"
        pieces = [outer] if inner is None else [(outer[0], inner[0]), (inner[1], outer[1])]
        out = [_within(max(a, 0.0), min(b, _MAST_MAX_M), _MAST_MAX_M) for a, b in pieces if b > 0 and a < b]
        return " or ".join(out) or "none"

    def _workspace(self) -> dict[str, tuple[float, float]] | None:
        """The profile's restricted box for this category, or None when the profile has none
        (fit one with :func:`planner.model.workspace.fit_restricted_box`; motion layers refuse
        Cartesian motion without a workspace and say so)."""
        box = self.profile.workspace.restricted.get(self.category)
        return box.as_dict() if box is not None else None

    def thesis_box(self) -> dict[str, tuple[float, float]]:
        """Table 3-7 box in the tractor frame, with the profile's zero of z."""
        ws = self.profile.workspace
        z0 = self.neutral_pose.z if ws.z_reference == "neutral" else 0.0
        b = ws.thesis_box.as_dict()
        return {"x": b["x"], "z": (b["z"][0] + z0, b["z"][1] + z0), "roll": b["roll"], "pitch": b["pitch"]}
