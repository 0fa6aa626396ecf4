"""Running a validated maneuver: pure step logic driven by the service's control loop.

:class:`ManeuverRunner` holds no thread, clock or I/O. The service calls
:meth:`ManeuverRunner.step` once per control tick with the time [s], a :class:`LoopState`
snapshot and the distance the tractor has travelled [m] (cumulative, from the wheel-based
speed on the CAN bus); it gets back a :class:`Command`:

* ``goto``     — start this motion now (full goal pose, speed scale), then report its id with
  :meth:`ManeuverRunner.motion_started` (or call :meth:`ManeuverRunner.abort` if it cannot start);
* ``continue`` — nothing new: let the running motion run, or keep waiting;
* ``stop``     — the maneuver was aborted: stop the motion (emitted once);
* ``done``     — the maneuver is over (finished or aborted earlier).

Each command carries the events of that tick as dicts for ``<prefix>/events``:
``maneuver_started``, ``maneuver_step`` (progress), ``maneuver_finished``, ``maneuver_aborted``.
Abort conditions, checked every tick before any progress: the maneuver timeout (from the
first tick), the ECU silent for more than ``ecu_timeout_s``, a predicted violation reported
by the guard, and the running motion replaced by another one (a jog, goto or stop from a
client: ``interrupted``); a stop request arrives through :meth:`ManeuverRunner.abort`.

Motion steps carry the full goal poses planned by
:func:`~bridge.service.maneuvers.language.validate`, so what runs is exactly what was validated;
the service validates again from the current state when a run starts.
"""

from __future__ import annotations

import math
from collections.abc import Hashable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

from bridge.isobus.heartbeat import HEARTBEAT_TIMEOUT_S
from bridge.service.maneuvers.language import PlannedStep, ValidationResult
from planner.errors import HitchInputError

__all__ = ["Command", "LoopState", "ManeuverRunner", "ManeuverRunError", "AbortReason", "RunnerStatus"]


class ManeuverRunError(HitchInputError):
    """The runner driven with values it cannot take (a non-finite time, an unvalidated maneuver …)."""


Action = Literal["goto", "continue", "stop", "done"]
AbortReason = Literal["stop", "timeout", "ecu_silent", "predicted_violation", "interrupted", "plan_failed"]
RunnerStatus = Literal["pending", "running", "finished", "aborted"]


@dataclass(frozen=True)
class LoopState:
    """What the runner reads from the control loop each tick (times on the runner's clock [s])."""

    moving: bool  # a trajectory is being executed
    motion_id: Hashable | None  # id of the running or the last motion
    ecu_last_seen_s: float | None  # last message from the cylinder ECU; None: never heard
    violation: str | None = None  # a predicted limit/stability violation ahead (guard message)


@dataclass(frozen=True)
class Command:
    action: Action
    step: int | None = None  # index of the script step (0-based)
    goal: Mapping[str, float] | None = None  # full pose (x, z [m]; roll, pitch [rad]) for ``goto``
    speed_scale: float = 1.0
    events: tuple[dict[str, Any], ...] = ()


def _finite(name: str, value: object, *, minimum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ManeuverRunError(f"{name} must be a finite number, got {value!r}")
    if minimum is not None and value < minimum:
        raise ManeuverRunError(f"{name} must be >= {minimum:g}, got {value!r}")
    return float(value)


class ManeuverRunner:
    """Step logic of one run of a validated maneuver; see the module docstring."""

    def __init__(self, validated: ValidationResult, *, ecu_timeout_s: float = HEARTBEAT_TIMEOUT_S):
        if not isinstance(validated, ValidationResult) or not validated.ok or validated.script is None:
            raise ManeuverRunError("validated must be a successful ValidationResult (validate() returned ok = False)")
        self.name = validated.script.name
        self.timeout_s = validated.script.timeout_s
        self.ecu_timeout_s = _finite("ecu_timeout_s", ecu_timeout_s, minimum=1e-3)
        self._steps: tuple[PlannedStep, ...] = validated.steps
        self._status: RunnerStatus = "pending"
        self._index = 0
        self._entered = False
        self._t0 = self._t_step = 0.0
        self._dist0: float | None = None
        self._motion_id: Hashable | None = None
        self._previous_motion: Hashable | None = None

    # ------------------------------------------------------------------ inspection
    @property
    def status(self) -> RunnerStatus:
        return self._status

    @property
    def current_step(self) -> int | None:
        """Script index of the step in progress (None before the start and after the end)."""
        if self._status != "running" or self._index >= len(self._steps):
            return None
        return self._steps[self._index].index

    # ------------------------------------------------------------------ driving
    def motion_started(self, motion_id: Hashable) -> None:
        """The service started the motion of the last ``goto`` command under ``motion_id``."""
        if self._status != "running" or not self._entered or self._steps[self._index].goal is None:
            raise ManeuverRunError("motion_started: the runner has not asked for a motion")
        if motion_id is None:
            raise ManeuverRunError("motion_id must not be None")
        self._motion_id = motion_id

    def abort(self, now_s: float, reason: AbortReason, message: str) -> Command:
        """Abort now (stop request, a motion that could not start, …): a ``stop`` command with the event."""
        now_s = _finite("now_s", now_s)
        if self._status in ("finished", "aborted"):
            return Command("done")
        step = self.current_step
        self._status = "aborted"
        event = {
            "event": "maneuver_aborted",
            "maneuver": self.name,
            "step": step,
            "reason": reason,
            "message": message,
            "t": now_s,
            "elapsed": now_s - self._t0,
        }
        return Command("stop", step=step, events=(event,))

    def step(self, now_s: float, state: LoopState, distance_travelled_m: float | None = None) -> Command:
        """Advance by one control tick; see the module docstring for the commands and events."""
        now_s = _finite("now_s", now_s)
        if distance_travelled_m is not None:
            distance_travelled_m = _finite("distance_travelled_m", distance_travelled_m, minimum=0.0)
        if not isinstance(state, LoopState):
            raise ManeuverRunError("state must be a LoopState")
        if self._status in ("finished", "aborted"):
            return Command("done")
        events: list[dict[str, Any]] = []
        if self._status == "pending":
            self._status, self._t0 = "running", now_s
            events.append(
                {
                    "event": "maneuver_started",
                    "maneuver": self.name,
                    "t": now_s,
                    "steps": len(self._steps),
                    "timeout": self.timeout_s,
                }
            )
        reason = self._abort_reason(now_s, state)
        if reason is not None:
            cmd = self.abort(now_s, *reason)
            return Command(cmd.action, cmd.step, events=tuple(events) + cmd.events)
        while self._index < len(self._steps):
            ps = self._steps[self._index]
            if not self._entered:
                self._enter(ps, now_s, state, distance_travelled_m, events)
                if ps.goal is not None:
                    return Command("goto", ps.index, dict(ps.goal), ps.speed_scale, tuple(events))
            verdict = self._progress(ps, now_s, state, distance_travelled_m)
            if verdict == "interrupted":
                cmd = self.abort(
                    now_s, "interrupted", f"the motion of step {ps.index} was replaced by motion {state.motion_id!r}"
                )
                return Command(cmd.action, cmd.step, events=tuple(events) + cmd.events)
            if verdict == "waiting":
                return Command("continue", ps.index, events=tuple(events))
            self._index += 1
            self._entered = False
        self._status = "finished"
        events.append({"event": "maneuver_finished", "maneuver": self.name, "t": now_s, "elapsed": now_s - self._t0})
        return Command("done", events=tuple(events))

    # ------------------------------------------------------------------ internals
    def _abort_reason(self, now_s: float, state: LoopState) -> tuple[AbortReason, str] | None:
        elapsed = now_s - self._t0
        if elapsed > self.timeout_s:
            return "timeout", f"the maneuver ran {elapsed:.2f} s, beyond its timeout of {self.timeout_s:g} s"
        if state.ecu_last_seen_s is None:
            return "ecu_silent", "the cylinder ECU has not been heard"
        silent = now_s - _finite("ecu_last_seen_s", state.ecu_last_seen_s)
        if silent > self.ecu_timeout_s:
            return "ecu_silent", (
                f"the cylinder ECU has been silent for {silent:.3f} s (timeout {self.ecu_timeout_s:g} s)"
            )
        if state.violation:
            return "predicted_violation", str(state.violation)
        return None

    def _enter(
        self, ps: PlannedStep, now_s: float, state: LoopState, dist: float | None, events: list[dict[str, Any]]
    ) -> None:
        self._entered, self._t_step, self._dist0 = True, now_s, dist
        self._motion_id, self._previous_motion = None, state.motion_id
        ev: dict[str, Any] = {
            "event": "maneuver_step",
            "maneuver": self.name,
            "step": ps.index,
            "kind": ps.kind,
            "t": now_s,
            "progress": self._index / len(self._steps),
        }
        if ps.goal is not None:
            ev.update(goal=dict(ps.goal), speed_scale=ps.speed_scale, planned_duration=ps.duration_s)
        elif ps.kind == "wait":
            ev["seconds"] = ps.seconds
        else:
            ev["distance"] = ps.distance_m
        events.append(ev)

    def _progress(self, ps: PlannedStep, now_s: float, state: LoopState, dist: float | None) -> str:
        """ "done", "waiting" or "interrupted" for the step in progress."""
        if ps.goal is not None:
            if self._motion_id is None:  # the service has not confirmed the start yet
                return "waiting"
            if state.motion_id == self._motion_id:
                return "waiting" if state.moving else "done"
            if state.motion_id == self._previous_motion:  # the snapshot predates the start
                return "waiting"
            return "interrupted"
        if ps.kind == "wait":
            return "done" if now_s - self._t_step >= ps.seconds else "waiting"
        # wait_for: distance since the step began; an odometer that goes back (reset) is re-based
        if dist is None:
            return "waiting"
        if self._dist0 is None or dist < self._dist0:
            self._dist0 = dist
        return "done" if dist - self._dist0 >= ps.distance_m else "waiting"
