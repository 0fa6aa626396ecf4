"""Following-error supervision: the cylinders must follow the references the planner streams.

Without it a cylinder that does not move (a pump off, a stuck valve, an ECU whose controllers are off, a
broken sensor cable reading a constant) was invisible: the plan ran to its end and ``motion_finished`` was
announced 50 mm short of the goal (an integrator's trial with his own ECU).

Each control cycle :class:`FollowingSupervisor` compares the newest measurement with the reference that
was being streamed when it was taken — the reference at the measurement's arrival on the link's clock
(``LinkState.measurement_t_s`` for the four cylinders of 0xFF22, ``lift_t_s`` for the lift from the rear
hitch status), so a measurement that is late under CPU load is not compared with a newer reference. An
actuator whose error exceeds its allowance

    |q_measured − q_reference| > e_max + lag_s · |q̇_reference|        (lift [rad], the others [m])

continuously for ``time_s`` trips the supervision: the controller then holds the fault ``following_error``
(latching: acknowledge it once the hydraulics are checked), aborts the motion and stops the reference
stream, so the ECU's watchdog holds the valves at zero. ``lag_s`` allows the hydraulics' delay while the
reference moves (the identified unit loops lag the reference by ~0.1 s; the simulated machine's largest
error in full-speed gotos is 3.7 mrad on the lift and 0.8 mm on the cylinders, ~5× below the defaults).

Only while references are streamed, the measurement is fresh (the stale-measurement fault covers the rest)
and the ECU reports its watchdog not expired (``references_lost`` covers that).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from planner.model.types import ACTUATOR_NAMES

__all__ = ["FOLLOWING_ERROR", "FollowingErrorLimits", "FollowingSupervisor"]

#: the fault the supervision raises (latching; docs/faults.md)
FOLLOWING_ERROR = "following_error"


@dataclass(frozen=True)
class FollowingErrorLimits:
    """Allowances of the following-error supervision (module docstring).

    Attributes:
        lift_rad: allowed lift error at rest [rad] (the lift sensor's count is ~4 mrad).
        length_m: allowed error of the tilt and top-link cylinders and the sway limiters at rest [m].
        lag_s: extra allowance per unit of reference speed [s] (the hydraulics' delay).
        time_s: how long an error must stay above its allowance before the fault [s].
    """

    lift_rad: float = 0.02
    length_m: float = 0.01
    lag_s: float = 0.3
    time_s: float = 0.5

    def __post_init__(self) -> None:
        bounds = (("lift_rad", 1e-3, 0.5), ("length_m", 1e-4, 0.2), ("lag_s", 0.0, 5.0), ("time_s", 0.05, 10.0))
        for name, lo, hi in bounds:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
                raise ValueError(f"following error {name} must be a number in [{lo:g}, {hi:g}], got {v!r}")

    def floors(self) -> np.ndarray:
        """The allowance at rest per actuator, in :data:`ACTUATOR_NAMES` order (lift [rad], others [m])."""
        return np.array([self.lift_rad if n == "lift" else self.length_m for n in ACTUATOR_NAMES])


_LIFT = ACTUATOR_NAMES.index("lift")


class FollowingSupervisor:
    """Compares measurements with the references streamed when they were taken (module docstring).

    :meth:`streamed` is told each cycle's streamed reference (or None: nothing streamed); :meth:`check`
    returns the reason once an actuator has stayed beyond its allowance for ``time_s``, else None. O(history)
    per cycle, no allocation beyond a few small arrays."""

    def __init__(self, limits: FollowingErrorLimits | None = None, history: int = 128):
        self.limits = limits or FollowingErrorLimits()
        self._floors = self.limits.floors()
        self._refs: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=history)
        self._last_ref: object = None
        self._over_since: list[float | None] = [None] * len(ACTUATOR_NAMES)
        self.worst: np.ndarray = np.zeros(len(ACTUATOR_NAMES))  # |error| / allowance of the last check

    def reset(self) -> None:
        """Forget the history (nothing streamed, or a fault ended the stream)."""
        self._refs.clear()
        self._last_ref = None
        self._over_since = [None] * len(ACTUATOR_NAMES)
        self.worst = np.zeros(len(ACTUATOR_NAMES))

    def streamed(self, now: float, reference: object | None, actuators: np.ndarray, rates: np.ndarray) -> None:
        """The reference streamed from ``now`` [s] on (the same object again: nothing new)."""
        if reference is None:
            self.reset()
            return
        if reference is not self._last_ref:
            self._last_ref = reference
            self._refs.append((now, np.asarray(actuators, dtype=float), np.asarray(rates, dtype=float)))

    def _reference_at(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The reference streamed at ``t`` (the newest one from before it); None before the history."""
        for t0, q, qd in reversed(self._refs):
            if t0 <= t + 1e-9:
                return q, qd
        return None

    def check(self, measured: np.ndarray, measurement_t: float, lift_t: float) -> str | None:
        """``measured`` actuators (lift [rad], others [m]); the cylinders' measurement arrived at
        ``measurement_t``, the lift's at ``lift_t`` [s, link clock]. The reason when tripped, else None."""
        reason = None
        for i, name in enumerate(ACTUATOR_NAMES):
            t = lift_t if i == _LIFT else measurement_t
            ref = self._reference_at(t)
            if ref is None:
                self._over_since[i] = None
                continue
            q, qd = ref
            err = float(measured[i] - q[i])
            allow = float(self._floors[i] + self.limits.lag_s * abs(qd[i]))
            self.worst[i] = abs(err) / allow
            if abs(err) <= allow:
                self._over_since[i] = None
                continue
            since = self._over_since[i]
            if since is None:
                self._over_since[i] = since = t
            if reason is None and t - since >= self.limits.time_s - 1e-9:
                unit, scale = ("mrad", 1e3) if i == _LIFT else ("mm", 1e3)
                floor = self._floors[i] * scale
                reason = (
                    f"{name} {err * scale:+.1f} {unit} from its reference (measured − reference) for "
                    f"{t - since:.2f} s (allowed {floor:g} {unit} + {self.limits.lag_s:g} s × its speed): the "
                    "cylinder does not follow — check the hydraulics (pump, valves), the ECU's controllers and "
                    "the sensor"
                )
        return reason
