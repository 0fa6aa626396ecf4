"""Teach-in: record what the operator does into a maneuver script for review.

``maneuvers/record/start`` starts a :class:`ManeuverRecorder`; while it records, the service tells it
every accepted command — a ``goto`` (its partial goal and speed scale), a preset move (by name), a
``jog`` (the recorder notes that a jog runs; the pose the jog ended at is read when the next command
arrives or recording stops, and recorded as a full-pose ``goto``) — with the command's planned
duration. The time between the planned end of one motion and the next command is a pause: when the
tractor travelled at least ``min_distance_m`` meanwhile (wheel-based speed) it is recorded as
``wait_for: {distance: …}``, else as ``wait: …`` seconds (pauses shorter than ``min_pause_s`` are
dropped). ``maneuvers/record/stop`` returns the script (YAML) for review and edit; the operator saves
it with ``maneuvers/save``. Nothing is stored by the recorder.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from typing import Any

import yaml

from bridge.service.maneuvers.language import MAX_STEPS, parse_maneuver
from bridge.service.maneuvers.steps import POSE_BOUNDS
from planner.errors import HitchInputError

__all__ = ["ManeuverRecorder", "RecorderError"]


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
        self._cmd_t = self._busy_until  # when the last motion was commanded [s]
        self._motion_time = 0.0

    # ------------------------------------------------------------------ what the operator does
    def on_goto(self, goal: Mapping[str, float], speed_scale: float, duration_s: float) -> None:
        self._before_command()
        step: dict[str, Any] = {k: _r(v) for k, v in goal.items() if k in POSE_BOUNDS}
        if not math.isclose(speed_scale, 1.0):
            step["speed_scale"] = _r(speed_scale, 3)
        self._add({"goto": step}, duration_s)

    def on_preset(self, name: str, speed_scale: float | None, duration_s: float) -> None:
        self._before_command()
        self._add(
            {"preset": name if speed_scale is None else {"name": name, "speed_scale": _r(speed_scale, 3)}}, duration_s
        )

    def on_jog(self, ttl_s: float) -> None:
        if self._jog_until is None:
            self._pause_until(self.clock())
        self._jog_until = self.clock() + float(ttl_s)

    def stop(self, name: str | None = None, description: str = "recorded by teach-in") -> str:
        """The recorded script (YAML); raises :class:`RecorderError` when nothing was recorded."""
        self._close_jog()
        if not self.steps:
            raise RecorderError("nothing was recorded (no goto, preset or jog between record/start and record/stop)")
        doc: dict[str, Any] = {"description": description}
        if name is not None:
            doc = {"name": name, **doc}
        total = sum(float(next(iter(s.values()))) for s in self.steps if "wait" in s)
        doc["timeout"] = float(min(3600.0, max(60.0, math.ceil(2 * (total + self._motion_time) + 30))))
        doc["steps"] = self.steps
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

    def _pause_until(self, now: float) -> None:
        gap = now - self._busy_until
        d = self.distance()
        travelled = None if d is None or self._dist_at is None else d - self._dist_at
        span = now - self._cmd_t  # the odometer was read at the command: the pause's share of the travel
        if travelled is not None and span > 1e-9:
            travelled *= max(0.0, gap) / span  # (constant ground speed assumed over one motion)
        if travelled is not None and travelled >= self.min_distance_m:
            self._append({"wait_for": {"distance": _r(travelled, 2)}})
        elif gap >= self.min_pause_s:
            self._append({"wait": _r(gap, 2)})
        self._busy_until, self._dist_at = max(self._busy_until, now), d

    def _add(self, step: dict[str, Any], duration_s: float, *, at: float | None = None) -> None:
        self._append(step)
        t = self.clock() if at is None else at
        self._cmd_t = t
        self._busy_until = t + max(0.0, float(duration_s))
        self._motion_time += max(0.0, float(duration_s))
        self._dist_at = self.distance()

    def _append(self, step: dict[str, Any]) -> None:
        if len(self.steps) >= MAX_STEPS:
            raise RecorderError(f"the recording has {MAX_STEPS} steps (allowed: at most {MAX_STEPS}); stop it")
        self.steps.append(step)


def recorder_for(motion: Any) -> ManeuverRecorder:
    """A recorder on a motion controller (or the core's proxy): its clock, pose and odometer."""
    return ManeuverRecorder(
        motion.clock,
        lambda: dict(zip(POSE_BOUNDS, map(float, motion.current_state().position), strict=True)),
        motion.distance_travelled,
    )


def maneuvers_using_preset(store: Any, preset: str) -> list[str]:
    """Names of the saved maneuvers with a ``preset`` step of that name (sorted)."""
    from bridge.service.maneuvers.steps import PresetStep

    out = []
    for summary in store.list_maneuvers():
        try:
            m = store.get_maneuver(summary.name)
        except ValueError:  # a row this program cannot parse (StoreError): it uses no preset we can tell
            continue
        if m is not None and any(isinstance(s, PresetStep) and s.name == preset for s in m.parsed.steps):
            out.append(m.name)
    return sorted(out)
