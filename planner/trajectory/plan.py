"""Plans and setpoints: sampling Ruckig trajectories into actuator setpoints and verifying them.

A :class:`Plan` is a chain of Ruckig trajectories in pose space (x, z, roll, pitch).
:func:`sample_plan` turns it into :class:`Setpoints` at the control rate: time, full pose,
actuators and actuator velocities, through the exact inverse at every sample.
:func:`verify_setpoints` checks every sample against every limit (strokes, top-link
angles, ground clearance, actuator velocity, and acceleration by finite differences).
"""

from __future__ import annotations

import itertools
import math
import threading
import weakref
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from ruckig import Trajectory

from planner.errors import HitchInputError, distinct_texts
from planner.model.exact_inverse import ExactInverse
from planner.model.fast_function import MappedFunction
from planner.model.hard_limits import STROKE_NAMES, HardLimits
from planner.model.kinematics import FEATURE_NAMES, POINT_NAMES, HitchModel
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES, POSE_NAMES, KinematicsError, ModelInputError
from planner.trajectory.actuator_limits import ActuatorLimits

__all__ = [
    "MotionState",
    "check_state",
    "Plan",
    "Setpoints",
    "PlanError",
    "TrajectoryInputError",
    "sample_plan",
    "verify_setpoints",
    "Violation",
    "ForwardBatch",
    "forward_batch",
    "plan_states",
]

#: ``velocity:<actuator>`` and ``acceleration:<actuator>``, order ACTUATOR_NAMES.
_VELOCITY_NAMES: tuple[str, ...] = tuple(str(LimitName("velocity", n)) for n in ACTUATOR_NAMES)
_ACCELERATION_NAMES: tuple[str, ...] = tuple(str(LimitName("acceleration", n)) for n in ACTUATOR_NAMES)
_JERK_NAMES: tuple[str, ...] = tuple(str(LimitName("jerk", n)) for n in ACTUATOR_NAMES)
#: closure residual [m] a batch row must keep to be trusted without the per-sample check (that one refuses > 1e-9)
_FK_CLOSED_M = 0.5e-9


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
        """At rest at ``position`` (x [m], z [m], roll [rad], pitch [rad]); :class:`TrajectoryInputError`
        for anything but 4 finite numbers (a 6-value pose or a NaN was taken, and failed deep in planning)."""
        try:
            p = np.array(position, dtype=float).reshape(-1)
        except (TypeError, ValueError):
            raise TrajectoryInputError(
                f"position must be 4 numbers (x, z, roll, pitch), got {type(position).__name__}"
            ) from None
        if p.shape != (4,) or not np.all(np.isfinite(p)):
            raise TrajectoryInputError(f"position must be 4 finite numbers (x, z, roll, pitch), got {p.tolist()}")
        return cls(p)

    def check(self, what: str = "state") -> MotionState:
        """This state if position, velocity and acceleration are each 4 finite numbers, else
        :class:`TrajectoryInputError` naming the first that is not (a NaN velocity reached Ruckig)."""
        for name in ("position", "velocity", "acceleration"):
            a = getattr(self, name)
            if not isinstance(a, np.ndarray) or a.shape != (4,) or not np.all(np.isfinite(a)):
                shown = a.tolist() if isinstance(a, np.ndarray) else repr(a)
                raise TrajectoryInputError(f"{what}.{name} must be 4 finite numbers (x, z, roll, pitch), got {shown}")
        return self

    @property
    def moving(self) -> bool:
        return bool(np.any(np.abs(self.velocity) > 1e-12) or np.any(np.abs(self.acceleration) > 1e-12))


def check_state(state: object, what: str = "state", *, values: bool = True) -> MotionState:
    """``state`` if it is a :class:`MotionState` (with ``values``: whose arrays pass :meth:`MotionState.check`),
    else :class:`TrajectoryInputError` naming ``what`` (a mapping or an array given for it failed as "'dict' object
    has no attribute 'check'"). ``values=False`` for a per-cycle path (the check costs ~8 µs) that refuses a NaN
    further on anyway."""
    if not isinstance(state, MotionState):
        raise TrajectoryInputError(
            f"{what} must be a MotionState (MotionState.at_rest([x, z, roll, pitch]) for one at rest), "
            f"got {type(state).__name__}"
        )
    return state.check(what) if values else state


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
        """Pose-space state at time t [s] (clamped to [0, duration]); :class:`TrajectoryInputError` for a NaN or
        a non-number (a NaN went on to Ruckig's ``at_time``, which crashed the interpreter)."""
        if t != t or isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)):
            raise TrajectoryInputError(f"t must be a number of seconds, got {t!r}")
        t = min(max(float(t), 0.0), self.duration)
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


def plan_states(plan: Plan, ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Positions and velocities (N, 4) of ``plan`` at times ``ts`` (N,): :meth:`Plan.state_at`
    of every time, without building a state per sample.

    A plan of one segment without brake or acceleration pre-profiles is evaluated from its
    jerk-limited profiles for all times at once, as Ruckig's ``at_time`` integrates them
    (p + t (v + t (a/2 + t j/6)), same operations, so the same values); times at or past a
    profile's end go through ``at_time``.
    """
    if np.isnan(ts).any():  # Ruckig's at_time crashes on NaN
        raise TrajectoryInputError("times must be numbers of seconds, got NaN")
    tt = np.minimum(np.maximum(ts, 0.0), plan.duration)  # as state_at clamps
    if len(plan.segments) == 1:
        states = _profile_states(plan.segments[0], tt)
        if states is not None:
            return states
    segs = plan.segments
    durations = [s.duration for s in segs]
    states_list = []
    last = len(segs) - 1
    for t in tt.tolist():
        for i, seg in enumerate(segs):  # as state_at: the first segment that holds t
            if t <= durations[i] or i == last:
                states_list.append(seg.at_time(min(t, durations[i])))
                break
            t -= durations[i]
    return _stack(states_list, len(tt))


def _stack(states: list, n: int) -> tuple[np.ndarray, np.ndarray]:
    flat = itertools.chain.from_iterable(itertools.chain.from_iterable(states))  # (p, v, a) of 4 each
    arr = np.fromiter(flat, float, 12 * n).reshape(n, 3, 4)
    return arr[:, 0].copy(), arr[:, 1].copy()


def _profile_states(traj: Trajectory, tt: np.ndarray) -> tuple[np.ndarray, np.ndarray] | None:
    """States of a one-section trajectory at times ``tt`` (within its duration) from its
    profiles; None when a profile has a brake or acceleration pre-profile (``at_time`` then)."""
    sections = traj.profiles
    if len(sections) != 1 or len(sections[0]) != 4:
        return None
    d = traj.duration
    n = len(tt)
    pos, vel = np.empty((n, 4)), np.empty((n, 4))
    late = np.zeros(n, bool)
    for dof, pr in enumerate(sections[0]):
        pre = [getattr(pr, name, None) for name in ("brake", "accel")]
        if any(b is None or b.duration != 0.0 for b in pre) or len(pr.t) != 7:
            return None
        t_sum, acc = [], 0.0
        for t in pr.t:  # Ruckig's cumulative phase times
            acc += t
            t_sum.append(acc)
        idx = np.searchsorted(t_sum, tt, side="right")  # std::upper_bound
        late |= tt >= t_sum[6]
        idx = np.minimum(idx, 6)
        t_diff = np.where(idx > 0, tt - np.array([0.0, *t_sum])[idx], tt)
        p0, v0, a0, j = (np.asarray(x, float)[idx] for x in (pr.p, pr.v, pr.a, pr.j))
        pos[:, dof] = p0 + t_diff * (v0 + t_diff * (a0 / 2 + t_diff * j / 6))
        vel[:, dof] = v0 + t_diff * (a0 + t_diff * j / 2)
    late |= tt >= d
    for k in np.flatnonzero(late).tolist():  # the end (and a profile ending before it)
        p, v, _ = traj.at_time(min(float(tt[k]), d))
        pos[k], vel[k] = p, v
    return pos, vel


def sample_plan(plan: Plan, inverse: ExactInverse, rate: float) -> Setpoints:
    """Sample at ``rate`` [Hz] (plus the exact endpoint); IK by the closed-form inverse.

    All samples in one mapped evaluation of the inverse (:meth:`ExactInverse.solve_batch`);
    a sample it cannot solve is refused with the reason :meth:`ExactInverse.solve_full` gives.
    """
    ts = sample_times(plan.duration, rate)
    pos, vel = plan_states(plan, ts)
    inv = inverse.solve_batch(pos, vel)
    q, qd, y, yaw = inv.actuators, inv.actuator_velocity, inv.y, inv.yaw
    for k in np.flatnonzero(~inv.ok).tolist():  # in time order: the first unreachable sample refuses
        try:
            qk, jac, (yk, yawk) = inverse.solve_full(pos[k])
        except KinematicsError as exc:
            raise PlanError(f"sample at t = {ts[k]:.3f} s is not reachable: {exc}") from None
        q[k], qd[k], y[k], yaw[k] = qk, jac @ vel[k], yk, yawk
    pose = np.column_stack([pos[:, 0], y, pos[:, 1], pos[:, 2], pos[:, 3], yaw])
    return Setpoints(rate, ts, pose, vel, q, qd)


class ForwardBatch:
    """Forward kinematics of many actuator rows through the model's mapped points function,
    the values of :meth:`HitchModel.forward` / :meth:`HitchModel.features`, bit for bit.

    The last result is kept: the planner's verification and the guard evaluate the same
    samples once. The arrays returned are read-only. One instance serves every planner and
    guard of a model (:func:`forward_batch`): calls are serialised.
    """

    def __init__(self, model: HitchModel):
        self._map = MappedFunction(model.points_function, compiled=True)
        self._key: bytes | None = None
        self._value: tuple[np.ndarray, np.ndarray, np.ndarray] = (np.empty(0), np.empty(0), np.empty(0))
        self._lock = threading.Lock()

    def __call__(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """For actuator rows ``q`` (N, 5): features (N, 11, order FEATURE_NAMES), points
        (N, 3, len(POINT_NAMES)) [m] and the closure checks (N, 5) (4 residuals [m], reach)."""
        q = np.ascontiguousarray(q, dtype=float)
        if q.ndim != 2 or q.shape[1] != len(ACTUATOR_NAMES):
            raise ModelInputError(f"actuators: expected rows of 5 values ({', '.join(ACTUATOR_NAMES)}), got {q.shape}")
        key = q.tobytes() + bytes(str(q.shape), "ascii")
        with self._lock:
            if key != self._key:
                f, pm, _, checks = self._map(q.T)
                pts = pm.reshape(3, len(POINT_NAMES), len(q), order="F").transpose(2, 0, 1)
                value = (f.T.copy(), np.ascontiguousarray(pts), checks.T.copy())
                for a in value:
                    a.setflags(write=False)
                self._key, self._value = key, value
            return self._value


_FORWARD: weakref.WeakKeyDictionary[HitchModel, ForwardBatch] = weakref.WeakKeyDictionary()
_FORWARD_LOCK = threading.Lock()


def forward_batch(model: HitchModel) -> ForwardBatch:
    """The (shared) :class:`ForwardBatch` of ``model``."""
    with _FORWARD_LOCK:
        fb = _FORWARD.get(model)
        if fb is None:
            fb = _FORWARD[model] = ForwardBatch(model)
        return fb


@dataclass(frozen=True)
class Violation:
    """A limit a sample exceeds: its name (``str`` of a :class:`~planner.model.limit_names.LimitName`),
    the sample time [s], the value and the bound, in the limit's own unit (:attr:`unit`)."""

    limit: str
    t: float
    value: float
    bound: float

    @property
    def unit(self) -> str:
        """SI unit of ``value`` and ``bound``: the lift and the top-link angles in rad, the other strokes and
        the ground clearance in m; rates per s, s², s³."""
        angle = self.limit.startswith(("stroke:lift", "top_link", "velocity:lift", "acceleration:lift", "jerk:lift"))
        base = "rad" if angle else "m"
        if self.limit.startswith("velocity:"):
            return base + "/s"
        if self.limit.startswith("jerk:"):
            return base + "/s³"
        return base + "/s²" if self.limit.startswith("acceleration:") else base

    def sentence(self) -> str:
        """``top_link_yaw_min = -0.3012 rad against its bound -0.3 rad at t = 5.92 s``: what a refusal says (it
        named the limit and the time only, not the value or the bound: a commissioning trial). A rate limit is a
        bound on the magnitude: ``|velocity:lift| = 0.2 rad/s against its bound 0.15 rad/s``. The two numbers
        are printed with the digits that tell them apart."""
        rate = self.limit.startswith(("velocity:", "acceleration:", "jerk:"))
        value = abs(self.value) if rate else self.value
        shown, bound = distinct_texts(value, self.bound)
        name = f"|{self.limit}|" if rate else self.limit
        return f"{name} = {shown} {self.unit} against its bound {bound} {self.unit} at t = {self.t:.2f} s"


#: relative tolerance of the mean velocity between samples over the limit (a plan's own is ≤ 1 + 1e-6: the excess
#: of a sampled exact trajectory between its samples; 800 plans and re-plans: at most 8.5e-7)
_MEAN_RATE_TOL = 1e-5


def verify_setpoints(
    sp: Setpoints,
    model: HitchModel,
    hard: HardLimits,
    limits: ActuatorLimits,
    *,
    rel_tol: float = 1e-6,
    check_acceleration: bool = True,
    mean_rates: bool = True,
    check_jerk: bool = False,
) -> list[Violation]:
    """Every limit on every sample; velocities also by forward differences of the positions (the mean velocity
    over each interval: samples made elsewhere are judged by their positions, not only by their velocity column),
    accelerations by forward differences of the velocities. ``mean_rates=False``: the samples are poses the
    hitch rests at one after another, not a trajectory (no velocity between them is judged).

    ``check_jerk``: also the actuators' jerk, by second divided differences of the sampled velocities,
    ``j_k = 2 (v[t_k+1, t_k+2] − v[t_k, t_k+1]) / (t_k+2 − t_k)`` with ``v[a, b]`` the mean acceleration between two
    samples. For a velocity with a continuous derivative (the acceleration; a jerk-limited trajectory mapped through
    the smooth inverse) the divided difference is a mean of the jerk over [t_k, t_k+2] weighted by a positive kernel
    of unit integral (Peano), so it never exceeds the largest |jerk| there: a sample over the limit is a real excess
    (at 50 Hz it can miss a short one). Stamped with the middle sample's time.

    The forward kinematics of all samples in one mapped evaluation (:func:`forward_batch`);
    a sample whose mechanism might not close is evaluated alone (:meth:`HitchModel.features`
    raises as for any sample).
    """
    out: list[Violation] = []
    Q = np.asarray(sp.actuators, float)
    n = len(sp.t)
    F = np.empty((n, len(FEATURE_NAMES)))
    if n:
        f_b, _, checks = forward_batch(model)(Q)
        F[:] = f_b
        with np.errstate(invalid="ignore"):
            sure = (
                np.isfinite(Q).all(axis=1)
                & (np.abs(checks[:, :4]) <= _FK_CLOSED_M).all(axis=1)
                & (np.abs(checks[:, 4]) <= 1.0)
                & np.isfinite(f_b).all(axis=1)
            )
        for k in np.flatnonzero(~sure).tolist():  # in time order: the first failing sample raises
            F[k] = model.features(Q[k])[0]
    tol = 1e-9  # as HardLimits.violations
    with np.errstate(invalid="ignore"):
        q_lo = Q < hard.actuator_lower - tol
        q_hi = ~q_lo & (Q > hard.actuator_upper + tol)
        Fl = F[:, list(hard.feature_index)]
        f_lo = Fl < hard.feature_lower - tol
        f_hi = ~f_lo & (Fl > hard.feature_upper + tol)
        over = np.abs(sp.actuator_velocity) > limits.velocity * (1 + rel_tol)
    hard_any = q_lo.any(axis=1) | q_hi.any(axis=1) | f_lo.any(axis=1) | f_hi.any(axis=1)
    for k in np.flatnonzero(hard_any | over.any(axis=1)).tolist():  # per sample: hard limits, then velocity
        t = float(sp.t[k])
        out += [
            Violation(STROKE_NAMES[i][0], t, float(Q[k, i]), float(hard.actuator_lower[i]))
            if q_lo[k, i]
            else Violation(STROKE_NAMES[i][1], t, float(Q[k, i]), float(hard.actuator_upper[i]))
            for i in range(Q.shape[1])
            if q_lo[k, i] or q_hi[k, i]
        ]
        out += [
            Violation(hard.names_lower[i], t, float(Fl[k, i]), float(hard.feature_lower[i]))
            if f_lo[k, i]
            else Violation(hard.names_upper[i], t, float(Fl[k, i]), float(hard.feature_upper[i]))
            for i in range(Fl.shape[1])
            if f_lo[k, i] or f_hi[k, i]
        ]
        for i in np.flatnonzero(over[k]).tolist():
            out.append(Violation(_VELOCITY_NAMES[i], t, float(sp.actuator_velocity[k, i]), float(limits.velocity[i])))
    if mean_rates and len(sp.t) >= 2:
        # the positions themselves: (q[k+1] − q[k]) / dt is the mean velocity over the interval, so it cannot
        # exceed a bound the true velocity respects; setpoints made elsewhere whose velocity column does not match
        # their positions (a jump 70 × the limit with zero velocity passed: a user's trial) are judged by it. Each
        # is stamped with its interval's start, as the accelerations are; a NaN rate (bad times) is over
        with np.errstate(invalid="ignore", divide="ignore"):
            rate = np.diff(Q, axis=0) / np.diff(np.asarray(sp.t, float))[:, None]
            fast = ~(np.abs(rate) <= limits.velocity * (1 + _MEAN_RATE_TOL))
        for k, i in zip(*(a.tolist() for a in np.nonzero(fast)), strict=True):
            out.append(Violation(_VELOCITY_NAMES[i], float(sp.t[k]), float(rate[k, i]), float(limits.velocity[i])))
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
    if check_jerk:
        out += jerk_violations(sp.t, sp.actuator_velocity, limits, rel_tol)
    return out


def jerk_violations(
    t: np.ndarray, actuator_velocity: np.ndarray, limits: ActuatorLimits, rel_tol: float = 1e-6
) -> list[Violation]:
    """The actuators' jerk beyond ``limits.jerk`` by second divided differences of their velocities (N, 5) at
    times ``t`` (N,) [s] (:func:`verify_setpoints`, ``check_jerk``): a lower bound of the largest |jerk| over each
    window [t_k, t_k+2], stamped with the middle sample's time; rows with a non-finite velocity are skipped."""
    ts = np.asarray(t, float)
    qd = np.asarray(actuator_velocity, float)
    if len(ts) < 3:
        return []
    with np.errstate(invalid="ignore"):
        acc = np.diff(qd, axis=0) / np.diff(ts)[:, None]
        jerk = 2.0 * np.diff(acc, axis=0) / (ts[2:] - ts[:-2])[:, None]
        over = np.abs(jerk) > limits.jerk * (1 + rel_tol)  # NaN (a row the inverse could not solve): not judged
    rows, cols = np.nonzero(over)
    return [
        Violation(_JERK_NAMES[i], float(ts[k + 1]), float(jerk[k, i]), float(limits.jerk[i]))
        for k, i in zip(rows.tolist(), cols.tolist(), strict=True)
    ]
