"""Jog: pose-rate commands (a joystick or the API) applied every control cycle (thesis "automatic mode").

Each cycle the commanded rates (vx, vz, vroll, vpitch) become Ruckig's target velocity
(velocity interface, jerk-limited). A command lives for its time-to-live: without a
fresh one the target becomes zero, a jerk-limited stop (dead-man). Near a workspace
face the rate towards it is capped so the jerk-limited braking distance fits before the
face: motion in that direction stops smoothly, the per-direction flag names the limit
(``{"x+": "workspace:x:max"}``), and motion away from it stays free.
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np
from ruckig import ControlInterface, InputParameter, OutputParameter, Result, Ruckig, Synchronization

from planner.errors import HitchError
from planner.model.hard_limits import WORKSPACE_NAMES
from planner.model.types import CONTROLLED_POSE_NAMES
from planner.trajectory.plan import MotionState, TrajectoryInputError
from planner.trajectory.planner import TrajectoryPlanner

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


class JogController:
    """Integrates rate commands at the planner's control rate within its workspace."""

    def __init__(self, planner: TrajectoryPlanner, start: MotionState, *, speed_scale: float = 1.0):
        self.planner = planner
        self.dt = 1.0 / planner.rate
        self.limits = planner.any_direction.scaled(speed_scale)
        self._ruckig = Ruckig(4, self.dt)
        self._in = InputParameter(4)
        self._out = OutputParameter(4)
        self._in.control_interface = ControlInterface.Velocity
        self._in.synchronization = Synchronization.No
        self._in.max_velocity = list(self.limits.velocity)
        self._in.max_acceleration = list(self.limits.acceleration)
        self._in.max_jerk = list(self.limits.jerk)
        self.reset(start)

    def reset(self, state: MotionState) -> None:
        self.state = state
        self.t = 0.0
        self._cmd = np.zeros(4)
        self._cmd_expires = -math.inf

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
        """Rates after the jog speed limits and the braking caps at the workspace faces, with flags."""
        v = np.clip(np.asarray(rates, float), -self.limits.velocity, self.limits.velocity)
        flags: dict[str, str] = {}
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

    def step(self, now_s: float | None = None) -> JogOutput:
        """Advance one control cycle (dt = 1/rate)."""
        now = self.t + self.dt if now_s is None else now_s
        expired = now > self._cmd_expires
        rates = np.zeros(4) if expired else self._cmd
        target, flags = self.clipped_rates(rates)
        inp = self._in
        inp.current_position = list(self.state.position)
        inp.current_velocity = list(self.state.velocity)
        inp.current_acceleration = list(self.state.acceleration)
        inp.target_velocity = list(target)
        inp.target_acceleration = [0.0] * 4
        res = self._ruckig.update(inp, self._out)
        if res not in (Result.Working, Result.Finished):
            raise JogError(f"jog: ruckig failed ({res})")
        out = self._out
        self.state = MotionState(np.array(out.new_position), np.array(out.new_velocity), np.array(out.new_acceleration))
        self.t = now
        q, jac, _ = self.planner.inverse.solve_full(self.state.position)
        return JogOutput(now, self.state, q, jac @ self.state.velocity, flags, bool(expired and np.any(self._cmd)))
