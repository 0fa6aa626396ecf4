"""Unit (per-cylinder) position controller of the cylinder ECU (thesis 2.56–2.57, §2.5.6).

The thesis tunes a PID controller

    C(s) = k + k_i/s + k_d s                                               (thesis 2.56)
    k = a / (Kv L),   k_i = 0,   k_d = a T_F / (Kv L),   a = 0.581           (thesis 2.57)

for the delayed lagged integrator of thesis 1.1 and uses it on the ECU with these
modifications (thesis §2.5.6, figure 2-21), all implemented here:

1. derivative of the *measurement* instead of the error (no kick on reference steps);
2. different P gains for positive and negative command: ``Kv`` is ``kv_pos`` or
   ``kv_neg`` of the direction the command points to.  Because k_d / k = T_F for
   both directions, the PD law is ``k_dir · (e − T_F · dy/dt)`` and the direction is
   the sign of ``e − T_F · dy/dt``;
3. dead-zone compensation: a non-zero command is pushed out of the valve dead zone
   by adding ``±dz``;
4. the command is cut to zero near the reference, with hysteresis: a cylinder is driven
   until the error is within ``settle_counts`` (0: the reading equals the reference); the
   command is then zero for ``settle_wait_s`` (the oil in flight: transport delay and lag
   still move the piston) unless the error leaves ``cutoff_counts``; if the reading is then
   still within ``settle_counts`` the cylinder is *held* (command zero) while the reference
   is unchanged and the error stays within ``cutoff_counts`` (1), so AD flicker and the
   ±1-count jitter of a settled piston do not restart the valve; otherwise (it coasted one
   count over) it is driven back. A new reference count, or a drift beyond the band, drives
   again.
   The thesis gives no distance ("a small distance of the reference"); settling on the
   count itself is what makes the steady state quantisation-limited (half an AD step).
   ``settle_counts = cutoff_counts`` is the plain cut-off without hysteresis.

Output stage, in this order (documented assumption; the thesis figure 2-21 is not
legible in the digest):  PD → cut-off → saturate to ±254 (controller range, the
joystick range of the calibration program) → × valve multiplier (thesis table 3-3,
chosen "for a suitable speed", so it limits the speed to m·254) → + sign·dz in
valve units (the dead zone is a valve property) → round half up, at least dz + 1,
at most 254 → end-stop relay.  With the thesis's identified Kv, the effective loop
gain is therefore m·a/L for commands well outside the dead zone.

Units: reference, measurement and errors in AD counts; derivative in counts/s;
commands in valve command units (integers −254…254); time in s.

End-stop protection (thesis §2.3.1, §2.5.6): a relay per cylinder; while the
measurement is at or beyond a limit near a stroke end, only commands towards
safety pass ("relay-type": an on/off switch with optional hysteresis).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from bridge.sim.cylinder import AD_MAX_COUNTS, VALVE_MAX, CylinderParams
from planner.errors import HitchInputError
from planner.profiles.hitch import THESIS_CONTROLLER_A

__all__ = [
    "THESIS_A",
    "ControllerError",
    "ControllerConfig",
    "ControllerGains",
    "RelayLimits",
    "ControllerOutput",
    "EndStopRelay",
    "UnitController",
    "build_controller_gains",
    "build_relay_limits",
]

#: Tuning parameter a of (thesis 2.57) used on the machine (thesis §3.1); profile data, see ``Motion.controller_a``.
THESIS_A = THESIS_CONTROLLER_A


class ControllerError(HitchInputError):
    """Bad controller configuration or input; the message names the field and the allowed range."""


@dataclass(frozen=True)
class ControllerConfig:
    """Settings shared by the five unit controllers.

    ``a``: tuning parameter of (thesis 2.57), 0 < a ≤ 2.  ``period_s``: controller
    sample time [s]; the thesis ECU's rate is not stated, 10 ms (100 Hz) is assumed
    (T_F = 0.01 s was identified at one sample of that rate and the position message is
    sent at 100 Hz).  ``settle_counts``: a driven cylinder stops when |error| ≤ this
    [counts]; ``cutoff_counts``: a settled cylinder stays stopped while its reference is
    unchanged and |error| ≤ this [counts] (≥ ``settle_counts``).  ``settle_wait_s``: how
    long the command stays zero after reaching ``settle_counts`` before the cylinder is held
    or driven back [s] (assumed 0.2 s: transport delay 0.1 s plus the lag, with margin).
    ``relay_margin_counts``: distance of the end-stop relay limits inside the
    calibrated stroke ends [counts]; ``None`` → max(2, ceil(1 % of the count span)).
    ``relay_hysteresis_counts``: the relay releases this far back inside its limit.
    """

    a: float = THESIS_A
    period_s: float = 0.01
    cutoff_counts: int = 1
    settle_counts: int = 0
    settle_wait_s: float = 0.2
    relay_margin_counts: int | None = None
    relay_hysteresis_counts: int = 0

    def __post_init__(self) -> None:
        if not (isinstance(self.a, (int, float)) and math.isfinite(self.a) and 0 < self.a <= 2):
            raise ControllerError(f"a = {self.a!r} outside (0, 2]")
        if not (
            isinstance(self.period_s, (int, float)) and math.isfinite(self.period_s) and 1e-4 <= self.period_s <= 1.0
        ):
            raise ControllerError(f"period_s = {self.period_s!r} outside [1e-4, 1] s")
        for name, lo, hi in (("cutoff_counts", 0, 100), ("settle_counts", 0, 100), ("relay_hysteresis_counts", 0, 100)):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or not lo <= v <= hi:
                raise ControllerError(f"{name} = {v!r} must be an integer in [{lo}, {hi}]")
        if not (
            isinstance(self.settle_wait_s, (int, float))
            and math.isfinite(self.settle_wait_s)
            and 0.0 <= self.settle_wait_s <= 10.0
        ):
            raise ControllerError(f"settle_wait_s = {self.settle_wait_s!r} outside [0, 10] s")
        if self.settle_counts > self.cutoff_counts:
            raise ControllerError(
                f"settle_counts = {self.settle_counts} must not exceed cutoff_counts = {self.cutoff_counts}"
            )
        m = self.relay_margin_counts
        if m is not None and (isinstance(m, bool) or not isinstance(m, int) or not 0 <= m <= 200):
            raise ControllerError(f"relay_margin_counts = {m!r} must be None or an integer in [0, 200]")


@dataclass(frozen=True)
class ControllerGains:
    """Gains of one unit controller (thesis 2.57): P gains per command direction
    [command units per count] and the derivative gains k_d = k · T_F [command units per count/s]."""

    k_pos: float
    k_neg: float
    kd_pos: float
    kd_neg: float
    derivative_time_s: float  # T_F = k_d / k


@dataclass(frozen=True)
class RelayLimits:
    """End-stop relay of one cylinder [counts]: positive commands blocked at ``high_counts``
    and above, negative at ``low_counts`` and below; released ``hysteresis_counts`` inside."""

    low_counts: int
    high_counts: int
    hysteresis_counts: int = 0

    def __post_init__(self) -> None:
        if not self.low_counts < self.high_counts:
            raise ControllerError(
                f"relay low_counts ({self.low_counts}) must be below high_counts ({self.high_counts})"
            )
        if self.hysteresis_counts < 0:
            raise ControllerError(f"relay hysteresis_counts must be >= 0, got {self.hysteresis_counts}")


@dataclass(frozen=True)
class ControllerOutput:
    """Everything one controller update computed (for logging and tests).

    ``error_counts`` = reference − measurement; ``rate_counts_per_s`` = backward
    difference of the measurement; ``pd`` = PD demand before saturation [command
    units]; ``valve_unlimited`` = command after multiplier and dead-zone compensation,
    before the relay; ``relay_blocked``: the relay zeroed it; ``command``: valve command.
    """

    error_counts: int
    rate_counts_per_s: float
    pd: float
    valve_unlimited: int
    relay_blocked: bool
    command: int


def build_controller_gains(params: CylinderParams, a: float = THESIS_A) -> ControllerGains:
    """Gains of (thesis 2.57) for one cylinder: k = a/(Kv L), k_d = a T_F/(Kv L), per direction."""
    if not (math.isfinite(a) and 0 < a <= 2):
        raise ControllerError(f"a = {a!r} outside (0, 2]")
    L = params.transport_delay_s
    if L <= 0:
        raise ControllerError(f"{params.name}: the tuning rule needs transport_delay_s > 0, got {L}")
    tf = params.time_constant_s
    k_pos = a / (params.kv_pos * L)
    k_neg = a / (params.kv_neg * L)
    return ControllerGains(k_pos=k_pos, k_neg=k_neg, kd_pos=k_pos * tf, kd_neg=k_neg * tf, derivative_time_s=tf)


def build_relay_limits(params: CylinderParams, config: ControllerConfig = ControllerConfig()) -> RelayLimits:
    """Relay limits inside the calibrated stroke ends (margin per ``config``)."""
    span = params.counts_max - params.counts_min
    margin = config.relay_margin_counts
    if margin is None:
        margin = max(2, math.ceil(0.01 * span))
    if 2 * margin >= span:
        raise ControllerError(f"{params.name}: relay_margin_counts = {margin} leaves no stroke (span {span} counts)")
    return RelayLimits(params.counts_min + margin, params.counts_max - margin, config.relay_hysteresis_counts)


def _check_counts(name: str, v) -> int:
    if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
        raise ControllerError(f"{name} must be an integer count, got {v!r}")
    v = int(v)
    if not 0 <= v <= AD_MAX_COUNTS:
        raise ControllerError(f"{name} = {v} outside the 10-bit range 0…1023")
    return v


class EndStopRelay:
    """Relay-type end-stop protection of one cylinder (thesis §2.3.1)."""

    def __init__(self, limits: RelayLimits) -> None:
        self.limits = limits
        self._high = False
        self._low = False

    def reset(self) -> None:
        self._high = self._low = False

    def observe(self, measurement_counts: int) -> None:
        """Update the relay state from a measurement [counts]."""
        lim = self.limits
        y = measurement_counts
        if y >= lim.high_counts:
            self._high = True
        elif y < lim.high_counts - lim.hysteresis_counts:
            self._high = False
        if y <= lim.low_counts:
            self._low = True
        elif y > lim.low_counts + lim.hysteresis_counts:
            self._low = False

    @property
    def engaged(self) -> bool:
        """True while the cylinder is at a protective limit."""
        return self._high or self._low

    def allows(self, command: int) -> bool:
        """Whether ``command`` points towards safety (or the relay is released)."""
        return not ((command > 0 and self._high) or (command < 0 and self._low))


class UnitController:
    """Modified PD unit controller of one cylinder (thesis 2.56–2.57, §2.5.6); call
    :meth:`update` once per controller period."""

    def __init__(self, params: CylinderParams, config: ControllerConfig = ControllerConfig()) -> None:
        self.params = params
        self.config = config
        self.gains = build_controller_gains(params, config.a)
        self.relay = EndStopRelay(build_relay_limits(params, config))
        self._prev: int | None = None
        self._wait_periods = math.ceil(config.settle_wait_s / config.period_s - 1e-9)
        self._settled_on: int | None = None  # reference count reached (waiting or holding)
        self._waited = 0  # controller periods since it was reached

    @property
    def holding(self) -> bool:
        """True while the cylinder is settled and held on its reference (command zero)."""
        return self._settled_on is not None and self._waited >= self._wait_periods

    def reset(self) -> None:
        """Forget the derivative memory and the settled state, release the relay (ECU restart, controllers off)."""
        self._prev = None
        self._settled_on = None
        self._waited = 0
        self.relay.reset()

    def observe(self, measurement_counts: int) -> None:
        """Take a measurement without producing a command (keeps derivative memory and relay current)."""
        y = _check_counts(f"{self.params.name} measurement_counts", measurement_counts)
        self.relay.observe(y)
        self._prev = y

    def update(self, reference_counts: int, measurement_counts: int) -> ControllerOutput:
        """One controller step: reference and measurement [counts] → valve command."""
        p, g, cfg = self.params, self.gains, self.config
        r = _check_counts(f"{p.name} reference_counts", reference_counts)
        y = _check_counts(f"{p.name} measurement_counts", measurement_counts)
        rate = 0.0 if self._prev is None else (y - self._prev) / cfg.period_s
        self._prev = y
        self.relay.observe(y)
        e = r - y
        s = e - g.derivative_time_s * rate
        pd = (g.k_pos if s > 0 else g.k_neg) * s
        if self._settled_on is not None:
            if r != self._settled_on or abs(e) > cfg.cutoff_counts:
                self._settled_on = None  # new reference or drift beyond the band: drive again
            elif self._waited < self._wait_periods:
                self._waited += 1  # oil in flight: wait, then hold or drive back
                if self._waited == self._wait_periods and abs(e) > cfg.settle_counts:
                    self._settled_on = None  # coasted over: drive back
        if self._settled_on is None and abs(e) <= cfg.settle_counts:
            self._settled_on, self._waited = r, 0
        if self._settled_on is not None or s == 0:
            valve = 0
        else:
            v = p.valve_multiplier * max(-VALVE_MAX, min(VALVE_MAX, pd))
            mag = math.floor(abs(v) + p.dead_zone + 0.5)
            mag = min(VALVE_MAX, max(mag, math.floor(p.dead_zone) + 1))
            valve = int(math.copysign(mag, v))
        allowed = self.relay.allows(valve)
        return ControllerOutput(
            error_counts=e,
            rate_counts_per_s=rate,
            pd=pd,
            valve_unlimited=valve,
            relay_blocked=not allowed,
            command=valve if allowed else 0,
        )
