"""Following-error supervision: the cylinders must follow the references the planner streams.

Without it a cylinder that does not move (a pump off, a stuck valve, an ECU whose controllers are off, a
broken sensor cable reading a constant) was invisible: the plan ran to its end and ``motion_finished`` was
announced 50 mm short of the goal (an integrator's trial with his own ECU).

Each control cycle :class:`FollowingSupervisor` compares the newest measurement with the reference that
was being streamed when it was taken — the reference at the measurement's arrival on the link's clock
(``LinkState.measurement_t_s`` for the four cylinders of 0xFF22, ``lift_t_s`` for the lift from the rear
hitch status), so a measurement that is late under CPU load is not compared with a newer reference. An
actuator whose error exceeds its allowance

    |q_measured − q_reference| > e_max + lag_s · max |q̇_reference| over the last lag_s   (lift [rad], others [m])

continuously for ``time_s`` without closing in on it by half its allowance ``e_max / 2`` meanwhile (a cylinder
that catches up — after a step of the reference, late at the end of a move — follows; a window in which it did
begins a new one) trips the supervision: the controller then holds the fault ``following_error``
(latching: acknowledge it once the hydraulics are checked), aborts the motion and stops the reference
stream, so the ECU's watchdog holds the valves at zero. ``lag_s`` allows the hydraulics' delay while the
reference moves, and for ``lag_s`` after it slowed or stepped (the unit loops still catching up: the largest
speed of the last ``lag_s``; a step — the reference after a stall of the control thread — counts as its size over
its period). On the simulated machine the largest errors were 7.2 mrad on the lift and 1.4 mm on the cylinders
with the feed-forward reference (the default; ≥ 4× below the allowance), 0.63 of the allowance without it
(``feedforward = false``: the top link lags at the end of a move).

Only while references are streamed, the measurement is fresh (the stale-measurement fault covers the rest)
and the ECU reports its watchdog not expired (``references_lost`` covers that).
"""

from __future__ import annotations

import math
from collections import deque
from dataclasses import dataclass

import numpy as np

from planner.model.types import ACTUATOR_NAMES

__all__ = ["FOLLOWING_ERROR", "LIMIT_RANGES", "FollowingErrorLimits", "FollowingSupervisor"]

#: the allowed range of each :class:`FollowingErrorLimits` field (the service's settings take theirs from here)
LIMIT_RANGES: dict[str, tuple[float, float]] = {
    "lift_rad": (1e-3, 0.5),
    "length_m": (1e-4, 0.2),
    "lag_s": (0.0, 5.0),
    "time_s": (0.05, 10.0),
}

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
        for name, (lo, hi) in LIMIT_RANGES.items():
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
        # (from [s], actuators, the speed it stands for: max(|its rates|, |its step from the one before| / Δt))
        self._refs: deque[tuple[float, np.ndarray, np.ndarray]] = deque(maxlen=history)
        self._last_ref: object = None
        self._over_since: list[float | None] = [None] * len(ACTUATOR_NAMES)
        self._over_error = [0.0] * len(ACTUATOR_NAMES)  # |error| when its window began
        self.worst: np.ndarray = np.zeros(len(ACTUATOR_NAMES))  # |error| / allowance of the last check

    def reset(self) -> None:
        """Forget the history (nothing streamed, or a fault ended the stream)."""
        self._refs.clear()
        self._last_ref = None
        self._over_since = [None] * len(ACTUATOR_NAMES)
        self._over_error = [0.0] * len(ACTUATOR_NAMES)
        self.worst = np.zeros(len(ACTUATOR_NAMES))

    def streamed(self, now: float, reference: object | None, actuators: np.ndarray, rates: np.ndarray) -> None:
        """The reference streamed from ``now`` [s] on (the same object again: nothing new)."""
        if reference is None:
            self.reset()
            return
        if reference is not self._last_ref:
            self._last_ref = reference
            q = np.asarray(actuators, dtype=float)
            speed = np.abs(np.asarray(rates, dtype=float))
            if self._refs:  # a step (the reference after a stall of the control thread) counts as its speed
                t_prev, q_prev, _ = self._refs[-1]
                if now > t_prev:
                    speed = np.maximum(speed, np.abs(q - q_prev) / (now - t_prev))
            self._refs.append((now, q, speed))

    def _reference_at(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """The reference streamed at ``t`` (the newest one from before it) and the largest speed the reference
        had over the ``lag_s`` before ``t`` (the hydraulics are still catching up with it: the allowance keeps
        it that long — at the end of a move, and after a step); None before the history."""
        found: tuple[np.ndarray, np.ndarray] | None = None
        since = t - self.limits.lag_s
        for t0, q, v in reversed(self._refs):
            if found is None:
                if t0 > t + 1e-9:
                    continue
                found = (q, v)
            else:
                found = (found[0], np.maximum(found[1], v))
            if t0 <= since:
                break
        return found

    def check(self, measured: np.ndarray, measurement_t: float, lift_t: float) -> str | None:
        """``measured`` actuators (lift [rad], others [m]); the cylinders' measurement arrived at
        ``measurement_t``, the lift's at ``lift_t`` [s, link clock]. The reason when tripped, else None."""
        reason = None
        # two arrival times (the lift's, the cylinders'): each looked up once per cycle, not once per actuator
        at = {t: self._reference_at(t) for t in {measurement_t, lift_t}}
        for i, name in enumerate(ACTUATOR_NAMES):
            t = lift_t if i == _LIFT else measurement_t
            ref = at[t]
            if ref is None:
                self._over_since[i] = None
                continue
            q, speed = ref
            err = float(measured[i] - q[i])
            allow = float(self._floors[i] + self.limits.lag_s * speed[i])
            self.worst[i] = abs(err) / allow
            if abs(err) <= allow:
                self._over_since[i] = None
                continue
            since = self._over_since[i]
            if since is None:
                since = t
                self._over_since[i], self._over_error[i] = t, abs(err)
            if t - since >= self.limits.time_s - 1e-9 and abs(err) <= self._over_error[i] - 0.5 * self._floors[i]:
                # closing in on its reference by at least half the allowance per time_s: it follows, late (a step
                # after a stall, a slow catch-up): a new window from here
                self._over_since[i], self._over_error[i] = t, abs(err)
                continue
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
