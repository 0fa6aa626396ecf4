"""The physical limit of tracking a DOF: the ideal follower with full preview, for comparisons.

Tracking one DOF sinusoidally, p_d(t) = p0_d + A·sin(ωt), asks of each actuator i the speed
|J_id|·A·ω, the acceleration |J_id|·A·ω² and the jerk |J_id|·A·ω³ (J = dq/dpose, the exact
inverse's Jacobian at the operating pose p0: the motion linearised there). A follower that knows
the whole signal in advance (full preview) needs no phase lag; the largest sine it can follow is
the requested one scaled by

    g(f) = min(1, min_i v_i / (|J_id| A ω), a_i / (|J_id| A ω²), j_i / (|J_id| A ω³)),

with the actuators' velocity, acceleration and jerk limits the planner uses
(:class:`~.actuator_limits.ActuatorLimits`). :func:`ideal_sine_gain` gives g and the binding
limit's name, :func:`ideal_bandwidth_hz` the frequency where g = 1/√2 (closed form: each term is
a power of ω). :class:`IdealFollower` is the best bounded follower of an arbitrary uniformly
sampled signal with full preview: the least-squares closest sequence whose finite-difference
velocity, acceleration and jerk keep within that DOF's limits (the tightest actuator through
|J_id|), a QP solved with one persistent OSQP instance. Guidance and levelling errors are
compared with what it achieves.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp
from numpy.typing import ArrayLike

from planner.errors import HitchError
from planner.model.limit_names import LimitName
from planner.model.types import ACTUATOR_NAMES, CONTROLLED_POSE_NAMES
from planner.trajectory.plan import TrajectoryInputError
from planner.trajectory.planner import TrajectoryPlanner

__all__ = [
    "DofLimits",
    "IdealFollow",
    "IdealFollower",
    "IdealFollowerError",
    "IdealGain",
    "dof_limits",
    "ideal_bandwidth_hz",
    "ideal_follow",
    "ideal_sine_gain",
]

_EPS = 1e-12
_KINDS = ("velocity", "acceleration", "jerk")


class IdealFollowerError(HitchError, RuntimeError):
    """The follower's QP did not solve (an internal failure, not bad input)."""


@dataclass(frozen=True)
class DofLimits:
    """One DOF's velocity, acceleration and jerk limits [unit/s, /s², /s³] at an operating pose: the
    tightest actuator's limit through |J_id|, with the names of the binding actuator limits."""

    dof: str
    pose: np.ndarray
    column: np.ndarray  # J[:, d]: d actuators / d dof, order ACTUATOR_NAMES
    velocity: float
    acceleration: float
    jerk: float
    names: tuple[str, str, str]  # "velocity:<actuator>", "acceleration:<actuator>", "jerk:<actuator>"


@dataclass(frozen=True)
class IdealGain:
    """Gain of the ideal follower for one sine (phase 0) and the limit that binds ("" when g = 1)."""

    gain: float
    limit: str
    dof: str
    amplitude: float
    frequency_hz: float


@dataclass(frozen=True)
class IdealFollow:
    """The ideal follower's output for a sampled signal (same times), its error and the limits used."""

    t: np.ndarray
    signal: np.ndarray
    x: np.ndarray
    limits: DofLimits

    @property
    def error(self) -> np.ndarray:
        return self.x - self.signal

    @property
    def rms_error(self) -> float:
        return float(np.sqrt(np.mean(self.error**2)))

    @property
    def max_error(self) -> float:
        return float(np.max(np.abs(self.error)))


def _positive(v: object, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
        raise TrajectoryInputError(f"{what} must be a finite number > 0, got {v!r}")
    return float(v)


def _dof_index(dof: object) -> int:
    if dof not in CONTROLLED_POSE_NAMES:
        raise TrajectoryInputError(f"dof must be one of {', '.join(CONTROLLED_POSE_NAMES)}, got {dof!r}")
    return CONTROLLED_POSE_NAMES.index(str(dof))


def _operating_pose(planner: TrajectoryPlanner, pose: ArrayLike | None) -> np.ndarray:
    if pose is None:  # the neutral pose, within the workspace
        return np.clip(planner.model.neutral_pose.controlled(), planner.lo, planner.hi)
    p = np.asarray(pose, float).reshape(-1)
    if p.size != 4 or not np.all(np.isfinite(p)):
        raise TrajectoryInputError("pose must be 4 finite numbers (x [m], z [m], roll [rad], pitch [rad])")
    planner.check_in_workspace(p, "pose")
    return p


def dof_limits(planner: TrajectoryPlanner, dof: str, pose: ArrayLike | None = None) -> DofLimits:
    """The limits of ``dof`` moving alone at ``pose`` (default: the neutral pose), linearised there."""
    d = _dof_index(dof)
    p = _operating_pose(planner, pose)
    col = planner.inverse.solve(p)[1][:, d]
    a = np.abs(col)
    lim = planner.limits
    vals, names = [], []
    for kind, arr in zip(_KINDS, (lim.velocity, lim.acceleration, lim.jerk), strict=True):
        with np.errstate(divide="ignore"):
            r = np.where(a > _EPS, arr / np.maximum(a, _EPS), np.inf)
        i = int(np.argmin(r))
        vals.append(float(r[i]))
        names.append(str(LimitName(kind, ACTUATOR_NAMES[i])))
    return DofLimits(str(dof), p, col.copy(), vals[0], vals[1], vals[2], (names[0], names[1], names[2]))


def ideal_sine_gain(
    planner: TrajectoryPlanner, dof: str, amplitude: float, frequency_hz: float, pose: ArrayLike | None = None
) -> IdealGain:
    """Gain of the ideal (full-preview, zero-phase) follower of A·sin(2πft) on ``dof`` at ``pose``."""
    amp = _positive(amplitude, "amplitude")
    f = _positive(frequency_hz, "frequency_hz")
    lim = dof_limits(planner, dof, pose)
    w = 2 * math.pi * f
    terms = (lim.velocity / (amp * w), lim.acceleration / (amp * w**2), lim.jerk / (amp * w**3))
    k = int(np.argmin(terms))
    if terms[k] >= 1.0:
        return IdealGain(1.0, "", str(dof), amp, f)
    return IdealGain(float(terms[k]), lim.names[k], str(dof), amp, f)


def ideal_bandwidth_hz(planner: TrajectoryPlanner, dof: str, amplitude: float, pose: ArrayLike | None = None) -> float:
    """The −3 dB frequency [Hz] of :func:`ideal_sine_gain`: where g(f) = 1/√2 (closed form)."""
    amp = _positive(amplitude, "amplitude")
    lim = dof_limits(planner, dof, pose)
    r2 = math.sqrt(2.0)
    w = min(r2 * lim.velocity / amp, math.sqrt(r2 * lim.acceleration / amp), (r2 * lim.jerk / amp) ** (1 / 3))
    return w / (2 * math.pi)


class IdealFollower:
    """The least-squares follower of a sampled signal within one DOF's finite-difference bounds.

    minimise Σ (x_k − s_k)²  subject to  |Δx/dt| ≤ v, |Δ²x/dt²| ≤ a, |Δ³x/dt³| ≤ j  (one OSQP instance,
    set up again only when the number of samples, the step or the use of position bounds changes),
    and with ``lower`` / ``upper`` given also ``lower ≤ x_k ≤ upper`` (the DOF's workspace). A signal
    within the bounds is reproduced (to the solver's tolerance); any other is followed as closely as
    the bounds allow.
    """

    def __init__(self, planner: TrajectoryPlanner, dof: str, pose: ArrayLike | None = None, *, tol: float = 1e-9):
        self.limits = dof_limits(planner, dof, pose)
        self.tol = _positive(tol, "tol")
        self._solver: Any = None
        self._key: tuple[int, float, bool] | None = None
        self._bounds = np.zeros(0)

    def follow(
        self, t: ArrayLike, x: ArrayLike, *, lower: float | None = None, upper: float | None = None
    ) -> IdealFollow:
        """The follower of samples ``x`` at uniformly spaced times ``t`` [s] (at least 4 samples), within
        the position bounds ``lower`` ≤ x ≤ ``upper`` (the DOF's unit; both or neither) when given."""
        ts = np.asarray(t, float).reshape(-1)
        xs = np.asarray(x, float).reshape(-1)
        if ts.size != xs.size or ts.size < 4:
            raise TrajectoryInputError(f"signal: t and x need the same length >= 4, got {ts.size} and {xs.size}")
        if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(xs))):
            raise TrajectoryInputError("signal: t and x must be finite numbers")
        steps = np.diff(ts)
        dt = float(np.mean(steps))
        if dt <= 0 or np.max(np.abs(steps - dt)) > 1e-6 * dt:
            raise TrajectoryInputError("signal: t must increase in uniform steps (relative spread <= 1e-6)")
        boxed = lower is not None or upper is not None
        if boxed:
            if lower is None or upper is None:
                raise TrajectoryInputError("signal: give both position bounds lower and upper, or neither")
            if not (math.isfinite(lower) and math.isfinite(upper) and lower < upper):
                raise TrajectoryInputError(f"signal: bounds must be finite with lower < upper, got {lower}, {upper}")
        import osqp  # here: only who follows a signal pays its import

        n = ts.size
        off = float(np.mean(xs)) if not boxed else float(np.clip(np.mean(xs), lower, upper))
        q = -(xs - off)
        key = (n, round(dt, 12), boxed)
        A, bound = self._constraints(n, dt)
        lo, hi = -bound, bound
        if boxed:
            assert lower is not None and upper is not None
            # position rows scaled like the rate rows (bounds of order one: OSQP converges with them active)
            k = 1.0 / max(abs(lower - off), abs(upper - off), 1e-12)
            A = sp.vstack([A, k * sp.identity(n, format="csc")], format="csc")
            lo = np.concatenate([lo, np.full(n, k * (lower - off))])
            hi = np.concatenate([hi, np.full(n, k * (upper - off))])
        if self._solver is None or key != self._key:
            self._solver = osqp.OSQP()
            self._solver.setup(
                sp.identity(n, format="csc"),
                q,
                A,
                lo,
                hi,
                eps_abs=self.tol,
                eps_rel=self.tol,
                polishing=True,
                max_iter=200000,
                verbose=False,
            )
            self._key, self._bounds = key, bound
        else:
            self._solver.update(q=q, l=lo, u=hi)
        res = self._solver.solve(raise_error=False)
        status = str(res.info.status)
        if not status.startswith("solved") or res.x is None:
            raise IdealFollowerError(f"ideal follower: the QP did not solve ({status})")
        return IdealFollow(ts, xs, np.asarray(res.x, float) + off, self.limits)

    def _constraints(self, n: int, dt: float) -> tuple[sp.csc_matrix, np.ndarray]:
        """Finite-difference rows (velocity, acceleration, jerk), each scaled to the bound 1."""
        lim = self.limits
        rows = []
        for order, bound in ((1, lim.velocity), (2, lim.acceleration), (3, lim.jerk)):
            coef = np.array([math.comb(order, i) * (-1) ** (order - i) for i in range(order + 1)], float)
            m = n - order
            D = sp.diags([np.full(m, c) for c in coef], list(range(order + 1)), shape=(m, n))
            rows.append(D / (bound * dt**order))
        A = sp.vstack(rows, format="csc")
        return A, np.ones(A.shape[0])


def ideal_follow(
    signal_t: ArrayLike,
    signal_x: ArrayLike,
    planner: TrajectoryPlanner,
    dof: str,
    pose: ArrayLike | None = None,
    *,
    workspace: bool = False,
) -> IdealFollow:
    """The best bounded follower of a sampled signal on ``dof`` with full preview (see :class:`IdealFollower`);
    with ``workspace`` also within the DOF's workspace range ``[planner.lo, planner.hi]``."""
    f = IdealFollower(planner, dof, pose)
    if not workspace:
        return f.follow(signal_t, signal_x)
    d = _dof_index(dof)
    return f.follow(signal_t, signal_x, lower=float(planner.lo[d]), upper=float(planner.hi[d]))
