"""The guard every motion passes through: limits and tractor stability, evaluated ahead (issue 5).

:class:`Guard` takes a plan (or a jog command) and returns it unchanged, scaled or
refused with reasons. For a plan it evaluates every sample before anything moves:

* free workspace: strokes, top-link angles, ground clearance (the samples are already
  verified by the planner) and the profile's keep-out spheres for the top link;
* the end-stop zone: velocity scaled down so no actuator reaches an end stop at speed;
* tractor + implement stability for the current slope (seed 003 / RELATED.md B):
  below a caution threshold the motion is slowed (factor 0.8); a plan that would cross
  a hard threshold is refused, naming the measure, the value, the threshold and the time
  in the plan — unless the motion improves a margin that is already low (never makes
  it worse than at the start), which is always allowed.

Jog motion is evaluated ``jog_horizon`` (~1 s) ahead along the commanded rates.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from ..kinematics import HitchModel
from ..trajectory import MotionState, Plan, PlanError, Setpoints, TrajectoryPlanner
from ..types import ACTUATOR_NAMES
from .end_stop import EndStopZone
from .kinematic_margin import KinematicMargin, kinematic_margin
from .stability import StabilityReport, StabilityThresholds, evaluate_stability
from .tractor import ImplementRecord, Tractor, load_tractor_profile

__all__ = ["Guard", "GuardDecision", "GuardReason", "GuardRefusal", "GuardedPlan"]

Action = Literal["ok", "scaled", "refused"]
_MEASURES = ("front_axle_load", "ssm", "lsm", "esm")


@dataclass(frozen=True)
class GuardReason:
    measure: str          # "ssm", "esm", "front_axle_load", "lsm", "keep_out:<name>", "end_stop:<actuator>"
    value: float
    threshold: float
    t_s: float            # time in the plan (jog: seconds ahead)
    level: Literal["hard", "caution", "speed"]

    def to_json(self) -> dict:
        return {"measure": self.measure, "value": self.value, "threshold": self.threshold, "t": self.t_s,
                "level": self.level}

    def sentence(self) -> str:
        return (f"{self.measure} would be {self.value:.4g} (threshold {self.threshold:.4g}) "
                f"at t = {self.t_s:.2f} s")


@dataclass(frozen=True)
class GuardDecision:
    action: Action
    speed_factor: float = 1.0
    reasons: tuple[GuardReason, ...] = ()
    worst: StabilityReport | None = field(default=None, repr=False)

    def to_json(self) -> dict:
        return {"action": self.action, "speed_factor": self.speed_factor,
                "reasons": [r.to_json() for r in self.reasons],
                "stability": None if self.worst is None else self.worst.as_dict()}


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

    def __init__(self, planner: TrajectoryPlanner, *, tractor: Tractor | None = None,
                 implement: ImplementRecord | None = None, thresholds: StabilityThresholds | None = None):
        self.planner = planner
        self.model: HitchModel = planner.model
        prof = self.model.profile
        self.settings = prof.stability
        self.tractor = tractor or load_tractor_profile(prof.stability.tractor_profile).tractor(prof.geometry.pivot_height)
        self.implement = implement
        self.thresholds = thresholds or StabilityThresholds()
        self.slope = (0.0, 0.0)
        self.end_stops = EndStopZone(self.model.lower, self.model.upper, planner.limits.velocity,
                                     prof.limits.end_stop_zone)
        self.keep_out = [(k.name, np.array(k.centre), k.radius) for k in prof.limits.keep_out]

    # ------------------------------------------------------------------ configuration
    def set_slope(self, roll: float, pitch: float) -> None:
        """Tractor attitude from its IMU [rad] (stability module convention)."""
        for n, v in (("slope_roll", roll), ("slope_pitch", pitch)):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or abs(v) >= math.pi / 2:
                raise ValueError(f"{n} must be a finite angle within ±π/2 rad, got {v!r}")
        self.slope = (float(roll), float(pitch))

    def set_implement(self, implement: ImplementRecord | None) -> None:
        self.implement = implement

    # ------------------------------------------------------------------ single states
    def stability_at(self, q, points=None) -> StabilityReport:
        """Stability of tractor + implement with the hitch at actuators ``q`` (``points``: its FK points)."""
        P = points if points is not None else self.model.forward(np.asarray(q, float)).points
        xi = P["L"] - P["R"]
        xi /= np.linalg.norm(xi)
        zi = P["U"] - P["T"]
        zi /= np.linalg.norm(zi)
        yi = np.cross(zi, xi)
        R = np.column_stack([xi, yi, zi])
        return evaluate_stability(self.tractor, self.implement, P["T"], R, *self.slope, thresholds=self.thresholds,
                                  front_ballast=self.settings.front_ballast)

    def keep_out_clearance(self, q, points=None) -> list[tuple[str, float, float]]:
        """(name, distance of the top link H–U from the sphere's centre, radius) for every keep-out."""
        if not self.keep_out:
            return []
        P = points if points is not None else self.model.forward(np.asarray(q, float)).points
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
    def check_setpoints(self, sp: Setpoints) -> GuardDecision:
        """Evaluate every sample of a plan; see the module docstring for the rules."""
        reasons: list[GuardReason] = []
        factor = 1.0
        start = self.stability_at(sp.actuators[0])
        start_vals = _measure_values(start)
        worst, worst_key = start, math.inf
        hard_th, caution_th = self._thresholds()
        end_stop: GuardReason | None = None  # the smallest end-stop speed factor over the samples
        for k in range(len(sp.t)):
            q, qd, t = sp.actuators[k], sp.actuator_velocity[k], float(sp.t[k])
            f, i = self.end_stops.speed_factor(q, qd)
            if i is not None and f < factor:
                factor = f
                end_stop = GuardReason(f"end_stop:{ACTUATOR_NAMES[i]}", f, 1.0, t, "speed")
            pts = self.model.forward(q).points
            for name, dist, r in self.keep_out_clearance(q, pts):
                if dist < r:
                    reasons.append(GuardReason(f"keep_out:{name}", dist, r, t, "hard"))
            rep = self.stability_at(q, pts)
            vals = _measure_values(rep)
            key = min(vals[m] / max(abs(hard_th[m]), 1e-9) for m in _MEASURES)
            if key < worst_key:
                worst, worst_key = rep, key
            for m in _MEASURES:
                v = vals[m]
                improving_only = start_vals[m] < hard_th[m] and v >= start_vals[m] - 1e-9
                if v < hard_th[m] and not improving_only:
                    reasons.append(GuardReason(m, v, hard_th[m], t, "hard"))
                elif v < caution_th[m] and not (start_vals[m] < caution_th[m] and v >= start_vals[m] - 1e-9):
                    reasons.append(GuardReason(m, v, caution_th[m], t, "caution"))
        if end_stop is not None:
            reasons.insert(0, end_stop)
        hard = sorted((r for r in reasons if r.level == "hard"), key=lambda r: r.t_s)
        if hard:  # the first crossing of each measure, earliest first
            return GuardDecision("refused", 0.0, tuple(_dedupe(hard)), worst)
        if any(r.level == "caution" for r in reasons):
            factor = min(factor, self.settings.caution_speed_factor)
        kept = tuple(_dedupe(reasons))
        return GuardDecision("ok" if factor >= 1.0 else "scaled", factor, kept, worst)

    def plan(self, start: MotionState, goal: Mapping[str, float], *, speed_scale: float = 1.0) -> GuardedPlan:
        """Plan a move and pass it through the guard: returned unchanged or slowed; GuardRefusal if refused.

        Slowing is a time dilation of the same path (Ruckig limits × f, f², f³): the caution
        factor is applied once; the end-stop factor (with a 2 % margin) until every sample
        keeps to the end-stop zone speed.
        """
        total, caution_applied, reasons = 1.0, False, []
        for _ in range(8):
            plan = self.planner.plan_move(start, goal, speed_scale=speed_scale * total)
            sp = plan.setpoints
            dec = self.check_setpoints(sp)
            if dec.action == "refused":
                raise GuardRefusal(dec)
            reasons.extend(r for r in dec.reasons if r not in reasons)
            end_stop = min((r.value for r in dec.reasons if r.level == "speed"), default=1.0)
            caution = any(r.level == "caution" for r in dec.reasons)
            if end_stop < 1.0:
                total *= end_stop * 0.98
            elif caution and not caution_applied:
                total *= self.settings.caution_speed_factor
                caution_applied = True
            else:
                action = "ok" if total >= 1.0 else "scaled"
                return GuardedPlan(plan, sp, GuardDecision(action, total, tuple(_dedupe(reasons)), dec.worst))
        raise GuardRefusal(GuardDecision("refused", 0.0, tuple(_dedupe(reasons)), dec.worst))

    # ------------------------------------------------------------------ jog
    def check_jog(self, state: MotionState, rates) -> tuple[np.ndarray, GuardDecision]:
        """Rates allowed for jog from ``state``: evaluated ``jog_horizon`` seconds ahead.

        A hard stability violation ahead that the motion makes worse stops the motion (rates
        zero); caution slows it (0.8); the end-stop zone scales it.
        """
        rates = np.asarray(rates, float)
        if not np.any(rates):
            return rates, GuardDecision("ok")
        h = self.settings.jog_horizon
        p_now = state.position
        p_ahead = np.clip(p_now + rates * h, self.planner.lo, self.planner.hi)
        q_now, jac, _ = self.planner.inverse.solve_full(p_now)
        q_ahead = self.planner.inverse(*p_ahead)
        now, ahead = _measure_values(self.stability_at(q_now)), self.stability_at(q_ahead)
        vals = _measure_values(ahead)
        hard_th, caution_th = self._thresholds()
        reasons, factor = [], 1.0
        for m in _MEASURES:
            worse = vals[m] < now[m] - 1e-9
            if vals[m] < hard_th[m] and worse:
                reasons.append(GuardReason(m, vals[m], hard_th[m], h, "hard"))
            elif vals[m] < caution_th[m] and worse:
                reasons.append(GuardReason(m, vals[m], caution_th[m], h, "caution"))
                factor = min(factor, self.settings.caution_speed_factor)
        for name, dist, r in self.keep_out_clearance(q_ahead):
            if dist < r:
                reasons.append(GuardReason(f"keep_out:{name}", dist, r, h, "hard"))
        if any(r.level == "hard" for r in reasons):
            return np.zeros(4), GuardDecision("refused", 0.0, tuple(reasons), ahead)
        f_end, i = self.end_stops.speed_factor(q_now, jac @ rates)
        if i is not None:
            reasons.append(GuardReason(f"end_stop:{ACTUATOR_NAMES[i]}", f_end, 1.0, 0.0, "speed"))
            factor = min(factor, f_end)
        return rates * factor, GuardDecision("ok" if factor >= 1.0 else "scaled", factor, tuple(reasons), ahead)

    def _thresholds(self) -> tuple[dict, dict]:
        th, w = self.thresholds, self.tractor.empty_weight
        hard = {"front_axle_load": th.front_axle_fraction_hard * w, "ssm": th.ssm_hard, "lsm": th.lsm_hard,
                "esm": th.esm_hard}
        caution = {"front_axle_load": th.front_axle_fraction_caution * w, "ssm": th.ssm_caution,
                   "lsm": th.lsm_caution, "esm": th.esm_caution}
        return hard, caution



def _dedupe(reasons):
    seen = set()
    for r in reasons:
        if (r.measure, r.level) not in seen:
            seen.add((r.measure, r.level))
            yield r

