"""The maneuver slot of the motion controller: at most one running maneuver.

Holds the :class:`~bridge.service.maneuvers.runner.ManeuverRunner` of the running maneuver with
the id and name the service gave it, forwards the control loop's ticks and tags the runner's
events (``maneuver_started``, ``maneuver_step``, ``maneuver_finished``, ``maneuver_aborted``) with
``maneuver_id`` for ``<prefix>/events``; :class:`ManeuverProgress` is the state message's
``maneuver``. Not thread-safe by itself: the controller's lock guards it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from bridge.service.maneuvers.language import ValidationResult
from bridge.service.maneuvers.runner import AbortReason, Command, LoopState, ManeuverRunner

__all__ = ["ManeuverSlot", "ManeuverProgress"]


@dataclass(frozen=True)
class ManeuverProgress:
    """The running maneuver: its name, id (``motion_id``) and the script step in progress."""

    name: str | None
    motion_id: int | None
    step: int | None

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "motion_id": self.motion_id, "step": self.step}


class ManeuverSlot:
    """At most one running maneuver (see the module docstring)."""

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

    def abort(self, now: float, reason: AbortReason, message: str, events: list[dict[str, Any]]) -> None:
        """Abort the running maneuver (if any), appending its ``maneuver_aborted`` event."""
        if self.runner is not None:
            events.extend(self._tag(self.runner.abort(now, reason, message).events))
            self.runner = None

    def tick(
        self, now: float, loop: LoopState, distance_m: float | None, events: list[dict[str, Any]]
    ) -> Command | None:
        """One control tick; the runner's command (None when nothing runs). After ``stop`` or
        ``done`` the slot is empty."""
        if self.runner is None:
            return None
        cmd = self.runner.step(now, loop, distance_m)
        events.extend(self._tag(cmd.events))
        if cmd.action in ("stop", "done"):
            self.runner = None
        return cmd

    def progress(self) -> ManeuverProgress | None:
        """The running maneuver for the state message (None when none runs)."""
        if self.runner is None:
            return None
        return ManeuverProgress(self.name, self.id, self.runner.current_step)

    def _tag(self, events: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
        return [{**e, "maneuver_id": self.id} for e in events]
