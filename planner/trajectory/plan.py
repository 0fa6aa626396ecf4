"""Plans and setpoints: sampling Ruckig trajectories into actuator setpoints and verifying them.

A :class:`Plan` is a chain of Ruckig trajectories in pose space (x, z, roll, pitch).
:func:`sample_plan` turns it into :class:`Setpoints` at the control rate: time, full pose,
actuators and actuator velocities, through the exact inverse at every sample.
:func:`verify_setpoints` checks every sample against every limit (strokes, top-link
angles, ground clearance, actuator velocity, and acceleration by finite differences).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from ruckig import Trajectory

from planner.errors import HitchInputError
from planner.model.exact_inverse import ExactInverse
from planner.model.hard_limits import HardLimits
from planner.model.kinematics import HitchModel
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES, POSE_NAMES, KinematicsError
from planner.trajectory.actuator_limits import ActuatorLimits

__all__ = [
    "MotionState",
    "Plan",
    "Setpoints",
    "PlanError",
    "TrajectoryInputError",
    "sample_plan",
    "verify_setpoints",
    "Violation",
]

#: ``velocity:<actuator>`` and ``acceleration:<actuator>``, order ACTUATOR_NAMES.
_VELOCITY_NAMES: tuple[str, ...] = tuple(str(LimitName("velocity", n)) for n in ACTUATOR_NAMES)
_ACCELERATION_NAMES: tuple[str, ...] = tuple(str(LimitName("acceleration", n)) for n in ACTUATOR_NAMES)


class PlanError(HitchInputError):
    """A motion that cannot be planned within the limits; the message names the limit."""


class TrajectoryInputError(HitchInputError):
    """A malformed request to the trajectory layer (speed scale, rate, goal, waypoint, jog command,
    joint-move limits); the message names the field and what is allowed.

    Not a :class:`PlanError`: the request is refused before any planning.
    """


@dataclass(frozen=True)
class MotionState:
    """Pose-space state: position, velocity, acceleration over (x, z, roll, pitch)."""

    position: np.ndarray
    velocity: np.ndarray = field(default_factory=lambda: np.zeros(4))
    acceleration: np.ndarray = field(default_factory=lambda: np.zeros(4))

    @classmethod
    def at_rest(cls, position: ArrayLike) -> MotionState:
        return cls(np.asarray(position, float).copy())

    @property
    def moving(self) -> bool:
        return bool(np.any(np.abs(self.velocity) > 1e-12) or np.any(np.abs(self.acceleration) > 1e-12))


@dataclass(frozen=True)
class Plan:
    """A chain of Ruckig trajectories; segment k starts where k−1 ends (p, v, a continuous)."""

    segments: tuple[Trajectory, ...]  # owned, not reused
    start: MotionState
    duration: float
    lower_bound: float
    #: the verified samples at the planner's rate (None for plans that were not sampled, e.g. stops)
    setpoints: Setpoints | None = field(default=None, repr=False)
    #: how the plan was made: kind, speed factor, attempts
    info: dict[str, Any] = field(default_factory=dict)

    def state_at(self, t: float) -> MotionState:
        """Pose-space state at time t (clamped to [0, duration])."""
        t = min(max(t, 0.0), self.duration)
        for seg in self.segments:
            if t <= seg.duration or seg is self.segments[-1]:
                p, v, a = seg.at_time(min(t, seg.duration))
                return MotionState(np.array(p), np.array(v), np.array(a))
            t -= seg.duration
        raise AssertionError("unreachable")  # pragma: no cover

    def sampled(self) -> Setpoints:
        """The verified samples of a planned move; :class:`PlanError` for a plan made without
        them (a stop)."""
        if self.setpoints is None:
            raise PlanError(f"this plan ({self.info.get('kind', 'unsampled')}) carries no verified setpoints")
        return self.setpoints


@dataclass(frozen=True)
class Setpoints:
    """Samples of a plan. Arrays: t (N,), pose (N, 6: x y z roll pitch yaw), pose_velocity (N, 4),
    actuators (N, 5), actuator_velocity (N, 5)."""

    rate: float
    t: np.ndarray
    pose: np.ndarray
    pose_velocity: np.ndarray
    actuators: np.ndarray
    actuator_velocity: np.ndarray

    def to_json(self) -> list[dict[str, Any]]:
        return [
            {
                "t": float(self.t[k]),
                "pose": dict(zip(POSE_NAMES, map(float, self.pose[k]), strict=True)),
                "actuators": dict(zip(ACTUATOR_NAMES, map(float, self.actuators[k]), strict=True)),
                "actuator_velocity": dict(zip(ACTUATOR_NAMES, map(float, self.actuator_velocity[k]), strict=True)),
            }
            for k in range(len(self.t))
        ]


def sample_times(duration: float, rate: float) -> np.ndarray:
    n = int(math.floor(duration * rate + 1e-9))
    t = np.arange(n + 1) / rate
    if duration - t[-1] > 1e-9:
        t = np.append(t, duration)  # the endpoint exactly
    return t


def sample_plan(plan: Plan, inverse: ExactInverse, rate: float) -> Setpoints:
    """Sample at ``rate`` [Hz] (plus the exact endpoint); IK by the closed-form inverse."""
    ts = sample_times(plan.duration, rate)
    n = len(ts)
    pose, pv = np.zeros((n, 6)), np.zeros((n, 4))
    q, qd = np.zeros((n, 5)), np.zeros((n, 5))
    for k, t in enumerate(ts):
        st = plan.state_at(t)
        try:
            qk, jac, (y, yaw) = inverse.solve_full(st.position)
        except KinematicsError as exc:
            raise PlanError(f"sample at t = {t:.3f} s is not reachable: {exc}") from None
        x, z, roll, pitch = st.position
        pose[k] = (x, y, z, roll, pitch, yaw)
        pv[k] = st.velocity
        q[k] = qk
        qd[k] = jac @ st.velocity
    return Setpoints(rate, ts, pose, pv, q, qd)


@dataclass(frozen=True)
class Violation:
    """A limit a sample exceeds: its name (``str`` of a :class:`~planner.model.limit_names.LimitName`),
    the sample time [s], the value and the bound (NaN for the hard limits, whose values differ in unit)."""

    limit: str
    t: float
    value: float
    bound: float


def verify_setpoints(
    sp: Setpoints,
    model: HitchModel,
    hard: HardLimits,
    limits: ActuatorLimits,
    *,
    rel_tol: float = 1e-6,
    check_acceleration: bool = True,
) -> list[Violation]:
    """Every limit on every sample; accelerations by forward differences of the velocities."""
    out: list[Violation] = []
    for k in range(len(sp.t)):
        q = sp.actuators[k]
        f, _ = model.features(q)
        for name in hard.violations(q, f, tol=1e-9):
            out.append(Violation(name, float(sp.t[k]), float("nan"), float("nan")))
        over = np.abs(sp.actuator_velocity[k]) > limits.velocity * (1 + rel_tol)
        for i in np.flatnonzero(over).tolist():
            out.append(
                Violation(
                    _VELOCITY_NAMES[i],
                    float(sp.t[k]),
                    float(sp.actuator_velocity[k, i]),
                    float(limits.velocity[i]),
                )
            )
    if check_acceleration and len(sp.t) >= 3:
        # forward differences: (v[k+1] − v[k]) / dt is the mean acceleration over the interval,
        # so it cannot exceed a bound the true acceleration respects
        acc = np.diff(sp.actuator_velocity, axis=0) / np.diff(sp.t)[:, None]
        allow = limits.acceleration * (1 + rel_tol)
        rows, cols = np.nonzero(np.abs(acc) > allow)
        for k, i in zip(rows.tolist(), cols.tolist(), strict=True):
            out.append(
                Violation(_ACCELERATION_NAMES[i], float(sp.t[k]), float(acc[k, i]), float(limits.acceleration[i]))
            )
    return out
