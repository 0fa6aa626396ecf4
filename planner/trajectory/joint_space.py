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


def _joint_vector(name: str, value: object, n: int | None, *, infinite: bool = False) -> np.ndarray:
    """``value`` as a 1-D float vector of finite numbers (``n`` of them when given; ``infinite``: ±inf allowed, a
    joint limit that is not there); TrajectoryInputError naming ``name`` otherwise."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrajectoryInputError(f"{name} must be a vector of numbers, got {value!r}") from exc
    if arr.ndim != 1 or arr.size == 0 or (n is not None and arr.size != n):
        want = "a non-empty vector" if n is None else f"{n} values (one per joint of the start)"
        raise TrajectoryInputError(f"{name} must be {want}, got shape {arr.shape}")
    bad = np.flatnonzero(np.isnan(arr) if infinite else ~np.isfinite(arr))
    if bad.size:
        what = "a number (±inf: no limit)" if infinite else "a finite number"
        raise TrajectoryInputError(f"{name}[{bad[0]}] must be {what}, got {arr[bad[0]]}")
    return arr


def _per_joint(name: str, value: object, n: int) -> np.ndarray:
    """A limit given once for every joint or per joint, finite and > 0."""
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise TrajectoryInputError(f"{name} limits must be numbers, got {value!r}") from exc
    if arr.ndim > 1 or (arr.ndim == 1 and arr.size != n):
        raise TrajectoryInputError(f"{name} limits must be one number or {n} (one per joint), got shape {arr.shape}")
    arr = np.broadcast_to(arr, (n,)).astype(float)
    bad = np.flatnonzero(~(np.isfinite(arr) & (arr > 0)))
    if bad.size:
        raise TrajectoryInputError(f"{name} limit of joint {bad[0]} must be finite and > 0, got {arr[bad[0]]}")
    return arr


def plan_joint_move(
    q0, q1, *, velocity, acceleration, jerk, rate: float = 50.0, lower=None, upper=None
) -> JointSamples:
    """Rest-to-rest move ``q0`` → ``q1`` (joint units: rad or m) within per-joint ``velocity`` [/s],
    ``acceleration`` [/s²] and ``jerk`` [/s³] limits (one number for all joints or one per joint), sampled at
    ``rate`` [Hz]; ``lower`` / ``upper`` (optional, one per joint): the joint limits the start, the goal and the
    whole move must keep (Ruckig does not: its extrema are checked here).

    Raises TrajectoryInputError for bad input (naming the argument, the joint and the value) and PlanError
    naming the joint, the value and the limit it would pass."""
    q0 = _joint_vector("start", q0, None)
    n = q0.size
    q1 = _joint_vector("goal", q1, n)
    v_max, a_max, j_max = (
        _per_joint(k, v, n) for k, v in (("velocity", velocity), ("acceleration", acceleration), ("jerk", jerk))
    )
    if isinstance(rate, bool) or not isinstance(rate, (int, float)) or not (1.0 <= rate <= 1000.0):
        raise TrajectoryInputError(f"rate must lie within 1..1000 Hz, got {rate!r}")
    lo = None if lower is None else _joint_vector("lower", lower, n, infinite=True)
    hi = None if upper is None else _joint_vector("upper", upper, n, infinite=True)
    if lo is not None and hi is not None and np.any(lo > hi):
        i = int(np.argmax(lo > hi))
        raise TrajectoryInputError(f"joint {i}: lower limit {lo[i]:g} is above its upper limit {hi[i]:g}")
    for name, q in (("start", q0), ("goal", q1)):
        for i in range(n):
            if lo is not None and q[i] < lo[i] - 1e-12:
                raise PlanError(
                    f"{name} joint {i} = {q[i]:.6g} is below its limit {lo[i]:.6g} (allowed [{lo[i]:.6g}, "
                    f"{'inf' if hi is None else format(hi[i], '.6g')}])"
                )
            if hi is not None and q[i] > hi[i] + 1e-12:
                raise PlanError(
                    f"{name} joint {i} = {q[i]:.6g} is above its limit {hi[i]:.6g} (allowed ["
                    f"{'-inf' if lo is None else format(lo[i], '.6g')}, {hi[i]:.6g}])"
                )
    r, inp, tr = Ruckig(n), InputParameter(n), Trajectory(n)
    inp.current_position, inp.target_position = q0.tolist(), q1.tolist()
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = v_max.tolist(), a_max.tolist(), j_max.tolist()
    inp.synchronization = Synchronization.Time
    try:
        result = r.calculate(inp, tr)
    except (RuntimeError, ValueError) as exc:  # Ruckig's own errors (and results its enum does not know)
        text = str(exc).splitlines()[0]
        if text.startswith("-101 "):  # Ruckig's ErrorTrajectoryDuration (not in the Python enum)
            text = "the move would last longer than Ruckig's numerical limit (limits far too small for the distance?)"
        raise PlanError(f"no joint-space trajectory within the limits (Ruckig: {text})") from exc
    if result not in (Result.Working, Result.Finished):
        raise PlanError(f"no joint-space trajectory within the limits (Ruckig: {result})")
    for i, ext in enumerate(tr.position_extrema):
        if lo is not None and ext.min < lo[i] - 1e-9:
            raise PlanError(f"joint {i} would reach {ext.min:.4f} below its limit {lo[i]:.4f}")
        if hi is not None and ext.max > hi[i] + 1e-9:
            raise PlanError(f"joint {i} would reach {ext.max:.4f} above its limit {hi[i]:.4f}")
    ts = sample_times(tr.duration, rate)
    P, V, A = (np.zeros((len(ts), n)) for _ in range(3))
    for k, t in enumerate(ts):
        p, v, a = tr.at_time(t)
        P[k], V[k], A[k] = p, v, a
    return JointSamples(tr.duration, ts, P, V, A)
