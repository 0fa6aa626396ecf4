"""The maneuver slot of the motion controller: at most one running maneuver.

Holds the :class:`~.maneuver_runner.ManeuverRunner` of the running maneuver with the id and
name the service gave it, forwards the control loop's ticks and tags the runner's events
(``maneuver_started``, ``maneuver_step``, ``maneuver_finished``, ``maneuver_aborted``) with
``maneuver_id`` for ``<prefix>/events``. Not thread-safe by itself: the controller's lock
guards it.
"""

from __future__ import annotations

from bridge.service.maneuvers.language import ValidationResult
from bridge.service.maneuvers.runner import Command, LoopState, ManeuverRunner

__all__ = ["ManeuverSlot"]


class ManeuverSlot:
    def __init__(self) -> None:
        self.runner: ManeuverRunner | None = None
        self.id: int | None = None
        self.name: str | None = None

    @property
    def running(self) -> bool:
        return self.runner is not None

    def start(self, validated: ValidationResult, name: str | None, maneuver_id: int) -> None:
        """Take a validated maneuver (the caller aborted the previous one)."""
        self.runner, self.id, self.name = ManeuverRunner(validated), maneuver_id, name

    def owns(self, runner: ManeuverRunner | None) -> bool:
        """Is ``runner`` still the running maneuver (not aborted or replaced meanwhile)?"""
        return runner is not None and runner is self.runner

    def abort(self, now: float, reason: str, message: str, events: list[dict]) -> None:
        """Abort the running maneuver (if any), appending its ``maneuver_aborted`` event."""
        if self.runner is not None:
            events.extend(self._tag(self.runner.abort(now, reason, message).events))
            self.runner = None

    def tick(self, now: float, loop: LoopState, distance_m: float | None, events: list[dict]) -> Command | None:
        """One control tick; the runner's command (None when nothing runs). After ``stop`` or
        ``done`` the slot is empty."""
        if self.runner is None:
            return None
        cmd = self.runner.step(now, loop, distance_m)
        events.extend(self._tag(cmd.events))
        if cmd.action in ("stop", "done"):
            self.runner = None
        return cmd

    def describe(self) -> dict | None:
        """``{"name", "motion_id", "step"}`` of the running maneuver for the state message."""
        if self.runner is None:
            return None
        return {"name": self.name, "motion_id": self.id, "step": self.runner.current_step}

    def _tag(self, events) -> list[dict]:
        return [{**e, "maneuver_id": self.id} for e in events]
