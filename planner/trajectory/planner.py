"""Jerk-limited, time-synchronised motion between implement poses (Ruckig in pose space).

From rest, a move follows a straight line in pose space (x, z, roll, pitch): the per-DOF
limits are the path's scalar limits times |u_d| (:func:`~.pose_limits.straight_line_limits`)
and Ruckig's phase synchronisation keeps every DOF on the line, starting and stopping
together. From a moving state (a re-plan), Ruckig time-synchronises from the current
position, velocity and acceleration, so nothing jumps; when that re-plan could not stay in
the workspace with the any-direction limits, the moving DOF may brake with the actuators'
real limits along the current motion (:mod:`.braking`). Every plan is sampled and verified
against every limit before it is returned; when a sample is over a limit the limits are
scaled down and the plan recomputed. Community Ruckig ignores position limits, so the
trajectory's position extrema are checked against the workspace here; a plan that starts
outside the workspace (after manual motion, say) may move back in, but no further out in
any DOF than where it starts.

Stops (:meth:`TrajectoryPlanner.plan_stop`) brake with the any-direction limits, or with the
real ones (:func:`~.braking.braking_limits`) from a state beyond those limits or whose
any-direction stop would leave the workspace.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Mapping, Sequence

import numpy as np
from numpy.typing import ArrayLike
from ruckig import ControlInterface, InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

from planner.errors import first_line, unit_hint
from planner.model.exact_inverse import ExactInverse
from planner.model.hard_limits import WORKSPACE_NAMES, HardLimits
from planner.model.kinematics import HitchModel
from planner.model.limit_names import beyond_words
from planner.model.types import CONTROLLED_POSE_NAMES, KinematicsError
from planner.trajectory.actuator_limits import ActuatorLimits
from planner.trajectory.braking import StopProbe, beyond, braking_limits, current_floor
from planner.trajectory.final_approach import final_approach_via
from planner.trajectory.plan import (
    MotionState,
    Plan,
    PlanError,
    Setpoints,
    TrajectoryInputError,
    Violation,
    check_state,
    jerk_violations,
    plan_states,
    sample_plan,
    verify_setpoints,
)
from planner.trajectory.pose_limits import PoseLimits, box_limits, straight_line_limits

__all__ = ["TrajectoryPlanner", "Waypoint"]

_OK = (Result.Working, Result.Finished)
#: how far [m or rad] a re-plan's first segment may run on past both the shortest stop (real braking limits)
#: and its target before it is made as that stop followed by the move from rest (TrajectoryPlanner._plan_segments)
OVERRUN_TOLERANCE = 1e-3
#: the step [s] of :meth:`TrajectoryPlanner._fine_jerk`
FINE_JERK_DT_S = 0.001
_RATE_LIMITS = ("velocity:", "acceleration:")
#: the rate limits with the actuators' jerk (a ramp rougher than the valves' own ramp times)
_ALL_RATES = (*_RATE_LIMITS, "jerk:")


def _check_scale(speed_scale: object) -> float:
    if (
        isinstance(speed_scale, bool)
        or not isinstance(speed_scale, (int, float))
        or not math.isfinite(speed_scale)
        or not 0.0 < speed_scale <= 1.0
    ):
        raise TrajectoryInputError(f"speed_scale must be a number in (0, 1], got {speed_scale!r}")
    return float(speed_scale)


class Waypoint:
    """A (possibly partial) goal pose with an optional speed scale for the segment that reaches it."""

    def __init__(self, goal: Mapping[str, float], speed_scale: float = 1.0):
        self.goal = dict(goal)
        self.speed_scale = _check_scale(speed_scale)


class TrajectoryPlanner:
    """Plans motions of one :class:`~planner.model.kinematics.HitchModel` within its workspace and limits."""

    def __init__(
        self,
        model: HitchModel,
        *,
        limits: ActuatorLimits | None = None,
        rate: float | None = None,
        workspace: Mapping[str, tuple[float, float]] | None = None,
    ):
        if not isinstance(model, HitchModel):
            raise TrajectoryInputError(f"model must be a HitchModel (HitchModel.from_profile(name)), got {model!r}")
        if limits is not None and not isinstance(limits, ActuatorLimits):
            raise TrajectoryInputError(f"limits must be ActuatorLimits (velocity, acceleration, jerk), got {limits!r}")
        self.model = model
        self.inverse = ExactInverse(model)
        self.hard = HardLimits.from_model(model)
        self.limits = limits or ActuatorLimits.from_profile(model.profile)
        self.rate = float(rate if rate is not None else model.profile.motion.control_rate)
        if not 1.0 <= self.rate <= 200.0:
            raise TrajectoryInputError(f"rate must lie within 1..200 Hz, got {self.rate}")
        ws = workspace if workspace is not None else model.workspace
        if ws is None:
            raise PlanError(
                f"no restricted workspace for category {model.category}: Cartesian motion is refused (fit one with "
                f"`hitch profile fit-workspace --profile PROFILE --category {model.category}` and put it under "
                f"[workspace.restricted.{model.category}]; docs/profiles.md)"
            )
        self.workspace = (
            _workspace_box(ws)
            if workspace is not None
            else {k: (float(ws[k][0]), float(ws[k][1])) for k in CONTROLLED_POSE_NAMES}
        )
        self.lo = np.array([self.workspace[k][0] for k in CONTROLLED_POSE_NAMES])
        self.hi = np.array([self.workspace[k][1] for k in CONTROLLED_POSE_NAMES])
        corners = [
            np.array(c)
            for c in itertools.product(*[(a, (a + b) / 2, b) for a, b in zip(self.lo, self.hi, strict=True)])
        ]
        if workspace is None:  # the profile's box (one given here may reach beyond the mechanism on purpose)
            self._check_box(corners, f"workspace.restricted.{model.category}")
        self.any_direction = box_limits(self.inverse, corners, self.limits)
        self._ruckig = Ruckig(4)
        self._input = InputParameter(4)
        self._ruckig1 = Ruckig(1)
        self._input1 = InputParameter(1)
        self._traj1 = Trajectory(1)
        self._probe = StopProbe()
        self._line_cache: dict[tuple[bytes, bytes], tuple[ActuatorLimits, PoseLimits]] = {}
        fa = model.profile.motion.final_approach
        #: rise of a goto's last segment per DOF [m, m, rad, rad] (``motion.final_approach``, negative with
        #: ``side = "above"``; None: off)
        self.final_approach: np.ndarray | None = None if fa is None else np.array(fa.rise())
        #: where a goto aims the mechanism relative to its goal so the lagging implement rests on it
        #: (``motion.final_approach.lag``) [m, m, rad, rad]
        self.aim_shift: np.ndarray = np.zeros(4) if fa is None else np.array(fa.aim_shift())

    def _check_box(self, points: Sequence[np.ndarray], field: str) -> None:
        """Every point of the box's 3⁴ grid reachable, within the hard limits up to :data:`BOX_LIMIT_TOLERANCE`,
        else a :class:`PlanError` naming ``field`` and the point (a box in mm, or wider than the mechanism, loaded
        before and failed at the first plan: "closure error 1.62e+05 m", "exceed top_link_yaw_min at t = 2.38 s").
        A corner a calibrated geometry moves a few mm past a limit is left to the plans' own checks (they refuse
        a plan there naming the limit); `hitch profile fit-workspace` fits the box to it."""
        box = ", ".join(f"{k} [{a:g}, {b:g}]" for k, (a, b) in self.workspace.items())
        hard, tol = self.hard, BOX_LIMIT_TOLERANCE
        for c in points:
            at = ", ".join(f"{k} = {v:.4g}" for k, v in zip(CONTROLLED_POSE_NAMES, c, strict=True))
            try:
                q = self.inverse(*c)
                bad = hard.violations(q, self.model.features(q)[0], tol)
            except KinematicsError as exc:  # the project's own one-line text, without "KinematicsError: "
                bad = (str(exc).strip().splitlines()[0],)
            if bad:
                raise PlanError(
                    f"{field} ({box}; m, rad) is not all reachable: at {at} {', '.join(bad)} "
                    "(fit a reachable box with `hitch profile fit-workspace`)"
                )

    # ------------------------------------------------------------------ goals
    def goal_vector(self, current: ArrayLike, goal: Mapping[str, float]) -> np.ndarray:
        """Full goal (x, z, roll, pitch) from a partial mapping; unspecified DOF keep ``current``, moved onto the
        workspace's face where ``current`` lies outside it (a jog or the sensors leave the hitch a little outside:
        a goal of z alone was refused as "goal.x = 0.0621 m is above the workspace", naming a DOF not given)."""
        if not isinstance(goal, Mapping):
            raise TrajectoryInputError(f"goal must be a mapping with any of {', '.join(CONTROLLED_POSE_NAMES)}")
        unknown = set(goal) - set(CONTROLLED_POSE_NAMES)
        if unknown:
            raise TrajectoryInputError(
                f"goal: unknown field(s) {', '.join(sorted(unknown))}; allowed: x, z, roll, pitch"
            )
        out = np.clip(np.asarray(current, float), self.lo, self.hi)
        for i, k in enumerate(CONTROLLED_POSE_NAMES):
            if k in goal:
                v = goal[k]
                if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                    raise TrajectoryInputError(f"goal.{k} must be a finite number, got {v!r}")
                out[i] = float(v)
        return out

    def check_in_workspace(self, p: np.ndarray, what: str = "goal") -> None:
        """PlanError naming the workspace face when pose ``p`` (x, z, roll, pitch) lies outside the workspace;
        :class:`TrajectoryInputError` for anything but 4 finite numbers (a NaN pose was taken as inside)."""
        p = _finite_vector(p, what, "x, z [m], roll, pitch [rad]")
        for i, (k, (name_min, name_max)) in enumerate(zip(CONTROLLED_POSE_NAMES, WORKSPACE_NAMES, strict=True)):
            unit = "m" if k in ("x", "z") else "rad"
            hint = unit_hint(float(p[i]), float(self.lo[i]), float(self.hi[i]), unit)  # "; did you mean mm? …"
            if p[i] < self.lo[i] - 1e-9:
                raise PlanError(
                    f"{what}.{k} = {p[i]:.4f} {unit} is {beyond_words(k, False)} the workspace "
                    f"({name_min} = {self.lo[i]:.4f} {unit})" + hint
                )
            if p[i] > self.hi[i] + 1e-9:
                raise PlanError(
                    f"{what}.{k} = {p[i]:.4f} {unit} is {beyond_words(k, True)} the workspace "
                    f"({name_max} = {self.hi[i]:.4f} {unit})" + hint
                )

    def state_from_actuators(self, q: ArrayLike, q_velocity: ArrayLike | None = None) -> MotionState:
        """Pose-space state of actuators ``q`` moving at ``q_velocity`` (least squares through the FK Jacobian)."""
        f, jac = self.model.features(np.asarray(q, float))
        rows = [0, 2, 3, 4]
        vel = np.zeros(4) if q_velocity is None else jac[rows] @ np.asarray(q_velocity, float)
        return MotionState(f[rows].copy(), vel, np.zeros(4))

    # ------------------------------------------------------------------ planning
    def implement_pose(self, mechanism: ArrayLike) -> np.ndarray:
        """Where the implement rests when the mechanism rests at ``mechanism`` after a goto whose final approach
        left it the profile's lag behind: ``mechanism − sign · lag`` (x, z, roll, pitch; the mechanism itself
        without a lag). The pose to record from where the hitch is (a preset, the work pose of a quick raise, a
        taught maneuver): a goto back to it aims the mechanism where it is now, instead of one lag further."""
        return np.asarray(mechanism, float) - self.aim_shift

    def plan_move(
        self,
        start: MotionState,
        goal: Mapping[str, float],
        *,
        speed_scale: float = 1.0,
        ceiling: ArrayLike | None = None,
    ) -> Plan:
        """Plan from ``start`` to a (partial) goal pose, ending at rest; with the profile's
        ``motion.final_approach`` through a via pose below the goal (above with ``side = "above"``;
        :mod:`.final_approach`; ``plan.info["final_approach"]`` gives the via and the DOF whose approach the
        workspace shortens), and with its ``lag`` ending with the mechanism at the goal plus ``sign · lag``
        (inside the workspace box; ``info["final_approach"]["aim"]``), where the lagging implement rests on the
        goal; a DOF the goal does not name is aimed where the mechanism is. ``ceiling`` (x, z, roll, pitch;
        ``inf`` for none): a bound the aim and the via stay below besides the box (the guard's implement upper
        height); a DOF whose aim a face or the ceiling cuts is named in ``info["final_approach"]["aim_short"]``
        (its implement then rests that much short of the goal)."""
        scale = _check_scale(speed_scale)
        check_state(start, "start")
        if ceiling is not None:  # checked whether or not a final approach uses it (bad ones passed, or numpy's error)
            ceiling = _ceiling(ceiling)
        p1 = self.goal_vector(start.position, goal)
        self.check_in_workspace(p1)
        if self.final_approach is None:
            return self._plan_segments(start, [(p1, np.zeros(4), scale)])
        # the mechanism's goal: the implement lags it; a DOF not named keeps the mechanism where it is (its
        # implement already lags it: shifting it again would creep by the lag with every goto)
        upper = self.hi if ceiling is None else np.minimum(self.hi, np.asarray(ceiling, float))
        named = np.array([k in goal for k in CONTROLLED_POSE_NAMES])
        wanted = p1 + self.aim_shift
        aim = np.where(named, np.clip(wanted, self.lo, np.maximum(upper, np.minimum(p1, self.hi))), p1)
        approach = final_approach_via(start.position, aim, self.final_approach, self.lo, np.maximum(upper, aim))
        targets = [(aim, np.zeros(4), scale)]
        if approach.via is not None:
            targets.insert(0, (approach.via, np.zeros(4), scale))
        plan = self._plan_segments(start, targets)
        via = None if approach.via is None else [float(v) for v in approach.via]
        plan.info["final_approach"] = {"via": via, "short": list(approach.short)}
        if np.any(self.aim_shift != 0.0):
            plan.info["final_approach"]["aim"] = [float(v) for v in aim]
            cut = named & (np.abs(aim - wanted) > 1e-12)
            plan.info["final_approach"]["aim_short"] = [k for k, c in zip(CONTROLLED_POSE_NAMES, cut, strict=True) if c]
        return plan

    def plan_sequence(
        self, start: MotionState, waypoints: Sequence[Waypoint], *, blend: bool = False, blend_fraction: float = 0.5
    ) -> Plan:
        """Through waypoints, stopping at each (``blend=False``) or passing with non-zero velocity."""
        check_state(start, "start")
        if not waypoints:
            raise TrajectoryInputError("waypoints: at least one waypoint is needed")
        pts, prev = [], start.position
        for k, w in enumerate(waypoints):
            if not isinstance(w, Waypoint):
                raise TrajectoryInputError(f"waypoints[{k}] must be a Waypoint")
            p = self.goal_vector(prev, w.goal)
            self.check_in_workspace(p, f"waypoints[{k}]")
            pts.append(p)
            prev = p
        vels = [np.zeros(4) for _ in pts]
        if blend:
            chain = [start.position] + pts
            for k in range(len(pts) - 1):
                vels[k] = self._blend_velocity(
                    chain[k],
                    chain[k + 1],
                    chain[k + 2],
                    blend_fraction,
                    min(waypoints[k].speed_scale, waypoints[k + 1].speed_scale),
                )
        return self._plan_segments(start, [(p, v, w.speed_scale) for p, v, w in zip(pts, vels, waypoints, strict=True)])

    def plan_stop(self, state: MotionState) -> Plan:
        """The jerk-limited shortest stop from ``state``, each DOF braking on its own.

        With the any-direction limits when the state keeps within them and that stop stays in
        the workspace (or, outside it, goes no further out); otherwise with the actuators' real
        limits along the current motion (:meth:`braking_limits`), e.g. from a goto at full speed.
        """
        check_state(state, "state")
        traj = self._probe.trajectory(state, self._stop_limits(state))
        return Plan((traj,), state, traj.duration, 0.0, info={"kind": "stop"})

    def _stop_limits(self, state: MotionState) -> PoseLimits:
        """The limits :meth:`plan_stop` brakes ``state`` with: the any-direction ones (floored by |v|, |a|), or
        the real braking limits from a state beyond them or whose any-direction stop would leave the workspace."""
        lim = self.any_direction.floored(self._abs_floor(state))
        if state.moving and (np.any(beyond(state, self.any_direction)) or self.stop_leaves_workspace(state, lim)):
            lim = self.braking_limits(state)
        return lim

    def braking_limits(self, state: MotionState) -> PoseLimits:
        """Per-DOF limits for braking ``state`` with the actuators' real limits along its motion
        (never below the any-direction limits nor the state's |v|, |a|; see :mod:`.braking`)."""
        return braking_limits(self.inverse, state, self.limits, self.any_direction)

    def stop_leaves_workspace(self, state: MotionState, limits: PoseLimits) -> bool:
        """The shortest stop from ``state`` within ``limits`` passes a workspace face (from outside
        the workspace: goes further out than where it starts)."""
        p = np.asarray(state.position, float)
        lo, hi = self._probe.extent(state, limits)
        return bool(np.any(lo < np.minimum(self.lo, p) - 1e-9) or np.any(hi > np.maximum(self.hi, p) + 1e-9))

    def sample(self, plan: Plan, rate: float | None = None) -> Setpoints:
        """``plan`` sampled at ``rate`` [Hz] (1..200; default the planner's control rate; plus the exact
        endpoint), the actuators of every sample (:func:`~planner.trajectory.plan.sample_plan`)."""
        r = self.rate if rate is None else float(rate)
        if not 1.0 <= r <= 200.0:
            raise TrajectoryInputError(f"rate must lie within 1..200 Hz, got {r}")
        return sample_plan(plan, self.inverse, r)

    def lower_bound(self, q0: ArrayLike, q1: ArrayLike, q0_velocity: ArrayLike | None = None) -> float:
        """Longest per-actuator time-optimal jerk-limited move q0 → q1 (at rest at q1) [s]; ``q0``, ``q1``: the 5
        actuators (lift [rad], tilt, top, left, right [m]), ``q0_velocity`` their rates at q0 (default at rest)."""
        q0 = _finite_vector(q0, "q0", "the 5 actuators", n=5)
        q1 = _finite_vector(q1, "q1", "the 5 actuators", n=5)
        if q0_velocity is not None:
            q0_velocity = _finite_vector(q0_velocity, "q0_velocity", "the 5 actuators' rates", n=5)
        inp, tr = self._input1, self._traj1
        t = 0.0
        for i in range(5):
            inp.current_position = [float(q0[i])]
            inp.current_velocity = [0.0 if q0_velocity is None else float(q0_velocity[i])]
            inp.current_acceleration = [0.0]
            inp.target_position = [float(q1[i])]
            inp.max_velocity = [float(self.limits.velocity[i])]
            inp.max_acceleration = [float(self.limits.acceleration[i])]
            inp.max_jerk = [float(self.limits.jerk[i])]
            try:
                ok = self._ruckig1.calculate(inp, tr) in _OK
            except (RuckigError, ValueError) as exc:
                raise PlanError(f"lower bound for actuator {i} could not be computed ({first_line(exc)})") from None
            if not ok:
                raise PlanError(f"lower bound for actuator {i} could not be computed")
            t = max(t, tr.duration)
        return t

    # ------------------------------------------------------------------ internals
    def _abs_floor(self, state: MotionState) -> PoseLimits:
        """Limits never below the current |v|, |a| (Ruckig rejects states beyond its limits)."""
        return current_floor(state)

    def _segment_limits(self, p0, p1, start_moving: bool, scale: float) -> PoseLimits:
        try:
            lim = self._line_limits(np.asarray(p0, float), np.asarray(p1, float)).scaled(scale)
        except KinematicsError as exc:
            raise PlanError(f"the straight line to the goal leaves the reachable set: {exc}") from None
        if start_moving:  # other DOF may carry velocity: allow them the any-direction limits
            lim = lim.floored(self.any_direction.scaled(scale))
        return lim

    def _line_limits(self, p0: np.ndarray, p1: np.ndarray) -> PoseLimits:
        """:func:`straight_line_limits` of p0 → p1 with the current actuator limits; the last few
        are kept (a guarded move plans the same line again, slower)."""
        key = (p0.tobytes(), p1.tobytes())
        hit = self._line_cache.get(key)
        if hit is not None and hit[0] is self.limits:
            return hit[1]
        lim = straight_line_limits(self.inverse, p0, p1, self.limits)
        if len(self._line_cache) >= 8:
            self._line_cache.pop(next(iter(self._line_cache)))
        self._line_cache[key] = (self.limits, lim)
        return lim

    def _blend_velocity(self, a, b, c, fraction: float, scale: float) -> np.ndarray:
        """Pass-through velocity at b: along (c − a), as large as both neighbouring segments allow."""
        d = c - a
        if np.linalg.norm(d) < 1e-12:
            return np.zeros(4)
        u = d / np.linalg.norm(d)
        lim = np.minimum(
            self._segment_limits(a, b, True, scale).velocity, self._segment_limits(b, c, True, scale).velocity
        )
        with np.errstate(divide="ignore"):
            speed = float(np.min(np.where(np.abs(u) > 1e-12, lim / np.abs(u), np.inf)))
        return fraction * speed * u

    def _set_limits(self, inp: InputParameter, lim: PoseLimits) -> None:
        inp.max_velocity = [float(max(v, 1e-9)) for v in lim.velocity]
        inp.max_acceleration = [float(max(v, 1e-9)) for v in lim.acceleration]
        inp.max_jerk = [float(max(v, 1e-9)) for v in lim.jerk]

    def _solve_segment(self, state: MotionState, p1, v1, lim: PoseLimits) -> Trajectory:
        inp = self._input
        inp.control_interface = ControlInterface.Position
        self._set_limits(
            inp,
            lim.floored(self._abs_floor(state)).floored(PoseLimits(np.abs(v1) * (1 + 1e-9), np.zeros(4), np.zeros(4))),
        )
        inp.current_position, inp.current_velocity = list(state.position), list(state.velocity)
        inp.current_acceleration = list(state.acceleration)
        inp.target_position, inp.target_velocity, inp.target_acceleration = list(p1), list(v1), [0.0] * 4
        inp.synchronization = Synchronization.Phase if not state.moving and not np.any(v1) else Synchronization.Time
        traj = Trajectory(4)
        try:
            res = self._ruckig.calculate(inp, traj)
        except (RuckigError, ValueError) as exc:  # input Ruckig cannot solve; a result code its enum lacks
            raise PlanError(f"no trajectory to the goal within the limits ({first_line(exc)})") from None
        if res not in _OK:
            raise PlanError(f"no trajectory to the goal within the limits (ruckig {res})")
        return traj

    def _plan_segments(self, start: MotionState, targets) -> Plan:
        """Plan the chain. From a moving state (a re-plan: a goto replacing a motion):

        * one that would leave the workspace with the any-direction limits is made again with the
          real braking limits (:meth:`braking_limits`) for the DOF the motion carries;
        * one that cannot be made that way (a speed scale whose limits the current motion exceeds, so
          Ruckig has no profile), or whose first segment runs on past both the shortest stop with the
          real braking limits and its own target by more than :data:`OVERRUN_TOLERANCE` (a reversal
          braked with the new move's smaller limits: e.g. 19 cm beyond a 2.5 cm stop), becomes a
          stop (the stop command's: :meth:`_stop_then`) followed by the move from rest;
        * so does one with a speed scale below 1 whose limits the current motion exceeds (its |v| or |a|):
          the move would otherwise keep the motion's speed (its limits floored by the state), not the
          speed asked for (a 5 % reversal ran at full speed)."""
        if not start.moving:
            try:
                return self._plan_chain(start, targets, None)
            except _LeavesWorkspace as exc:
                raise PlanError(str(exc)) from None
        p1, _, scale = targets[0]
        if scale < 1.0 and np.any(beyond(start, self._segment_limits(start.position, p1, True, scale))):
            # a slower move than the motion it replaces: its limits would be raised to the motion's |v|, |a|
            # (Ruckig starts within its limits) and the move would go on at the old speed, not the one asked for
            return self._stop_then(start, targets)
        try:
            try:
                plan = self._plan_chain(start, targets, None)
            except _LeavesWorkspace:
                plan = self._plan_chain(start, targets, self.braking_limits(start))
        except PlanError:
            return self._stop_then(start, targets)
        if self._overruns_stop(plan.segments[0], start, np.asarray(targets[0][0], float)):
            return self._stop_then(start, targets)
        return plan

    def _overruns_stop(self, first: Trajectory, start: MotionState, target: np.ndarray) -> bool:
        """``first`` (from the moving ``start`` to ``target``) passes, in some DOF, beyond both the shortest
        stop with the real braking limits and ``target`` (and the start) by more than OVERRUN_TOLERANCE."""
        lo_stop, hi_stop = self._probe.extent(start, self.braking_limits(start))
        p = np.asarray(start.position, float)
        lo_ok = np.minimum(np.minimum(lo_stop, target), p) - OVERRUN_TOLERANCE
        hi_ok = np.maximum(np.maximum(hi_stop, target), p) + OVERRUN_TOLERANCE
        ext = first.position_extrema
        lo = np.array([e.min for e in ext])
        hi = np.array([e.max for e in ext])
        return bool(np.any(lo < lo_ok) or np.any(hi > hi_ok))

    def _stop_then(self, start: MotionState, targets) -> Plan:
        """A stop from ``start``, then the chain from rest there.

        The stop is first the one :meth:`plan_stop` makes (the stop command's). It brakes each DOF on its own, so
        where DOFs combine its actuator rates can exceed the actuators' limits (a re-plan reached 1.07 × an
        acceleration limit): then the same stop with the DOFs braking together along the motion's line
        (``along_line``) is tried, then the first with the pose accelerations × 0.9, 0.81 … (never below the
        state's own |a|; 8 stops in all), and the first stop without an excess is kept, else the one with the
        smallest. Only the acceleration is lowered: a lower jerk would let a state still speeding up run on
        faster before it brakes (its speed grows by a²/2j; lowering it too ran a re-plan at 1.58 × lift's
        velocity limit). The excess kept is within the stop and never more than the stop command's own
        (``info["stop_excess"]``: the largest |rate| / limit; the actuators' jerk is kept out of that choice and its
        excess within the stop given as ``info["stop_jerk_excess"]``, a jerk whose window of two sample intervals
        starts within the stop counted as the stop's); any other violation is a :class:`PlanError`. A
        move that, verified on its own samples, exceeds a rate limit on the whole plan's (shifted in time by the
        stop) is made a little slower (× 0.9, down to half; ``info["move_scale"]``). A try after the first that
        fails (its stop passes a workspace face, its move cannot be made) is passed over: the plan in hand stays."""
        brake = self._stop_limits(start)
        tries = [(1.0, False), (1.0, True), *((0.9**k, False) for k in range(1, 7))]
        best: tuple[float, Plan] | None = None
        move_scale, k = 1.0, 0
        while k < len(tries):
            factor, along_line = tries[k]
            lim = PoseLimits(brake.velocity, brake.acceleration * factor, brake.jerk)
            try:
                stop = self._probe.trajectory(start, lim, along_line=along_line)
                # from outside the workspace: no further out (the stop's extent from its start: Ruckig's extrema of
                # a velocity-interface stop include 0, which a workspace need not: every such re-plan was refused)
                self._check_stop_extent(start, lim, along_line)
                p_stop, _, _ = stop.at_time(stop.duration)
                # a slower move passes its waypoints slower too (as _plan_chain's speed factor)
                chain = [(p, np.asarray(v, float) * move_scale, scale * move_scale) for p, v, scale in targets]
                move = self._plan_chain(MotionState.at_rest(np.array(p_stop, float)), chain, None)
                plan = Plan((stop, *move.segments), start, float(stop.duration + move.duration), 0.0)
                sp = self.sample(plan)
                self._check_samples(sp, start.position, stop.duration)
                bad = verify_setpoints(sp, self.model, self.hard, self.limits, check_jerk=True)
                # a jerk is stamped with the middle of its window [t - dt, t + dt]: one whose window starts within
                # the stop holds the stop's jerk too (a stop's last jerk phase made the move after it slower)
                in_stop_all = [v for v in bad if _in_stop(v, stop.duration, self.rate)]
                in_stop = [v for v in in_stop_all if v.limit.startswith(_RATE_LIMITS)]
                if len(in_stop_all) < len(bad):
                    worst = next(v for v in bad if v not in in_stop_all)
                    if worst.limit.startswith(_ALL_RATES) and move_scale > 0.5:
                        move_scale *= 0.9  # the same stop again, the move after it slower
                        continue
                    raise PlanError(f"the plan would exceed {worst.sentence()}")
            except PlanError as exc:  # _LeavesWorkspace too
                if k == 0:  # the stop command's own stop, or the move from where it ends
                    raise PlanError(str(exc)) from None
                k += 1  # another stop, which ends elsewhere: the one in hand stays; try the next
                continue
            excess = max((abs(v.value) / v.bound for v in in_stop), default=0.0)
            info = {
                **move.info,
                "braking": "stop first (actuator limits)",
                "stop_duration": float(stop.duration),
                "stop_factor": factor,
                "stop_along_line": along_line,
                "move_scale": move_scale,
            }
            if in_stop:
                info["stop_excess"] = excess
            jerks = [abs(v.value) / v.bound for v in in_stop_all if v.limit.startswith("jerk:")]
            if jerks:
                info["stop_jerk_excess"] = max(jerks)
            if best is None or excess < best[0]:
                lb = float(stop.duration) + move.lower_bound
                best = (excess, Plan(plan.segments, start, plan.duration, lb, sp, info))
            if not in_stop:
                break
            k += 1
        assert best is not None  # the first try either gives a plan or raises
        return best[1]

    def _check_stop_extent(self, start: MotionState, lim: PoseLimits, along_line: bool) -> None:
        """:class:`_LeavesWorkspace` when the stop from ``start`` within ``lim`` passes a workspace face (from
        outside the workspace: goes further out than where it starts)."""
        lo, hi = self._probe.extent(start, lim, along_line=along_line)
        p = np.asarray(start.position, float)
        lo_ok, hi_ok = np.minimum(self.lo, p), np.maximum(self.hi, p)
        for i, (k, (name_min, name_max)) in enumerate(zip(CONTROLLED_POSE_NAMES, WORKSPACE_NAMES, strict=True)):
            if lo[i] < lo_ok[i] - 1e-6:
                raise _LeavesWorkspace(
                    f"the stop would leave the workspace: {k} reaches {lo[i]:.4f} ({name_min} = {self.lo[i]:.4f}"
                    f"{_start_note(lo_ok[i], self.lo[i])})"
                )
            if hi[i] > hi_ok[i] + 1e-6:
                raise _LeavesWorkspace(
                    f"the stop would leave the workspace: {k} reaches {hi[i]:.4f} ({name_max} = {self.hi[i]:.4f}"
                    f"{_start_note(hi_ok[i], self.hi[i])})"
                )

    def _plan_chain(self, start: MotionState, targets, brake: PoseLimits | None) -> Plan:
        """The segments through ``targets`` from ``start``, verified on their samples; a velocity, acceleration or
        jerk excess of an actuator makes the whole chain again as a slower copy (limits × the speed factor, its
        powers, and the pass-through velocities × the factor), up to 12 times."""
        factor = 1.0
        for attempt in range(12):
            segs, state = [], start
            for k, (p1, v1, scale) in enumerate(targets):
                lim = self._segment_limits(state.position, p1, state.moving or bool(np.any(v1)), scale * factor)
                if k == 0 and brake is not None:
                    lim = lim.floored(brake.scaled(factor))
                traj = self._solve_segment(state, p1, np.asarray(v1, float) * factor, lim)
                # the first segment may start outside the workspace: it must not go further out
                self._check_extrema(traj, start.position if k == 0 else None)
                segs.append(traj)
                p, v, a = traj.at_time(traj.duration)
                state = MotionState(np.array(p), np.array(v), np.array(a))
            duration = float(sum(s.duration for s in segs))
            plan = Plan(tuple(segs), start, duration, 0.0)
            sp = self.sample(plan)
            self._check_samples(sp, start.position, segs[0].duration)
            bad = verify_setpoints(sp, self.model, self.hard, self.limits, check_jerk=True)
            if not bad and (start.moving or any(np.any(v1) for _, v1, _ in targets)):
                bad = self._fine_jerk(plan)  # DOFs not on one line: an excess shorter than the samples' windows
            if not bad:
                q0, q0d = sp.actuators[0], sp.actuator_velocity[0]
                lb = self.lower_bound(q0, sp.actuators[-1], q0d)
                info = {"kind": "move", "speed_factor": factor, "attempts": attempt + 1}
                if brake is not None:
                    info["braking"] = "actuator limits"
                return Plan(plan.segments, start, duration, lb, sp, info)
            worst = bad[0]
            if worst.limit.startswith(_ALL_RATES):
                factor *= 0.9
                continue
            raise PlanError(f"the plan would exceed {worst.sentence()}")
        raise PlanError(f"the plan keeps exceeding {worst.sentence()} even at {factor:.2f} of full speed")

    def _fine_jerk(self, plan: Plan) -> list[Violation]:
        """The actuators' jerk of ``plan`` judged every :data:`FINE_JERK_DT_S` (the control rate's 20 ms windows
        averaged a 22 ms excess at a re-plan's start to 0.87 of the limit, truly 1.34 ×, and a 6.5 ms one in a
        blend to 0.92, truly 1.40 ×: a review at 1 kHz). Only for chains that start moving or pass waypoints
        moving: a move from rest keeps the jerk by construction. About 1.5 ms per second of plan."""
        ts = np.unique(np.append(np.arange(0.0, plan.duration, FINE_JERK_DT_S), plan.duration))
        pos, vel = plan_states(plan, ts)
        inv = self.inverse.solve_batch(pos, vel)
        qd = np.where(inv.ok[:, None], inv.actuator_velocity, np.nan)
        return jerk_violations(ts, qd, self.limits)

    def _check_extrema(self, traj: Trajectory, start: np.ndarray | None = None) -> None:
        """Every DOF of ``traj`` within the workspace; with a ``start`` pose outside it, within
        the workspace widened to that start (back in is allowed, further out is not)."""
        lo, hi = self.lo, self.hi
        if start is not None:
            lo, hi = np.minimum(lo, start), np.maximum(hi, start)
        extrema = zip(CONTROLLED_POSE_NAMES, WORKSPACE_NAMES, traj.position_extrema, strict=True)
        for i, (k, (name_min, name_max), ext) in enumerate(extrema):
            if ext.min < lo[i] - 1e-6:
                raise _LeavesWorkspace(
                    f"the trajectory would leave the workspace: {k} reaches {ext.min:.4f} at t = {ext.t_min:.2f} s "
                    f"({name_min} = {self.lo[i]:.4f}{_start_note(lo[i], self.lo[i])})"
                )
            if ext.max > hi[i] + 1e-6:
                raise _LeavesWorkspace(
                    f"the trajectory would leave the workspace: {k} reaches {ext.max:.4f} at t = {ext.t_max:.2f} s "
                    f"({name_max} = {self.hi[i]:.4f}{_start_note(hi[i], self.hi[i])})"
                )

    def _check_samples(self, sp: Setpoints, start: np.ndarray, first: float) -> None:
        """Every sample within the workspace (those of the first segment, ending at ``first`` [s],
        within it widened to ``start``): Ruckig's position extrema of a time-synchronised profile
        from a moving state can miss an excursion, the samples do not (to ~a·dt²/8 at a turn)."""
        pose = sp.pose[:, [0, 2, 3, 4]]
        if np.all(pose.min(axis=0) >= self.lo - 1e-6) and np.all(pose.max(axis=0) <= self.hi + 1e-6):
            return  # within the workspace itself (the bounds below are never tighter)
        in_first = (sp.t <= first + 1e-12)[:, None]
        lo = np.where(in_first, np.minimum(self.lo, start), self.lo) - 1e-6
        hi = np.where(in_first, np.maximum(self.hi, start), self.hi) + 1e-6
        for i, (k, (name_min, name_max)) in enumerate(zip(CONTROLLED_POSE_NAMES, WORKSPACE_NAMES, strict=True)):
            for side, bad, name, face in (
                ("min", pose[:, i] < lo[:, i], name_min, self.lo[i]),
                ("max", pose[:, i] > hi[:, i], name_max, self.hi[i]),
            ):
                if np.any(bad):
                    j = int(np.flatnonzero(bad)[0])
                    bound = float((lo if side == "min" else hi)[j, i]) + (1e-6 if side == "min" else -1e-6)
                    raise _LeavesWorkspace(
                        f"the trajectory would leave the workspace: {k} reaches {pose[j, i]:.4f} at "
                        f"t = {sp.t[j]:.2f} s ({name} = {face:.4f}{_start_note(bound, face)})"
                    )


def _in_stop(v: Violation, stop_end: float, rate: float) -> bool:
    """A rate violation of a stop-first plan that belongs to its stop (ending at ``stop_end`` [s]): a velocity or
    acceleration at a sample within it, a jerk whose window (the two intervals about ``v.t`` at ``rate`` [Hz])
    starts within it."""
    if v.limit.startswith("jerk:"):
        return v.t - 1.0 / rate < stop_end
    return v.limit.startswith(_RATE_LIMITS) and v.t <= stop_end + 1e-9


def _shown(values: object) -> str:
    """``values`` as typed, cut to 80 characters (a 400-digit integer filled the message)."""
    text = repr(values)
    return text if len(text) <= 80 else text[:77] + "..."


def _floats(values: object) -> np.ndarray:
    """``values`` as a float array; ValueError for text (numpy would read "1" as 1.0) or a number beyond a float."""
    items = np.ravel(np.array(values, dtype=object))
    if isinstance(values, (str, bytes)) or any(isinstance(v, (str, bytes)) for v in items):
        raise ValueError("text")
    try:
        return np.asarray(values, dtype=float)
    except OverflowError:
        raise ValueError("beyond a float") from None


def _ceiling(values: object) -> np.ndarray:
    """``ceiling`` of :meth:`TrajectoryPlanner.plan_move`: 4 numbers (x, z [m], roll, pitch [rad]), ``inf`` for none;
    :class:`TrajectoryInputError` naming it otherwise (NaN and −inf included)."""
    try:
        out = _floats(values)
    except (TypeError, ValueError):
        raise TrajectoryInputError(
            f"ceiling must be 4 numbers (x, z [m], roll, pitch [rad]; inf: none), got {_shown(values)}"
        ) from None
    if out.shape != (4,) or np.any(np.isnan(out)) or np.any(out == -np.inf):
        raise TrajectoryInputError(
            f"ceiling must be 4 numbers (x, z [m], roll, pitch [rad]; inf: none), got {_shown(values)}"
        )
    return out


def _finite_vector(values: object, what: str, names: str, *, n: int = 4) -> np.ndarray:
    """``values`` as ``n`` finite floats, else :class:`TrajectoryInputError` naming ``what`` and ``names``."""
    try:
        out = _floats(values)
    except (TypeError, ValueError):
        raise TrajectoryInputError(f"{what} must be {n} numbers ({names}), got {_shown(values)}") from None
    if out.shape != (n,):
        raise TrajectoryInputError(f"{what} must be {n} numbers ({names}), got shape {out.shape}")
    if not np.all(np.isfinite(out)):
        raise TrajectoryInputError(f"{what} must be finite ({names}), got {out.tolist()}")
    return out


def _workspace_box(ws: object) -> dict[str, tuple[float, float]]:
    """The ``workspace`` argument checked: (lo, hi) of each of x, z [m], roll, pitch [rad], finite and lo < hi;
    :class:`TrajectoryInputError` naming the argument (a partial one raised KeyError 'z', an inverted one was
    taken and refused later as a goal "below the workspace" in a DOF the goal did not name)."""
    if not isinstance(ws, Mapping) or set(ws) != set(CONTROLLED_POSE_NAMES):
        keys = sorted(ws) if isinstance(ws, Mapping) else type(ws).__name__
        raise TrajectoryInputError(f"workspace must map each of x, z, roll, pitch to (lo, hi), got {keys}")
    out = {}
    for k in CONTROLLED_POSE_NAMES:
        unit = "m" if k in ("x", "z") else "rad"
        try:
            lo, hi = (float(v) for v in ws[k])
        except (TypeError, ValueError):
            raise TrajectoryInputError(f"workspace.{k} must be two numbers (lo, hi) [{unit}], got {ws[k]!r}") from None
        if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
            raise TrajectoryInputError(f"workspace.{k} must be finite with lo < hi [{unit}], got ({lo:g}, {hi:g})")
        out[k] = (lo, hi)
    return out


class _LeavesWorkspace(PlanError):
    """A trajectory passing a workspace face (internal: a moving re-plan is tried again with the braking limits)."""


#: how far [m or rad] a point of a profile's restricted box may lie beyond a hard limit before loading refuses
#: the box (TrajectoryPlanner._check_box): more is a box of another machine or in other units
BOX_LIMIT_TOLERANCE = 0.01


def _start_note(bound: float, face: float) -> str:
    return "" if bound == face else f"; it starts outside at {bound:.4f} and may only move back in"
