"""Jog: pose-rate commands (a joystick or the API) applied every control cycle (thesis "automatic mode").

Each cycle the commanded rates (vx, vz, vroll, vpitch) become Ruckig's target velocity
(velocity interface, jerk-limited). A command lives for its time-to-live: without a
fresh one the target becomes zero, a jerk-limited stop (dead-man). Near a workspace
face the rate towards it is capped so the jerk-limited braking distance fits before the
face: motion in that direction stops smoothly, the per-direction flag names the limit
(``{"x+": "workspace:x:max"}``), and motion away from it stays free.

A jog that takes over a moving state (a goto at full speed) inherits velocities and
accelerations beyond its own limits. A DOF beyond them brakes with the actuators' real
limits along the current motion (:func:`~.braking.braking_limits`), the limits the goto was
allowed to use, not with the jog's smaller ones. And every cycle the state one step ahead
must still be able to stop within the workspace (the jerk-limited shortest stop from its
velocity and acceleration, :class:`~.braking.StopProbe`); a DOF for which it could not
brakes now with those real limits. Within its own limits and away from the faces a jog
moves, and dies with its command, exactly as before.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, Synchronization, Trajectory

from planner.errors import HitchError
from planner.model.hard_limits import WORKSPACE_NAMES
from planner.model.limit_names import LimitName
from planner.model.types import CONTROLLED_POSE_NAMES
from planner.trajectory.braking import StopProbe, beyond, current_floor
from planner.trajectory.plan import MotionState, PlanError, TrajectoryInputError
from planner.trajectory.planner import TrajectoryPlanner
from planner.trajectory.pose_limits import PoseLimits

__all__ = ["JogController", "JogError", "JogOutput", "JOG_FIELDS"]

JOG_FIELDS = ("vx", "vz", "vroll", "vpitch")


class JogError(HitchError, RuntimeError):
    """Ruckig could not compute the next jog cycle: an internal failure, not bad input."""


@dataclass(frozen=True)
class JogOutput:
    """One control cycle of jog: the new pose-space state and its actuators."""

    t: float
    state: MotionState
    actuators: np.ndarray
    actuator_velocity: np.ndarray
    limited: dict[str, str] = field(default_factory=dict)  # "x+" / "x-" … → limit name
    expired: bool = False  # the command's TTL ran out (dead-man stop)

    @property
    def moving(self) -> bool:
        return self.state.moving


def _braking_speed(distance: float, a: float, j: float) -> float:
    """Largest speed from which a jerk-limited stop (a ≤ a_max, |jerk| ≤ j) fits in ``distance``.

    Stopping distance from v at zero acceleration is ≤ v²/(2a) + v·a/(2j) (a ramp of a/j
    seconds at each end); solved for v.
    """
    if distance <= 0:
        return 0.0
    b = a / (2 * j)
    return a * (-b + math.sqrt(b * b + 2 * distance / a))


@dataclass(frozen=True)
class _Cycle:
    """One planned jog cycle: the target rates given to Ruckig, the flags, the next state."""

    target: np.ndarray
    flags: dict[str, str]
    state: MotionState  # one cycle ahead (Ruckig's calculate; the step itself runs through update)
    brake: np.ndarray  # DOF braking with the real limits


class JogController:
    """Integrates rate commands at the planner's control rate within its workspace."""

    def __init__(self, planner: TrajectoryPlanner, start: MotionState, *, speed_scale: float = 1.0):
        self.planner = planner
        self.dt = 1.0 / planner.rate
        self.limits = planner.any_direction.scaled(speed_scale)
        self._ruckig = Ruckig(4, self.dt)  # the committed steps (update: as a jog always ran)
        self._out = OutputParameter(4)
        self._in = InputParameter(4)
        self._ahead = Ruckig(4)  # looking one cycle ahead (calculate)
        self._ahead_in = InputParameter(4)
        self._traj = Trajectory(4)
        for inp in (self._in, self._ahead_in):
            inp.control_interface = ControlInterface.Velocity
            inp.synchronization = Synchronization.No
        self._probe = StopProbe()
        self.reset(start)

    def reset(self, state: MotionState) -> None:
        self.state = state
        self.t = 0.0
        self._cmd = np.zeros(4)
        self._cmd_expires = -math.inf
        self._brake: PoseLimits | None = None  # real braking limits of the motion being braked (lazily)

    def command(self, rates: Mapping[str, float] | Iterable[float], ttl_s: float, now_s: float | None = None) -> None:
        """Set the rates (mapping with vx, vz, vroll, vpitch or 4 numbers; m/s, rad/s) for ``ttl_s`` seconds."""
        if isinstance(rates, Mapping):
            unknown = set(rates) - set(JOG_FIELDS)
            if unknown:
                raise TrajectoryInputError(
                    f"jog: unknown field(s) {', '.join(sorted(unknown))}; allowed: {', '.join(JOG_FIELDS)}"
                )
            vals = [rates.get(k, 0.0) for k in JOG_FIELDS]
        else:
            vals = list(rates)
            if len(vals) != 4:
                raise TrajectoryInputError("jog: 4 rates needed (vx, vz, vroll, vpitch)")
        for k, v in zip(JOG_FIELDS, vals, strict=True):
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise TrajectoryInputError(f"jog.{k} must be a finite number, got {v!r}")
        if isinstance(ttl_s, bool) or not isinstance(ttl_s, (int, float)) or not 0 < ttl_s <= 5.0:
            raise TrajectoryInputError(f"jog ttl must lie within (0, 5] s, got {ttl_s!r}")
        now = self.t if now_s is None else now_s
        self._cmd = np.array(vals, dtype=float)
        self._cmd_expires = now + ttl_s

    def clipped_rates(self, rates: np.ndarray) -> tuple[np.ndarray, dict[str, str]]:
        """Rates after the jog speed limits and the braking caps at the workspace faces, with flags.

        The caps account for the current state: a DOF that could not stop within the workspace
        after one more cycle towards its rate gets rate 0 (it brakes now with the real limits).
        """
        cyc = self._plan_cycle(np.asarray(rates, float))
        return cyc.target, cyc.flags

    def speed_flags(self, rates: np.ndarray) -> dict[str, str]:
        """The DOFs whose rate ``rates`` [m/s, rad/s] exceeds the jog speed limit: ``{"x+": "velocity:x", …}``
        (a rate above it is capped to it, and said so)."""
        r = np.asarray(rates, float)
        return {
            f"{k}{'+' if r[d] > 0 else '-'}": str(LimitName("velocity", k))
            for d, k in enumerate(CONTROLLED_POSE_NAMES)
            if abs(r[d]) > self.limits.velocity[d] * (1.0 + 1e-9)
        }

    def step(self, now_s: float | None = None) -> JogOutput:
        """Advance one control cycle (dt = 1/rate)."""
        now = self.t + self.dt if now_s is None else now_s
        expired = now > self._cmd_expires
        rates = np.zeros(4) if expired else self._cmd
        cyc = self._plan_cycle(rates)
        self._set_input(self._in, cyc.target, cyc.brake)
        res = self._ruckig.update(self._in, self._out)
        if res not in (Result.Working, Result.Finished):
            raise JogError(f"jog: ruckig failed ({res})")
        out = self._out
        self.state = MotionState(np.array(out.new_position), np.array(out.new_velocity), np.array(out.new_acceleration))
        self.t = now
        if not self.state.moving:
            self._brake = None
        q, jac, _ = self.planner.inverse.solve_full(self.state.position)
        return JogOutput(now, self.state, q, jac @ self.state.velocity, cyc.flags, bool(expired and np.any(self._cmd)))

    # ------------------------------------------------------------------ internals
    def _face_caps(self, rates: np.ndarray) -> tuple[np.ndarray, dict[str, str]]:
        """The jog speed limits and the caps at the faces for braking from the capped speed
        with the jog's own limits (the approach to a face within those limits)."""
        v = np.clip(rates, -self.limits.velocity, self.limits.velocity)
        flags = self.speed_flags(rates)
        p = self.state.position
        cur = self.state.velocity
        for d, (k, (name_min, name_max)) in enumerate(zip(CONTROLLED_POSE_NAMES, WORKSPACE_NAMES, strict=True)):
            a, j = self.limits.acceleration[d], self.limits.jerk[d]
            slack = 2 * abs(cur[d]) * self.dt  # one cycle of reaction plus the discrete step
            up = _braking_speed(self.planner.hi[d] - p[d] - slack, a, j)
            down = _braking_speed(p[d] - self.planner.lo[d] - slack, a, j)
            if v[d] > up:
                if rates[d] > 0:
                    flags[f"{k}+"] = name_max
                v[d] = max(up, 0.0) if rates[d] > 0 else v[d]
            if v[d] < -down:
                if rates[d] < 0:
                    flags[f"{k}-"] = name_min
                v[d] = -max(down, 0.0) if rates[d] < 0 else v[d]
        return v, flags

    def _braking(self) -> PoseLimits:
        """The real braking limits of the current motion (computed once per braking episode)."""
        if self._brake is None:
            self._brake = self.planner.braking_limits(self.state).floored(self.limits)
        self._brake = self._brake.floored(current_floor(self.state))
        return self._brake

    def _set_input(self, inp: InputParameter, target: np.ndarray, brake: np.ndarray) -> None:
        """Ruckig's input for a cycle towards ``target``; DOF marked in ``brake`` with the real limits."""
        st = self.state
        lim = self.limits
        if np.any(brake):  # the real limits, floored by the state's |v|, |a| (within the jog's own: as before)
            real = self._braking()
            lim = PoseLimits(
                np.where(brake, real.velocity, lim.velocity),
                np.where(brake, real.acceleration, lim.acceleration),
                np.where(brake, real.jerk, lim.jerk),
            )
        inp.max_velocity = [float(max(x, abs(t), 1e-9)) for x, t in zip(lim.velocity, target, strict=True)]
        inp.max_acceleration = [float(max(x, 1e-9)) for x in lim.acceleration]
        inp.max_jerk = [float(max(x, 1e-9)) for x in lim.jerk]
        inp.current_position = list(st.position)
        inp.current_velocity = list(st.velocity)
        inp.current_acceleration = list(st.acceleration)
        inp.target_velocity = list(target)
        inp.target_acceleration = [0.0] * 4

    def _advance(self, target: np.ndarray, brake: np.ndarray) -> MotionState:
        """The state one cycle ahead towards ``target`` (see :meth:`_set_input`)."""
        self._set_input(self._ahead_in, target, brake)
        res = self._ahead.calculate(self._ahead_in, self._traj)
        if res not in (Result.Working, Result.Finished):
            raise JogError(f"jog: ruckig failed ({res})")
        p, v, a = self._traj.at_time(self.dt)  # past its duration: on at the target velocity (as update does)
        return MotionState(np.array(p), np.array(v), np.array(a))

    def _cannot_stop(self, state: MotionState, limits: PoseLimits) -> tuple[np.ndarray, np.ndarray]:
        """Per DOF: the shortest stop from ``state`` passes the upper / lower face (beyond the
        current position when that is already outside)."""
        try:
            lo, hi = self._probe.extent(state, limits)
        except PlanError as exc:
            raise JogError(f"jog: {exc}") from None
        p = self.state.position
        return hi > np.maximum(self.planner.hi, p) + 1e-9, lo < np.minimum(self.planner.lo, p) - 1e-9

    def _plan_cycle(self, rates: np.ndarray) -> _Cycle:
        target, flags = self._face_caps(rates)
        brake = beyond(self.state, self.limits)
        nxt = self._advance(target, brake)
        for _ in range(3):
            up, down = self._cannot_stop(nxt, self.limits)  # cheap: the jog's own limits first
            if not (np.any(up) or np.any(down)):
                break
            up, down = self._cannot_stop(nxt, self._braking())
            # braking already as hard as it gets: nothing more to do for that DOF
            up &= ~(brake & (target <= 0))
            down &= ~(brake & (target >= 0))
            if not (np.any(up) or np.any(down)):
                break
            for d, (k, (name_min, name_max)) in enumerate(zip(CONTROLLED_POSE_NAMES, WORKSPACE_NAMES, strict=True)):
                if up[d]:
                    target[d] = min(target[d], 0.0)
                    if rates[d] > 0:
                        flags[f"{k}+"] = name_max
                if down[d]:
                    target[d] = max(target[d], 0.0)
                    if rates[d] < 0:
                        flags[f"{k}-"] = name_min
            brake = brake | up | down
            nxt = self._advance(target, brake)
        return _Cycle(target, flags, nxt, brake)
