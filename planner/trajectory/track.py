"""Track mode: streamed pose setpoints followed with jerk-limited motion, re-targeted every control cycle.

A client streams setpoints (pose, optionally pose velocity) at up to 100 Hz; every control
cycle (``1/planner.rate``) :meth:`TrackFollower.step` re-targets Ruckig as an online
generator from the current position, velocity and acceleration: position interface, the
target the latest setpoint (extrapolated with its velocity, acceleration and jerk to the cycle's
time) clipped to the workspace, its velocity clipped to the pose velocity limits and capped near a
face so that a jerk-limited stop from it still fits before the face. A tracked DOF that can meet the
setpoint's own motion on time moves on that rendezvous (``TrackFollower._rendezvous``: a stream
within the limits is followed without lag), else time-optimally towards the cycle's target. Each
tracked DOF moves on its own (no synchronisation) within the *subset limits* (:func:`subset_limits`): the largest
per-DOF limits the actuators allow for any combination of the DOFs that move (the tracked ones,
and untracked ones still braking from a take-over) anywhere in the workspace range of those DOFs
(the others where they are); untracked DOFs brake to rest (they hold their start value when the
follower starts at rest) and then hold still. So a session tracking fewer DOFs is not bound by the
any-direction limits over all four (about half of what one DOF alone may do). The limits hold for
the whole session (computed once, again only when an untracked DOF came to rest: then they grow),
so the Jacobian's change from cycle to cycle is covered by construction.

Safety follows :class:`~.jog.JogController`: a DOF moving faster or accelerating harder than
the subset limits (a take-over of a full-speed goto) brakes with the actuators' real limits along
the current motion (:func:`~.braking.braking_limits`) to the pose speed limit (towards its
target) or to rest (away from it); and every cycle the state one cycle ahead must still be
able to stop within the workspace (:class:`~.braking.StopProbe`), else that DOF brakes now: with
the subset limits (the state now passed that check one cycle ago), after a take-over with the real
limits until a state can stop within the subset limits again (computed once per braking episode).

Staleness: when no setpoint arrived within ``ttl_s`` the follower brakes to rest
(``stale=True``) and stays latched: a later setpoint is refused (:class:`TrackStateError`)
unless the follower was built with ``resume_after_stale=True`` or the caller calls
:meth:`TrackFollower.resume` (the policy is the caller's; the motion controller ends the
session instead). :meth:`TrackFollower.stop` brakes to rest the same way, :attr:`TrackFollower.finished`
once at rest. Braking to rest uses the planned stop's limits (:meth:`~.planner.TrajectoryPlanner.plan_stop`: the
any-direction limits, or the real braking limits along the motion when the state moves beyond them
or that stop would leave the workspace), so a stale stream stops as a planned stop would.

Sequence numbers are the service's business; :class:`SeqFilter` is the pure rule it uses
(strictly increasing per session, the others counted and ignored).
"""

from __future__ import annotations

import itertools
import math
import statistics
from collections import deque
from collections.abc import Collection, Mapping
from dataclasses import dataclass, field

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, RuckigError, Synchronization, Trajectory

from planner.errors import HitchError
from planner.model.exact_inverse import ExactInverse
from planner.model.hard_limits import WORKSPACE_NAMES
from planner.model.limit_names import LimitName
from planner.model.types import CONTROLLED_POSE_NAMES, CONTROLLED_POSE_UNITS, KinematicsError
from planner.trajectory.actuator_limits import ActuatorLimits
from planner.trajectory.braking import StopProbe, beyond, current_floor
from planner.trajectory.plan import MotionState, PlanError, TrajectoryInputError
from planner.trajectory.planner import TrajectoryPlanner
from planner.trajectory.pose_limits import PoseLimits

__all__ = [
    "SeqFilter",
    "SEQ_AHEAD",
    "SEQ_AHEAD_PER_S",
    "TrackError",
    "TrackFollower",
    "TrackInputError",
    "TrackOutput",
    "TrackSetpoint",
    "TrackStateError",
    "TrackBounds",
    "TRACK_DOFS",
    "SUBSET_GRID",
    "SUBSET_MARGIN",
    "subset_limits",
]

#: The DOFs a track session may follow (SI: m, m, rad, rad).
TRACK_DOFS = CONTROLLED_POSE_NAMES
#: Setpoints further than this outside the workspace [m or rad] are not plausible SI values (mm, deg).
PLAUSIBLE_MARGIN = 0.5
#: Largest plausible setpoint velocity [m/s or rad/s]; below it a velocity is clipped to the limits.
PLAUSIBLE_VELOCITY = 1.0
#: Largest plausible setpoint acceleration [m/s² or rad/s²]; below it clipped to the limits.
PLAUSIBLE_ACCELERATION = 10.0
#: Largest plausible setpoint jerk [m/s³ or rad/s³]; below it clipped to the limits.
PLAUSIBLE_JERK = 100.0
_OK = (Result.Working, Result.Finished)
_VELOCITY_NAMES = tuple(str(LimitName("velocity", k)) for k in CONTROLLED_POSE_NAMES)
_POS, _VEL = ControlInterface.Position, ControlInterface.Velocity
#: Grid points per active DOF over its workspace range on which the Jacobian is sampled (1-2 DOFs / 3-4).
SUBSET_GRID = (5, 3)
#: Share of the actuator limits the subset limits use: room for what the bound leaves out (the
#: second-order change of the Jacobian between grid points, the third derivative of the inverse in
#: the jerk).
SUBSET_MARGIN = 0.95
_REL = 1e-6  # Ruckig's rounding at a limit (as braking.beyond)
#: The rendezvous times with a setpoint's own motion the follower tries, in control cycles from the
#: current state, shortest first (``TrackFollower._rendezvous``): one cycle, then up to 8 (0.16 s at 50 Hz).
RENDEZVOUS_CYCLES = (1, 2, 3, 4, 6, 8)
#: a setpoint is extrapolated with its velocity for at most this many of the stream's own intervals (the median
#: of the last :data:`_INTERVALS_KEPT`), at least two control periods and at most ``ttl_s``; a setpoint older than
#: that is late: the target rests where the extrapolation got to. Without the bound a stream that died ran on
#: along its last velocity for the whole time-to-live before braking (+47 mm at 0.04 m/s with ttl 1 s, +85 mm at
#: 0.08 m/s: a new user's report)
EXTRAPOLATION_INTERVALS = 3.0
#: the bound before the stream's interval is known (one setpoint so far) [s]
FIRST_EXTRAPOLATION_S = 0.1
_INTERVALS_KEPT = 8
#: how far a follower's shortest stop may pass the demand's before it brakes (:meth:`TrackFollower._passes_demand`)
#: [m or rad]: Ruckig's round-off, far below a sensor count
DEMAND_TOLERANCE = 1e-5


def subset_limits(
    inverse: ExactInverse,
    pose: np.ndarray,
    active: np.ndarray,
    limits: ActuatorLimits,
    lo: np.ndarray,
    hi: np.ndarray,
    margin: float = SUBSET_MARGIN,
) -> PoseLimits | None:
    """Per-DOF pose limits for any combination of the ``active`` DOFs moving anywhere in [lo, hi]
    (the other DOFs at rest where ``pose`` has them); None when the curvature leaves no room (the
    caller keeps the any-direction limits). Inactive DOFs get 0 (the caller fills them).

    The exact inverse's Jacobian G = ∂q/∂p (5 actuators × the active DOFs) is sampled on a grid
    over the active DOFs' ranges (:data:`SUBSET_GRID` points each, all combinations); ḡ_id = the
    largest |G_id| there plus half the largest change between neighbouring grid points (the
    first-order variation within a cell), H̄_ide the largest |ΔG_id/Δp_e| between neighbours.
    Velocity: each DOF alone v_d⁰ = min_i v̂_i/ḡ_id, all of them scaled by
    κ = min(1, min_i v̂_i/Σ_d ḡ_id·v_d⁰), so Σ_d ḡ_id·|ṗ_d| ≤ v̂_i for every actuator i in any
    combination (one DOF: κ = 1, the tightest actuator through its Jacobian column, as the ideal
    follower). Acceleration q̈ = G·p̈ + H(ṗ, ṗ): a_d = ρ·v_d with Σ_d ḡ_id·a_d + Σ_de H̄_ide·v_d·v_e
    ≤ â_i; jerk q⃛ = G·p⃛ + 3H(ṗ, p̈) + …: j_d = σ·a_d with Σ_d ḡ_id·j_d + 3Σ_de H̄_ide·v_d·a_e ≤ ĵ_i;
    v̂, â, ĵ the actuator limits × ``margin``.
    """
    p = np.asarray(pose, float)
    idx = np.flatnonzero(active)
    n = len(idx)
    k = SUBSET_GRID[0] if n <= 2 else SUBSET_GRID[1]
    axes = [np.linspace(lo[e], hi[e], k) for e in idx.tolist()]
    grid = np.empty((k,) * n + (5, n))
    for ij in itertools.product(range(k), repeat=n):
        q = p.copy()
        q[idx] = [axes[m][j] for m, j in enumerate(ij)]
        grid[ij] = inverse.solve(q)[1][:, idx]
    flat = np.abs(grid.reshape(-1, 5, n))
    step = np.zeros((5, n))
    h = np.zeros((5, n, n))  # h[i, d, e] ≥ |∂G_id / ∂p_e|
    for m in range(n):
        dg = np.abs(np.diff(grid, axis=m)).reshape(-1, 5, n).max(axis=0)
        step = np.maximum(step, dg)
        h[:, :, m] = dg / (axes[m][1] - axes[m][0])
    g = flat.max(axis=0) + 0.5 * step + 1e-12
    vmax, amax, jmax = limits.velocity * margin, limits.acceleration * margin, limits.jerk * margin
    axis = np.min(vmax[:, None] / g, axis=0)
    v = axis * min(1.0, float(np.min(vmax / (g @ axis))))
    room_a = amax - np.einsum("ide,d,e->i", h, v, v)
    if np.any(room_a <= 0):
        return None
    acc = v * float(np.min(room_a / (g @ v)))
    room_j = jmax - 3 * np.einsum("ide,d,e->i", h, v, acc)
    if np.any(room_j <= 0):
        return None
    jerk = acc * float(np.min(room_j / (g @ acc)))
    out = [np.zeros(4), np.zeros(4), np.zeros(4)]
    for arr, val in zip(out, (v, acc, jerk), strict=True):
        arr[idx] = val
    return PoseLimits(*out)


@dataclass(frozen=True)
class TrackBounds:
    """Bounds of a session beyond the workspace (an implement's, :mod:`planner.limits.implement_limits`):
    ``z_max_m`` [m] lowers the workspace's upper z face (setpoints above it are clipped, flagged
    ``z_max_name``; a session starting above it may only go down to it), ``z_descent_m_s`` [m/s]
    bounds the downward z velocity (Ruckig's ``min_velocity``; setpoint velocities below it are
    clipped, flagged ``z_descent_name``). None: no such bound."""

    z_max_m: float | None = None
    z_descent_m_s: float | None = None
    z_max_name: str = "z_max"
    z_descent_name: str = "z_descent"

    def __post_init__(self) -> None:
        for name in ("z_max_m", "z_descent_m_s"):
            v = getattr(self, name)
            if v is not None and (isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)):
                raise TrackInputError(f"bounds.{name} must be a finite number or None, got {v!r}")
        if self.z_descent_m_s is not None and not self.z_descent_m_s > 0:
            raise TrackInputError(f"bounds.z_descent_m_s must be > 0 m/s, got {self.z_descent_m_s!r}")


class TrackInputError(TrajectoryInputError):
    """A malformed setpoint, TTL, DOF set or time; the message names the field and the allowed range."""


class TrackError(HitchError, RuntimeError):
    """Ruckig could not compute a track cycle: an internal failure, not bad input."""


class TrackStateError(HitchError, RuntimeError):
    """A setpoint the follower does not take in its state: after :meth:`TrackFollower.stop`, or after the
    stream went stale without ``resume_after_stale`` / :meth:`TrackFollower.resume`."""


@dataclass(frozen=True)
class TrackSetpoint:
    """A setpoint as taken: the requested pose and velocity (full vectors, untracked DOFs at their held
    value and 0) and the target after clipping, with the names of the limits that clipped it."""

    t: float
    requested_position: np.ndarray
    requested_velocity: np.ndarray
    position: np.ndarray  # clipped to the workspace
    velocity: np.ndarray  # clipped to the pose velocity limits (not yet capped at a face: see TrackOutput)
    acceleration: np.ndarray  # given or estimated from consecutive velocities, within the acceleration limits
    limited: dict[str, str] = field(default_factory=dict)  # "x" → "workspace:x:max", "vx" → "velocity:x"
    jerk: np.ndarray = field(default_factory=lambda: np.zeros(4))
    """From consecutive given accelerations (at most ``ttl_s`` apart), within the jerk limits; else 0."""
    requested_acceleration: np.ndarray = field(default_factory=lambda: np.zeros(4))
    """The acceleration given or estimated, before the limits clipped it (where the demand turns)."""

    @property
    def control_limited(self) -> bool:
        return bool(self.limited)


@dataclass(frozen=True)
class TrackOutput:
    """One control cycle of track mode: the new pose-space state and its actuators.

    ``limited`` names what limited the motion this cycle: the setpoint's clipping (``"x"``,
    ``"vx"``) and a face the state had to brake for (``"x"`` → ``workspace:x:max``).
    ``braking``: some DOF is not tracking its target this cycle (stale or stopped stream, a
    take-over beyond the pose limits, a face ahead, or a demand that outran it whose stop it would pass:
    ``TrackFollower._passes_demand``).
    """

    t: float
    state: MotionState
    actuators: np.ndarray
    actuator_velocity: np.ndarray
    limited: dict[str, str] = field(default_factory=dict)
    stale: bool = False
    braking: bool = False

    @property
    def moving(self) -> bool:
        return self.state.moving


#: how far a sequence number may lie ahead of the last one taken: this many + :data:`SEQ_AHEAD_PER_S` per second
#: since — room for a client that numbers its setpoints by nanoseconds (``time.time_ns()``; a review: a bound of
#: 1000 + 1000/s refused streams numbered by µs); 2^53 from a stream near 0 is refused
SEQ_AHEAD = 10**9
SEQ_AHEAD_PER_S = 1e9


class SeqFilter:
    """Accepts strictly increasing sequence numbers of one session; counts the others (ignored). A number further
    ahead of the last one taken than :data:`SEQ_AHEAD` + :data:`SEQ_AHEAD_PER_S` × the seconds since is refused
    (:class:`TrackInputError`): taken, it would have every later setpoint of the session's own stream ignored (a
    fleet trial: one put with seq 2^53 from another client froze a live session's 50 Hz stream until it went
    stale, and its client was told nothing)."""

    def __init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """A new session: any sequence number is accepted next."""
        self.last: int | None = None
        self.last_t: float | None = None  # when the last one was taken [s] (None: not told)
        self.accepted = 0
        self.ignored = 0

    def accept(self, seq: int, now_s: float | None = None) -> bool:
        """True for a sequence number above every one accepted before (then it is the last one, taken at
        ``now_s`` [s])."""
        if not self.is_new(seq, now_s):
            self.ignored += 1
            return False
        self.last, self.last_t = seq, now_s
        self.accepted += 1
        return True

    def is_new(self, seq: int, now_s: float | None = None) -> bool:
        """Whether ``seq`` is above every one accepted before, without taking it (a setpoint is validated
        before its number is used up: a refused one leaves it for the corrected resend). With ``now_s`` [s], a
        number too far ahead of the last one (class docstring) raises :class:`TrackInputError` naming the
        allowed range."""
        if isinstance(seq, bool) or not isinstance(seq, int) or seq < 0:
            raise TrackInputError(f"seq must be an integer >= 0, got {seq!r}")
        if self.last is None or seq <= self.last:
            return self.last is None
        if now_s is not None and self.last_t is not None:
            since = max(now_s - self.last_t, 0.0)
            most = self.last + SEQ_AHEAD + int(SEQ_AHEAD_PER_S * since + 1e-6)
            if seq > most:
                raise TrackInputError(
                    f"seq = {seq} is more than {SEQ_AHEAD:g} + {SEQ_AHEAD_PER_S:g}/s x {since:.3f} s ahead of the "
                    f"last one taken ({self.last}; allowed: {self.last + 1} … {most}): taken, it would have the "
                    "session's own later setpoints ignored"
                )
        return True


def _braking_speed(distance: float, a: float, j: float) -> float:
    """Largest speed from which a jerk-limited stop (a ≤ a_max, |jerk| ≤ j, from zero acceleration)
    fits in ``distance``: the stop takes at most v²/(2a) + v·a/(2j)."""
    if distance <= 0:
        return 0.0
    b = a / (2 * j)
    return a * (-b + math.sqrt(b * b + 2 * distance / a))


#: Slack of :func:`_jerk_reachable` beyond Ruckig's own tolerances (its final-state precision is 1e-8 in
#: position and velocity, 1e-10 in acceleration; its duration check in ``_rendezvous`` 1e-9 relative).
_REACH_REL, _REACH_ABS = 1e-6, 1e-7


def _jerk_reachable(
    p0: float, v0: float, a0: float, pt: float, vt: float, at: float, jerk: float, horizon: float
) -> bool:
    """False only when no motion with |jerk| ≤ ``jerk`` [m/s³ or rad/s³] goes from (p0, v0, a0) to
    (pt, vt, at) [m, m/s, m/s² or rad, …] in ``horizon`` [s] (up to a relative 1e-6 and absolute 1e-7
    slack): an exact necessary condition, whatever the velocity and acceleration limits. The state after
    time T under jerk j(u) is a(T) = a0 + ∫j, v(T) = v0 + a0·T + ∫(T−u)·j, p(T) = p0 + v0·T + a0·T²/2 +
    ∫(T−u)²/2·j, so |a(T) − a0| ≤ J·T, |v(T) − v0 − a0·T| ≤ J·T²/2, |p(T) − p0 − v0·T − a0·T²/2| ≤ J·T³/6
    (the Taylor remainder of a motion with bounded third derivative)."""
    t = horizon * (1 + _REACH_REL)
    j = jerk * (1 + _REACH_REL)
    return (
        abs(at - a0) <= j * t + _REACH_ABS
        and abs(vt - v0 - a0 * t) <= j * t * t / 2 + _REACH_ABS + abs(a0) * horizon * _REACH_REL
        and _jerk_reaches_position(p0, v0, a0, pt, jerk, horizon)
    )


def _jerk_reaches_position(p0: float, v0: float, a0: float, pt: float, jerk: float, horizon: float) -> bool:
    """The position part of :func:`_jerk_reachable` alone (it needs no target velocity or acceleration)."""
    t = horizon * (1 + _REACH_REL)
    j = jerk * (1 + _REACH_REL)
    return (
        abs(pt - p0 - v0 * t - a0 * t * t / 2)
        <= j * t**3 / 6 + _REACH_ABS + (abs(v0) + abs(a0) * t) * horizon * _REACH_REL
    )


def _arrays(lim: PoseLimits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return lim.velocity, lim.acceleration, lim.jerk


def _number(v: object, what: str) -> float:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise TrackInputError(f"{what} must be a finite number, got {v!r}")
    return float(v)


class _DemandStop:
    """The cycle's :meth:`TrackFollower._demand_extent`, computed at its first use (once per step)."""

    def __init__(self, follower: TrackFollower, p_t: np.ndarray, v_t: np.ndarray, a_t: np.ndarray, lim: PoseLimits):
        self._args = (follower, p_t, v_t, a_t, lim)  # the step does not change them after
        self._done = False
        self._extent: tuple[np.ndarray, np.ndarray] | None = None

    def extent(self) -> tuple[np.ndarray, np.ndarray] | None:
        if not self._done:
            follower, p_t, v_t, a_t, lim = self._args
            self._extent, self._done = follower._demand_extent(p_t, v_t, a_t, lim), True
        return self._extent


class TrackFollower:
    """Follows streamed pose setpoints with online jerk-limited motion within the planner's workspace.

    Args:
        planner: limits, workspace, control rate and exact inverse.
        start: the state the follower takes over (at rest, or moving: a goto, a jog).
        dofs: the tracked DOFs (a subset of x, z, roll, pitch); the others brake to rest and hold.
        ttl_s: a setpoint lives this long (0 < ttl ≤ 5 s); without a fresh one the follower brakes.
        t0_s: the time of ``start`` (the TTL of the session counts from it until the first setpoint).
        resume_after_stale: track a fresh setpoint after the stream went stale (default: refuse it).
        bounds: extra bounds of the session (:class:`TrackBounds`: an implement's upper height and
            lowering speed); default none.
    """

    def __init__(
        self,
        planner: TrajectoryPlanner,
        start: MotionState,
        dofs: Collection[str],
        ttl_s: float,
        *,
        t0_s: float = 0.0,
        resume_after_stale: bool = False,
        bounds: TrackBounds | None = None,
    ):
        if isinstance(dofs, str) or not isinstance(dofs, Collection):
            raise TrackInputError(f"dofs must be a collection of DOF names out of {', '.join(TRACK_DOFS)}")
        unknown = set(dofs) - set(TRACK_DOFS)
        if unknown or not dofs:
            raise TrackInputError(
                f"dofs: unknown or none {sorted(map(str, unknown))}; allowed: a non-empty subset of "
                f"{', '.join(TRACK_DOFS)}"
            )
        ttl = _number(ttl_s, "ttl_s")
        if not 0.0 < ttl <= 5.0:
            raise TrackInputError(f"ttl_s must lie within (0, 5] s, got {ttl_s!r}")
        self.planner = planner
        self.dofs = tuple(k for k in TRACK_DOFS if k in dofs)
        self.tracked = np.array([k in self.dofs for k in TRACK_DOFS])
        self.ttl_s = ttl
        self.resume_after_stale = bool(resume_after_stale)
        self.dt = 1.0 / planner.rate
        # the faces the session keeps within: the workspace's, the z top lowered by the bounds
        self.bounds = bounds if bounds is not None else TrackBounds()
        self.lo, self.hi = np.asarray(planner.lo, float).copy(), np.asarray(planner.hi, float).copy()
        self._names = list(WORKSPACE_NAMES)
        if self.bounds.z_max_m is not None and self.bounds.z_max_m < self.hi[1]:
            self.hi[1] = max(float(self.bounds.z_max_m), float(self.lo[1]))
            self._names[1] = (WORKSPACE_NAMES[1][0], self.bounds.z_max_name)
        self._descent = self.bounds.z_descent_m_s
        self._any = planner.any_direction
        self.limits = self._any  # the subset limits in force (set by reset; a stop to rest: see _rest_limits)
        self.refreshes = 0  # subset limits computed (at reset, and when an untracked DOF came to rest)
        self._lo_ok = planner.lo - PLAUSIBLE_MARGIN
        self._hi_ok = planner.hi + PLAUSIBLE_MARGIN
        # one Ruckig, input and trajectory, reused every cycle (calculate, then the state one cycle in)
        self._ruckig = Ruckig(4)
        self._in = InputParameter(4)
        self._in.synchronization = Synchronization.No
        self._traj = Trajectory(4)
        # one DOF meeting the setpoint's own motion at a given time (the minimum duration): see _rendezvous
        self._ruckig1 = Ruckig(1)
        self._in1 = InputParameter(1)
        self._traj1 = Trajectory(1)
        # one DOF chasing a target that runs away at the velocity limit (velocity interface): see _chase
        self._in_chase = InputParameter(1)
        self._in_chase.control_interface = _VEL
        # per step (cleared by step): each DOF's rendezvous by its limits (the current state and the
        # targets are the step's), for the re-advances of _cannot_stop
        self._rv_memo: dict[tuple[int, float, float, float, float], tuple[float, float, float] | None] = {}
        self.rendezvous_tries = 0  # one-DOF Ruckig calculations of the rendezvous search (the cost)
        self.rendezvous_skips = 0  # horizons the exact jerk bound ruled out without Ruckig (_jerk_reachable)
        self.rendezvous = 0  # DOF-cycles that moved on a rendezvous with the setpoint's motion (_rendezvous)
        self.chases = 0  # DOF-cycles that chased a target running away instead of a detour (_chase)
        self.held_short = 0  # DOF-cycles braked so as not to pass where the demand would stop (_passes_demand)
        self._met = np.zeros(4, bool)  # per DOF: the last advance moved on a rendezvous (see _passes_demand)
        # per DOF: a setpoint's velocity or acceleration was beyond the limit since it last met the demand
        # (_passes_demand)
        self._outrun = np.zeros(4, bool)
        self._probe = StopProbe()
        self._demand_probe = StopProbe()
        self.fallbacks = 0  # cycles Ruckig refused, braked to rest instead (should stay 0)
        self.reset(start, t0_s)

    # ------------------------------------------------------------------ session
    def reset(self, state: MotionState, t0_s: float = 0.0) -> None:
        """Take over ``state`` at time ``t0_s``: holding its position until the first setpoint."""
        self.state = state
        self.t = _number(t0_s, "t0_s")
        self.hold = np.asarray(state.position, float).copy()
        self._sp: TrackSetpoint | None = None
        # per DOF, the setpoint, faces and limits in Python floats for _target_dof (set by _target_terms)
        self._terms: list[tuple[float, ...]] = []
        self._last_v: np.ndarray | None = None
        self._last_a_given = False
        self._last_s = self.t
        self._intervals: deque[float] = deque(maxlen=_INTERVALS_KEPT)  # between this session's setpoints [s]
        self._late = False  # the setpoint is older than extrapolation_s (set per step)
        self._extrapolation_s = self._extrapolation_bound()
        self._stale = False
        self._outrun[:] = False
        self._met[:] = False
        self._stopping = False
        self._brake: PoseLimits | None = None  # real braking limits of the current braking episode (lazily)
        # a take-over: braking may need the real limits until a cycle's state can stop within the pose limits
        self._takeover = state.moving
        self._active: np.ndarray | None = None
        self._rest: PoseLimits | None = None  # the limits of the stop to rest (stale, stopped)
        self._refresh()

    @property
    def stale(self) -> bool:
        """The stream went stale (latched until :meth:`resume` or a setpoint with ``resume_after_stale``)."""
        return self._stale

    @property
    def stopping(self) -> bool:
        return self._stopping

    @property
    def finished(self) -> bool:
        """Stopped (by :meth:`stop` or a stale stream) and at rest."""
        return (self._stopping or self._stale) and not self.state.moving

    @property
    def setpoint(self) -> TrackSetpoint | None:
        return self._sp

    def stop(self) -> None:
        """End the session smoothly: the shortest jerk-limited stop from the current state (target velocity 0)."""
        self._stopping = True

    def resume(self) -> None:
        """Clear a stale latch: the next setpoint is tracked again (the caller's decision)."""
        self._stale = False

    # ------------------------------------------------------------------ input
    def set_setpoint(
        self,
        pose: Mapping[str, float],
        velocity: Mapping[str, float] | None = None,
        now_s: float | None = None,
        *,
        acceleration: Mapping[str, float] | None = None,
        jerk: Mapping[str, float] | None = None,
    ) -> TrackSetpoint:
        """Take a setpoint: every tracked DOF's pose [m, rad], optionally its velocity [m/s, rad/s]
        (missing DOFs 0), arriving at ``now_s`` (default: the follower's time).

        Validated (finite numbers, tracked DOF names only, plausible SI values) then clipped to
        the workspace and the pose velocity limits; ``limited`` names the limits that clipped it.
        The target acceleration is ``acceleration`` [m/s², rad/s²] when given, else the difference of
        this and the previous setpoint's velocities (both given, at most ``ttl_s`` apart), else 0;
        clipped to the acceleration limits (without it a re-targeted follower lags a curved path).
        The jerk [m/s³, rad/s³] (the setpoint's extrapolation to the cycle's time, :meth:`target`) is
        ``jerk`` when given, else the difference of this and the previous setpoint's given
        accelerations (at most ``ttl_s`` apart), else 0; clipped to the jerk limits. A client streaming
        a path within the limits with its velocity, acceleration and jerk is followed exactly.
        """
        now = self.t if now_s is None else _number(now_s, "now_s")
        jerk_given: Mapping[str, float] | None = jerk
        if self._stopping:
            raise TrackStateError("track: the session is stopping; no further setpoints are taken")
        if self._stale and not self.resume_after_stale:
            raise TrackStateError(
                f"track: the setpoint stream went stale (no setpoint within {self.ttl_s:g} s); "
                "resume() before streaming again"
            )
        p_req, v_req = self._validate(pose, velocity)
        p, v = p_req.copy(), v_req.copy()
        acc = self._acceleration(acceleration, velocity, v_req, now)
        limited: dict[str, str] = {}
        lo, hi = self.lo, self.hi
        for d, (k, (name_min, name_max)) in enumerate(zip(TRACK_DOFS, self._names, strict=True)):
            if not self.tracked[d]:
                continue
            if p[d] > hi[d]:
                p[d], limited[k] = hi[d], name_max
            elif p[d] < lo[d]:
                p[d], limited[k] = lo[d], name_min
            if abs(v[d]) > self._v_lim[d]:
                v[d] = math.copysign(self._v_lim[d], v[d])
                limited[f"v{k}"] = _VELOCITY_NAMES[d]
                self._outrun[d] = True  # the demand runs away faster than the DOF may (see _passes_demand)
        if self._descent is not None and self.tracked[1] and v[1] < -self._descent:
            v[1], limited["vz"] = -self._descent, self.bounds.z_descent_name
            self._outrun[1] = True
        # the demand outruns a DOF whose acceleration is beyond the limit too (its turn is sharper than the
        # follower's: chasing it overshoots as one beyond the velocity limit does; see _passes_demand)
        self._outrun |= self.tracked & (np.abs(acc) > self._a_lim * (1 + 1e-6))
        a_req = np.where(self.tracked, acc, 0.0)
        acc = np.clip(acc, -self._a_lim, self._a_lim)
        # a reachable target state: |v| + a²/(2j) within the velocity limit (Ruckig refuses it otherwise)
        room = np.maximum(self._v_lim * (1 - 1e-6) - np.abs(v), 0.0)
        acc = np.sign(acc) * np.minimum(np.abs(acc), np.sqrt(2 * self._j_lim * room))
        self._cap_descent_acceleration(v, acc)
        acc = np.where(self.tracked, acc, 0.0)
        jk = np.zeros(4)
        prev = self._sp
        if jerk_given is not None:
            jk = self._derivative_values(jerk_given, "jerk", "/s³", PLAUSIBLE_JERK, self._j_lim)
        elif acceleration is not None and prev is not None and self._last_a_given and 0 < now - prev.t <= self.ttl_s:
            jk = (acc - prev.acceleration) / (now - prev.t)
        jk = np.where(self.tracked, np.clip(jk, -self._j_lim, self._j_lim), 0.0)
        self._last_a_given = acceleration is not None
        sp = TrackSetpoint(now, p_req, v_req, p, v, acc, limited, jk, a_req)
        if prev is not None and now > prev.t:
            self._intervals.append(now - prev.t)
            self._extrapolation_s = self._extrapolation_bound()
        self._sp = sp
        self._late = False
        self._target_terms()
        self._last_s = now
        self._last_v = v_req if velocity is not None else None
        self._stale = False
        return sp

    def _acceleration(
        self,
        acceleration: Mapping[str, float] | None,
        velocity: Mapping[str, float] | None,
        v_req: np.ndarray,
        now: float,
    ) -> np.ndarray:
        acc = np.zeros(4)
        if acceleration is not None:
            return self._derivative_values(acceleration, "acceleration", "/s²", PLAUSIBLE_ACCELERATION, self._a_lim)
        prev = self._sp
        if velocity is not None and self._last_v is not None and prev is not None and 0 < now - prev.t <= self.ttl_s:
            acc = (v_req - self._last_v) / (now - prev.t)
        return acc

    def _derivative_values(
        self, given: Mapping[str, float], name: str, per: str, plausible: float, limit: np.ndarray
    ) -> np.ndarray:
        """A setpoint's ``acceleration`` or ``jerk`` mapping as four values (missing DOFs 0): only tracked
        DOFs, finite numbers within ±``plausible`` (beyond ``limit`` they are clipped later)."""
        if not isinstance(given, Mapping):
            raise TrackInputError(f"setpoint.{name} must be a mapping with any of {', '.join(self.dofs)}")
        self._only_tracked(name, given)
        out = np.zeros(4)
        for d, k in enumerate(TRACK_DOFS):
            if k in given:
                w = _number(given[k], f"setpoint.{name}.{k}")
                if abs(w) > plausible:
                    u = CONTROLLED_POSE_UNITS[k]
                    raise TrackInputError(
                        f"setpoint.{name}.{k} = {w:g} {u}{per} is not a plausible SI value: allowed "
                        f"±{plausible:g} {u}{per} (beyond ±{limit[d]:.4f} it is clipped)"
                    )
                out[d] = w
        return out

    def _only_tracked(self, what: str, given: Mapping[str, float]) -> None:
        """Refuse fields of ``setpoint.<what>`` that this session does not track (naming them and the allowed)."""
        bad = set(given) - set(self.dofs)
        if bad:
            raise TrackInputError(
                f"setpoint.{what}: field(s) {', '.join(sorted(map(str, bad)))} not tracked in this session; "
                f"allowed: {', '.join(self.dofs)}"
            )

    def plausible_range(self, dof: str) -> tuple[float, float]:
        """The values of ``dof`` [m or rad] a setpoint may name (the workspace widened by
        :data:`PLAUSIBLE_MARGIN`; beyond the workspace it is clipped), in the tractor frame."""
        d = TRACK_DOFS.index(dof)
        return float(self._lo_ok[d]), float(self._hi_ok[d])

    def validate(self, pose: Mapping[str, float], velocity: Mapping[str, float] | None = None) -> None:
        """The checks of :meth:`set_setpoint` on ``pose`` and ``velocity`` (TrackInputError naming the field),
        without taking the setpoint."""
        self._validate(pose, velocity)

    def _validate(
        self, pose: Mapping[str, float], velocity: Mapping[str, float] | None
    ) -> tuple[np.ndarray, np.ndarray]:
        if not isinstance(pose, Mapping):
            raise TrackInputError(f"setpoint.pose must be a mapping with {', '.join(self.dofs)}")
        if velocity is not None and not isinstance(velocity, Mapping):
            raise TrackInputError(f"setpoint.velocity must be a mapping with any of {', '.join(self.dofs)}")
        for what, m in (("pose", pose), ("velocity", velocity or {})):
            self._only_tracked(what, m)
        missing = [k for k in self.dofs if k not in pose]
        if missing:
            raise TrackInputError(
                f"setpoint.pose: missing field(s) {', '.join(missing)}; required: {', '.join(self.dofs)}"
            )
        p = self.hold.copy()
        v = np.zeros(4)
        for d, k in enumerate(TRACK_DOFS):
            if k in pose:
                x = _number(pose[k], f"setpoint.pose.{k}")
                if not self._lo_ok[d] <= x <= self._hi_ok[d]:
                    u = CONTROLLED_POSE_UNITS[k]
                    raise TrackInputError(
                        f"setpoint.pose.{k} = {x:g} {u} is not a plausible SI value: allowed "
                        f"[{self._lo_ok[d]:.3f}, {self._hi_ok[d]:.3f}] {u} (beyond the workspace "
                        f"[{self.planner.lo[d]:.3f}, {self.planner.hi[d]:.3f}] it is clipped)"
                    )
                p[d] = x
            if velocity is not None and k in velocity:
                w = _number(velocity[k], f"setpoint.velocity.{k}")
                if abs(w) > PLAUSIBLE_VELOCITY:
                    u = CONTROLLED_POSE_UNITS[k]
                    raise TrackInputError(
                        f"setpoint.velocity.{k} = {w:g} {u}/s is not a plausible SI value: allowed "
                        f"±{PLAUSIBLE_VELOCITY:g} {u}/s (beyond ±{self._v_lim[d]:.4f} it is clipped)"
                    )
                v[d] = w
        return p, v

    # ------------------------------------------------------------------ the cycle
    def target(self, now_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, str]]:
        """The cycle's target (position, velocity, acceleration, flags) at ``now_s``: the setpoint
        extrapolated with its velocity, clipped to the workspace, its velocity capped so that a
        jerk-limited stop from the target fits before the face (its acceleration then dropped when
        it pushes towards the face). While the *requested* setpoint, extrapolated with its requested
        velocity, is beyond a face, the target is that face at rest: a demand beyond the face that
        heads back inside does not pull the target off the face before it is inside again (the
        hitch would leave the face and come back to it)."""
        sp = self._sp
        if sp is None:
            return self.hold.copy(), np.zeros(4), np.zeros(4), {}
        flags = dict(sp.limited)
        ahead = max(now_s - sp.t, 0.0)
        p, v, acc = [0.0] * 4, [0.0] * 4, [0.0] * 4
        for d, k in enumerate(TRACK_DOFS):
            p[d], v[d], acc[d], face, vface = self._target_dof(d, ahead)
            if face is not None:
                flags.setdefault(k, face)
            if vface is not None:
                flags[f"v{k}"] = vface
        return np.array(p), np.array(v), np.array(acc), flags

    def _target_terms(self) -> None:
        """Per DOF, what :meth:`_target_dof` reads, in Python floats: the setpoint's position, velocity,
        acceleration, jerk, requested position and velocity, the faces and the limits in force (at a new
        setpoint and new limits)."""
        sp = self._sp
        if sp is None:
            return
        self._terms = list(
            zip(
                *(
                    x.tolist()
                    for x in (
                        sp.position,
                        sp.velocity,
                        sp.acceleration,
                        sp.jerk,
                        sp.requested_position,
                        sp.requested_velocity,
                        self.lo,
                        self.hi,
                        self._v_lim,
                        self._a_lim,
                        self._j_lim,
                    )
                ),
                strict=True,
            )
        )

    @property
    def extrapolation_s(self) -> float:
        """How long after its arrival a setpoint is extrapolated with its velocity [s]:
        :data:`EXTRAPOLATION_INTERVALS` × the median interval of the stream, within [2 dt, ttl_s]
        (:data:`FIRST_EXTRAPOLATION_S` before an interval is known). A setpoint older than this is late: the
        target rests where its extrapolation got to (a dead stream is not followed on for a whole ttl)."""
        return self._extrapolation_s

    def _extrapolation_bound(self) -> float:
        """:attr:`extrapolation_s` from the intervals kept (at each setpoint, not per cycle)."""
        if self._intervals:
            bound = EXTRAPOLATION_INTERVALS * statistics.median(self._intervals)
        else:
            bound = FIRST_EXTRAPOLATION_S
        return min(max(bound, 2.0 * self.dt), self.ttl_s)

    def _target_position(self, d: int, ahead: float) -> tuple[float, str | None, bool]:
        """DOF ``d``'s position of :meth:`target` ``ahead`` [s] after the setpoint (there is one) [m or rad],
        the name of the face that clipped it (None: none) and whether the target rests there (the demand is
        beyond that face, or the setpoint is late: its extrapolation stops at :attr:`extrapolation_s`)."""
        if self._late:
            p, face, _ = self._target_position_at(d, min(ahead, self.extrapolation_s))
            return p, face, True
        return self._target_position_at(d, ahead)

    def _target_position_at(self, d: int, ahead: float) -> tuple[float, str | None, bool]:
        """:meth:`_target_position` of a setpoint that is not late."""
        pos, vel, acc0, jk, p_req0, v_req0, lo, hi = self._terms[d][:8]
        # the setpoint's own motion to the cycle's time: constant acceleration (the target acceleration's
        # model), so a stream within the limits is met where it is now, not where it was when it was sent
        p = pos + vel * ahead + acc0 * ahead**2 / 2 + jk * ahead**3 / 6
        if not self.tracked[d]:
            return p, None, False
        p_req = p_req0 + v_req0 * ahead
        name_min, name_max = self._names[d]
        if p_req >= hi:  # the demand is beyond the face: at the face, at rest
            return hi, name_max, True
        if p_req <= lo:
            return lo, name_min, True
        if p >= hi:
            return hi, name_max, False
        if p <= lo:
            return lo, name_min, False
        return p, None, False

    def _target_dof(
        self, d: int, ahead: float, position: tuple[float, str | None, bool] | None = None
    ) -> tuple[float, float, float, str | None, str | None]:
        """DOF ``d`` of :meth:`target` ``ahead`` [s] after the setpoint (there is one): position, velocity,
        acceleration [m, m/s, m/s² or rad, …] and the names of the face that clipped the position and the
        velocity (None: none), in Python floats (the rendezvous search calls it per DOF and horizon);
        ``position``: :meth:`_target_position`'s answer when the caller has it already."""
        p, face, rest = self._target_position(d, ahead) if position is None else position
        _, vel, acc0, jk, _, _, lo, hi, vl, al, jl = self._terms[d]
        # the limits may have changed since the setpoint was taken (a new box): a reachable target again
        v = min(max(vel + acc0 * ahead + jk * ahead**2 / 2, -vl), vl)
        acc = min(max(acc0 + jk * ahead, -al), al)
        if acc != 0.0:
            acc = math.copysign(min(abs(acc), math.sqrt(2 * jl * max(vl * (1 - 1e-6) - abs(v), 0.0))), acc)
        if d == 1 and self._descent is not None:  # as _cap_descent_acceleration
            v = max(v, -self._descent)
            room = max(self._descent * (1 - 1e-6) + v, 0.0)
            acc = min(max(acc, -math.sqrt(2 * jl * room)), math.sqrt(2 * jl * room))
        if not self.tracked[d]:
            return p, v, acc, None, None
        name_min, name_max = self._names[d]
        vface = None
        if rest:
            v, acc = 0.0, 0.0
        # the speeds a stop fits from (≥ 0), each only where it can bind (v or the acceleration towards it)
        up = _braking_speed(hi - p, al, jl) if acc > 0 or v > 0 else math.inf
        down = _braking_speed(p - lo, al, jl) if acc < 0 or v < 0 else math.inf
        # the stop from (v, a) pushing outwards ends no further than one from |v| + a²/(2j) at a = 0
        if acc > 0 and max(v, 0.0) + acc**2 / (2 * jl) > up:
            acc = 0.0
        elif acc < 0 and max(-v, 0.0) + acc**2 / (2 * jl) > down:
            acc = 0.0
        if v > up:
            v, vface = up, name_max
        elif v < -down:
            v, vface = -down, name_min
        return p, v, acc, face, vface

    def step(self, now_s: float | None = None) -> TrackOutput:
        """Advance one control cycle (dt = 1/rate) to time ``now_s`` (default: t + dt)."""
        now = self.t + self.dt if now_s is None else _number(now_s, "now_s")
        self._rv_memo.clear()  # the rendezvous hold for this step only
        if not self._stale and not self._stopping and now - self._last_s > self.ttl_s:
            self._stale = True
        to_rest = self._stale or self._stopping
        flags: dict[str, str]
        state = self.state
        if to_rest:  # the planned stop's limits, chosen once (see the module docstring)
            lim = self._rest_limits()
            p_t, v_t, a_t, flags = self.hold, np.zeros(4), np.zeros(4), {}
            stream = False
            vel_mode = np.ones(4, bool)
            brake = np.zeros(4, bool)
        else:
            self._rest = None
            self._refresh()
            lim = self.limits
            self._late = self._sp is not None and now - self._sp.t > self.extrapolation_s
            p_t, v_t, a_t, flags = self.target(now)
            stream = self._sp is not None
            vel_mode = ~self.tracked
            brake = beyond(state, lim, _REL)
            self._takeover |= bool(np.any(brake))
        v_lim = lim.velocity
        tv = np.where(vel_mode, 0.0, v_t)
        ta = np.where(vel_mode, 0.0, a_t)
        p_now, v_now = state.position, state.velocity
        for i in np.flatnonzero(brake & ~vel_mode).tolist():  # beyond the pose limits: slow down (towards) or stop
            towards = v_now[i] * (p_t[i] - p_now[i]) > 0
            vel_mode[i] = True
            tv[i] = float(np.clip(v_now[i], -v_lim[i], v_lim[i])) if towards else 0.0
            ta[i] = 0.0
        if self._descent is not None and not to_rest:  # never re-target faster downwards than the bound
            tv[1] = max(tv[1], -self._descent)
            self._cap_descent_acceleration(tv, ta)
        # a demand faster than the limits: where it would come to rest stopping now (see _passes_demand;
        # computed when a DOF needs it)
        demand = _DemandStop(self, p_t, v_t, a_t, lim) if stream and not to_rest and np.any(self._outrun) else None
        try:
            nxt = self._advance(p_t, tv, ta, vel_mode, brake, lim, stream)
            for n in range(3):
                extent = self._probe.extent(nxt, lim)  # its stop within the pose limits: the faces', the demand's
                up, down = self._cannot_stop(nxt, lim, extent)  # cheap: the pose limits first
                if not (np.any(up) or np.any(down)):
                    if n == 0 and not np.any(brake):
                        self._takeover = False  # within the pose limits and stoppable with them: they suffice
                else:
                    up, down = self._cannot_stop(nxt, self._braking(lim))
                short_up, short_down = self._passes_demand(extent, demand, vel_mode)
                # braking to rest with the real limits already: nothing more to do for that DOF
                up &= ~(brake & vel_mode & (tv <= 0))
                down &= ~(brake & vel_mode & (tv >= 0))
                short_up &= ~up & ~down
                short_down &= ~up & ~down
                if not np.any(up | down | short_up | short_down):
                    break
                for d, (k, (name_min, name_max)) in enumerate(zip(TRACK_DOFS, self._names, strict=True)):
                    if up[d] or down[d] or short_up[d] or short_down[d]:
                        vel_mode[d] = True
                        tv[d] = min(tv[d], 0.0) if up[d] or short_up[d] else max(tv[d], 0.0)
                        ta[d] = 0.0
                        if (up[d] or down[d]) and self.tracked[d] and not to_rest:
                            flags[k] = name_max if up[d] else name_min
                self.held_short += int(np.sum(short_up | short_down))
                brake = brake | up | down | short_up | short_down
                nxt = self._advance(p_t, tv, ta, vel_mode, brake, lim, stream)
        except (TrackError, PlanError):  # never stuck: the shortest stop with the real limits
            self.fallbacks += 1
            vel_mode[:] = True
            tv[:] = 0.0
            ta[:] = 0.0
            brake[:] = True
            try:
                nxt = self._advance(p_t, tv, ta, vel_mode, brake, lim)
            except (TrackError, PlanError) as exc:
                raise TrackError(f"track: {exc}") from None
        self.state = nxt
        self.t = now
        if not np.any(brake):
            self._brake = None
        if to_rest and not nxt.moving:
            self.hold = np.asarray(nxt.position, float).copy()
        q, jac, _ = self.planner.inverse.solve_full(nxt.position)
        braking = bool(to_rest or np.any(vel_mode & self.tracked))
        return TrackOutput(now, nxt, q, jac @ nxt.velocity, flags, self._stale, braking)

    # ------------------------------------------------------------------ for the guard
    def guard_rates(self, horizon_s: float) -> np.ndarray:
        """A constant rate vector that reaches, after ``horizon_s``, where the motion heads: the target
        extrapolated by the horizon and clipped to the workspace (zero when braking to rest).

        :meth:`planner.limits.guard.Guard.check_jog` evaluates stability at ``position + rates·horizon``:
        pass it ``(follower.state, follower.guard_rates(guard.settings.jog_horizon))``.
        """
        h = _number(horizon_s, "horizon_s")
        if h <= 0:
            raise TrackInputError(f"horizon_s must be > 0 s, got {horizon_s!r}")
        if self._stale or self._stopping or self._sp is None:
            return np.zeros(4)
        p_t, v_t, _, _ = self.target(self.t)
        ahead = np.where(self.tracked, np.clip(p_t + v_t * h, self.lo, self.hi), self.state.position)
        return (ahead - self.state.position) / h

    # ------------------------------------------------------------------ internals
    def _refresh(self) -> None:
        """The subset limits of the DOFs that move: at the start, and when an untracked DOF came to rest
        (fewer DOFs move: the limits grow; else the previous ones, still valid, are kept); cheap otherwise."""
        st = self.state
        active = self.tracked | (st.velocity != 0) | (st.acceleration != 0)
        if self._active is not None and np.array_equal(active, self._active):
            return
        tp = self.planner
        try:
            new = subset_limits(tp.inverse, st.position, active, tp.limits, tp.lo, tp.hi)
        except KinematicsError:
            new = None
        base = self._any if self._active is None else self.limits
        self._active = active
        if new is None:
            self.limits = base
        else:
            cand = PoseLimits(*(np.where(active, x, y) for x, y in zip(_arrays(new), _arrays(self._any), strict=True)))
            # one valid set or the other, never mixed per DOF: the subset limits where they are the larger
            ok = all(np.all(x[active] >= y[active]) for x, y in zip(_arrays(cand), _arrays(base), strict=True))
            self.limits = cand if ok else base
        self.refreshes += 1
        lim = self.limits
        self._v_lim, self._a_lim, self._j_lim = lim.velocity, lim.acceleration, lim.jerk
        if self._sp is not None:
            self._target_terms()

    def _rest_limits(self) -> PoseLimits:
        """The limits of the stop to rest, chosen at its first cycle as
        :meth:`~.planner.TrajectoryPlanner.plan_stop` does (then the per-cycle re-plan is that stop)."""
        if self._rest is None:
            st, tp = self.state, self.planner
            lim = self._any.floored(current_floor(st))
            if st.moving and (np.any(beyond(st, self._any)) or tp.stop_leaves_workspace(st, lim)):
                lim = tp.braking_limits(st)
            self._rest = lim
        return self._rest

    def _braking(self, lim: PoseLimits) -> PoseLimits:
        """The braking limits, floored by ``lim`` and by the state's |v|, |a|: after a take-over (a state
        beyond ``lim``, or one that cannot stop within it) the real braking limits of the current motion
        (computed once per braking episode); otherwise ``lim`` itself, which suffices: every cycle's state
        was checked to stop within it one cycle earlier, so braking from it now fits (and costs nothing)."""
        if not self._takeover:
            return lim.floored(current_floor(self.state))
        if self._brake is None:
            self._brake = self.planner.braking_limits(self.state)
        return self._brake.floored(lim).floored(current_floor(self.state))

    def _advance(
        self,
        p_t: np.ndarray,
        tv: np.ndarray,
        ta: np.ndarray,
        vel_mode: np.ndarray,
        brake: np.ndarray,
        lim: PoseLimits,
        stream: bool = False,
    ) -> MotionState:
        """The state one cycle ahead: Ruckig from the current state, position interface towards
        (``p_t``, ``tv``, ``ta``) or velocity interface towards ``tv`` (``vel_mode``) within ``lim``;
        ``brake``: the real limits."""
        st = self.state
        vl, al, jl = lim.velocity, lim.acceleration, lim.jerk
        if np.any(brake):  # the real limits, floored by the state's |v|, |a| (the others keep within theirs)
            real = self._braking(lim)
            vl = np.where(brake, real.velocity, vl)
            al = np.where(brake, real.acceleration, al)
            jl = np.where(brake, real.jerk, jl)
        inp = self._in
        inp.per_dof_control_interface = [_VEL if m else _POS for m in vel_mode.tolist()]
        vmax = np.maximum(vl, np.maximum(np.abs(tv), 1e-9)).tolist()
        inp.max_velocity = vmax
        vmin: list[float] | None = None
        if self._descent is not None:  # the downward z bound (TrackBounds): Ruckig's asymmetric velocity limit
            down = np.maximum(vl, np.maximum(-tv, 1e-9))
            if not vel_mode[1]:
                down[1] = max(min(down[1], self._descent), -tv[1], 1e-9)
            vmin = (-down).tolist()
            inp.min_velocity = vmin
        amax = np.maximum(al, 1e-9).tolist()
        jmax = np.maximum(jl, 1e-9).tolist()
        inp.max_acceleration = amax
        inp.max_jerk = jmax
        inp.current_position = st.position.tolist()
        inp.current_velocity = st.velocity.tolist()
        inp.current_acceleration = st.acceleration.tolist()
        inp.target_position = p_t.tolist()
        inp.target_velocity = tv.tolist()
        inp.target_acceleration = ta.tolist()
        try:
            res = self._ruckig.calculate(inp, self._traj)
        except RuckigError as exc:
            raise TrackError(f"track: ruckig refused the cycle ({str(exc).strip()})") from None
        if res not in _OK:
            raise TrackError(f"track: ruckig failed ({res})")
        p, v, a = self._traj.at_time(self.dt)  # past its duration: on at the target velocity
        p, v, a = list(p), list(v), list(a)
        self._met[:] = False
        if stream:
            for d in np.flatnonzero(self.tracked & ~vel_mode & ~brake).tolist():
                lim_d = (d, vmax[d], -math.inf if vmin is None else vmin[d], amax[d], jmax[d])
                memo = self._rv_memo
                if lim_d in memo:  # a re-advance of this step (_cannot_stop) with the same limits for d
                    hit = memo[lim_d]
                else:
                    hit = memo[lim_d] = self._rendezvous(*lim_d)
                if hit is None:
                    hit = self._chase(
                        d, float(p_t[d]), float(tv[d]), a[d], self._traj.independent_min_durations[d], *lim_d[1:]
                    )
                    if hit is not None:
                        self.chases += 1
                else:
                    self.rendezvous += 1
                    self._met[d] = True
                    self._outrun[d] = False
                if hit is not None:
                    p[d], v[d], a[d] = hit
        return MotionState(np.array(p), np.array(v), np.array(a))

    def _chase(
        self,
        d: int,
        pt: float,
        vt: float,
        a_opt: float,
        t_opt: float,
        vmax: float,
        vmin: float,
        amax: float,
        jmax: float,
    ) -> tuple[float, float, float] | None:
        """DOF ``d`` one cycle along a chase of a target it is behind and that runs away from it faster
        than it moves (the target ``pt`` lies in the direction of its velocity ``vt``), or None (no
        chase: the caller keeps the time-optimal approach). When no rendezvous is on time — the target
        moves at nearly the velocity limit, the gap closes only at the difference — the time-optimal
        approach to the target *state* (``pt`` reached at velocity ``vt``) cannot arrive at that speed
        without passing it, so it brakes (``a_opt`` not towards ``vt``; its time ``t_opt`` longer than
        the longest rendezvous), falls back and comes round again: a detour of up to a second (a 30 mm
        error on a terrain profile at z's velocity limit). The chase instead runs after the target (velocity interface,
        jerk-limited) at the target's speed plus the gap over the longest rendezvous time, at most the
        velocity limit on its side (at the limit alone it overshoots a target that slows); a rendezvous
        takes over once one is on time again."""
        p0, v0 = float(self.state.position[d]), float(self.state.velocity[d])
        gap = pt - p0
        if gap * vt <= 0.0 or v0 * vt < 0.0 or abs(v0) >= abs(vt):
            return None  # not behind a target running away faster than it (catching up: braking is right)
        if a_opt * vt > 0.0 or t_opt <= RENDEZVOUS_CYCLES[-1] * self.dt:
            return None  # the approach speeds on towards it, or it is short: no detour
        one = self._in_chase
        one.max_acceleration = [amax]
        one.max_jerk = [jmax]
        top_up = max(vmax, abs(vt))
        top_down = top_up if vmin == -math.inf else max(-vmin, -vt)
        one.max_velocity = [top_up]
        one.min_velocity = [-top_down]
        top = top_up if vt > 0 else top_down
        one.current_position = [p0]
        one.current_velocity = [v0]
        one.current_acceleration = [float(self.state.acceleration[d])]
        # the target's speed plus the gap closed within the longest rendezvous, at most the limit
        closing = abs(gap) / (RENDEZVOUS_CYCLES[-1] * self.dt)
        one.target_velocity = [math.copysign(min(top, abs(vt) + closing), vt)]
        one.target_acceleration = [0.0]
        try:
            res = self._ruckig1.calculate(one, self._traj1)
        except RuckigError:
            return None
        if res not in _OK:
            return None
        (p,), (v,), (a,) = self._traj1.at_time(self.dt)
        return p, v, a

    def _rendezvous(
        self, d: int, vmax: float, vmin: float, amax: float, jmax: float
    ) -> tuple[float, float, float] | None:
        """DOF ``d`` (tracked, in the position interface, not braking) one cycle along its rendezvous
        with the setpoint's own motion (position, velocity, acceleration), or None: it meets the
        setpoint's motion (:meth:`target` at a later time: the setpoint extrapolated with its velocity
        and acceleration) at the earliest of :data:`RENDEZVOUS_CYCLES` it can reach *on time* within
        the limits ``vmax``, ``vmin`` (-inf: symmetric), ``amax``, ``jmax`` (its own Ruckig with that
        time as the minimum duration). A target that moves is not a point to reach as fast as
        possible: the time-optimal approach, re-targeted every cycle, arrives early and runs on alone
        or, a hair behind a target it cannot reach within one cycle, takes a detour of up to a second;
        on a setpoint stream within the limits it lagged 3–6 cycles. The one-cycle rendezvous of a
        stream within the limits is the stream itself (followed without lag). None (no rendezvous on
        time): the caller keeps the time-optimal approach. A horizon whose target no motion with
        |jerk| ≤ ``jmax`` reaches (:func:`_jerk_reachable`, exact) is not tried."""
        st, sp = self.state, self._sp
        if sp is None:
            return None
        p0, v0, a0 = float(st.position[d]), float(st.velocity[d]), float(st.acceleration[d])
        one = self._in1
        one.max_acceleration = [amax]
        one.max_jerk = [jmax]
        one.current_position = [p0]
        one.current_velocity = [v0]
        one.current_acceleration = [a0]
        for n in RENDEZVOUS_CYCLES:
            horizon = n * self.dt
            ahead = max(self.t + horizon - sp.t, 0.0)
            position = self._target_position(d, ahead)
            if not _jerk_reaches_position(p0, v0, a0, position[0], jmax, horizon):  # the cheap part first
                self.rendezvous_skips += 1
                continue
            pt, vt, at, _, _ = self._target_dof(d, ahead, position)
            if not _jerk_reachable(p0, v0, a0, pt, vt, at, jmax, horizon):
                self.rendezvous_skips += 1
                continue
            one.minimum_duration = horizon
            one.max_velocity = [max(vmax, abs(vt))]
            if vmin != -math.inf:
                one.min_velocity = [min(vmin, vt)]
            one.target_position, one.target_velocity, one.target_acceleration = [pt], [vt], [at]
            self.rendezvous_tries += 1
            try:
                res = self._ruckig1.calculate(one, self._traj1)
            except RuckigError:
                continue
            if res in _OK and self._traj1.duration <= horizon * (1 + 1e-9):
                (p,), (v,), (a,) = self._traj1.at_time(self.dt)
                return p, v, a
        return None

    def _demand_extent(
        self, p_t: np.ndarray, v_t: np.ndarray, a_t: np.ndarray, lim: PoseLimits
    ) -> tuple[np.ndarray, np.ndarray] | None:
        """The lowest and highest position per DOF of the shortest stop of the cycle's target (the demand's
        position, velocity and acceleration) within ``lim``: how far the demand goes were it to stop now as
        fast as the follower may (None where Ruckig finds no stop); and no further than where the demand
        turns by its own (unclipped) deceleration: ``p + v·|v| / (2·|a|)`` of the setpoint's requested velocity
        and acceleration where they oppose (a demand turning harder than the limits allow stops sooner than
        the stop within them says: a three-sine stream passed its extreme by 2.9 mm; a reviewer's report).
        For a sine that point is never short of its peak: ``A·(1 + sin²φ) / (2·sin φ) ≥ A``."""
        try:
            lo, hi = self._demand_probe.extent(MotionState(p_t, v_t, a_t), lim)
        except PlanError:
            return None
        sp = self._sp
        if sp is not None:
            v, a = sp.requested_velocity, sp.requested_acceleration
            turning = (v * a < 0.0) & self.tracked
            if np.any(turning):
                with np.errstate(divide="ignore", invalid="ignore"):
                    turn = np.where(turning, sp.requested_position + v * np.abs(v) / (2.0 * np.abs(a)), p_t)
                hi = np.where(turning & (v > 0.0), np.minimum(hi, np.maximum(turn, p_t)), hi)
                lo = np.where(turning & (v < 0.0), np.maximum(lo, np.minimum(turn, p_t)), lo)
        return lo, hi

    def _passes_demand(
        self,
        extent: tuple[np.ndarray, np.ndarray],
        demand: _DemandStop | None,
        vel_mode: np.ndarray,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per tracked DOF outrun by the demand (a setpoint's velocity or acceleration beyond its limit,
        clipped, since the DOF last met the demand's motion on a rendezvous) and not moving on a
        rendezvous this cycle (a chase, or the time-optimal approach to the target state): the shortest stop
        of the cycle's state within the pose limits (``extent``: its lowest and highest position) passes,
        upwards / downwards, the furthest the demand reaches were it to stop now as fast
        (:meth:`_demand_extent`; beyond the current position when that is beyond it already). Chasing a
        demand faster than the limits at the velocity limit overshoots it when it reverses (a 1 Hz ±20 mm z
        sine: the hitch went 5–13 mm past the extremes commanded, deeper into the soil than asked; a new
        user's report): such a DOF brakes instead. A demand within the limits is left to the follower (a
        rendezvous meets its motion on time; bounding a catch-up would only lag)."""
        none = np.zeros(4, bool)
        if demand is None:
            return none, none
        check = self.tracked & self._outrun & ~vel_mode & ~self._met
        stop = demand.extent() if np.any(check) else None
        if stop is None:
            return none, none
        lo, hi = extent
        d_lo, d_hi = stop
        p = self.state.position
        up = check & (hi > np.maximum(d_hi, p) + DEMAND_TOLERANCE)
        down = check & ~up & (lo < np.minimum(d_lo, p) - DEMAND_TOLERANCE)
        return up, down

    def _cannot_stop(
        self, state: MotionState, limits: PoseLimits, extent: tuple[np.ndarray, np.ndarray] | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        """Per DOF: the shortest stop from ``state`` within ``limits`` (``extent``: its lowest and highest
        position, when the caller has it) passes the upper / lower face (beyond the current position when
        that is already outside)."""
        lo, hi = self._probe.extent(state, limits) if extent is None else extent
        p = self.state.position
        return hi > np.maximum(self.hi, p) + 1e-9, lo < np.minimum(self.lo, p) - 1e-9

    def _cap_descent_acceleration(self, v: np.ndarray, acc: np.ndarray) -> None:
        """In place: a target acceleration of z that the descent bound makes unreachable is reduced (Ruckig
        refuses such a target): a downward one whose velocity would pass the bound before it reaches zero
        (v − a²/(2j) below −bound), and an upward one at a velocity it could only have come to from below the
        bound (the same room: at v = −bound it must be 0; with it Ruckig refused 88 of 400 cycles of a fast z
        sine, each braking to rest instead; a reviewer's report)."""
        if self._descent is None or acc[1] == 0:
            return
        cap = math.sqrt(2 * float(self._j_lim[1]) * max(self._descent * (1 - 1e-6) + float(v[1]), 0.0))
        acc[1] = min(max(float(acc[1]), -cap), cap)
