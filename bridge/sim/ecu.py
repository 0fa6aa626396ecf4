"""The simulated cylinder ECU: five cylinders, their unit controllers, the watchdog and
the system-state byte, stepped in simulated time (thesis §2.4–2.5.6).

This is the machine's twin behind the CAN API, without the CAN wiring: a caller
(the CAN loop, a test, a bench script) delivers position references with
:meth:`CylinderECU.set_reference` and advances time with :meth:`CylinderECU.step`.
No threads, no wall clock: time only moves in ``step``.

Timing (all on an integer grid of internal steps, default 1 ms):

* every controller period (default 10 ms, 100 Hz — assumed, see
  :class:`~bridge.sim.controller.ControllerConfig`) the ECU samples the five AD
  channels (this is what :meth:`measurement_counts` returns and what 0xFF22 carries),
  and — if controllers are on, a reference has arrived and the watchdog has not
  expired — runs the unit controllers to new valve commands;
* every internal step the watchdog is checked (valves forced to zero as soon as the
  last reference is ``watchdog_timeout_s`` old, independent of the controller tick; after such a
  trip they stay at zero until the references have arrived without a break for
  ``watchdog_rearm_s``: references queued up during a link stall never move a cylinder,
  :mod:`bridge.sim.watchdog`),
  and each cylinder integrates one step with its valve command (see
  :mod:`bridge.sim.cylinder` for the exact ZOH scheme and the transport delay).

A reference delivered at ``now_s`` is latched at the step ``now_s`` falls on and used
from the next controller tick on.

The system-state byte it sends is defined in :mod:`bridge.isobus.system_state`.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np

from bridge.isobus.system_state import (
    STATE_CONTROLLERS_ON,
    STATE_END_STOP_RELAY,
    STATE_NO_REFERENCE,
    STATE_RESTART_SHIFT,
    STATE_WATCHDOG_TRIPPED,
)
from bridge.sim.controller import ControllerConfig, ControllerOutput, UnitController
from bridge.sim.cylinder import AD_MAX_COUNTS, Cylinder, CylinderParams, build_cylinder_params
from bridge.sim.watchdog import DEFAULT_REARM_S, Watchdog
from planner.errors import HitchInputError
from planner.profiles.hitch import Profile, load_profile

__all__ = ["ACTUATOR_ORDER", "CylinderECU", "ECUError", "HOLD_AFTER_REPEATS"]

#: Actuator order of every array in and out of the ECU.
ACTUATOR_ORDER: tuple[str, ...] = ("lift", "tilt", "top", "left", "right")
#: repeats of one reference in a row after which the ECU counts as holding (:attr:`CylinderECU.holding`)
HOLD_AFTER_REPEATS = 2


class ECUError(HitchInputError):
    """Bad input to the simulated ECU; the message names the field and the allowed range."""


def _per_cylinder(name: str, value, default: float) -> list[float]:
    """Scalar, 5-sequence (ACTUATOR_ORDER) or mapping → list of 5 floats."""
    if value is None:
        return [default] * 5
    if isinstance(value, Mapping):
        unknown = set(value) - set(ACTUATOR_ORDER)
        if unknown:
            raise ECUError(f"{name}: unknown actuator(s) {sorted(unknown)}; allowed {ACTUATOR_ORDER}")
        out = [value.get(n, default) for n in ACTUATOR_ORDER]
    elif isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        out = [value] * 5
    else:
        out = list(np.asarray(value, dtype=float).reshape(-1))
        if len(out) != 5:
            raise ECUError(f"{name} needs 5 values ({', '.join(ACTUATOR_ORDER)}), got {len(out)}")
    res = [float(v) for v in out]
    if not all(math.isfinite(v) for v in res):
        raise ECUError(f"{name} must be finite, got {res}")
    return res


def _reference_counts(counts) -> tuple[int, ...]:
    if isinstance(counts, Mapping):
        keys = set(counts)
        if keys != set(ACTUATOR_ORDER):
            raise ECUError(
                f"reference needs exactly the keys {ACTUATOR_ORDER}; "
                f"missing {sorted(set(ACTUATOR_ORDER) - keys)}, unknown {sorted(keys - set(ACTUATOR_ORDER))}"
            )
        values = [counts[n] for n in ACTUATOR_ORDER]
    else:
        if isinstance(counts, (str, bytes)) or not isinstance(counts, (Sequence, np.ndarray)):
            raise ECUError(f"reference must be a mapping or a sequence of 5 counts, got {type(counts).__name__}")
        if isinstance(counts, np.ndarray):
            if counts.dtype == np.bool_:
                raise ECUError("reference counts must be integers, got a boolean array")
            values = list(counts.reshape(-1))
        else:
            values = list(counts)
        if len(values) != 5:
            raise ECUError(f"reference needs 5 counts ({', '.join(ACTUATOR_ORDER)}), got {len(values)}")
    out = []
    for n, v in zip(ACTUATOR_ORDER, values, strict=True):
        if isinstance(v, (bool, np.bool_)) or not isinstance(v, (int, float, np.integer, np.floating)):
            raise ECUError(f"reference {n} must be an integer count, got {v!r}")
        if not (math.isfinite(v) and float(v).is_integer()):
            raise ECUError(f"reference {n} = {v!r} is not an integer count")
        if not 0 <= int(v) <= AD_MAX_COUNTS:
            raise ECUError(f"reference {n} = {int(v)} outside the 10-bit range 0…{AD_MAX_COUNTS}")
        out.append(int(v))
    return tuple(out)


class CylinderECU:
    """Simulated cylinder ECU (PhyCORE-MPC555 of the thesis, source address 169).

    ``profile``: a :class:`~planner.profiles.hitch.Profile` or a profile name / path.
    ``rng``: ``numpy.random.Generator`` or int seed for the AD noise (None → seed 0,
    reproducible).  ``noise_counts``: AD noise standard deviation [counts], scalar or per
    cylinder.  ``gain_error``: relative valve-gain error of the simulated plant (scalar,
    5-sequence or mapping by actuator name; the controllers keep the identified gains).
    ``watchdog_timeout_s``, ``watchdog_rearm_s``: see :mod:`bridge.sim.watchdog`.  ``controller``: shared
    unit-controller settings (default: :class:`ControllerConfig` with the profile's
    ``motion.controller_a``).  ``step_s``: internal integration step [s].
    ``initial_counts``: start positions [counts] (default: the profile's neutral, else
    mid-stroke).  ``controllers_enabled``: initial position of the on/off switch.
    ``calibration``: the AD calibration the ECU's firmware was configured with, when the
    simulated machine (``profile``, a truth of :mod:`bridge.sim.truth`) differs from it: the
    rear hitch position the ECU reports is the lift reading as a fraction of this
    calibration's travel (default: ``profile``'s own, the twin of today).
    """

    def __init__(
        self,
        profile: Profile | str | Path = "thesis-t132",
        *,
        rng: np.random.Generator | int | None = None,
        noise_counts=0.0,
        gain_error=None,
        watchdog_timeout_s: float = 0.1,
        watchdog_rearm_s: float = DEFAULT_REARM_S,
        controller: ControllerConfig | None = None,
        step_s: float = 1e-3,
        initial_counts=None,
        controllers_enabled: bool = True,
        calibration: Profile | None = None,
    ) -> None:
        if not isinstance(profile, Profile):
            profile = load_profile(profile)
        if calibration is not None and not isinstance(calibration, Profile):
            raise ECUError(f"calibration must be a Profile or None, got {type(calibration).__name__}")
        lift_cal = (calibration if calibration is not None else profile).actuator("lift")
        self._lift_calibration = (float(lift_cal.counts_min), float(lift_cal.counts_max))
        if controller is None:  # the machine's own tuning a (thesis 2.57), profile data
            controller = ControllerConfig(a=profile.motion.controller_a)
        if not isinstance(controller, ControllerConfig):
            raise ECUError(f"controller must be a ControllerConfig, got {type(controller).__name__}")
        if isinstance(rng, np.random.Generator):
            self._rng = rng
        elif rng is None or (isinstance(rng, (int, np.integer)) and not isinstance(rng, bool) and rng >= 0):
            self._rng = np.random.default_rng(0 if rng is None else int(rng))
        else:
            raise ECUError(f"rng must be a numpy.random.Generator, a non-negative int seed or None, got {rng!r}")
        if not (isinstance(step_s, (int, float)) and math.isfinite(step_s) and 1e-5 <= step_s <= 0.01):
            raise ECUError(f"step_s = {step_s!r} outside [1e-5, 0.01] s")
        ratio = controller.period_s / step_s
        if abs(ratio - round(ratio)) > 1e-6 or round(ratio) < 1:
            raise ECUError(f"controller.period_s ({controller.period_s}) must be a whole multiple of step_s ({step_s})")
        self.profile = profile
        self.config = controller
        self._h = float(step_s)
        self._ticks_per_period = int(round(ratio))
        self.params: tuple[CylinderParams, ...] = tuple(
            build_cylinder_params(n, profile.actuator(n)) for n in ACTUATOR_ORDER
        )
        noise = _per_cylinder("noise_counts", noise_counts, 0.0)
        gains = _per_cylinder("gain_error", gain_error, 0.0)
        x0 = self._initial_counts(initial_counts)
        self._cylinders = tuple(
            Cylinder(p, step_s=self._h, gain_error=g, noise_counts=s, rng=self._rng, initial_counts=x)
            for p, g, s, x in zip(self.params, gains, noise, x0, strict=True)
        )
        self._controllers = tuple(UnitController(p, controller) for p in self.params)
        self._watchdog = Watchdog(watchdog_timeout_s, watchdog_rearm_s)
        self._tick = 0
        self._enabled = bool(controllers_enabled)
        self._restarts = 0
        self._reference: tuple[int, ...] | None = None
        self._repeats = 0  # references in a row equal to the one before
        self._valves = [0] * 5
        self._outputs: list[ControllerOutput | None] = [None] * 5
        self._meas = [c.measure() for c in self._cylinders]

    def _initial_counts(self, initial_counts) -> list[float]:
        out = []
        for n, p in zip(ACTUATOR_ORDER, self.params, strict=True):
            neutral = self.profile.actuator(n).neutral
            out.append(p.si_to_counts(neutral) if neutral is not None else 0.5 * (p.counts_min + p.counts_max))
        if initial_counts is None:
            return out
        if isinstance(initial_counts, Mapping):
            given = _per_cylinder("initial_counts", {n: initial_counts[n] for n in initial_counts}, 0.0)
            return [g if n in initial_counts else d for n, g, d in zip(ACTUATOR_ORDER, given, out, strict=True)]
        return _per_cylinder("initial_counts", initial_counts, 0.0)

    # -- inputs ------------------------------------------------------------------------
    @property
    def time_s(self) -> float:
        """Simulated time [s]."""
        return self._tick * self._h

    @property
    def step_s(self) -> float:
        """Internal integration step [s]."""
        return self._h

    def set_reference(self, counts, now_s: float) -> None:
        """Deliver a position reference (5 counts, ACTUATOR_ORDER or mapping) arriving at ``now_s`` [s].

        Advances the simulation to ``now_s`` first; ``now_s`` may not lie in the past.
        """
        ref = _reference_counts(counts)
        self.step(now_s)
        self._watchdog.feed(self.time_s)
        self._repeats = self._repeats + 1 if ref == self._reference else 0
        self._reference = ref

    def step(self, until_s: float) -> None:
        """Advance simulated time to ``until_s`` [s] (to the internal step it falls on).

        Afterwards the cylinders have been integrated up to ``time_s``; the outputs are
        the last AD sample and the valve commands held from ``time_s`` on (the watchdog
        is applied at ``time_s`` itself).
        """
        if (
            isinstance(until_s, bool)
            or not isinstance(until_s, (int, float, np.integer, np.floating))
            or not math.isfinite(until_s)
        ):
            raise ECUError(f"time must be a finite number of seconds, got {until_s!r}")
        if until_s < self.time_s - 0.5 * self._h:
            raise ECUError(f"time {until_s} s is before the ECU's simulated time {self.time_s} s")
        target = math.floor(until_s / self._h + 1e-6)
        while self._tick < target:
            self._advance(target)
        if self._watchdog.expired(self.time_s):  # the watchdog is a timer, not tied to ticks
            self._valves = [0] * 5

    @property
    def controllers_enabled(self) -> bool:
        """The controllers on/off switch; off → valves zero at once."""
        return self._enabled

    @controllers_enabled.setter
    def controllers_enabled(self, on: bool) -> None:
        if not isinstance(on, (bool, np.bool_)):
            raise ECUError(f"controllers_enabled must be a bool, got {on!r}")
        self._enabled = bool(on)
        if not on:
            self._valves = [0] * 5

    def restart(self) -> None:
        """Simulate an ECU reset: controllers, relays and watchdog reset, reference forgotten,
        valves zero, restart counter +1.  The switch position and the machine are unchanged."""
        self._restarts += 1
        self._reference, self._repeats = None, 0
        self._valves = [0] * 5
        self._outputs = [None] * 5
        self._watchdog.reset()
        for c in self._controllers:
            c.reset()

    # -- simulation --------------------------------------------------------------------
    def _advance(self, target: int) -> None:
        """One internal step; with every valve closed, every step up to the next controller period
        (or ``target``) at once — nothing but the cylinders changes between controller updates, and a
        watchdog expiring meanwhile closes valves that are closed already."""
        now = self._tick * self._h
        if self._tick % self._ticks_per_period == 0:
            self._control(now)
        if self._watchdog.expired(now):
            self._valves = [0] * 5
        if any(self._valves):
            for cyl, u in zip(self._cylinders, self._valves, strict=True):
                cyl.step(u)
            self._tick += 1
            return
        period = self._ticks_per_period
        n = min(target, (self._tick // period + 1) * period) - self._tick
        for cyl in self._cylinders:
            cyl.run(0, n)
        self._tick += n

    def _control(self, now: float) -> None:
        self._meas = [c.measure() for c in self._cylinders]
        ref = self._reference if self._enabled and not self._watchdog.expired(now) else None
        for i, ctrl in enumerate(self._controllers):
            if ref is not None:
                out = ctrl.update(ref[i], self._meas[i])
                self._outputs[i] = out
                self._valves[i] = out.command
            else:
                ctrl.observe(self._meas[i])
                self._outputs[i] = None
                self._valves[i] = 0

    # -- outputs -----------------------------------------------------------------------
    def measurement_counts(self) -> np.ndarray:
        """Last AD sample of the five channels [counts, int], ACTUATOR_ORDER."""
        return np.array(self._meas, dtype=np.int64)

    def measurement_tuple(self) -> tuple[int, ...]:
        """:meth:`measurement_counts` as a tuple of ints (no array: what a node compares and encodes 100 times
        a second)."""
        return tuple(self._meas)

    def positions_si(self) -> np.ndarray:
        """Last measurement converted to SI (lift [rad], others [m]) through the calibration."""
        return np.array([p.counts_to_si(m) for p, m in zip(self.params, self._meas, strict=True)])

    def lift_calibration_counts(self) -> tuple[float, float]:
        """(counts_min, counts_max) of the lift as configured in the ECU: the travel the reported
        rear hitch position is a fraction of."""
        return self._lift_calibration

    def piston_counts(self) -> np.ndarray:
        """True (unquantised, noise-free) piston positions [counts, float] — simulation truth."""
        return np.array([c.position_counts for c in self._cylinders])

    def valve_commands(self) -> np.ndarray:
        """Valve commands the ECU is outputting now [command units, int], ACTUATOR_ORDER."""
        return np.array(self._valves, dtype=np.int64)

    def reference_counts(self) -> np.ndarray | None:
        """Latched reference [counts], or None since start / restart."""
        return None if self._reference is None else np.array(self._reference, dtype=np.int64)

    def controller_outputs(self) -> tuple[ControllerOutput | None, ...]:
        """Details of the last controller update per cylinder (None when inactive)."""
        return tuple(self._outputs)

    def relay_engaged(self) -> tuple[bool, ...]:
        """End-stop relay state per cylinder."""
        return tuple(c.relay.engaged for c in self._controllers)

    @property
    def restart_count(self) -> int:
        """Number of :meth:`restart` calls since construction."""
        return self._restarts

    @property
    def fed(self) -> bool:
        """True while references arrive: the last one is younger than the watchdog's timeout at
        :attr:`time_s` (a pure reading: the watchdog's trip count is not touched)."""
        return self._watchdog.fed_at(self.time_s)

    @property
    def holding(self) -> bool:
        """Fed with the same reference again and again (at least :data:`HOLD_AFTER_REPEATS` repeats in a
        row): the planner holds a pose. The twin's runner then reads the bus at its ticks
        (:func:`bridge.service.machine.start_can`), as while no reference arrives."""
        return self._repeats >= HOLD_AFTER_REPEATS and self.fed

    @property
    def watchdog(self) -> Watchdog:
        """The reference watchdog (read its ``trip_count``, ``last_feed_s``)."""
        return self._watchdog

    def system_state(self) -> int:
        """System-state byte (bit layout: :mod:`bridge.isobus.system_state`)."""
        s = 0
        if self._enabled:
            s |= STATE_CONTROLLERS_ON
        if self._watchdog.expired(self.time_s):
            s |= STATE_WATCHDOG_TRIPPED
        if any(self.relay_engaged()):
            s |= STATE_END_STOP_RELAY
        if self._reference is None:
            s |= STATE_NO_REFERENCE
        return s | ((self._restarts & 0x0F) << STATE_RESTART_SHIFT)
