"""The guard every motion passes through: limits and tractor stability, evaluated ahead.

:class:`Guard` takes a plan (or a jog command) and returns it unchanged, scaled or
refused with reasons. For a plan it evaluates every sample before anything moves:

* free workspace: strokes, top-link angles, ground clearance (the samples are already
  verified by the planner) and the profile's keep-out spheres for the top link;
* the end-stop zone: velocity scaled down so no actuator reaches an end stop at speed;
* tractor + implement stability for the current slope (seed 003):
  below a caution threshold the motion is slowed (factor 0.8); a plan that would cross
  a hard threshold is refused, naming the measure, the value, the threshold and the time
  in the plan — unless the motion improves a margin that is already low (never makes
  it worse than at the start), which is always allowed.

Jog motion is evaluated ``jog_horizon`` (~1 s) ahead along the commanded rates.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from planner.errors import HitchError, unit_hint
from planner.limits.end_stop import EndStopZone
from planner.limits.implement_limits import (
    LOWERING_SPEED_LIMIT,
    UPPER_HEIGHT_LIMIT,
    ImplementLimits,
    clip_jog_z_rate,
    lowering_speed_factor,
    upper_height_violation,
)
from planner.limits.kinematic_margin import KinematicMargin, kinematic_margin
from planner.limits.stability import MEASURE_UNITS, StabilityReport, StabilityThresholds, _cross3
from planner.limits.stability_batch import StabilityBatch, cross_rows, evaluate_stability_batch
from planner.limits.stability_scalar import evaluate_stability_scalar
from planner.limits.tractor import ImplementRecord, StabilityInputError, Tractor, load_tractor_profile
from planner.model.kinematics import POINT_NAMES, HitchModel
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES
from planner.trajectory.plan import (
    MotionState,
    Plan,
    PlanError,
    Setpoints,
    check_state,
    forward_batch,
    verify_setpoints,
)
from planner.trajectory.planner import TrajectoryPlanner

__all__ = ["Guard", "GuardDecision", "GuardReason", "GuardRefusal", "GuardedPlan"]

Action = Literal["ok", "scaled", "refused"]
_MEASURES = ("front_axle_load", "ssm", "lsm", "esm")
#: samples of a jog's straight path over the horizon judged on the way (besides its end)
JOG_PATH_SAMPLES = 8
#: a violated margin getting worse on a jog's way counts from this share of its value now (smaller: the wobble of
#: a margin that improves overall, ~5e-4 of it)
JOG_WAY_DIP = 0.001
#: the top link's way between two poses bends: its points may stray this much more than the ends' displacement
JOG_WAY_REACH_FACTOR = 1.5
_FK_CLOSED_M = 0.5e-9  # closure residual [m] trusted in a batch (HitchModel.forward refuses > 1e-9)
_KEEP_OUT_TOL_M = 1e-10  # bound on |batch - per-sample| keep-out distance [m] (rounding ~1e-15 m)
#: ``end_stop:<actuator>`` per actuator, order ACTUATOR_NAMES.
_END_STOP_NAMES: tuple[str, ...] = tuple(str(LimitName("end_stop", n)) for n in ACTUATOR_NAMES)
#: ``velocity:<actuator>`` per actuator: a jog asked faster than an actuator can go, outside its end-stop zone
_VELOCITY_NAMES: tuple[str, ...] = tuple(str(LimitName("velocity", n)) for n in ACTUATOR_NAMES)
#: per sample: keep-out clearances (name, distance [m], radius [m]) and the stability report
_Exact = tuple[list[tuple[str, float, float]], StabilityReport]


@dataclass(frozen=True)
class GuardReason:
    #: "ssm", "esm", "front_axle_load", "lsm", "keep_out:<name>", "end_stop:<actuator>", "velocity:<actuator>"
    measure: str
    value: float
    threshold: float
    t_s: float  # time in the plan (jog: seconds ahead)
    level: Literal["hard", "caution", "speed"]
    unit: str = ""  # of value and threshold (SI: "N", "m", "J", "m/s"); "" for a speed factor

    def to_json(self) -> dict:
        out = {
            "measure": self.measure,
            "value": self.value,
            "threshold": self.threshold,
            "t": self.t_s,
            "level": self.level,
        }
        if self.unit:
            out["unit"] = self.unit
        return out

    def sentence(self) -> str:
        u = f" {self.unit}" if self.unit else ""
        return (
            f"{self.measure} would be {self.value:.4g}{u} (threshold {self.threshold:.4g}{u}) at t = {self.t_s:.2f} s"
        )


@dataclass(frozen=True)
class GuardDecision:
    action: Action
    speed_factor: float = 1.0
    reasons: tuple[GuardReason, ...] = ()
    worst: StabilityReport | None = field(default=None, repr=False)

    def to_json(self) -> dict:
        return {
            "action": self.action,
            "speed_factor": self.speed_factor,
            "reasons": [r.to_json() for r in self.reasons],
            "stability": None if self.worst is None else self.worst.as_dict(),
        }


class GuardRefusal(PlanError):
    """A motion the guard refuses; ``decision`` carries the reasons."""

    def __init__(self, decision: GuardDecision):
        self.decision = decision
        hard = [r for r in decision.reasons if r.level == "hard"] or list(decision.reasons)
        super().__init__("refused: " + "; ".join(r.sentence() for r in hard[:3]))


@dataclass(frozen=True)
class GuardedPlan:
    plan: Plan
    setpoints: Setpoints
    decision: GuardDecision


def _measure_values(rep: StabilityReport) -> dict[str, float]:
    return {"front_axle_load": rep.axle_loads.front, "ssm": rep.ssm, "lsm": rep.lsm, "esm": rep.esm}


class Guard:
    """Limits and stability guard for one hitch model, tractor and implement."""

    def __init__(
        self,
        planner: TrajectoryPlanner,
        *,
        tractor: Tractor | None = None,
        implement: ImplementRecord | None = None,
        thresholds: StabilityThresholds | None = None,
        implement_limits: ImplementLimits | None = None,
    ):
        if not isinstance(planner, TrajectoryPlanner):  # Guard(model) failed later as "has no attribute 'model'"
            raise StabilityInputError(
                f"planner must be a TrajectoryPlanner (Guard(TrajectoryPlanner(model))), got {type(planner).__name__}"
            )
        self.planner = planner
        #: the implement's upper height, lowering speed and transport lock (:mod:`.implement_limits`)
        self.implement_limits = implement_limits if implement_limits is not None else ImplementLimits()
        self.model: HitchModel = planner.model
        prof = self.model.profile
        self.settings = prof.stability
        self.tractor = tractor or load_tractor_profile(prof.stability.tractor_profile).tractor(
            prof.geometry.pivot_height
        )
        self.implement = self._checked_implement(implement)
        self.thresholds = thresholds or StabilityThresholds()
        self.slope = (0.0, 0.0)
        self.end_stops = EndStopZone(
            self.model.lower, self.model.upper, planner.limits.velocity, prof.limits.end_stop_zone
        )
        self.keep_out = [(k.name, np.array(k.centre), k.radius) for k in prof.limits.keep_out]
        self._keep_out_names = tuple(str(LimitName("keep_out", k.name)) for k in prof.limits.keep_out)

    # ------------------------------------------------------------------ configuration
    def set_slope(self, roll: float, pitch: float) -> None:
        """Tractor attitude from its IMU [rad] (:mod:`planner.limits.stability`): ``roll`` > 0 = the tractor's
        left side up, ``pitch`` > 0 = nose up. (The implement's pose ``roll`` > 0 is its right side higher:
        the opposite sign, another frame.)"""
        for n, v in (("roll", roll), ("pitch", pitch)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or abs(v) >= math.pi / 2:
                hint = unit_hint(float(v), -math.pi / 2, math.pi / 2, "rad") if isinstance(v, (int, float)) else ""
                raise StabilityInputError(
                    f"set_slope: {n} (the tractor's slope) must be a finite angle within ±π/2 rad, got {v!r}{hint}"
                )
        self.slope = (float(roll), float(pitch))

    def set_implement(self, implement: ImplementRecord | None) -> None:
        """The implement on the hitch (an :class:`ImplementRecord`, None for none) for every later check."""
        self.implement = self._checked_implement(implement)

    def _checked_implement(self, implement: object) -> ImplementRecord | None:
        """``implement`` if it is an :class:`ImplementRecord` or None, else a :class:`StabilityInputError` saying how
        to get one (a name given for the record passed here and failed at the first plan, "'str' object has no
        attribute 'centre_of_mass'")."""
        if implement is None or isinstance(implement, ImplementRecord):
            return implement
        source = self.model.profile.stability.tractor_profile
        name = implement if isinstance(implement, str) else "<name>"
        raise StabilityInputError(
            f"implement must be an ImplementRecord or None, got {type(implement).__name__} {implement!r}; "
            f"get the record from its tractor profile: load_tractor_profile({source!r}).implement({name!r})"
        )

    def set_implement_limits(self, limits: ImplementLimits) -> None:
        """The implement's limits (:mod:`planner.limits.implement_limits`) for every later check."""
        self.implement_limits = limits

    # ------------------------------------------------------------------ single states
    def stability_at(self, q, points=None) -> StabilityReport:
        """Stability of tractor + implement with the hitch at actuators ``q`` (``points``: its FK points)."""
        P = points if points is not None else self.model.points(np.asarray(q, float))
        # x_i = (L − R)/|L − R|, z_i = (U − T)/|U − T|, y_i = z_i × x_i in Python floats: the differences,
        # the norm as sqrt of the left-to-right sum of squares (stability._dot's; np.linalg.norm's BLAS may fuse
        # multiply-add) and the quotients
        (l0, l1, l2), (r0, r1, r2) = P["L"].tolist(), P["R"].tolist()
        (u0, u1, u2), (t0, t1, t2) = P["U"].tolist(), P["T"].tolist()
        x0, x1, x2 = l0 - r0, l1 - r1, l2 - r2
        nx = math.sqrt(x0 * x0 + x1 * x1 + x2 * x2)
        z0, z1, z2 = u0 - t0, u1 - t1, u2 - t2
        nz = math.sqrt(z0 * z0 + z1 * z1 + z2 * z2)
        if nx > 0.0 and nz > 0.0:
            x0, x1, x2 = x0 / nx, x1 / nx, x2 / nx
            z0, z1, z2 = z0 / nz, z1 / nz, z2 / nz
            y0, y1, y2 = z1 * x2 - z2 * x1, z2 * x0 - z0 * x2, z0 * x1 - z1 * x0  # _cross3(z_i, x_i)
            R = np.array([[x0, y0, z0], [x1, y1, z1], [x2, y2, z2]])
        else:  # degenerate (or NaN) points: numpy's inf / nan and the evaluation's error, as before
            xi = (P["L"] - P["R"]) / np.linalg.norm(P["L"] - P["R"])
            zi = (P["U"] - P["T"]) / np.linalg.norm(P["U"] - P["T"])
            R = np.column_stack([xi, _cross3(zi, xi), zi])
        return evaluate_stability_scalar(  # evaluate_stability's report bit for bit, ~5× cheaper
            self.tractor,
            self.implement,
            P["T"],
            R,
            *self.slope,
            thresholds=self.thresholds,
            front_ballast=self.settings.front_ballast,
        )

    def keep_out_clearance(self, q, points=None) -> list[tuple[str, float, float]]:
        """(name, distance of the top link H–U from the sphere's centre, radius) for every keep-out."""
        if not self.keep_out:
            return []
        P = points if points is not None else self.model.points(np.asarray(q, float))
        H, U = P["H"], P["U"]
        d = U - H
        out = []
        for name, c, r in self.keep_out:
            a = float(np.clip(np.dot(c - H, d) / np.dot(d, d), 0.0, 1.0))
            out.append((name, float(np.linalg.norm(H + a * d - c)), r))
        return out

    def margin(self, q, q_velocity) -> KinematicMargin:
        """Kinematic margin at actuators ``q`` moving at ``q_velocity``."""
        q = np.asarray(q, float)
        qd = np.asarray(q_velocity, float)
        f, jac = self.model.features(q)
        fr = jac @ qd
        rows = [0, 2, 3, 4]
        return kinematic_margin(f[rows], fr[rows], q, qd, f, fr, self.planner.hard, self.planner.workspace)

    # ------------------------------------------------------------------ plans
    def check_setpoints(self, sp: Setpoints, *, rest_poses: bool = False) -> GuardDecision:
        """Evaluate every sample of a plan; see the module docstring for the rules. ``rest_poses``: the samples
        are poses the hitch rests at one after another (a count approach's via and final pose), not a trajectory:
        no velocity between them is judged from their positions.

        All samples at once: forward kinematics through the mapped CasADi function, end-stop
        factors, keep-out distances and stability measures vectorised (:mod:`.stability_batch`).
        Decisions and reported values are those of evaluating each sample with
        :meth:`stability_at` and :meth:`keep_out_clearance`: the samples reported (reasons,
        worst), the suspect ones and those whose batch value lies within the batch's agreement
        bound of a threshold are evaluated that way.

        Samples made elsewhere (not by this guard's planner, which verifies its own) are first checked
        against every hard limit, speed and acceleration (:func:`verify_setpoints`): one beyond is refused,
        naming the limit — a tilt of 0.9 m against a 0.73 m stroke was "ok" here, the planner having been
        trusted to have checked it.
        """
        if not isinstance(sp, Setpoints):
            raise StabilityInputError(
                f"setpoints must be a Setpoints (a planned move's .setpoints; a stop has none), got {type(sp).__name__}"
            )
        _check_setpoint_shapes(sp)
        bad = verify_setpoints(sp, self.model, self.planner.hard, self.planner.limits, mean_rates=not rest_poses)
        if bad:
            reasons = tuple(_dedupe(GuardReason(v.limit, v.value, v.bound, v.t, "hard", v.unit) for v in bad))
            return GuardDecision("refused", 0.0, reasons)
        dec, worst = self._check_setpoints(sp, {})
        return replace(dec, worst=worst())

    def _check_setpoints(
        self, sp: Setpoints, cache: dict[bytes, _Exact]
    ) -> tuple[GuardDecision, Callable[[], StabilityReport | None]]:
        """:meth:`check_setpoints` with ``cache``: the per-sample results by actuator bytes, to
        share between the plans of one :meth:`plan` (same slope, implement and thresholds).

        The decision comes without its ``worst`` report, and beside it the function that finds
        that report: a plan the guard slows and plans again never needs it (its exact
        evaluations of the worst candidates are skipped)."""
        Q, QD, ts = np.asarray(sp.actuators, float), np.asarray(sp.actuator_velocity, float), sp.t
        above = upper_height_violation(np.asarray(sp.pose, float)[:, 2], self.implement_limits)
        if above is not None:  # the implement's upper height limit (implement_limits)
            upper = float(self.implement_limits.upper_height_m or 0.0)
            reason = GuardReason(UPPER_HEIGHT_LIMIT, above[1], upper, float(ts[above[0]]), "hard", "m")
            return GuardDecision("refused", 0.0, (reason,)), lambda: None
        P, suspect = self._points_batch(Q)
        fk_ok = ~suspect  # rows whose batch points are HitchModel.forward's, bit for bit

        def exact(k: int) -> _Exact:  # the per-sample path: keep-out clearances, report
            points = (lambda: {n: P[n][k].copy() for n in P}) if fk_ok[k] else None  # the batch's, bit for bit
            return self._exact_entry(Q[k], cache, points)

        start = exact(0)[1]
        start_vals = _measure_values(start)
        hard_th, caution_th = self._thresholds()
        H, C, S = (np.array([d[m] for m in _MEASURES]) for d in (hard_th, caution_th, start_vals))
        Sm = S - 1e-9
        batch = evaluate_stability_batch(
            self.tractor, self.implement, *_implement_frames(P), *self.slope, front_ballast=self.settings.front_ballast
        )
        vals = batch.values
        dist = self._keep_out_batch(P)
        suspect |= batch.suspect | ~np.isfinite(dist).all(axis=0)
        radii = np.array([r for _, _, r in self.keep_out]).reshape(-1, 1)
        check = suspect | (np.abs(dist - radii) <= _KEEP_OUT_TOL_M).any(axis=0)
        if not batch.exact:
            tol = np.array([batch.tolerance[m] for m in _MEASURES])
            near = (np.abs(vals - H) <= tol) | (np.abs(vals - C) <= tol)
            near |= ((S < C) | (S < H)) & (np.abs(vals - Sm) <= tol)
            check |= near.any(axis=1)
        for k in np.flatnonzero(check).tolist():  # in sample order: the first failing sample raises, as before
            clear, rep = exact(k)
            dist[:, k] = [d for _, d, _ in clear]
            vals[k] = [_measure_values(rep)[m] for m in _MEASURES]

        with np.errstate(invalid="ignore"):
            hard = (vals < H) & ~((S < H) & (vals >= Sm))
            caution = ~hard & (vals < C) & ~((S < C) & (vals >= Sm))
        events: list[tuple[float, int, int, GuardReason]] = []  # (t, k, order in a sample, reason): first only
        for j, (_, _, r) in enumerate(self.keep_out):
            if (k_ko := _earliest(dist[j] < r, ts)) is not None:
                d = exact(k_ko)[0][j][1]
                t_ko = float(ts[k_ko])
                events.append((t_ko, k_ko, j, GuardReason(self._keep_out_names[j], d, r, t_ko, "hard", "m")))
        for j, m in enumerate(_MEASURES):
            if (k_hard := _earliest(hard[:, j], ts)) is not None:
                v = _measure_values(exact(k_hard)[1])[m]
                t_hard = float(ts[k_hard])
                events.append(
                    (
                        t_hard,
                        k_hard,
                        len(self.keep_out) + j,
                        GuardReason(m, v, hard_th[m], t_hard, "hard", MEASURE_UNITS[m]),
                    )
                )

        def worst() -> StabilityReport:  # only when asked for (see above)
            return self._worst(vals, batch, hard_th, exact, start)

        if events:  # the first crossing of each measure, earliest first
            events.sort(key=lambda e: e[:3])
            return GuardDecision("refused", 0.0, tuple(_dedupe(e[3] for e in events))), worst

        reasons: list[GuardReason] = []
        factor = 1.0
        end_stop = self._end_stop_batch(Q, QD)
        if end_stop is not None:
            k_end, factor, i = end_stop
            reasons.append(GuardReason(_END_STOP_NAMES[i], factor, 1.0, float(ts[k_end]), "speed"))
        lowering = lowering_speed_factor(np.asarray(sp.pose_velocity, float)[:, 1], self.implement_limits)
        if lowering is not None:  # slowed as a whole (Ruckig's z limit is symmetric): a "speed" reason
            k_low, f_low, _ = lowering
            reasons.append(GuardReason(LOWERING_SPEED_LIMIT, f_low, 1.0, float(ts[k_low]), "speed"))
            factor = min(factor, f_low)
        cautions: list[tuple[int, int, GuardReason]] = []
        for j, m in enumerate(_MEASURES):
            if caution[:, j].any():
                k_c = int(np.argmax(caution[:, j]))
                v = _measure_values(exact(k_c)[1])[m]
                cautions.append((k_c, j, GuardReason(m, v, caution_th[m], float(ts[k_c]), "caution", MEASURE_UNITS[m])))
        if cautions:
            factor = min(factor, self.settings.caution_speed_factor)
        reasons += [c[2] for c in sorted(cautions, key=lambda c: c[:2])]
        return GuardDecision("ok" if factor >= 1.0 else "scaled", factor, tuple(_dedupe(reasons))), worst

    def _worst(
        self,
        vals: np.ndarray,
        batch: StabilityBatch,
        hard_th: dict[str, float],
        exact: Callable[[int], _Exact],
        start: StabilityReport,
    ) -> StabilityReport:
        """Report of the first sample with the smallest min_m value_m / |hard_m| (as the per-sample loop);
        ``vals`` (N, 4) batch values, those of samples already evaluated one by one replaced."""
        scale = np.array([max(abs(hard_th[m]), 1e-9) for m in _MEASURES])
        keys = np.min(vals / scale, axis=1)
        for k in np.flatnonzero(np.isnan(vals).any(axis=1)).tolist():  # Python's min with NaN, as the loop had
            keys[k] = min(float(v) / s for v, s in zip(vals[k], scale, strict=True))
        tol = 0.0 if batch.exact else max(batch.tolerance[m] / s for m, s in zip(_MEASURES, scale, strict=True))
        if not np.any(keys == keys):
            return start
        cand = np.flatnonzero(keys <= np.nanmin(keys) + 2 * tol)
        worst_k: int | None = None
        worst_key = math.inf
        for k in cand.tolist():
            key = (
                keys[k]
                if tol == 0.0
                else min(v / s for v, s in zip(_measure_values(exact(k)[1]).values(), scale, strict=True))
            )
            if key < worst_key:
                worst_k, worst_key = k, key
        return start if worst_k is None else exact(worst_k)[1]

    # ------------------------------------------------------------------ batches (all samples of a plan)
    def _points_batch(self, Q: np.ndarray) -> tuple[dict[str, np.ndarray], np.ndarray]:
        """FK points L, R, T, U, H (N, 3) [m] of actuator rows Q (N, 5), bit for bit those of
        :meth:`HitchModel.forward`, and the rows it might refuse (not closing, not finite)."""
        f, pts, checks = forward_batch(self.model)(Q)  # shared with the planner's verification of these samples
        with np.errstate(invalid="ignore"):
            ok = (np.abs(checks[:, :4]) <= _FK_CLOSED_M).all(axis=1) & (np.abs(checks[:, 4]) <= 1.0)
            bad = ~(ok & np.isfinite(f).all(axis=1)) | ~np.isfinite(Q).all(axis=1)
        return {n: pts[:, :, POINT_NAMES.index(n)] for n in ("L", "R", "T", "U", "H")}, bad

    def _keep_out_batch(self, P: dict[str, np.ndarray]) -> np.ndarray:
        """(n_keep_out, N) distances [m] of the top link H–U from each keep-out centre."""
        H, U = P["H"], P["U"]
        d = U - H
        out = np.empty((len(self.keep_out), len(H)))
        with np.errstate(invalid="ignore", divide="ignore"):
            for j, (_, c, _) in enumerate(self.keep_out):
                a = np.clip(np.einsum("ij,ij->i", c - H, d) / np.einsum("ij,ij->i", d, d), 0.0, 1.0)
                out[j] = np.linalg.norm(H + a[:, None] * d - c, axis=1)
        return out

    def _end_stop_batch(self, Q: np.ndarray, QD: np.ndarray) -> tuple[int, float, int] | None:
        """(sample, factor, actuator) of the smallest end-stop speed factor < 1 (first such sample), or None."""
        allow = self.end_stops.allowed_speed(Q, np.sign(QD))
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.abs(QD) > 1e-12, allow / np.abs(QD), np.inf)
        i = np.argmin(ratio, axis=1)
        rmin = ratio[np.arange(len(Q)), i]
        binding = np.flatnonzero(rmin < 1.0)
        if not binding.size:
            return None
        k = int(binding[np.argmin(rmin[binding])])
        return k, float(rmin[k]), int(i[k])

    def plan(self, start: MotionState, goal: Mapping[str, float], *, speed_scale: float = 1.0) -> GuardedPlan:
        """Plan a move and pass it through the guard: returned unchanged or slowed; GuardRefusal if refused.

        Slowing is a time dilation of the same path (Ruckig limits × f, f², f³): the caution
        factor is applied once; the end-stop factor (with a 2 % margin) until every sample
        keeps to the end-stop zone speed.

        A goal that is itself in the caution band (:meth:`caution_at_goal`) slows the move whatever
        the path: it is planned at the caution factor at once, not first at full speed only to be
        thrown away (every plan's last sample is its goal, so the check of the full-speed plan would
        have cautioned it). The end-stop factor found on such a plan is relative to the cautioned
        speed, so the caution factor is applied after it once more: the result is the end-stop-limited
        speed × the caution factor, as when the full-speed plan comes first. A speed reason's value is
        the factor relative to the speed asked for (``speed_scale``), whichever plan found it.
        """
        check_state(start, "start")
        total, caution_applied = 1.0, False
        reasons: list[GuardReason] = []
        cache: dict[bytes, _Exact] = {}  # per-sample results: the plans share start and goal
        context = self._context()
        foreseen = self._caution_at_goal(start, goal, cache)
        recaution = bool(foreseen)  # the caution factor is due again after the first end-stop scaling
        if foreseen:
            total, caution_applied = self.settings.caution_speed_factor, True
        upper = self.implement_limits.upper_height_m  # the aim for the play's lag stays below it too
        ceiling = None if upper is None else np.array([np.inf, float(upper), np.inf, np.inf])
        for _ in range(8):
            plan = self.planner.plan_move(start, goal, speed_scale=speed_scale * total, ceiling=ceiling)
            sp = plan.sampled()
            if self._context() != context:  # changed meanwhile (another thread): evaluate afresh
                cache.clear()
                context = self._context()
            dec, worst = self._check_setpoints(sp, cache)
            if dec.action == "refused":
                raise GuardRefusal(replace(dec, worst=worst()))
            # a speed reason's factor is relative to the plan checked: stated relative to the speed asked for
            found = (
                replace(r, value=r.value * total) if r.level == "speed" and total != 1.0 else r for r in dec.reasons
            )
            reasons.extend(r for r in found if r not in reasons)
            end_stop = min((r.value for r in dec.reasons if r.level == "speed"), default=1.0)
            caution = any(r.level == "caution" for r in dec.reasons)
            if end_stop < 1.0:
                total *= end_stop * 0.98
                if recaution:
                    total *= self.settings.caution_speed_factor
                    recaution = False
            elif caution and not caution_applied:
                total *= self.settings.caution_speed_factor
                caution_applied = True
            else:
                seen = {r.measure for r in reasons if r.level == "caution"}
                # a goal on a caution threshold to ~1e-15 the plan's own last sample may not cross: named anyway
                reasons.extend(replace(r, t_s=plan.duration) for r in foreseen if r.measure not in seen)
                action: Action = "ok" if total >= 1.0 else "scaled"
                return GuardedPlan(plan, sp, GuardDecision(action, total, tuple(_dedupe(reasons)), worst()))
        raise GuardRefusal(GuardDecision("refused", 0.0, tuple(_dedupe(reasons)), worst()))

    def caution_at_goal(self, start: MotionState, goal: Mapping[str, float]) -> tuple[GuardReason, ...]:
        """Caution reasons (``t_s`` NaN: no plan yet) that the goal pose alone proves for a move from
        ``start``: a measure below its caution threshold at the goal and not below its hard one, unless
        the start is below the caution threshold too and the goal is no worse (the rule of every
        sample in :meth:`check_setpoints`). Empty when it proves none, when the goal is refused
        (planning says why) or cannot be evaluated. A start that is no :class:`MotionState` and a goal
        :meth:`~planner.trajectory.planner.TrajectoryPlanner.plan_move` would not take (an unknown field,
        not a number) are refused as there (an unknown field gave an empty answer)."""
        return self._caution_at_goal(check_state(start, "start"), goal, {})

    def _caution_at_goal(
        self, start: MotionState, goal: Mapping[str, float], cache: dict[bytes, _Exact]
    ) -> tuple[GuardReason, ...]:
        """:meth:`caution_at_goal`; the start's and the goal's results go into ``cache`` (by actuator bytes)."""
        p0 = np.asarray(start.position, float)
        p1 = self.planner.goal_vector(p0, goal)  # a malformed goal: TrajectoryInputError naming it, as plan_move
        try:
            ends = [self._exact_entry(self.planner.inverse(*p), cache)[1] for p in (p0, p1)]
        except HitchError:
            return ()
        s, g = (_measure_values(r) for r in ends)
        hard_th, caution_th = self._thresholds()
        out: list[GuardReason] = []
        for m in _MEASURES:
            if not (g[m] < caution_th[m]) or (s[m] < caution_th[m] and g[m] >= s[m] - 1e-9):
                continue  # not below the caution threshold, or no worse than an already low start
            if g[m] < hard_th[m] and not (s[m] < hard_th[m] and g[m] >= s[m] - 1e-9):
                return ()  # a goal the check refuses: the plan says where and why
            out.append(GuardReason(m, g[m], caution_th[m], math.nan, "caution", MEASURE_UNITS[m]))
        return tuple(out)

    def _exact_entry(
        self, q: np.ndarray, cache: dict[bytes, _Exact], points: Callable[[], dict[str, np.ndarray]] | None = None
    ) -> _Exact:
        """Keep-out clearances and stability report at actuators ``q`` (the per-sample path), cached by bytes;
        the points ``points()`` gives (a batch's, equal to :meth:`HitchModel.forward`'s) or ``forward``'s."""
        key = q.tobytes()
        if key not in cache:
            pts = points() if points is not None else self.model.forward(q).points
            cache[key] = (self.keep_out_clearance(q, pts), self.stability_at(q, pts))
        return cache[key]

    # ------------------------------------------------------------------ jog
    def check_jog(
        self, state: MotionState, rates: ArrayLike, *, along_path: bool = True
    ) -> tuple[np.ndarray, GuardDecision]:
        """Rates allowed for jog from ``state``: evaluated ``jog_horizon`` seconds ahead.

        A hard stability violation ahead that the motion makes worse stops the motion (rates
        zero); caution slows it (0.8); the end-stop zone scales it. ``rates``: 4 finite numbers (vx, vz [m/s],
        vroll, vpitch [rad/s]), else :class:`StabilityInputError` (2 rates failed as numpy's broadcast error).
        """
        check_state(state, "state", values=False)  # per cycle: a NaN state is refused by the inverse below
        given = rates
        try:
            rates = np.asarray(rates, float)
        except (TypeError, ValueError):
            rates = np.full(0, np.nan)
        if rates.shape != (4,) or not np.isfinite(rates).all():
            raise StabilityInputError(
                f"check_jog: rates must be 4 finite numbers (vx, vz [m/s], vroll, vpitch [rad/s]), got {given!r}"
            )
        if not np.any(rates):
            return rates, GuardDecision("ok")
        h = self.settings.jog_horizon
        p_now = state.position
        asked_vz = float(rates[1])
        vz, clipped_by = clip_jog_z_rate(float(p_now[1]), asked_vz, h, self.implement_limits)
        if clipped_by is not None:  # the implement's lowering speed / upper height (implement_limits)
            rates = rates.copy()
            rates[1] = vz
        p_ahead = np.clip(p_now + rates * h, self.planner.lo, self.planner.hi)
        q_now, jac, _ = self.planner.inverse.solve_full(p_now)
        q_ahead = self.planner.inverse(*p_ahead)
        points_ahead = self.model.points(q_ahead)  # for the stability and the keep-outs ahead
        now, ahead = _measure_values(self.stability_at(q_now)), self.stability_at(q_ahead, points_ahead)
        vals = _measure_values(ahead)
        hard_th, caution_th = self._thresholds()
        reasons: list[GuardReason] = []
        factor = 1.0
        if clipped_by is not None:  # what was asked for against the limit: the descent speed, or the height reached
            lim = self.implement_limits
            if clipped_by == LOWERING_SPEED_LIMIT:
                reason = GuardReason(clipped_by, -asked_vz, float(lim.lowering_speed_m_s or 0.0), 0.0, "speed", "m/s")
            else:
                reached = float(p_now[1]) + asked_vz * h
                reason = GuardReason(clipped_by, reached, float(lim.upper_height_m or 0.0), h, "speed", "m")
            reasons.append(reason)
        for m in _MEASURES:
            worse = vals[m] < now[m] - 1e-9
            if vals[m] < hard_th[m] and worse:
                reasons.append(GuardReason(m, vals[m], hard_th[m], h, "hard", MEASURE_UNITS[m]))
            elif vals[m] < caution_th[m] and worse:
                reasons.append(GuardReason(m, vals[m], caution_th[m], h, "caution", MEASURE_UNITS[m]))
                factor = min(factor, self.settings.caution_speed_factor)
        for j, (_, dist, r) in enumerate(self.keep_out_clearance(q_ahead, points_ahead)):
            if dist < r:
                reasons.append(GuardReason(self._keep_out_names[j], dist, r, h, "hard", "m"))
        if (  # the way only where it is asked for and may matter (the track look-ahead asks for the end alone)
            along_path
            and not any(r.level == "hard" for r in reasons)
            and self._near_a_limit(now, vals, q_now, points_ahead)
        ):
            on_the_way = self._jog_path_refusal(p_now, rates, h, now, q_now)
            if on_the_way is not None:
                reasons = [r for r in reasons if r.level != "caution"] + list(on_the_way.reasons)
        if any(r.level == "hard" for r in reasons):
            return np.zeros(4), GuardDecision("refused", 0.0, tuple(reasons), ahead)
        qdot = jac @ rates
        f_end, i = self.end_stops.speed_factor(q_now, qdot)
        if i is not None:  # named for the end stop inside its zone, else the actuator's speed limit (an operator
            # read "lift arm slowing before its stroke end" for a jog asked faster than the lift can go, mid-stroke)
            name = _END_STOP_NAMES[i] if self.end_stops.in_zone(q_now, qdot, i) else _VELOCITY_NAMES[i]
            reasons.append(GuardReason(name, f_end, 1.0, 0.0, "speed"))
            factor = min(factor, f_end)
        action: Action = "ok" if factor >= 1.0 and clipped_by is None else "scaled"
        return rates * factor, GuardDecision(action, factor, tuple(reasons), ahead)

    def _near_a_limit(
        self, now: dict[str, float], ahead: dict[str, float], q_now: np.ndarray, points_ahead: dict[str, np.ndarray]
    ) -> bool:
        """Whether the way of a jog (or a track session's look-ahead) may hold what its end does not show: a
        stability measure now or at the end below its caution threshold, or a keep-out the top link may reach on
        the way. The top link's ends move by at most ``reach`` from now to the end (the larger of H's and U's
        displacement, × :data:`JOG_WAY_REACH_FACTOR` for the way's curvature), so each point of it stays within
        ``reach`` of where it was: a keep-out farther than ``reach`` beyond its radius now cannot be entered.
        Elsewhere no dip on the way reaches hard (a dip from above caution to below hard within the horizon is not
        looked for)."""
        _, caution_th = self._thresholds()
        if any(min(now[m], ahead[m]) < caution_th[m] for m in _MEASURES):
            return True
        if not self.keep_out:
            return False
        pts_now = self.model.points(q_now)
        reach = JOG_WAY_REACH_FACTOR * max(float(np.linalg.norm(points_ahead[n] - pts_now[n])) for n in ("H", "U"))
        return any(d < r + reach for _, d, r in self.keep_out_clearance(q_now, pts_now))

    def _jog_path_refusal(
        self, p_now: np.ndarray, rates: np.ndarray, h: float, now: dict[str, float], q_now: np.ndarray
    ) -> GuardDecision | None:
        """The refusal of a jog that enters a keep-out (or goes deeper into one it is in), crosses a stability
        threshold from above, or makes a hard stability violation worse by more than :data:`JOG_WAY_DIP` of the
        value now, somewhere on its way over the horizon ``h`` (:data:`JOG_PATH_SAMPLES` samples of the straight
        path ``p_now + rates · t`` within the box); None: no refusal. A sample without an inverse ends the way
        looked at there (the end's own check names it).

        Judged at the horizon's end alone, the way was not looked at: a keep-out the top link passes half-way was
        entered by a jog a goto along the same line was refused for (a review), and with 2500 kg 1.2 m behind the
        hitch a jog asked at 1 m/s was judged at the face 1 m ahead (an operator's trial). Worse than now counts
        from :data:`JOG_WAY_DIP` of the value on (the margins wobble on the way while they improve: lowering a
        heavy implement, the way out of a low margin, was refused for 0.6 N of 1199 N of front-axle load, a
        review), not from a share of the threshold (1 % of it let a 0.3 % dip of a 76 J energy margin 2000 J
        below its threshold through, a second review); a crossing of the threshold counts at once. The end is
        judged strictly (:meth:`check_jog`)."""
        t = np.linspace(0.0, h, JOG_PATH_SAMPLES + 1)[1:]
        poses = np.clip(p_now + np.outer(t, rates), self.planner.lo, self.planner.hi)
        inv = self.planner.inverse.solve_batch(poses, np.tile(rates, (len(t), 1)))
        n_ok = int(np.argmin(inv.ok)) if not bool(np.all(inv.ok)) else len(t)  # the way up to the first without one
        if n_ok == 0:
            return None
        t, Q = t[:n_ok], inv.actuators[:n_ok]
        P, suspect = self._points_batch(Q)
        batch = evaluate_stability_batch(
            self.tractor, self.implement, *_implement_frames(P), *self.slope, front_ballast=self.settings.front_ballast
        )
        vals = np.array(batch.values, float)
        dist = self._keep_out_batch(P)
        cache: dict[bytes, _Exact] = {}
        exact_rows = suspect | batch.suspect | ~np.isfinite(dist).all(axis=0)
        if self.keep_out:
            radii = np.array([r for _, _, r in self.keep_out]).reshape(-1, 1)
            exact_rows |= (np.abs(dist - radii) <= _KEEP_OUT_TOL_M).any(axis=0)
        for k in np.flatnonzero(exact_rows).tolist():  # rows the batch cannot vouch for: per sample
            clear, rep = self._exact_entry(Q[k], cache)
            vals[k] = [_measure_values(rep)[m] for m in _MEASURES]
            if clear:
                dist[:, k] = [d for _, d, _ in clear]
        hard_th, _ = self._thresholds()
        reasons: list[GuardReason] = []
        for j, m in enumerate(_MEASURES):
            h_m, s_m = hard_th[m], now[m]
            # ok now: any sample below the threshold crosses it; violated now: worse than now beyond the wobble
            limit = h_m if s_m >= h_m else s_m - JOG_WAY_DIP * max(abs(s_m), 1e-9)
            slack = 0.0 if batch.exact else batch.tolerance[m]
            for k in np.flatnonzero(vals[:, j] < limit + slack).tolist():
                v = _measure_values(self._exact_entry(Q[k], cache)[1])[m]  # the value reported: exact
                if v < limit:
                    reasons.append(GuardReason(m, v, h_m, float(t[k]), "hard", MEASURE_UNITS[m]))
                    break
        for j, (_, d_now, r) in enumerate(self.keep_out_clearance(q_now)):
            # outside now: entering refuses; inside now: only going deeper (leaving it is the way out, a review)
            bad = dist[j] < r if d_now >= r else dist[j] < d_now - _KEEP_OUT_TOL_M
            if (k_in := _earliest(bad, t)) is not None:
                name = self._keep_out_names[j]
                reasons.append(GuardReason(name, float(dist[j, k_in]), r, float(t[k_in]), "hard", "m"))
        return GuardDecision("refused", 0.0, tuple(reasons)) if reasons else None

    def _context(self) -> tuple:
        """What the per-sample results depend on besides the actuators."""
        return (
            self.slope,
            self.implement,
            id(self.tractor),
            self.thresholds,
            self.settings.front_ballast,
            self.implement_limits,
        )

    def _thresholds(self) -> tuple[dict[str, float], dict[str, float]]:
        th, w = self.thresholds, self.tractor.empty_weight
        hard = {
            "front_axle_load": th.front_axle_fraction_hard * w,
            "ssm": th.ssm_hard,
            "lsm": th.lsm_hard,
            "esm": th.esm_hard,
        }
        caution = {
            "front_axle_load": th.front_axle_fraction_caution * w,
            "ssm": th.ssm_caution,
            "lsm": th.lsm_caution,
            "esm": th.esm_caution,
        }
        return hard, caution


def _check_setpoint_shapes(sp: Setpoints) -> None:
    """:class:`StabilityInputError` unless ``sp`` holds N ≥ 1 samples with t (N,), pose (N, 6), pose_velocity (N, 4),
    actuators (N, 5) and actuator_velocity (N, 5) (none failed as an IndexError at the first sample)."""
    n = np.shape(sp.t)[0] if np.ndim(sp.t) == 1 else -1
    if n < 1:
        raise StabilityInputError(
            f"setpoints.t must hold at least one sample time (N,) [s], got shape {np.shape(sp.t)}"
        )
    for name, cols in (("pose", 6), ("pose_velocity", 4), ("actuators", 5), ("actuator_velocity", 5)):
        if np.shape(getattr(sp, name)) != (n, cols):
            raise StabilityInputError(
                f"setpoints.{name} must be ({n}, {cols}) for {n} sample(s), got shape {np.shape(getattr(sp, name))}"
            )
    t = np.asarray(sp.t, float)
    if not (np.all(np.isfinite(t)) and np.all(np.diff(t) > 0.0)):  # (a NaN time let a 70x jump pass a review)
        raise StabilityInputError(f"setpoints.t must be finite and strictly increasing [s], got {t[:8].tolist()}")


def _implement_frames(P: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Tool points T (N, 3) [m] and implement rotations (N, 3, 3) as :meth:`Guard.stability_at` builds them."""
    with np.errstate(invalid="ignore", divide="ignore"):
        xi = P["L"] - P["R"]
        xi = xi / np.linalg.norm(xi, axis=1)[:, None]
        zi = P["U"] - P["T"]
        zi = zi / np.linalg.norm(zi, axis=1)[:, None]
    return P["T"], np.stack([xi, cross_rows(zi, xi), zi], axis=2)


def _earliest(mask: np.ndarray, t: np.ndarray) -> int | None:
    """Sample with the smallest time among ``mask`` (the first of equal times), or None."""
    idx = np.flatnonzero(mask)
    return int(idx[np.argmin(t[idx])]) if idx.size else None


def _dedupe(reasons):
    seen = set()
    for r in reasons:
        if (r.measure, r.level) not in seen:
            seen.add((r.measure, r.level))
            yield r
