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
from typing import Any, Literal, Protocol

from bridge.isobus.heartbeat import HEARTBEAT_TIMEOUT_S
from bridge.service.maneuvers.language import PlannedStep, ValidationResult
from bridge.service.maneuvers.steps import step_words
from planner.errors import HitchInputError

__all__ = [
    "Command",
    "LoopState",
    "ManeuverRunner",
    "ManeuverRunError",
    "AbortReason",
    "RunnerStatus",
    "LineTrigger",
    "START_LATENCY_S",
]

#: a ``wait_for: distance`` step without a distance travelled (no wheel-based speed, PGN 65096) this long — since the
#: step began, since it was resumed or since the last one — is aborted ``trigger_unavailable`` [s] (a field trial:
#: with no tractor on the bus the step waited until the maneuver's timeout, its state saying nothing)
DISTANCE_SILENT_S = 2.0
#: a motion step asked for is followed by the measured hitch this long later [s]: the controller's
#: plan lead (80 ms), the control ticks until the reference streams and the hydraulics' response.
#: Measured in bench/headland_bench.py (``latency_measured_s``: the time from the trigger's tick until
#: the measured pose leaves its start by more than the pose tolerance, less the plan's own time to do
#: so): 0.136 s at 6 and at 12 km/h (the reference alone: 0.116 s). Added to a lead-compensated step's
#: time to come within the pose tolerance
START_LATENCY_S = 0.14


class LineTrigger(Protocol):
    """What a ``wait_for`` line step reads (:class:`bridge.service.gnss.GnssTracker`)."""

    def crossings(self, name: str) -> int | None:
        """How often line ``name`` was crossed (None: no such line)."""
        ...

    def approach(self, name: str, now_s: float) -> Any:
        """``distance_m`` (to go along the course, or None) and ``speed_m_s`` at ``now_s``; None: no fresh fix."""
        ...


class ManeuverRunError(HitchInputError):
    """The runner driven with values it cannot take (a non-finite time, an unvalidated maneuver …)."""


Action = Literal["goto", "continue", "stop", "done"]
AbortReason = Literal[
    "stop",
    "fault",
    "timeout",
    "ecu_silent",
    "predicted_violation",
    "interrupted",
    "plan_failed",
    "refused",
    "trigger_unavailable",
    "deadline",
]
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
    #: for ``goto``: the number of this motion request; its plan may start it only while it is still
    #: the request the runner awaits (:meth:`ManeuverRunner.awaits`), not after a skip, pause or resume
    request: int | None = None


def _finite(name: str, value: object, *, minimum: float | None = None) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ManeuverRunError(f"{name} must be a finite number, got {value!r}")
    if minimum is not None and value < minimum:
        raise ManeuverRunError(f"{name} must be >= {minimum:g}, got {value!r}")
    return float(value)


class ManeuverRunner:
    """Step logic of one run of a validated maneuver; see the module docstring."""

    def __init__(
        self,
        validated: ValidationResult,
        *,
        ecu_timeout_s: float = HEARTBEAT_TIMEOUT_S,
        lines: LineTrigger | None = None,
        start_latency_s: float = START_LATENCY_S,
    ):
        if not isinstance(validated, ValidationResult) or not validated.ok or validated.script is None:
            raise ManeuverRunError("validated must be a successful ValidationResult (validate() returned ok = False)")
        self.name = validated.script.name
        self.timeout_s = validated.script.timeout_s
        self.ecu_timeout_s = _finite("ecu_timeout_s", ecu_timeout_s, minimum=1e-3)
        self._steps: tuple[PlannedStep, ...] = validated.steps
        self._script_steps = len(validated.script.steps)
        self._status: RunnerStatus = "pending"
        self._index = 0
        self._entered = False
        self._t0 = self._t_step = 0.0
        self._dist0: float | None = None
        self._dist_seen_s = 0.0  # a distance wait's last distance travelled (or when it began) [s]
        self._motion_id: Hashable | None = None
        self._previous_motion: Hashable | None = None
        self.lines = lines
        self.start_latency_s = _finite("start_latency_s", start_latency_s, minimum=0.0)
        self._crossings0 = 0
        self._awaiting = False  # a goto command was given and its motion has not been reported started
        self._request = 0  # number of the latest goto command (a plan of an older one is stale)
        self._paused_at: float | None = None
        self._left: dict[str, float] = {}  # what is left of the step in progress (time or distance)

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
    def motion_started(self, motion_id: Hashable, request: int | None = None) -> None:
        """The service started the motion of the last ``goto`` command under ``motion_id`` (``request``:
        that command's :attr:`Command.request`; an older request is refused)."""
        if self._status != "running" or not self._entered or self._steps[self._index].goal is None:
            raise ManeuverRunError("motion_started: the runner has not asked for a motion")
        if request is not None and not self.awaits(request):
            raise ManeuverRunError(f"motion_started: request {request} is stale (the runner awaits {self._request})")
        if motion_id is None:
            raise ManeuverRunError("motion_id must not be None")
        self._motion_id, self._awaiting = motion_id, False

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
            self._paused_at = None
            events.append(
                {
                    "event": "maneuver_started",
                    "maneuver": self.name,
                    "t": now_s,
                    "steps": self._script_steps,  # as maneuvers/save and list count them
                    "actions": len(self._steps),  # those that run (a speed step only sets a scale)
                    "timeout": self.timeout_s,
                }
            )
        reason = self._abort_reason(now_s, state)
        if reason is not None:
            cmd = self.abort(now_s, *reason)
            return Command(cmd.action, cmd.step, events=tuple(events) + cmd.events)
        if self._paused_at is not None:  # paused: the hitch holds; nothing progresses
            return Command("continue", self.current_step, events=tuple(events))
        while self._index < len(self._steps):
            ps = self._steps[self._index]
            if not self._entered:
                self._enter(ps, now_s, state, distance_travelled_m, events)
                if ps.goal is not None:
                    self._awaiting = True
                    self._request += 1
                    return Command("goto", ps.index, dict(ps.goal), ps.speed_scale, tuple(events), self._request)
            verdict = self._progress(ps, now_s, state, distance_travelled_m)
            if verdict == "unavailable":
                cmd = self.abort(now_s, "trigger_unavailable", f"{step_words(ps.index)}: no line {ps.line!r} is saved")
                return Command(cmd.action, cmd.step, events=tuple(events) + cmd.events)
            if verdict == "no_distance":
                cmd = self.abort(
                    now_s,
                    "trigger_unavailable",
                    f"{step_words(ps.index)}: no distance travelled for {DISTANCE_SILENT_S:g} s (no wheel-based speed, "
                    "PGN 65096, from the tractor on the bus): wait_for distance cannot be measured",
                )
                return Command(cmd.action, cmd.step, events=tuple(events) + cmd.events)
            if verdict == "interrupted":
                replaced = f"the motion of {step_words(ps.index)} was replaced by motion {state.motion_id!r}"
                cmd = self.abort(now_s, "interrupted", replaced)
                return Command(cmd.action, cmd.step, events=tuple(events) + cmd.events)
            if verdict == "waiting":
                return Command("continue", ps.index, events=tuple(events))
            self._index += 1
            self._entered = False
        self._status = "finished"
        events.append({"event": "maneuver_finished", "maneuver": self.name, "t": now_s, "elapsed": now_s - self._t0})
        return Command("done", events=tuple(events))

    # ------------------------------------------------------------------ pause, resume, skip
    @property
    def awaiting_motion(self) -> bool:
        """A motion step's motion was asked for and not started yet (not paused or skipped meanwhile)."""
        return self._awaiting

    def awaits(self, request: int) -> bool:
        """Is ``request`` (a ``goto`` command's :attr:`Command.request`) the motion the runner still awaits?
        False once the step was skipped, paused or resumed (re-planned) after it was asked for."""
        return self._awaiting and request == self._request

    @property
    def paused(self) -> bool:
        return self._paused_at is not None

    def pause(self, now_s: float) -> dict[str, Any]:
        """Pause (the caller brakes the hitch to rest): nothing progresses and the clock of the step
        and of the timeout stands still until :meth:`resume`. Returns the ``maneuver_paused`` event."""
        now_s = _finite("now_s", now_s)
        self._require_running("pause")
        if self._paused_at is not None:
            raise ManeuverRunError("pause: the maneuver is paused already")
        self._paused_at, self._awaiting = now_s, False
        return {"event": "maneuver_paused", "maneuver": self.name, "step": self.current_step, "t": now_s}

    def resume(self, now_s: float) -> dict[str, Any]:
        """Resume a paused maneuver: a motion step is planned again from the pose the hitch is at
        (its ``maneuver_step`` event again, ``resumed``); a wait keeps the time it had left."""
        now_s = _finite("now_s", now_s)
        if self._status != "running":
            raise ManeuverRunError(f"resume: no maneuver is running (status {self._status})")
        if self._paused_at is None:
            raise ManeuverRunError("resume: the maneuver is not paused")
        held = max(0.0, now_s - self._paused_at)
        self._t0 += held
        self._t_step += held
        self._dist_seen_s += held
        self._paused_at = None
        if self._index < len(self._steps) and self._steps[self._index].goal is not None:
            self._entered = False  # re-plan the motion from the current pose
        return {"event": "maneuver_resumed", "maneuver": self.name, "step": self.current_step, "t": now_s, "held": held}

    def skip(self, now_s: float) -> tuple[list[dict[str, Any]], bool]:
        """End the step in progress and go on with the next one (also while paused). Returns the events —
        ``maneuver_skipped``, and ``maneuver_finished`` when that was the last step: the maneuver ends at
        once, paused or not (a pause held it, its timeout frozen, until a resume or stop) — and whether the
        skipped step was a motion (the caller brakes it)."""
        now_s = _finite("now_s", now_s)
        self._require_running("skip")
        ps = self._steps[self._index]
        self._index += 1
        self._entered = self._awaiting = False
        self._left = {}
        nxt = self.current_step
        events: list[dict[str, Any]] = [
            {
                "event": "maneuver_skipped",
                "maneuver": self.name,
                "step": ps.index,
                "kind": ps.kind,
                "next": nxt,
                "t": now_s,
            }
        ]
        if self._index >= len(self._steps):  # nothing left: finished now (the hitch stays where it is)
            elapsed_at = now_s if self._paused_at is None else self._paused_at  # a pause's time is not run time
            self._paused_at = None
            self._status = "finished"
            events.append(
                {"event": "maneuver_finished", "maneuver": self.name, "t": now_s, "elapsed": elapsed_at - self._t0}
            )
        return events, ps.goal is not None

    def progress(self) -> dict[str, Any]:
        """The step in progress for the state message: index, kind, paused, and the time [s] or
        distance [m] left (as of the last tick)."""
        out: dict[str, Any] = {"step": self.current_step, "paused": self.paused}
        if self._status == "running" and self._index < len(self._steps):
            out["kind"] = self._steps[self._index].kind
            out.update(self._left)
        return out

    def _require_running(self, what: str) -> None:
        if self._status != "running" or self._index >= len(self._steps):
            raise ManeuverRunError(f"{what}: no maneuver step is in progress (status {self._status})")

    # ------------------------------------------------------------------ internals
    def _abort_reason(self, now_s: float, state: LoopState) -> tuple[AbortReason, str] | None:
        elapsed = now_s - self._t0 if self._paused_at is None else self._paused_at - self._t0
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
        self._dist_seen_s = now_s  # a distance wait's last distance travelled (or when it began) [s]
        self._motion_id, self._previous_motion = None, state.motion_id
        self._left = {}
        if ps.line is not None:
            c = None if self.lines is None else self.lines.crossings(ps.line)
            self._crossings0 = 0 if c is None else c
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
        elif ps.line is not None:
            ev.update(line=ps.line, lead_s=ps.lead_s)
        else:
            ev["distance"] = ps.distance_m
        events.append(ev)

    def _progress(self, ps: PlannedStep, now_s: float, state: LoopState, dist: float | None) -> str:
        """ "done", "waiting", "interrupted" or "unavailable" (no such line) for the step in progress."""
        if ps.goal is not None:
            if self._motion_id is None:  # the service has not confirmed the start yet
                return "waiting"
            if state.motion_id == self._motion_id:
                return "waiting" if state.moving else "done"
            if state.motion_id == self._previous_motion:  # the snapshot predates the start
                return "waiting"
            return "interrupted"
        if ps.kind == "wait":
            left = ps.seconds - (now_s - self._t_step)
            self._left = {"time_left": max(0.0, left)}
            return "done" if left <= 0.0 else "waiting"
        if ps.line is not None:
            return self._at_line(ps, now_s)
        # wait_for: distance since the step began; an odometer that goes back (reset) is re-based
        if dist is None:
            return "no_distance" if now_s - self._dist_seen_s > DISTANCE_SILENT_S else "waiting"
        self._dist_seen_s = now_s
        if self._dist0 is None or dist < self._dist0:
            self._dist0 = dist
        left = ps.distance_m - (dist - self._dist0)
        self._left = {"distance_left": max(0.0, left)}
        return "done" if left <= 0.0 else "waiting"

    def _at_line(self, ps: PlannedStep, now_s: float) -> str:
        """A line reached: crossed since the step began, or (lead compensation, ``lead_s`` > 0) the
        distance to go along the course at most the ground speed × (the next step's planned duration
        + the start latency), so that step is complete as the line is reached."""
        assert ps.line is not None
        lines = self.lines
        c = None if lines is None else lines.crossings(ps.line)
        if lines is None or c is None:
            return "unavailable"
        if c > self._crossings0:
            self._left = {"distance_left": 0.0}
            return "done"
        a = lines.approach(ps.line, now_s)
        if a is None or a.distance_m is None:
            return "waiting"  # no fresh fix, or not heading for the line
        lead_m = (ps.lead_s + self.start_latency_s) * a.speed_m_s if ps.lead_s > 0.0 else 0.0
        self._left = {"distance_left": max(0.0, float(a.distance_m) - lead_m)}
        return "done" if a.distance_m <= lead_m else "waiting"
