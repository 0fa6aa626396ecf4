"""Braking from a moving state with the actuators' real limits, and where that stop ends.

A motion that takes over another one (a jog or a stop replacing a goto, a goto replacing a
goto) inherits its position, velocity and acceleration. The goto moved along a straight
line in pose space with that line's limits (:func:`~.pose_limits.straight_line_limits`),
which can be several times the any-direction limits a jog uses
(:func:`~.pose_limits.box_limits`). Braking such a state with the smaller limits runs past
the point where the goto itself would have stopped: out of the workspace near a face.

:func:`braking_limits` gives per-DOF limits for stopping along the current direction of
motion u = v/|v| with what the actuators allow on that line (the line limits of the path the
stop covers, never below the any-direction ones, nor below |v| and |a| now): braking each DOF
on its own with limits proportional to |u_d| from a state along u stays on the line, as the
goto's own braking would. :class:`StopProbe` gives the extent of the jerk-limited shortest
stop (each DOF to rest on its own, Ruckig's velocity interface), the check that a state can
still stop within the workspace.
"""

from __future__ import annotations

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory

from planner.model.exact_inverse import ExactInverse
from planner.model.types import KinematicsError
from planner.trajectory.actuator_limits import ActuatorLimits
from planner.trajectory.plan import MotionState, PlanError
from planner.trajectory.pose_limits import PoseLimits

__all__ = ["StopProbe", "beyond", "braking_limits", "current_floor"]

_OK = (Result.Working, Result.Finished)
_EPS = 1e-12
_POINTS = 24  # points along the braking line (as for a planned segment)


def current_floor(state: MotionState) -> PoseLimits:
    """Limits never below the state's |v| and |a| (Ruckig refuses states beyond its limits)."""
    return PoseLimits(np.abs(state.velocity) * (1 + 1e-9), np.abs(state.acceleration) * (1 + 1e-9), np.zeros(4))


def beyond(state: MotionState, limits: PoseLimits, rel_tol: float = 1e-6) -> np.ndarray:
    """Per DOF: the state moves faster or accelerates harder than ``limits`` allow, by more than
    ``rel_tol`` (Ruckig's own rounding at a limit is not "beyond"; bool (4,))."""
    return (np.abs(state.velocity) > limits.velocity * (1 + rel_tol)) | (
        np.abs(state.acceleration) > limits.acceleration * (1 + rel_tol)
    )


def braking_limits(inverse: ExactInverse, state: MotionState, limits: ActuatorLimits, floor: PoseLimits) -> PoseLimits:
    """Per-DOF limits for braking ``state`` to rest with the actuators' ``limits``.

    The actuator limits mapped onto the line along the direction of motion (of the velocity,
    or of the acceleration when at a standstill), at the state's speed, over the length the
    stop covers at most, floored by ``floor`` (the any-direction limits) and by the state's |v|
    and |a|. The length is bounded first with ``floor`` (the longest stop), then with the line
    limits found, as long as the stop they give stays within the line they were taken on
    (larger limits, a shorter stop, a shorter line, larger limits again). Without a direction
    (at rest) the floored ``floor`` itself.
    """
    v, a = np.asarray(state.velocity, float), np.asarray(state.acceleration, float)
    d = v if np.linalg.norm(v) > _EPS else a
    out = floor.floored(current_floor(state))
    n = float(np.linalg.norm(d))
    if n <= _EPS:
        return out
    u = d / n
    speed, a0 = float(np.linalg.norm(v)), float(np.linalg.norm(a))
    p = np.asarray(state.position, float)
    best, length = out, _stop_length(out, u, speed, a0)
    for _ in range(3):
        try:
            line = _line_braking(inverse, p, u, length, speed, limits)
        except KinematicsError:  # the line leaves the reachable set: a shorter one, if the stop fits it
            line, length = None, length / 2
            continue
        if line is None:
            break
        cand = line.floored(out)
        stop = _stop_length(cand, u, speed, a0)
        if stop > length * (1 + 1e-9):
            break
        best, length = cand, stop
    return best


def _stop_length(lim: PoseLimits, u: np.ndarray, speed: float, a0: float) -> float:
    """An upper bound on the path length of the jerk-limited stop from path speed ``speed`` and
    acceleration ``a0`` along ``u`` with per-DOF limits ``lim`` (their scalar share along u)."""
    au = np.abs(u)
    on = au > 1e-9
    acc = float(np.min(lim.acceleration[on] / au[on]))
    jerk = float(np.min(lim.jerk[on] / au[on]))
    ve = speed + a0 * a0 / (2 * jerk)
    return max(ve * ve / (2 * acc) + ve * acc / jerk + a0**3 / jerk**2, 1e-4)


def _line_braking(
    inverse: ExactInverse, p: np.ndarray, u: np.ndarray, length: float, speed: float, limits: ActuatorLimits
) -> PoseLimits | None:
    """Per-DOF braking limits along the line p + s·u, s in [0, length], from path speed ``speed``.

    As :func:`~.pose_limits.straight_line_limits` (actuator acceleration q'·s̈ + q''·ṡ², jerk
    q'·s⃛ + 3·q''·ṡ·s̈ + q'''·ṡ³ along the path), with the curvature terms at the actual speed:
    a brake only slows down. None when the curvature leaves nothing (the caller's floor applies).
    """
    s = np.linspace(0.0, length, _POINTS)
    g = np.array([inverse.solve(p + si * u)[1] @ u for si in s])  # q'(s), (K, 5)
    h = np.gradient(g, s, axis=0)  # q''(s)
    k = np.gradient(h, s, axis=0)  # q'''(s)
    ag, ah, ak = np.abs(g) + _EPS, np.abs(h), np.abs(k)
    vs = max(float(np.min(limits.velocity / ag)), speed)
    as_ = float(np.min((limits.acceleration - ah * speed**2) / ag))
    if as_ <= 0:
        return None
    js = float(np.min((limits.jerk - 3 * ah * speed * as_ - ak * speed**3) / ag))
    if js <= 0:
        return None
    au = np.abs(u)
    return PoseLimits(vs * au, as_ * au, js * au)


class StopProbe:
    """The jerk-limited shortest stop of a pose-space state, each DOF to rest on its own."""

    def __init__(self, dofs: int = 4):
        self._ruckig = Ruckig(dofs)
        self._input = InputParameter(dofs)
        self._input.control_interface = ControlInterface.Velocity
        self._input.synchronization = Synchronization.No
        self._input.target_velocity = [0.0] * dofs
        self._input.target_acceleration = [0.0] * dofs
        self._dofs = dofs
        self._traj = Trajectory(dofs)  # reused by :meth:`extent` (called every control cycle)

    def trajectory(
        self,
        state: MotionState,
        limits: PoseLimits,
        *,
        relative: bool = False,
        out: Trajectory | None = None,
        along_line: bool = False,
    ) -> Trajectory:
        """The stop from ``state`` (from position 0 when ``relative``) within ``limits`` (floored by |v|, |a|);
        computed into ``out`` when given (no allocation), else into a new trajectory. ``along_line``: the DOFs
        brake together, phase-synchronised (the state's v and a on one line stay on it; Ruckig falls back to
        time synchronisation otherwise) — longer in the DOFs that could stop sooner, but the actuators' mix stays
        that of the motion (each on its own they can combine beyond an actuator's limits)."""
        lim = limits.floored(current_floor(state))
        inp = self._input
        inp.synchronization = Synchronization.Phase if along_line else Synchronization.No
        inp.max_velocity = [float(max(x, 1e-9)) for x in lim.velocity]
        inp.max_acceleration = [float(max(x, 1e-9)) for x in lim.acceleration]
        inp.max_jerk = [float(max(x, 1e-9)) for x in lim.jerk]
        inp.current_position = [0.0] * self._dofs if relative else [float(x) for x in state.position]
        inp.current_velocity = [float(x) for x in state.velocity]
        inp.current_acceleration = [float(x) for x in state.acceleration]
        traj = Trajectory(self._dofs) if out is None else out
        res = self._ruckig.calculate(inp, traj)
        if res not in _OK:
            raise PlanError(f"stop could not be computed (ruckig {res})")
        return traj

    def extent(
        self, state: MotionState, limits: PoseLimits, *, along_line: bool = False
    ) -> tuple[np.ndarray, np.ndarray]:
        """Lowest and highest position per DOF the stop from ``state`` passes (absolute; ``along_line`` as
        :meth:`trajectory`).

        Computed from position 0 and shifted: Ruckig's velocity-interface extrema start
        from 0 rather than from the current position.
        """
        traj = self.trajectory(state, limits, relative=True, out=self._traj, along_line=along_line)
        ext = traj.position_extrema
        p = np.asarray(state.position, float)
        lo = np.array([min(e.min, 0.0) for e in ext]) + p
        hi = np.array([max(e.max, 0.0) for e in ext]) + p
        return lo, hi
