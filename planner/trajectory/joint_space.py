"""Joint-space moves: time-synchronised jerk-limited Ruckig profiles for any mechanism.

Every joint starts and stops together; positions, velocities and accelerations sampled at a
rate. Used for serial arms (and for per-actuator moves of the hitch, e.g. manual mode).
Community Ruckig ignores position limits: the extrema are checked against the joint limits.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from ruckig import InputParameter, Result, Ruckig, Synchronization, Trajectory

from planner.trajectory.plan import PlanError, TrajectoryInputError, sample_times

__all__ = ["JointSamples", "plan_joint_move"]


@dataclass(frozen=True)
class JointSamples:
    """Samples of a joint-space move: duration [s], times t (N,) [s], position, velocity and
    acceleration (N, n) in joint units (rad or m) per s⁰, s¹, s²."""

    duration: float
    t: np.ndarray
    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


def plan_joint_move(
    q0, q1, *, velocity, acceleration, jerk, rate: float = 50.0, lower=None, upper=None
) -> JointSamples:
    """Rest-to-rest move q0 → q1 within per-joint limits; raises PlanError naming a violated limit."""
    q0, q1 = np.asarray(q0, float), np.asarray(q1, float)
    n = q0.size
    for name, v in (("velocity", velocity), ("acceleration", acceleration), ("jerk", jerk)):
        arr = np.broadcast_to(np.asarray(v, float), (n,))
        if not np.all(np.isfinite(arr)) or np.any(arr <= 0):
            raise TrajectoryInputError(f"{name} limits must be finite and > 0")
    if not (1.0 <= rate <= 1000.0):
        raise TrajectoryInputError(f"rate must lie within 1..1000 Hz, got {rate}")
    for name, q in (("start", q0), ("goal", q1)):
        if lower is not None and np.any(q < np.asarray(lower) - 1e-12):
            raise PlanError(f"{name} joint {int(np.argmax(np.asarray(lower) - q))} is below its limit")
        if upper is not None and np.any(q > np.asarray(upper) + 1e-12):
            raise PlanError(f"{name} joint {int(np.argmax(q - np.asarray(upper)))} is above its limit")
    r, inp, tr = Ruckig(n), InputParameter(n), Trajectory(n)
    inp.current_position, inp.target_position = list(q0), list(q1)
    inp.max_velocity = list(np.broadcast_to(velocity, (n,)).astype(float))
    inp.max_acceleration = list(np.broadcast_to(acceleration, (n,)).astype(float))
    inp.max_jerk = list(np.broadcast_to(jerk, (n,)).astype(float))
    inp.synchronization = Synchronization.Time
    if r.calculate(inp, tr) not in (Result.Working, Result.Finished):
        raise PlanError("no joint-space trajectory within the limits")
    for i, ext in enumerate(tr.position_extrema):
        if lower is not None and ext.min < lower[i] - 1e-9:
            raise PlanError(f"joint {i} would reach {ext.min:.4f} below its limit {lower[i]:.4f}")
        if upper is not None and ext.max > upper[i] + 1e-9:
            raise PlanError(f"joint {i} would reach {ext.max:.4f} above its limit {upper[i]:.4f}")
    ts = sample_times(tr.duration, rate)
    P, V, A = (np.zeros((len(ts), n)) for _ in range(3))
    for k, t in enumerate(ts):
        p, v, a = tr.at_time(t)
        P[k], V[k], A[k] = p, v, a
    return JointSamples(tr.duration, ts, P, V, A)
