"""Teach-in: record what the operator does into a maneuver script for review.

``maneuvers/record/start`` starts a :class:`ManeuverRecorder`; while it records, the service tells it
every accepted command — a ``goto`` (its partial goal and speed scale), a preset move (by name), a
``jog`` (the recorder notes that a jog runs; the pose the jog ended at is read when the next command
arrives or recording stops, and recorded as a full-pose ``goto``) — with the command's planned
duration. The time between the planned end of one motion and the next command is a pause: when the
tractor travelled at least ``min_distance_m`` meanwhile (wheel-based speed) it is recorded as
``wait_for: {distance: …}``, else as ``wait: …`` seconds (pauses shorter than ``min_pause_s`` are
dropped; a pause longer than one step allows — ``wait`` (0, 3600] s, ``wait_for distance`` (0, 10000] m —
is recorded as several such steps). ``maneuvers/record/stop`` returns the script (YAML) for review and
edit; the operator saves it with ``maneuvers/save``. Nothing is stored by the recorder.

Threads: the service tells the recorder from its request threads (a jog inline, a goto from the motion
lane); every method holds the recorder's own lock for its O(1) bookkeeping. Telling it never raises —
the operator's command was accepted and moves, whatever the recording does: once the recording holds
:data:`~bridge.service.maneuvers.language.MAX_STEPS` steps, later steps are dropped and counted
(:attr:`ManeuverRecorder.dropped`; the script's description says so).
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable, Mapping
from typing import Any

import yaml

from bridge.service.maneuvers.language import MAX_STEPS, parse_maneuver
from bridge.service.maneuvers.steps import MAX_TIMEOUT_S, POSE_BOUNDS, PresetStep, WaitForStep
from planner.errors import HitchInputError

__all__ = ["ManeuverRecorder", "RecorderError", "discarded_recording"]

#: the longest single ``wait`` [s] and ``wait_for distance`` [m] a script allows (steps.WaitStep, WaitForStep)
_MAX_WAIT_S = MAX_TIMEOUT_S
_MAX_DISTANCE_M = 10_000.0


class RecorderError(HitchInputError):
    """The recorder used out of order, or full (the message says what is allowed)."""


def _r(v: float, nd: int = 4) -> float:
    return float(round(float(v), nd))


class ManeuverRecorder:
    """See the module docstring. ``clock`` [s], ``pose()`` the hitch pose now (x, z, roll, pitch),
    ``distance()`` the tractor's travelled distance [m] or None (no odometer)."""

    def __init__(
        self,
        clock: Callable[[], float],
        pose: Callable[[], Mapping[str, float]],
        distance: Callable[[], float | None],
        *,
        min_pause_s: float = 0.5,
        min_distance_m: float = 0.5,
    ):
        self.clock, self.pose, self.distance = clock, pose, distance
        self.min_pause_s, self.min_distance_m = float(min_pause_s), float(min_distance_m)
        self.steps: list[dict[str, Any]] = []
        self._busy_until = clock()  # planned end of the last motion [s]
        self._dist_at = distance()  # odometer at that time [m]
        self._jog_until: float | None = None  # a jog runs (its last command's end of life)
        self._jog_read: tuple[float, float | None] = (
            self._busy_until,
            self._dist_at,
        )  # (time, odometer) of its last command
        self._cmd_t = self._busy_until  # when the last motion was commanded [s]
        self._motion_time = 0.0
        #: steps not recorded because the recording was full (MAX_STEPS)
        self.dropped = 0
        self._lock = threading.Lock()

    # ------------------------------------------------------------------ what the operator does
    def on_goto(self, goal: Mapping[str, float], speed_scale: float, duration_s: float) -> None:
        with self._lock:
            self._before_command()
            step: dict[str, Any] = {k: _r(v) for k, v in goal.items() if k in POSE_BOUNDS}
            if not math.isclose(speed_scale, 1.0):
                step["speed_scale"] = _r(speed_scale, 3)
            self._add({"goto": step}, duration_s)

    def on_preset(self, name: str, speed_scale: float | None, duration_s: float) -> None:
        with self._lock:
            self._before_command()
            step = name if speed_scale is None else {"name": name, "speed_scale": _r(speed_scale, 3)}
            self._add({"preset": step}, duration_s)

    def on_jog(self, ttl_s: float) -> None:
        with self._lock:
            if self._jog_until is None:
                self._pause_until(self.clock())
            self._jog_until = self.clock() + float(ttl_s)
            self._jog_read = (self.clock(), self.distance())  # the odometer at the jog's last command

    def stop(self, name: str | None = None, description: str = "recorded by teach-in") -> str:
        """The recorded script (YAML); raises :class:`RecorderError` when nothing was recorded."""
        with self._lock:
            self._close_jog()
            steps = list(self.steps)
            dropped = self.dropped
        if not steps:
            raise RecorderError("nothing was recorded (no goto, preset or jog between record/start and record/stop)")
        if dropped:
            description = f"{description} (the last {dropped} step(s) were dropped: at most {MAX_STEPS} steps)"
        doc: dict[str, Any] = {"description": description}
        if name is not None:
            doc = {"name": name, **doc}
        total = sum(float(next(iter(s.values()))) for s in steps if "wait" in s)
        doc["timeout"] = float(min(MAX_TIMEOUT_S, max(60.0, math.ceil(2 * (total + self._motion_time) + 30))))
        doc["steps"] = steps
        text = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None)
        parse_maneuver(text)  # what is handed out parses
        return text

    # ------------------------------------------------------------------ internals
    def _before_command(self) -> None:
        self._close_jog()
        self._pause_until(self.clock())

    def _close_jog(self) -> None:
        if self._jog_until is None:
            return
        end = self._jog_until
        self._jog_until = None
        pose = self.pose()
        self._add({"goto": {k: _r(pose[k]) for k in POSE_BOUNDS}}, 0.0, at=end)
        # the jog is closed by the next command: the odometer was read at the jog's last command, not at its end
        # (reading it now counted the whole pause after a jog as 0 m: `wait: 3.1` while the tractor drove 4.6 m)
        self._cmd_t, self._dist_at = self._jog_read

    def _pause_until(self, now: float) -> None:
        gap = now - self._busy_until
        d = self.distance()
        travelled = None if d is None or self._dist_at is None else d - self._dist_at
        span = now - self._cmd_t  # the odometer was read at the command: the pause's share of the travel
        if travelled is not None and span > 1e-9:
            travelled *= max(0.0, gap) / span  # (constant ground speed assumed over one motion)
        if self.steps:  # before the first command no motion has ended: no pause (module docstring)
            self._append_pause(gap, travelled)
        self._busy_until, self._dist_at = max(self._busy_until, now), d

    def _append_pause(self, gap: float, travelled: float | None) -> None:
        """A pause of ``gap`` s (``travelled`` m meanwhile) as ``wait_for distance`` or ``wait`` steps."""
        if travelled is not None and travelled >= self.min_distance_m:
            for part in _parts(_r(travelled, 2), _MAX_DISTANCE_M):
                self._append({"wait_for": {"distance": part}})
        elif gap >= self.min_pause_s:
            for part in _parts(_r(gap, 2), _MAX_WAIT_S):
                self._append({"wait": part})

    def _add(self, step: dict[str, Any], duration_s: float, *, at: float | None = None) -> None:
        self._append(step)
        t = self.clock() if at is None else at
        self._cmd_t = t
        self._busy_until = t + max(0.0, float(duration_s))
        self._motion_time += max(0.0, float(duration_s))
        self._dist_at = self.distance()

    def _append(self, step: dict[str, Any]) -> None:
        if len(self.steps) >= MAX_STEPS:  # full: the command itself was accepted; the step is dropped
            self.dropped += 1
            return
        self.steps.append(step)


def _parts(total: float, most: float) -> list[float]:
    """``total`` (> 0) as pieces of at most ``most``, in order (the last one the rest)."""
    n = max(1, math.ceil(total / most - 1e-9))
    return [most] * (n - 1) + [_r(total - most * (n - 1), 2)]


def recorder_for(motion: Any) -> ManeuverRecorder:
    """A recorder on a motion controller (or the core's proxy): its clock, pose and odometer."""
    return ManeuverRecorder(
        motion.clock,
        # the implement's pose (the mechanism less the profile's lag), which a replayed step aims back at
        lambda: dict(
            zip(POSE_BOUNDS, map(float, motion.planner.implement_pose(motion.current_state().position)), strict=True)
        ),
        motion.distance_travelled,
    )


def discarded_recording(api: Any) -> dict[str, Any] | None:
    """At shutdown: the teach-in recording the service's API (``api.recorder``) still holds, unsaved — for the
    black box (it was discarded without trace) — as ``{"what", "steps", "dropped", "message"}``; None when
    nothing records."""
    rec = getattr(api, "recorder", None)
    if not isinstance(rec, ManeuverRecorder):
        return None
    with rec._lock:
        steps, dropped = len(rec.steps), rec.dropped
    return {
        "what": "recording_discarded",
        "steps": steps,
        "dropped": dropped,
        "message": f"an unsaved teach-in recording of {steps} step(s) was discarded when the service stopped "
        "(maneuvers/record/stop returns and saves a recording)",
    }


def maneuvers_using_preset(store: Any, preset: str) -> list[str]:
    """Names of the saved maneuvers with a ``preset`` step of that name (sorted)."""
    return _maneuvers_with(store, lambda s: isinstance(s, PresetStep) and s.name == preset)


def maneuvers_using_line(store: Any, line: str) -> list[str]:
    """Names of the saved maneuvers with a ``wait_for: {line: …}`` step on that line (sorted)."""
    return _maneuvers_with(store, lambda s: isinstance(s, WaitForStep) and s.line == line)


def _maneuvers_with(store: Any, uses: Callable[[Any], bool]) -> list[str]:
    out = []
    for summary in store.list_maneuvers():
        try:
            m = store.get_maneuver(summary.name)
        except ValueError:  # a row this program cannot parse (StoreError): it uses nothing we can tell
            continue
        if m is not None and any(uses(s) for s in m.parsed.steps):
            out.append(m.name)
    return sorted(out)
