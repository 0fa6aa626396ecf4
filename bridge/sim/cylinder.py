"""One hydraulic cylinder with its proportional valve, as identified in the thesis (thesis 1.1).

The valve + cylinder is the delayed, lagged integrator

    G(s) = K / (s (1 + T_F s)) · e^(−sL)                                   (thesis 1.1)

from the integer valve command ``u`` ∈ [−254, 254] (after the valve multiplier of
thesis table 3-3) to the cylinder position in AD counts, with the valve
non-idealities of thesis figure 1-10: a dead zone ``dz`` and a minimum flow
``dy_min`` once the dead zone is crossed.  Parameters come from thesis table 3-4
(profile ``[actuators.*]``).

Static valve characteristic (flow demand, AD counts per second)::

    q_cmd(u) = 0                                          if |u| <= dz
    q_cmd(u) = sign(u) · Kv_dir · g · (|u| − dz + dy_min)  if |u| >  dz

with ``Kv_dir = kv_pos`` for ``u > 0`` (the reading grows) and ``kv_neg`` for
``u < 0``, and ``g = 1 + gain_error`` the simulated valve-gain error.  So the
flow jumps to ``Kv·dy_min`` as the dead zone is crossed ("the flow does not start
exactly from zero", thesis §1.4) and then grows with slope ``Kv`` per command
unit, which is the slope the thesis identified on the differentiated reading.

Integration scheme.  Time advances in fixed internal steps ``h`` (default 1 ms).
The valve command is held constant over a step (zero-order hold) and enters a
FIFO delay line of ``round(L / h)`` steps (the transport delay L).  The lag and
the integrator are then advanced with their *exact* ZOH solution::

    α      = exp(−h / T_F)
    x[n+1] = x[n] + q_cmd·h + (q[n] − q_cmd)·T_F·(1 − α)
    q[n+1] = q_cmd + (q[n] − q_cmd)·α

(``q`` = flow after the lag, ``x`` = position in counts, float), so for commands
that change only on the step grid the simulation equals the continuous model
except at the end stops, where the position is clamped to
``[counts_min, counts_max]`` at the end of every step (the piston stops at the
physical end; the valve flow state ``q`` is unaffected, the excess goes over the
relief valve).  The clamp is therefore resolved to one step.

Measurement: a 10-bit AD conversion of the position — optional Gaussian noise
(counts), then round-half-up to an integer and clip to 0…1023.
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from planner.errors import HitchInputError

__all__ = [
    "AD_MAX_COUNTS",
    "VALVE_MAX",
    "CylinderError",
    "CylinderParams",
    "Cylinder",
    "build_cylinder_params",
    "valve_flow_counts_per_s",
]

#: Largest 10-bit AD reading.
AD_MAX_COUNTS = 1023
#: Largest valve command magnitude (thesis §3.1: commands −254 … 254).
VALVE_MAX = 254
#: Allowed relative valve-gain error of the simulated plant.
GAIN_ERROR_RANGE = (-0.9, 10.0)
#: Allowed AD noise standard deviation [counts].
NOISE_COUNTS_RANGE = (0.0, 100.0)


class CylinderError(HitchInputError):
    """Bad input to the cylinder model; the message names the field and the allowed range."""


def _finite(name: str, value: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise CylinderError(f"{name} must be a real number, got {value!r}") from None
    if not math.isfinite(v):
        raise CylinderError(f"{name} must be finite, got {value!r}")
    return v


@dataclass(frozen=True)
class CylinderParams:
    """Identified parameters of one valve + cylinder (thesis tables 3-1 … 3-4).

    ``stroke_min``/``stroke_max`` are the SI stroke ends (lift: lift-arm angle [rad];
    the others: pin-to-pin length [m]) that correspond linearly to
    ``counts_min``/``counts_max`` [AD counts].  ``kv_pos``/``kv_neg`` [counts/s per
    command unit], ``transport_delay_s`` = L [s], ``time_constant_s`` = T_F [s],
    ``min_flow`` = dy_min and ``dead_zone`` = dz [command units],
    ``valve_multiplier`` (thesis table 3-3, used by the unit controller).
    """

    name: str
    stroke_min: float
    stroke_max: float
    counts_min: int
    counts_max: int
    valve_multiplier: float
    kv_pos: float
    kv_neg: float
    transport_delay_s: float
    time_constant_s: float
    min_flow: float
    dead_zone: float

    def __post_init__(self) -> None:
        for f in (
            "stroke_min",
            "stroke_max",
            "valve_multiplier",
            "kv_pos",
            "kv_neg",
            "transport_delay_s",
            "time_constant_s",
            "min_flow",
            "dead_zone",
        ):
            _finite(f"{self.name}.{f}", getattr(self, f))
        if not self.stroke_min < self.stroke_max:
            raise CylinderError(
                f"{self.name}: stroke_min ({self.stroke_min}) must be below stroke_max ({self.stroke_max})"
            )
        if not 0 <= self.counts_min < self.counts_max <= AD_MAX_COUNTS:
            raise CylinderError(
                f"{self.name}: need 0 <= counts_min < counts_max <= {AD_MAX_COUNTS}, "
                f"got {self.counts_min}, {self.counts_max}"
            )
        if self.kv_pos <= 0 or self.kv_neg <= 0:
            raise CylinderError(f"{self.name}: kv_pos and kv_neg must be > 0")
        if not 0 < self.valve_multiplier <= 1:
            raise CylinderError(f"{self.name}.valve_multiplier must lie in (0, 1], got {self.valve_multiplier}")
        if self.transport_delay_s < 0 or self.time_constant_s < 0:
            raise CylinderError(f"{self.name}: transport_delay_s and time_constant_s must be >= 0")
        if not 0 <= self.dead_zone < VALVE_MAX or not 0 <= self.min_flow <= VALVE_MAX:
            raise CylinderError(f"{self.name}: dead_zone must lie in [0, {VALVE_MAX}), min_flow in [0, {VALVE_MAX}]")

    @property
    def counts_per_unit(self) -> float:
        """Calibration slope [counts per m, or per rad for the lift]."""
        return (self.counts_max - self.counts_min) / (self.stroke_max - self.stroke_min)

    def counts_to_si(self, counts: float) -> float:
        """AD reading [counts] → position [m or rad], linear through the stroke ends (thesis table 3-1).

        Accepts any reading 0…1023 (a noisy reading may lie slightly outside the stroke).
        """
        c = _finite(f"{self.name} counts", counts)
        if not 0 <= c <= AD_MAX_COUNTS:
            raise CylinderError(f"{self.name} counts = {counts!r} outside the 10-bit range 0…{AD_MAX_COUNTS}")
        return self.stroke_min + (c - self.counts_min) / self.counts_per_unit

    def si_to_counts(self, value: float) -> float:
        """Position [m or rad] within the stroke → AD reading [counts, float; round at the bus]."""
        v = _finite(f"{self.name} position", value)
        if not self.stroke_min <= v <= self.stroke_max:
            raise CylinderError(
                f"{self.name} position = {value!r} outside the stroke [{self.stroke_min}, {self.stroke_max}]"
            )
        return self.counts_min + (v - self.stroke_min) * self.counts_per_unit


def build_cylinder_params(name: str, spec) -> CylinderParams:
    """Parameters of one cylinder from a profile's ``ActuatorSpec`` (``profile.actuator(name)``)."""
    return CylinderParams(
        name=name,
        stroke_min=float(spec.min),
        stroke_max=float(spec.max),
        counts_min=int(spec.counts_min),
        counts_max=int(spec.counts_max),
        valve_multiplier=float(spec.valve_multiplier),
        kv_pos=float(spec.kv_pos),
        kv_neg=float(spec.kv_neg),
        transport_delay_s=float(spec.transport_delay),
        time_constant_s=float(spec.time_constant),
        min_flow=float(spec.min_flow),
        dead_zone=float(spec.dead_zone),
    )


def _check_command(name: str, u) -> int:
    if isinstance(u, bool) or not isinstance(u, (int, np.integer)):
        raise CylinderError(f"{name} valve command must be an integer, got {u!r}")
    if not -VALVE_MAX <= int(u) <= VALVE_MAX:
        raise CylinderError(f"{name} valve command = {u} outside −{VALVE_MAX}…{VALVE_MAX}")
    return int(u)


def valve_flow_counts_per_s(params: CylinderParams, u: int, gain_factor: float = 1.0) -> float:
    """Static valve characteristic q_cmd(u) [counts/s] (thesis 1.1 with dead zone and dy_min).

    ``gain_factor`` multiplies the identified gain (1 + valve gain error).
    """
    u = _check_command(params.name, u)
    mag = abs(u)
    if mag <= params.dead_zone:
        return 0.0
    kv = params.kv_pos if u > 0 else params.kv_neg
    return math.copysign(kv * gain_factor * (mag - params.dead_zone + params.min_flow), u)


class Cylinder:
    """Simulated valve + cylinder, advanced in fixed steps of ``step_s`` (default 1 ms).

    ``gain_error`` is the relative valve-gain error of the *true* plant (0.1 → 10 %
    faster than identified); ``noise_counts`` is the standard deviation of the
    Gaussian AD noise [counts], drawn from ``rng`` (a seeded ``numpy.random.Generator``).
    ``initial_counts`` defaults to mid-stroke.
    """

    def __init__(
        self,
        params: CylinderParams,
        *,
        step_s: float = 1e-3,
        gain_error: float = 0.0,
        noise_counts: float = 0.0,
        rng: np.random.Generator | None = None,
        initial_counts: float | None = None,
    ) -> None:
        self.params = params
        step_s = _finite("step_s", step_s)
        if not 1e-5 <= step_s <= 0.01:
            raise CylinderError(f"step_s = {step_s} outside [1e-5, 0.01] s")
        gain_error = _finite(f"{params.name} gain_error", gain_error)
        if not GAIN_ERROR_RANGE[0] <= gain_error <= GAIN_ERROR_RANGE[1]:
            raise CylinderError(f"{params.name} gain_error = {gain_error} outside [−0.9, 10] (relative)")
        noise_counts = _finite("noise_counts", noise_counts)
        if not NOISE_COUNTS_RANGE[0] <= noise_counts <= NOISE_COUNTS_RANGE[1]:
            raise CylinderError(f"noise_counts = {noise_counts} outside [0, 100] counts")
        if noise_counts > 0 and rng is None:
            raise CylinderError("noise_counts > 0 needs an rng (numpy.random.Generator)")
        self._h = step_s
        self._gain = 1.0 + gain_error
        self._noise = noise_counts
        self._rng = rng
        t = params.time_constant_s
        self._alpha = math.exp(-step_s / t) if t > 0 else 0.0
        self._lag_gain = t * (1.0 - self._alpha)  # ∫ e^(−τ/T) dτ over one step
        self._delay_steps = int(round(params.transport_delay_s / step_s))
        self._line: deque[int] = deque([0] * self._delay_steps)
        self._quiet_steps = self._delay_steps  # commands in a row inside the dead zone (≥ delay: a quiet line)
        if initial_counts is None:
            x0 = 0.5 * (params.counts_min + params.counts_max)
        else:
            x0 = _finite(f"{params.name} initial_counts", initial_counts)
            if not params.counts_min <= x0 <= params.counts_max:
                raise CylinderError(
                    f"{params.name} initial_counts = {x0} outside the stroke {params.counts_min}…{params.counts_max}"
                )
        self._x = x0
        self._q = 0.0
        self._u = 0

    # -- state -------------------------------------------------------------------------
    @property
    def step_s(self) -> float:
        """Internal integration step [s]."""
        return self._h

    @property
    def delay_steps(self) -> int:
        """Transport delay in internal steps (round(L / step))."""
        return self._delay_steps

    @property
    def position_counts(self) -> float:
        """True piston position [counts, float]."""
        return self._x

    @property
    def position_si(self) -> float:
        """True piston position [m, or rad for the lift]."""
        return self.params.counts_to_si(self._x)

    @property
    def flow_counts_per_s(self) -> float:
        """Valve flow after the lag [counts/s] (the piston velocity unless at an end stop)."""
        return self._q

    @property
    def valve_command(self) -> int:
        """Command currently given to the valve (before the transport delay)."""
        return self._u

    # -- simulation --------------------------------------------------------------------
    def step(self, u: int) -> None:
        """Hold valve command ``u`` for one internal step and advance the model (exact ZOH)."""
        u = _check_command(self.params.name, u)
        self._u = u
        p = self.params
        self._quiet_steps = self._quiet_steps + 1 if -p.dead_zone <= u <= p.dead_zone else 0
        if self._delay_steps:
            self._line.append(u)
            u = self._line.popleft()
        if self._q == 0.0 and -p.dead_zone <= u <= p.dead_zone:
            return  # at rest with a closed valve: q_cmd = 0 and the lag is settled, so x and q stay exactly
        qc = valve_flow_counts_per_s(p, u, self._gain)
        dq = self._q - qc
        if p.time_constant_s > 0:
            x = self._x + qc * self._h + dq * self._lag_gain
            self._q = qc + dq * self._alpha
        else:
            x = self._x + qc * self._h
            self._q = qc
        self._x = min(max(x, float(p.counts_min)), float(p.counts_max))

    def run(self, u: int, n_steps: int) -> None:
        """Hold ``u`` for ``n_steps`` internal steps (exactly as ``n_steps`` calls of :meth:`step`).

        At rest — :meth:`settled`, and ``u`` and every command still in the transport delay inside the
        dead zone — every step leaves position and flow exactly as they are and only moves the delay
        line: the remaining steps are done at once (a hitch at rest costs no integration).
        """
        if n_steps < 0:
            raise CylinderError(f"n_steps must be >= 0, got {n_steps}")
        if n_steps == 0:
            return
        u = _check_command(self.params.name, u)
        dz = self.params.dead_zone
        left = n_steps
        if -dz <= u <= dz:
            while left and not (self.settled() and self._quiet_steps >= self._delay_steps):
                self.step(u)
                left -= 1
            if left:
                self._u = u
                self._quiet_steps += left
                line = self._line
                if line.count(u) != len(line):  # a line holding only u already stays as it is
                    for _ in range(min(left, self._delay_steps)):
                        line.popleft()
                        line.append(u)
            return
        for _ in range(left):
            self.step(u)

    def settled(self) -> bool:
        """True when a step with the valve in its dead zone leaves position and flow exactly as they
        are (a fixed point of :meth:`step`'s floating-point update, not a tolerance): no flow, or a
        lag so far decayed that it no longer changes in floating point — after a move the flow
        decays towards 0.0 but stops at the smallest subnormal numbers, which move nothing."""
        q = self._q
        if q == 0.0:
            return True
        if self.params.time_constant_s <= 0:
            return False
        x = self._x + 0.0 * self._h + q * self._lag_gain  # step() with q_cmd = 0.0, operation for operation
        p = self.params
        return 0.0 + q * self._alpha == q and min(max(x, float(p.counts_min)), float(p.counts_max)) == self._x

    def measure(self) -> int:
        """One 10-bit AD sample [counts]: position + noise, rounded half up, clipped to 0…1023."""
        x = self._x
        if self._noise > 0 and self._rng is not None:  # the constructor requires an rng with noise
            x += self._noise * float(self._rng.standard_normal())
        return int(min(max(math.floor(x + 0.5), 0), AD_MAX_COUNTS))
