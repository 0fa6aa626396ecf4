"""Feed-forward through the cylinder ECU's unit loops: the reference that makes each
cylinder follow its plan.

The ECU closes one position loop per cylinder (thesis 2.56–2.57; simulated in ``bridge.sim.controller``):
PD on the AD reading with k = a/(Kv L), k_d = k·T_F, derivative on the measurement,
dead-zone compensation, the valve multiplier m. For commands outside the dead zone the valve
and cylinder of (thesis 1.1) then move as

    T_F ÿ(t) + ẏ(t) = G·[r − y − T_F ẏ](t − L) + w·sign,      G = m·a/L,   w = Kv·dy_min,

a slow loop (1/G = 0.17 s for the lift, 0.34 s tilt and top link, 0.86 s sway limiters).
Streaming the plan's actuator positions as references makes every cylinder lag by its
own L/(m a) + T_F (:func:`unit_loop_lag_s`), so a straight pose move bends, the thesis's
"sequential" look. Inverting the loop along the plan q(t) gives the reference under which
y = q exactly (for this model):

    r(t) = q(t) + T_F q̇(t) + [q̇(t+L) + T_F q̈(t+L) − w·sign q̇(t+L)] / G

(the minimum flow Kv±·dy_min takes the sign of the bracket, as the valve's does with the
command, and only while the P part stays on its side of zero). The plan is known
ahead, so q̇(t+L) is read from it. The reference leads the plan by about q̇/G; near the end
of a move it runs beyond the goal by up to a_max/(2G²) before coming back to it — the
overshoot the slow loop needs to stop on time; the piston itself does not overshoot.

Safety: :func:`safe_reference` clips the shaped reference into the strokes and hands it to
the link's hard-limit check; a refused one is pulled back towards the plan sample (which the
planner has already checked) until it passes.

Units: SI (m; rad for the lift), s.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Protocol

import numpy as np

from planner.errors import HitchInputError
from planner.model.sensors import SensorScaling
from planner.model.types import ACTUATOR_NAMES
from planner.profiles.hitch import Profile

__all__ = [
    "ActuatorMotion",
    "FeedforwardShaper",
    "PoseState",
    "SolveFull",
    "UnitLoop",
    "UnitLoopError",
    "actuator_motion",
    "build_unit_loops",
    "feedforward_reference",
    "safe_reference",
    "unit_loop_lag_s",
]


class UnitLoopError(HitchInputError):
    """A tuning or profile value the unit-loop model cannot take; the message names it."""


class PoseState(Protocol):
    """Pose-space state over (x, z, roll, pitch), SI: what a plan's ``state_at(t)`` returns
    (:class:`planner.trajectory.plan.MotionState`)."""

    @property
    def position(self) -> np.ndarray: ...

    @property
    def velocity(self) -> np.ndarray: ...

    @property
    def acceleration(self) -> np.ndarray: ...


SolveFull = Callable[[np.ndarray], tuple[np.ndarray, np.ndarray, object]]
"""The exact inverse: pose (4,) → (actuators (5,), d actuators / d pose (5, 4), …)
(:meth:`planner.model.exact_inverse.ExactInverse.solve_full`)."""


@dataclass(frozen=True)
class UnitLoop:
    """One cylinder's closed position loop as the planner models it (SI).

    Attributes:
        name: actuator name.
        gain_per_s: G = m·a/L, the loop gain from reference error to piston speed, 1/s.
        delay_s: transport delay L, s (thesis table 3-4).
        lag_s: valve lag T_F, s.
        min_flow_pos, min_flow_neg: speed the valve gives just outside its dead zone,
            Kv±·dy_min through the AD calibration (m/s; rad/s for the lift).
        lower, upper: stroke ends (m; rad).
    """

    name: str
    gain_per_s: float
    delay_s: float
    lag_s: float
    min_flow_pos: float
    min_flow_neg: float
    lower: float
    upper: float


@dataclass(frozen=True)
class ActuatorMotion:
    """Actuator positions, velocities and accelerations now and one transport delay ahead (SI, (5,) each)."""

    q: np.ndarray
    velocity: np.ndarray
    velocity_ahead: np.ndarray
    acceleration_ahead: np.ndarray


def actuator_motion(
    state_at: Callable[[float], PoseState],
    solve_full: SolveFull,
    t: float,
    loops: tuple[UnitLoop, ...],
    q: np.ndarray,
    velocity: np.ndarray,
) -> ActuatorMotion:
    """Actuator motion of a pose plan whose actuators at ``t`` are ``q`` moving at ``velocity``
    (the caller has them: the plan's samples, or the control cycle's inverse), and one
    transport delay ahead.

    ``state_at(t)`` → pose state (``position``, ``velocity``, ``acceleration`` over x, z,
    roll, pitch); ``solve_full(pose)`` → (actuators, d actuators / d pose, …), the exact
    inverse. Velocities map through the Jacobian; the acceleration ahead as J·p̈ (the
    curvature term J̇·ṗ is left out: it enters the reference only times T_F/G = 0.0017–0.0086 s²).
    """
    v_ahead, a_ahead = np.empty(5), np.empty(5)
    delays = np.array([u.delay_s for u in loops])
    for d in np.unique(delays):
        ahead = state_at(t + float(d))
        jac_a = solve_full(ahead.position)[1]
        pick = delays == d
        v_ahead[pick] = (jac_a @ ahead.velocity)[pick]
        a_ahead[pick] = (jac_a @ ahead.acceleration)[pick]
    return ActuatorMotion(np.asarray(q, float), np.asarray(velocity, float), v_ahead, a_ahead)


def build_unit_loops(profile: Profile, a: float | None = None) -> tuple[UnitLoop, ...]:
    """The five unit loops of ``profile`` (tables 3-3, 3-4) under tuning ``a`` (thesis 2.57;
    default the profile's ``motion.controller_a``)."""
    if a is None:
        a = profile.motion.controller_a
    if not (isinstance(a, (int, float)) and 0.0 < a <= 2.0):
        raise UnitLoopError(f"a must be a number in (0, 2], got {a!r}")
    loops = []
    resolution = SensorScaling(profile).resolution  # SI per count
    for name, res in zip(ACTUATOR_NAMES, resolution, strict=True):
        s = profile.actuator(name)
        if s.transport_delay <= 0:
            raise UnitLoopError(
                f"actuators.{name}.transport_delay must be > 0 for the loop model, got {s.transport_delay}"
            )
        loops.append(
            UnitLoop(
                name=name,
                gain_per_s=s.valve_multiplier * a / s.transport_delay,
                delay_s=float(s.transport_delay),
                lag_s=float(s.time_constant),
                min_flow_pos=s.kv_pos * s.min_flow * res,
                min_flow_neg=s.kv_neg * s.min_flow * res,
                lower=float(s.min),
                upper=float(s.max),
            )
        )
    return tuple(loops)


def unit_loop_lag_s(loops: tuple[UnitLoop, ...]) -> np.ndarray:
    """How long each loop lags a ramp reference without feed-forward, L/(m a) + T_F, s.

    0.18 s lift, 0.35 s tilt and top link, 0.87 s sway limiters for the thesis values. (The
    minimum flow shortens the P part by the factor 1 − w/v: under 5 % at planned speeds.)
    """
    return np.array([1.0 / u.gain_per_s + u.lag_s for u in loops])


def feedforward_reference(loops: tuple[UnitLoop, ...], motion: ActuatorMotion) -> np.ndarray:
    """The reference under which each loop follows ``motion`` (module docstring), SI, clipped to the strokes."""
    r = np.empty(5)
    for i, u in enumerate(loops):
        v_ahead = float(motion.velocity_ahead[i])
        drive = v_ahead + u.lag_s * float(motion.acceleration_ahead[i])
        sgn = float(np.sign(drive))  # the valve's minimum flow follows the command's sign
        w = u.min_flow_pos if sgn > 0 else u.min_flow_neg if sgn < 0 else 0.0
        p_part = drive - sgn * w if abs(drive) > w else 0.0
        r[i] = float(motion.q[i]) + u.lag_s * float(motion.velocity[i]) + p_part / u.gain_per_s
        r[i] = min(max(r[i], u.lower), u.upper)
    return r


def safe_reference(
    check: Callable[[np.ndarray], object], planned: np.ndarray, shaped: np.ndarray, tries: int = 4
) -> tuple[np.ndarray, float]:
    """The shaped reference if ``check`` accepts it, else pulled back towards ``planned``.

    ``check(q)`` raises :class:`ValueError` for a reference outside a hard limit (the link's
    :meth:`~bridge.link.can_link.CanLink.check_reference`). Tries ``shaped``, then halves the
    feed-forward ``tries`` times; returns (reference, fraction of the feed-forward kept). The
    planned sample itself is returned unchecked (fraction 0): the planner checked it, and the
    link checks it again when it is sent.
    """
    planned, shaped = np.asarray(planned, float), np.asarray(shaped, float)
    frac = 1.0
    for _ in range(tries + 1):
        r = planned + frac * (shaped - planned)
        try:
            check(r)
        except ValueError:
            frac *= 0.5
            continue
        return r, frac
    return planned.copy(), 0.0


class FeedforwardShaper:
    """The reference to stream for a motion, for a control loop that evaluates its motion each cycle.

    ``loops``: :func:`build_unit_loops`; ``solve_full``: the exact inverse (pose → actuators,
    Jacobian, …); ``check``: the link's hard-limit check (raises :class:`ValueError`).
    ``enabled=False`` streams the planned actuators unchanged.
    """

    def __init__(
        self,
        loops: tuple[UnitLoop, ...],
        solve_full: SolveFull,
        check: Callable[[np.ndarray], object],
        *,
        enabled: bool = True,
    ) -> None:
        self.loops, self._solve_full, self._check, self.enabled = loops, solve_full, check, bool(enabled)
        self.pulled_back = 0
        """References whose feed-forward the hard-limit check made smaller (a count)."""

    def for_plan(
        self, state_at: Callable[[float], PoseState], t: float, planned: np.ndarray, rates: np.ndarray
    ) -> np.ndarray:
        """Reference at time ``t`` of a pose plan ``state_at`` whose actuators at ``t`` are ``planned``
        moving at ``rates``."""
        if not self.enabled:
            return np.asarray(planned, float)
        motion = actuator_motion(state_at, self._solve_full, t, self.loops, planned, rates)
        return self._safe(planned, feedforward_reference(self.loops, motion))

    def for_state(
        self, state: PoseState, planned: np.ndarray, rates: np.ndarray, *, jerk: np.ndarray | None = None
    ) -> np.ndarray:
        """Reference for a motion known only now (jog, track): pose-space ``state`` (position, velocity,
        acceleration) with actuators ``planned`` moving at ``rates``, and optionally the pose-space
        ``jerk`` now [m/s³, rad/s³]. The rates and accelerations one delay L ahead are extrapolated,
        v + L·a + L²·j/2 and a + L·j (J·p̈, J·p⃛), and stop at zero rather than change sign (a jog
        brakes to rest, it does not reverse by itself). Without the jerk (None: 0) a jerk-limited stop
        is over-led while its deceleration builds up (v + L·a overestimates the velocity one delay
        ahead by L²·|j|/2): the pistons ran up to 0.44 mrad past a stop at the roll face."""
        if not self.enabled:
            return np.asarray(planned, float)
        planned, rates = np.asarray(planned, float), np.asarray(rates, float)
        jac = self._solve_full(state.position)[1]
        acc = jac @ np.asarray(state.acceleration, float)
        jrk = np.zeros_like(acc) if jerk is None else jac @ np.asarray(jerk, float)
        delays = np.array([u.delay_s for u in self.loops])
        v_ahead = rates + delays * acc + 0.5 * delays**2 * jrk
        stops = v_ahead * rates < 0
        v_ahead[stops], a_ahead = 0.0, np.where(stops, 0.0, acc + delays * jrk)
        motion = ActuatorMotion(planned, rates, v_ahead, a_ahead)
        return self._safe(planned, feedforward_reference(self.loops, motion))

    def _safe(self, planned: np.ndarray, shaped: np.ndarray) -> np.ndarray:
        r, frac = safe_reference(self._check, planned, shaped)
        if frac < 1.0:
            self.pulled_back += 1
        return r
